"""mi_loop.io.files.staged_directory: a whole directory appears at once, or not at all."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from mi_loop.io.files import remove_stale_stages, staged_directory, write_text


def test_the_directory_appears_with_everything_written_in_the_stage(tmp_path):
    umask = os.umask(0o022)
    try:
        with staged_directory(tmp_path / "out") as stage:
            assert stage.parent == tmp_path and stage.name.startswith(".out.staging-")
            write_text(stage / "a.txt", "a")
            (stage / "sub").mkdir()
            write_text(stage / "sub" / "b.txt", "b")
            assert not (tmp_path / "out").exists()                 # nothing there before the end
    finally:
        os.umask(umask)
    assert sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*")) == [
        "out", "out/a.txt", "out/sub", "out/sub/b.txt"]
    assert (tmp_path / "out").stat().st_mode & 0o777 == 0o755       # not mkdtemp's 0700


def test_a_failure_leaves_no_directory_and_keeps_an_existing_one(tmp_path):
    with pytest.raises(OSError, match="disk full"), staged_directory(tmp_path / "new") as stage:
        write_text(stage / "half.txt", "half")
        raise OSError("disk full")
    assert list(tmp_path.iterdir()) == []

    write_text((tmp_path / "old").mkdir() or tmp_path / "old" / "kept.txt", "kept")
    with pytest.raises(KeyboardInterrupt), staged_directory(tmp_path / "old") as stage:
        write_text(stage / "new.txt", "new")
        raise KeyboardInterrupt
    assert [p.name for p in tmp_path.iterdir()] == ["old"]
    assert [p.name for p in (tmp_path / "old").iterdir()] == ["kept.txt"]


def test_success_replaces_an_existing_directory_whole(tmp_path):
    (tmp_path / "out").mkdir()
    write_text(tmp_path / "out" / "stale.txt", "from an interrupted run")
    with staged_directory(tmp_path / "out") as stage:
        write_text(stage / "fresh.txt", "fresh")
    assert [p.name for p in tmp_path.iterdir()] == ["out"]                       # the old one removed
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["fresh.txt"]


def test_a_file_in_the_way_is_an_error_and_stays(tmp_path):
    write_text(tmp_path / "out", "a file")
    with pytest.raises(OSError), staged_directory(tmp_path / "out") as stage:
        write_text(stage / "a.txt", "a")
    assert [p.name for p in tmp_path.iterdir()] == ["out"] and (tmp_path / "out").read_text() == "a file"


def test_remove_stale_stages_removes_only_the_stages_of_that_directory(tmp_path):
    for name in (".out.staging-x1", ".out.staging-x2", ".other.staging-x3", "out"):
        (tmp_path / name).mkdir()
    write_text(tmp_path / ".out.staging-x1" / "half.txt", "half")
    removed = remove_stale_stages(tmp_path / "out")
    assert [p.name for p in removed] == [".out.staging-x1", ".out.staging-x2"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [".other.staging-x3", "out"]


def test_a_failed_swap_puts_the_existing_directory_back(tmp_path, monkeypatch):
    (tmp_path / "out").mkdir()
    write_text(tmp_path / "out" / "kept.txt", "kept")
    replace, moved = os.replace, []

    def flaky(src, dst):                  # moving the old one aside works, moving the new one in does not
        moved.append(Path(src).name)
        if Path(src).name.startswith(".out.staging-"):
            raise OSError("device busy")
        replace(src, dst)

    monkeypatch.setattr(os, "replace", flaky)
    with pytest.raises(OSError, match="device busy"), staged_directory(tmp_path / "out") as stage:
        write_text(stage / "new.txt", "new")
    assert [p.name for p in tmp_path.iterdir()] == ["out"]
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["kept.txt"]
    # the new file, the old directory aside, the stage in (refused), the old directory back
    assert len(moved) == 4 and moved[1] == moved[3] == "out" and moved[2].startswith(".out.staging-")
