"""Shared pytest fixtures: the Mitsuba variant and paths inside the repository."""
from __future__ import annotations

from pathlib import Path

import pytest

import mi_loop

REPO = Path(__file__).resolve().parent.parent


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


def one_line_error(capsys, argv, status=1):
    """Run ``mi-loop`` with ``argv``; check the status and a single ``mi-loop: error:`` line; return it."""
    from mi_loop.cli import main

    code = main(argv)
    captured = capsys.readouterr()
    assert code == status, captured.err
    lines = [line for line in captured.err.splitlines() if not line.startswith("[mi-loop")]
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("mi-loop: error: ")
    assert "Traceback" not in captured.err
    return lines[0]
