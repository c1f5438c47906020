"""The rules of the optimisation loop (:mod:`mi_loop.fitting.loop`): seeds, refresh, convergence, failure.

- :class:`Seeds`: one tree of seeds (``numpy.random.SeedSequence``) keyed by
  stage, frame, purpose and iteration, so that no two samplers share a seed by
  construction;
- :class:`Refresh`: when the terms rebuild what depends on the iterate;
- :class:`Convergence`: when the loop stops, or halves its step and goes back
  to the best iterate;
- :class:`Failure`: how a non-finite energy is reported, and how often the
  loop may recover from one.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mi_loop.errors import FitError, fail

__all__ = ["Convergence", "Failure", "Refresh", "Seeds"]


class Seeds:
    """One tree of seeds: ``numpy.random.SeedSequence`` keyed by stage / frame / view / iteration.

    Parameters
    ----------
    seed : int
        The user's seed (``--seed``), >= 0.
    key : int, optional
        Path in the tree (e.g. the frame index), any number of them: :meth:`child` appends to it.

    Examples
    --------
    >>> Seeds(0).child(3).integer(7) == Seeds(0, 3).integer(7) != Seeds(0, 3).integer(8)
    True
    """

    def __init__(self, seed: int, *key: int):
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            fail("Seeds", "an integer seed >= 0", seed)
        self.seed, self.key = int(seed), tuple(int(k) for k in key)

    def child(self, *key: int) -> Seeds:
        """The sub-tree at ``key`` below this one."""
        return Seeds(self.seed, *self.key, *key)

    def sequence(self, *key: int) -> np.random.SeedSequence:
        """The ``SeedSequence`` at ``key`` below this node."""
        return np.random.SeedSequence(self.seed, spawn_key=self.key + tuple(int(k) for k in key))

    def integer(self, *key: int) -> int:
        """A 32-bit seed at ``key`` (a sampler's seed): distinct keys never share one by construction."""
        return int(self.sequence(*key).generate_state(1, np.uint32)[0])

    def generator(self, *key: int) -> np.random.Generator:
        """A NumPy generator at ``key``."""
        return np.random.default_rng(self.sequence(*key))


@dataclass
class Refresh:
    """When terms rebuild what depends on the iterate (neighbour lists, reference normals, weights).

    Attributes
    ----------
    every : int
        Every ``every`` iterations, the first included.
    move : float or None
        Also whenever a sample of ``probe`` moved by more than this (any
        coordinate) since the last refresh; None: never.
    probe : LimitOperator or None
        The samples ``move`` watches.
    """

    every: int = 20
    move: float | None = None
    probe: object = None

    def __post_init__(self):
        self._at = None       # the probe's samples at the last refresh (True when no movement is watched)

    def due(self, state) -> bool:
        """Whether the terms refresh in this iteration."""
        if state.it % self.every == 0 or self._at is None:
            return True
        if self.move is None:
            return False
        # the samples' host copy, shared through the state with the terms that refresh from it
        return bool(np.abs(state.host(self.probe) - self._at).max() > self.move)

    def done(self, state) -> None:
        """Remember where the terms refreshed."""
        self._at = state.host(self.probe) if self.move is not None else True


@dataclass
class Convergence:
    """The stopping and step-halving rule on the monitored value (the total energy, or one term's loss).

    Values are averaged over blocks of ``block`` iterations (1 for a
    deterministic energy; two sweeps of the photos for a noisy image loss). A
    block improves when its mean is below ``(1 - tolerance)`` times the best
    earlier block mean. After ``patience`` blocks without improvement the
    step halves and the iterate goes back to the best one; the loop stops at
    the next such plateau once it has halved ``halvings`` times, or when the
    best value improved by less than ``tolerance`` (relative) over the last
    ``window`` blocks. Neither happens before iteration ``start``.

    Attributes
    ----------
    tolerance : float
        Relative improvement; 0: the loop runs all its iterations.
    patience, halvings, window, block, start : int
    monitor : str or None
        The history key watched (None: the total energy).
    """

    tolerance: float = 0.0
    patience: int = 12
    halvings: int = 3
    window: int = 40
    block: int = 1
    start: int = 0
    monitor: str | None = None

    def __post_init__(self):
        self._values, self._blocks = [], []
        self._best, self._best_at, self.decays = math.inf, 0, 0

    def update(self, it: int, value: float) -> str:
        """``'go'``, ``'halve'`` or ``'stop'`` after the value of iteration ``it``."""
        if self.tolerance <= 0:
            return "go"
        self._values.append(value)
        if len(self._values) < self.block:
            return "go"
        mean = float(np.mean(self._values)) if self.block > 1 else self._values[0]
        self._values = []
        self._blocks.append(mean)
        k = len(self._blocks) - 1
        if mean < self._best * (1.0 - self.tolerance):
            self._best_at = k
        self._best = min(self._best, mean)
        if it + 1 < self.start:
            return "go"
        if k - self._best_at > self.patience:
            if self.decays >= self.halvings:
                return "stop"
            self.decays += 1
            self._best_at = k
            return "halve"
        w = self.window
        if w and k > w and self._blocks[-w - 1] > 0:
            old = min(self._blocks[:-w])
            if old - self._best < self.tolerance * old:
                return "stop"
        return "go"


@dataclass
class Failure:
    """How a non-finite energy is reported (and whether the loop may recover from it).

    Attributes
    ----------
    where : str
        The public function, for the message (``'fit'``, ``'fit_frame'``).
    context : str
        What is being fitted (``'frame 3, '``, ``'stage 1, '``), before ``iteration N``.
    recoveries : int
        How often a non-finite energy may restore the best iterate with a quarter
        of the step before the loop gives up.
    hint : str
        Appended to the message (what to try).
    """

    where: str = "optimise"
    context: str = ""
    recoveries: int = 0
    hint: str = ""

    def error(self, it: int, values: dict) -> FitError:
        bad = next(((k, v) for k, v in values.items() if not np.isfinite(v)), ("control points", "non-finite"))
        hint = f"; {self.hint}" if self.hint else ""
        return FitError(f"{self.where}(): expected a finite energy, got {bad[0]} {bad[1]} at {self.context}"
                        f"iteration {it} (the optimisation diverged{hint})")
