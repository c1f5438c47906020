"""Tests of mi_loop._llvm: finding libLLVM >= 16 and the one-line error otherwise."""
from __future__ import annotations

import subprocess
import sys
import types
from pathlib import Path

import pytest

from mi_loop import _llvm
from mi_loop._llvm import check_loaded_llvm, configure_llvm, find_libllvm, libllvm_version

from helpers import run_python

HINT = r"apt-get install libllvm19"


def touch(root, *relpaths):
    for rel in relpaths:
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"\x7fELF")


@pytest.mark.parametrize("path, expected", [
    ("/usr/lib/x86_64-linux-gnu/libLLVM-19.so", 19),
    ("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1", 15),
    ("/usr/lib/x86_64-linux-gnu/libLLVM-14.0.6.so.1", 14),
    ("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1", 19),
    ("/usr/lib/llvm-17/lib/libLLVM.so", 17),
    ("/usr/lib/llvm-17/lib/libLLVM-17.so.1", 17),
    ("/usr/lib/llvm-14/lib/libLLVMCore.a", None),
    ("/usr/lib/x86_64-linux-gnu/libLLVMSupport.so.19", None),
    ("/usr/lib/libLLVM.so", None),
])
def test_libllvm_version_parses_debian_names(path, expected):
    assert libllvm_version(path) == expected


def test_find_picks_highest_version(tmp_path):
    touch(tmp_path,
          "usr/lib/x86_64-linux-gnu/libLLVM-15.so.1",
          "usr/lib/x86_64-linux-gnu/libLLVM-15.so",
          "usr/lib/llvm-17/lib/libLLVM.so",
          "usr/lib/llvm-14/lib/libLLVMCore.a",
          "usr/lib/x86_64-linux-gnu/libLLVM-19.so",
          "usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")
    path, version = find_libllvm(str(tmp_path))
    assert version == 19
    assert path == str(tmp_path / "usr/lib/x86_64-linux-gnu/libLLVM-19.so")


def test_find_searches_aarch64_and_llvm_dirs(tmp_path):
    touch(tmp_path, "usr/lib/aarch64-linux-gnu/libLLVM-16.so.1", "usr/lib/llvm-18/lib/libLLVM-18.so")
    assert find_libllvm(str(tmp_path)) == (str(tmp_path / "usr/lib/llvm-18/lib/libLLVM-18.so"), 18)
    (tmp_path / "usr/lib/llvm-18/lib/libLLVM-18.so").unlink()
    assert find_libllvm(str(tmp_path)) == (str(tmp_path / "usr/lib/aarch64-linux-gnu/libLLVM-16.so.1"), 16)


def test_find_returns_none_on_empty_tree(tmp_path):
    touch(tmp_path, "usr/lib/x86_64-linux-gnu/libc.so.6")
    assert find_libllvm(str(tmp_path)) is None


def test_configure_sets_environment_to_newest(tmp_path):
    touch(tmp_path, "usr/lib/x86_64-linux-gnu/libLLVM-15.so.1", "usr/lib/x86_64-linux-gnu/libLLVM-19.so")
    env = {}
    path = configure_llvm(environ=env, modules={}, root=str(tmp_path))
    assert path == str(tmp_path / "usr/lib/x86_64-linux-gnu/libLLVM-19.so")
    assert env == {"DRJIT_LIBLLVM_PATH": path}


def test_configure_leaves_llvm_15_alone(tmp_path):
    """Only LLVM 15 and 14: nothing is set and nothing raised (``import mi_loop`` must not fail)."""
    touch(tmp_path, "usr/lib/x86_64-linux-gnu/libLLVM-15.so.1", "usr/lib/llvm-14/lib/libLLVM.so")
    env = {}
    assert configure_llvm(environ=env, modules={}, root=str(tmp_path)) is None
    assert env == {}


def test_configure_without_any_llvm_returns_none(tmp_path):
    env = {}
    assert configure_llvm(environ=env, modules={}, root=str(tmp_path)) is None
    assert env == {}


def test_configure_respects_user_setting(tmp_path):
    env = {"DRJIT_LIBLLVM_PATH": "/opt/llvm/libLLVM.so"}
    assert configure_llvm(environ=env, modules={}, root=str(tmp_path)) is None
    assert env == {"DRJIT_LIBLLVM_PATH": "/opt/llvm/libLLVM.so"}


