"""Helpers shared by the tests: paths, test meshes and point clouds, Dr.Jit conversions, CLI checks."""
from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
#: The shared real test data (scans, meshes, sequences), beside the repository.
DATA = REPO.parent / "shared" / "data"


def one_line_error(capsys, argv, status=1):
    """Run ``mi-loop`` with ``argv``; check the status and a single ``mi-loop: error:`` line; return it."""
    from mi_loop.app.cli import main

    code = main(argv)
    captured = capsys.readouterr()
    assert code == status, captured.err
    lines = [line for line in captured.err.splitlines() if not line.startswith("[mi-loop")]
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("mi-loop: error: ")
    assert "Traceback" not in captured.err
    return lines[0]
