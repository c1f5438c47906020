"""Tests of mi_loop._llvm: finding libLLVM >= 16 and the one-line error otherwise."""
from __future__ import annotations

import subprocess
import sys
import types

import pytest

from mi_loop import _llvm
from mi_loop._llvm import configure_llvm, find_libllvm, libllvm_version

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


def test_configure_rejects_llvm_15_with_one_line(tmp_path):
    touch(tmp_path, "usr/lib/x86_64-linux-gnu/libLLVM-15.so.1", "usr/lib/llvm-14/lib/libLLVM.so")
    env = {}
    with pytest.raises(RuntimeError, match=HINT) as info:
        configure_llvm(environ=env, modules={}, root=str(tmp_path))
    assert "\n" not in str(info.value)
    assert "LLVM 15" in str(info.value)
    assert env == {}


def test_configure_rejects_missing_llvm(tmp_path):
    with pytest.raises(RuntimeError, match=f"no libLLVM found.*{HINT}"):
        configure_llvm(environ={}, modules={}, root=str(tmp_path))


def test_configure_respects_user_setting(tmp_path):
    env = {"DRJIT_LIBLLVM_PATH": "/opt/llvm/libLLVM.so"}
    assert configure_llvm(environ=env, modules={}, root=str(tmp_path)) is None
    assert env == {"DRJIT_LIBLLVM_PATH": "/opt/llvm/libLLVM.so"}


def fake_drjit(version):
    detail = types.SimpleNamespace(llvm_version=lambda: version)
    return types.SimpleNamespace(detail=detail)


def test_configure_checks_already_imported_drjit(tmp_path):
    touch(tmp_path, "usr/lib/x86_64-linux-gnu/libLLVM-19.so")
    env = {}
    with pytest.raises(RuntimeError, match=f"loaded LLVM 15.*{HINT}"):
        configure_llvm(environ=env, modules={"drjit": fake_drjit((15, 0, 6))}, root=str(tmp_path))
    with pytest.raises(RuntimeError, match=f"no libLLVM loaded.*{HINT}"):
        configure_llvm(environ=env, modules={"drjit": fake_drjit((-1, -1, -1))}, root=str(tmp_path))
    assert configure_llvm(environ=env, modules={"drjit": fake_drjit((19, 1, 7))}, root=str(tmp_path)) is None
    assert env == {}


def test_loaded_llvm_is_new_enough():
    import drjit as dr

    assert dr.detail.llvm_version()[0] >= _llvm.MIN_LLVM_VERSION


def test_script_mode_reports_usable_llvm():
    """setup.sh runs the module as a script with the system python3 (no venv needed)."""
    result = subprocess.run([sys.executable, _llvm.__file__], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.startswith("libLLVM: /")
