"""Every application test runs once per JIT variant this machine has (``llvm_ad_rgb``; ``cuda_ad_rgb`` with a GPU).

The commands the tests run (in process or as subprocesses) take the variant
from ``MI_LOOP_VARIANT``, the command line's default ``--variant``.
"""
from __future__ import annotations

import pytest

from mi_loop.render.variant import VARIANT_ENV


@pytest.fixture(autouse=True)
def on_every_variant(jit_variant, monkeypatch) -> str:
    """The variant under test, set for the test and as the commands' default."""
    monkeypatch.setenv(VARIANT_ENV, jit_variant)
    return jit_variant
