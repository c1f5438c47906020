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


def pytest_generate_tests(metafunc):
    """Tests taking ``jit_variant`` run once per variant this machine can run (as Mitsuba's conftest).

    ``llvm_ad_rgb`` everywhere, ``cuda_ad_rgb`` where Dr.Jit finds a GPU: on a
    machine without one the CUDA case is not generated at all (not skipped).
    """
    if "jit_variant" in metafunc.fixturenames:
        metafunc.parametrize("jit_variant", _usable_variants(), indirect=True)


@functools.cache
def _usable_variants() -> list:
    from mi_loop.render.variant import usable_variants

    return usable_variants()


@pytest.fixture
def jit_variant(request):
    """Switch to the variant under test for one test, then back to ``llvm_ad_rgb``."""
    mi_loop.set_variant(request.param)
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
