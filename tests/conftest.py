"""Shared pytest fixtures: the Mitsuba variant and paths inside the repository."""
from __future__ import annotations

from pathlib import Path

import pytest

import mi_loop

from helpers import REPO


@pytest.fixture(scope="session", autouse=True)
def variant() -> str:
    """Set the ``llvm_ad_rgb`` variant (and register ``loop_subdiv``) once per session."""
    mi_loop.set_variant("llvm_ad_rgb")
    return "llvm_ad_rgb"


@pytest.fixture(scope="session")
def repo() -> Path:
    """Root of the repository."""
    return REPO


@pytest.fixture(scope="session")
def scenes_dir() -> Path:
    """The repository's ``scenes/`` folder."""
    return REPO / "scenes"
