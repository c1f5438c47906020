"""Every fitting test runs once per JIT variant this machine has (``llvm_ad_rgb``; ``cuda_ad_rgb`` with a GPU)."""
from __future__ import annotations

import pytest


@pytest.fixture(autouse=True)
def on_every_variant(jit_variant) -> str:
    """The variant under test, set for the test (see ``jit_variant`` in tests/conftest.py)."""
    return jit_variant
