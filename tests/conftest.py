"""Shared pytest fixtures: the Mitsuba variant and paths inside the repository."""
from __future__ import annotations

import functools
from pathlib import Path

import pytest

import mi_loop

from helpers import REPO


@pytest.fixture(scope="session", autouse=True)
def variant() -> str:
    """Set the ``llvm_ad_rgb`` variant (and register ``loop_subdiv``) once per session."""
    mi_loop.set_variant("llvm_ad_rgb")
    return "llvm_ad_rgb"


#: Test directories whose every test runs on every variant present (the fitting and application tests).
EVERY_VARIANT = ("fitting", "app")


def pytest_generate_tests(metafunc):
    """Tests taking ``jit_variant``, and every test of :data:`EVERY_VARIANT`, run once per variant this
    machine can run (as Mitsuba's conftest does with ``variants_all_ad_rgb``).

    ``llvm_ad_rgb`` everywhere, ``cuda_ad_rgb`` where Dr.Jit finds a GPU: on a
    machine without one the CUDA case is not generated at all (not skipped).
    """
    if metafunc.definition.path.parent.name in EVERY_VARIANT and "jit_variant" not in metafunc.fixturenames:
        metafunc.fixturenames.append("jit_variant")
    if "jit_variant" in metafunc.fixturenames:
        metafunc.parametrize("jit_variant", _usable_variants(), indirect=True)


@functools.cache
def _usable_variants() -> list:
    from mi_loop.render.variant import usable_variants

    return usable_variants()


@pytest.fixture
def jit_variant(request, monkeypatch):
    """Switch to the variant under test for one test, then back to ``llvm_ad_rgb``.

    The commands a test runs (in process or as subprocesses) take it too, from
    ``MI_LOOP_VARIANT``: the command line's default ``--variant``.
    """
    from mi_loop.render.variant import VARIANT_ENV

    mi_loop.set_variant(request.param)
    monkeypatch.setenv(VARIANT_ENV, request.param)
    yield request.param
    mi_loop.set_variant("llvm_ad_rgb")


@pytest.fixture(scope="session")
def repo() -> Path:
    """Root of the repository."""
    return REPO


@pytest.fixture(scope="session")
def scenes_dir() -> Path:
    """The repository's ``scenes/`` folder."""
    return REPO / "scenes"
