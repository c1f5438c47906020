"""The option classes (mi_loop.fitting.options): every nonsense value refused with its message."""
from __future__ import annotations

import pytest

from mi_loop.fitting.options import SequenceOptions


def test_sequence_options_reject_nonsense():
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected views_per_iteration to be an integer "
                                         r"in \[1, views=4\], got 5$"):
        SequenceOptions(views=4, views_per_iteration=5)
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected loss to be one of \('l1', 'l2'\), "
                                         r"got 'l3'$"):
        SequenceOptions(loss="l3")
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected mode to be one of"):
        SequenceOptions(mode="depth")
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected seen to be a number in \[0, 1\], "
                                         r"got 1.5$"):
        SequenceOptions(seen=1.5)
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected reach to be an integer in 0..10, "
                                         r"got 11$"):
        SequenceOptions(reach=11)
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected image_every to be an integer >= 1, "
                                         r"got 0$"):
        SequenceOptions(image_every=0)
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected geometric or image to be True "
                                         r"\(both terms are off: nothing to fit\), got False$"):
        SequenceOptions(geometric=False, image=False)
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected deterministic to be True or False, "
                                         r"got 'yes'$"):
        SequenceOptions(deterministic="yes")
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected level to be an integer in 0\.\.6, "
                                         r"got 7$"):
        SequenceOptions(level=7)
    with pytest.raises(ValueError, match=r"^SequenceOptions\(\): expected every key to be one of the fields "
                                         r"\[.*\], got \['colour'\]$"):
        SequenceOptions.from_dict({"colour": "red"})
    assert SequenceOptions.from_dict({"alpha": 0.5}) == SequenceOptions(alpha=0.5)   # older files: defaults
    assert SequenceOptions.from_dict({"alpha": 0.5, "joint_iterations": 8}) == SequenceOptions(alpha=0.5)  # retired
