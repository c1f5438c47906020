"""Choosing the Mitsuba variant (mi_loop.render.variant): JIT AD variants only, CUDA only with a GPU."""
from __future__ import annotations

import mitsuba as mi
import pytest

import mi_loop


def test_set_variant_rejects_non_ad_variant():
    with pytest.raises(ValueError, match=r"set_variant\(\): expected one of .*llvm_ad_rgb.*got 'scalar_rgb'"):
        mi_loop.set_variant("scalar_rgb")
    assert mi.variant() == "llvm_ad_rgb"


def test_set_variant_without_a_gpu_refuses_cuda_with_one_line():
    from mi_loop.render.variant import cuda_available

    if cuda_available():          # on a GPU machine the CUDA variants run (see jit_variant); nothing to refuse
        mi_loop.set_variant("cuda_ad_rgb")
        assert mi.variant() == "cuda_ad_rgb"
        mi_loop.set_variant("llvm_ad_rgb")
        return
    with pytest.raises(RuntimeError, match=r"set_variant\(\): expected a CUDA device for 'cuda_ad_rgb', got none "
                                           r"\(Dr.Jit found no CUDA driver or GPU\); use an llvm_ad_\* variant"):
        mi_loop.set_variant("cuda_ad_rgb")
    assert mi.variant() == "llvm_ad_rgb"
