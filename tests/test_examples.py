"""The examples run as a user runs them (subprocesses from the repository root) and do what they say."""
from __future__ import annotations

import os
import re
import subprocess
import sys

import numpy as np
import pytest
from matplotlib.image import imread

from helpers import REPO


def run_example(name: str, out) -> str:
    env = {**os.environ, "MI_LOOP_EXAMPLES_OUT": str(out)}
    done = subprocess.run([sys.executable, str(REPO / "examples" / name)], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


def test_example_01_renders_a_blue_surface_on_a_grey_background(tmp_path):
    stdout = run_example("01_render_limit_surface.py", tmp_path)
    assert str(tmp_path / "01_blob.png") in stdout
    rgb = imread(tmp_path / "01_blob.png")[..., :3]                  # PNG -> floats in [0, 1]
    blue = rgb[..., 2] - rgb[..., 0] > 0.1                           # the diffuse blue blob
    assert 0.1 < blue.mean() < 0.9
    border = np.concatenate([rgb[:4].reshape(-1, 3), rgb[-4:].reshape(-1, 3)])
    assert np.ptp(border, axis=1).max() < 0.02                       # grey: R = G = B
    assert not blue[:4].any() and blue[rgb.shape[0] // 2].any()      # framed: centred, not clipped


@pytest.mark.slow
def test_example_02_brings_the_limit_surface_closer_to_the_target(tmp_path):
    stdout = run_example("02_optimise_from_images.py", tmp_path)
    before, after = map(float, re.search(r"surfaces: ([\d.]+) -> ([\d.]+)", stdout).groups())
    assert after < 0.5 * before                          # the README quotes 0.081 -> 0.033
    rows = imread(tmp_path / "02_before_after.png")
    assert rows.shape[0] == 3 * 64                       # target, start, result


def test_example_03_imports_and_defines_its_entry_point():
    """Example 03 takes about two minutes; here only that it still imports against the package."""
    source = (REPO / "examples" / "03_fit_images.py").read_text()
    path = REPO / "examples" / "03_fit_images.py"
    code = compile(source, str(path), "exec")
    namespace = {"__name__": "not_main", "__file__": str(path)}
    exec(code, namespace)
    assert callable(namespace.get("main"))