def fake_drjit(version):
    detail = types.SimpleNamespace(llvm_version=lambda: version)
    return types.SimpleNamespace(detail=detail)


def test_configure_does_nothing_once_drjit_is_imported(tmp_path):
    touch(tmp_path, "usr/lib/x86_64-linux-gnu/libLLVM-19.so")
    env = {}
    assert configure_llvm(environ=env, modules={"drjit": fake_drjit((15, 0, 6))}, root=str(tmp_path)) is None
    assert env == {}


def test_check_rejects_a_loaded_llvm_15_with_one_line(tmp_path):
    touch(tmp_path, "usr/lib/x86_64-linux-gnu/libLLVM-19.so")
    with pytest.raises(RuntimeError, match=f"loaded LLVM 15; .*libLLVM-19.so would work: import mi_loop "
                                           f"before drjit and mitsuba.*{HINT}") as info:
        check_loaded_llvm(modules={"drjit": fake_drjit((15, 0, 6))}, environ={}, root=str(tmp_path))
    assert "\n" not in str(info.value)


def test_check_names_the_variable_and_a_missing_library(tmp_path):
    env = {"DRJIT_LIBLLVM_PATH": "/opt/none/libLLVM.so"}
    with pytest.raises(RuntimeError, match=f"no libLLVM loaded from DRJIT_LIBLLVM_PATH=/opt/none/libLLVM.so.*{HINT}"):
        check_loaded_llvm(modules={"drjit": fake_drjit((-1, -1, -1))}, environ=env, root=str(tmp_path))
    touch(tmp_path, "usr/lib/x86_64-linux-gnu/libLLVM-15.so")
    with pytest.raises(RuntimeError, match=f"loaded LLVM 14; newest found is LLVM 15: .*{HINT}"):
        check_loaded_llvm(modules={"drjit": fake_drjit((14, 0, 6))}, environ={}, root=str(tmp_path))


def test_check_accepts_llvm_19():
    assert check_loaded_llvm(modules={"drjit": fake_drjit((19, 1, 7))}, environ={}) == 19


def test_import_loads_neither_drjit_nor_mitsuba_and_limit_matrix_works_without_llvm():
    """With a libLLVM that cannot load, ``import mi_loop`` and the NumPy limit still work."""
    code = ("import sys, numpy as np, mi_loop\n"
            "from mi_loop import datasets, limit_matrix\n"
            "V, F = datasets.blob()\n"
            "W = limit_matrix(F, len(V), np.array([0, 1]), np.array([[0.2, 0.3], [0.1, 0.1]]))\n"
            "print(W.shape, 'drjit' in sys.modules, 'mitsuba' in sys.modules)")
    result = run_python(code, timeout=120, DRJIT_LIBLLVM_PATH="/nonexistent/libLLVM.so")
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["(2,", "42)", "False", "False"]


@pytest.mark.skipif(not Path("/usr/lib/x86_64-linux-gnu/libLLVM-15.so").exists(),
                    reason="needs Debian's libLLVM 15 (present on Debian 12 machines)")
def test_set_variant_with_llvm_15_stops_with_one_line_instead_of_crashing():
    code = ("import mi_loop\n"
            "try:\n    mi_loop.set_variant('llvm_ad_rgb')\n"
            "except RuntimeError as exc:\n    print('refused:', exc)\n")
    result = run_python(code, timeout=120, DRJIT_LIBLLVM_PATH="/usr/lib/x86_64-linux-gnu/libLLVM-15.so")
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("refused: mi_loop needs libLLVM >= 16")
    assert "loaded LLVM 15" in result.stdout and "apt-get install libllvm19" in result.stdout
    assert "LLVM ERROR" not in result.stderr


def test_loaded_llvm_is_new_enough():
    import drjit as dr

    assert dr.detail.llvm_version()[0] >= _llvm.MIN_LLVM_VERSION


def test_script_mode_reports_usable_llvm():
    """setup.sh runs the module as a script with the system python3 (no venv needed)."""
    result = subprocess.run([sys.executable, _llvm.__file__], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.startswith("libLLVM: /")
