"""README checks: the quick start is two commands that CI runs, and the Python snippets run."""
from __future__ import annotations

import re

import pytest

from helpers import REPO

README = (REPO / "README.md").read_text()
FENCE = re.compile(r"```(\w*)\n(.*?)```", re.S)


def section(title: str) -> str:
    """The body of the README's ``## title`` section."""
    match = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", README, re.S | re.M)
    assert match, f"README has no '## {title}' section"
    return match.group(1)


def commands(block: str) -> list[str]:
    """The non-blank, non-comment lines of a shell block, stripped."""
    return [line.strip() for line in block.splitlines() if line.strip() and not line.strip().startswith("#")]


def test_quick_start_is_one_block_of_two_commands():
    blocks = FENCE.findall(section("Quick start"))
    assert len(blocks) == 1
    main_job, tests = commands(blocks[0][1])             # exactly two commands
    assert "mi-loop fit --demo" in main_job and "pytest" in tests
    assert "/work/shared" not in main_job


def test_ci_runs_the_readme_test_command_then_ruff():
    """.ci/run runs the README's test command exactly as written, then the linter."""
    _, tests = commands(FENCE.findall(section("Quick start"))[0][1])
    ci = (REPO / ".ci" / "run").read_text()
    assert commands(ci)[-2:] == [tests, ".venv/bin/ruff check ."]


PYTHON_SNIPPETS = [code for lang, code in FENCE.findall(README) if lang == "python"]


@pytest.mark.parametrize("code", PYTHON_SNIPPETS, ids=[f"snippet{i}" for i in range(len(PYTHON_SNIPPETS))])
def test_python_snippet_runs(code, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "readme"}
    exec(compile(code, "README.md", "exec"), namespace)   # asserts inside the snippet must hold
    assert len(namespace) > 1


def test_readme_has_python_snippets():
    assert PYTHON_SNIPPETS
