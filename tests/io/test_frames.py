"""Frame sequences (mi_loop.io.frames.read_frames): NPZ sequences, directories, patterns, clear errors."""
from __future__ import annotations

import numpy as np

from mi_loop import datasets, io

from helpers import DATA, value_error

#: What an NPZ sequence must hold, as the messages say it.
WANT = "arrays 'vertices' (T, V, 3) and 'faces' (F, 3), or 'points' (T, N, 3)"


def error(inputs) -> str:
    """The one-line message of ``read_frames(inputs)``, after ``read_frames(): ``."""
    return value_error(io.read_frames, inputs, function="read_frames")


def test_npz_sequence(tmp_path):
    V, F = datasets.blob()
    np.savez(tmp_path / "seq.npz", vertices=np.stack([V, 2 * V, 3 * V]).astype(np.float32), faces=F)
    frames = io.read_frames([tmp_path / "seq.npz"])
    assert len(frames) == 3
    frame = frames[2]()
    assert frame.name == "seq[2]" and frame.normals is None
    np.testing.assert_array_equal(frame.vertices, (3 * V).astype(np.float32))
    np.testing.assert_array_equal(frame.faces, F)


def test_shared_npz_sequence():
    frames = io.read_frames([DATA / "sequences" / "fox_walk_24f.npz"])
    frame = frames[23]()
    assert len(frames) == 24 and frame.name == "fox_walk_24f[23]"
    assert frame.vertices.shape == (290, 3) and frame.faces.shape == (576, 3)


def test_an_npz_of_one_cloud_is_one_frame_and_of_clouds_in_correspondence_a_sequence(tmp_path):
    """D-FAUST's frames (points (N, 3), loc, scale) are single clouds; points (T, N, 3) are frames whose
    point k is the same material point in every frame."""
    P = np.random.default_rng(0).normal(size=(50, 3))
    np.savez(tmp_path / "cloud.npz", points=P.astype(np.float16), loc=np.array([1.0, 2.0, 3.0]), scale=np.array(2.0))
    frames = io.read_frames([tmp_path / "cloud.npz"])
    assert len(frames) == 1 and not frames[0].correspondence
    np.testing.assert_allclose(frames[0]().vertices, P.astype(np.float16) * 2.0 + [1, 2, 3])
    np.savez(tmp_path / "clouds.npz", points=np.stack([P, P + 1.0]))
    frames = io.read_frames([tmp_path / "clouds.npz"])
    assert len(frames) == 2 and all(f.correspondence for f in frames)
    frame = frames[1]()
    assert frame.name == "clouds[1]" and frame.faces is None
    np.testing.assert_array_equal(frame.vertices, P + 1.0)
    np.savez(tmp_path / "two.npz", points=np.zeros((3, 2, 3)))
    assert error([tmp_path / "two.npz"]) == (
        f"expected 'points' of shape (T, N, 3) with T > 0 and N >= 3 in '{tmp_path / 'two.npz'}', "
        "got points of shape (3, 2, 3)")
    np.savez(tmp_path / "nan.npz", points=np.full((2, 4, 3), np.nan))
    assert error([tmp_path / "nan.npz"]) == f"expected finite points in '{tmp_path / 'nan.npz'}', got 8 non-finite"


def test_npz_without_the_sequence_arrays(tmp_path):
    np.savez(tmp_path / "novert.npz", faces=np.zeros((1, 3), int))
    assert error([tmp_path / "novert.npz"]) == (
        f"expected {WANT} in '{tmp_path / 'novert.npz'}', got arrays ['faces']")
    np.savez(tmp_path / "flat.npz", vertices=np.zeros((4, 3)), faces=np.zeros((1, 3), int))
    assert error([tmp_path / "flat.npz"]) == (
        f"expected {WANT} in '{tmp_path / 'flat.npz'}', with T > 0, "
        "got vertices of shape (4, 3)")
    np.savez(tmp_path / "quads.npz", vertices=np.zeros((2, 4, 3)), faces=np.zeros((1, 4), int))
    assert error([tmp_path / "quads.npz"]) == (
        f"expected {WANT} in '{tmp_path / 'quads.npz'}', "
        "got faces of shape (1, 4) and dtype int64")
    (tmp_path / "bad.npz").write_bytes(b"not a zip file")
    assert error([tmp_path / "bad.npz"]).startswith(f"expected a readable NPZ file '{tmp_path / 'bad.npz'}', got ")


def test_directory_takes_only_mesh_and_point_files(tmp_path):
    """readme.txt, notes, images, hidden and AppleDouble files are not frames; order is by name."""
    V, F = datasets.blob()
    io.write_ply(tmp_path / "f_01.ply", V, F)
    io.write_ply(tmp_path / "f_00.ply", 2 * V, F)
    np.savetxt(tmp_path / "f_02.xyz", V)
    for junk in ("readme.txt", "notes.md", "preview.png", ".DS_Store", "._f_00.ply", ".hidden.xyz"):
        (tmp_path / junk).write_bytes(b"not a frame\n")
    (tmp_path / "sub.ply").mkdir()                      # a directory with a frame suffix is not a frame either
    frames = io.read_frames([tmp_path])
    assert [frame().name for frame in frames] == ["f_00.ply", "f_01.ply", "f_02.xyz"]
    cloud = frames[2]()
    assert cloud.faces is None and cloud.normals is None
    np.testing.assert_allclose(cloud.vertices, V)
    np.testing.assert_array_equal(frames[0]().vertices, 2 * V)


def test_text_frames_given_by_name_or_pattern(tmp_path):
    """A .txt point cloud is a frame when named explicitly or matched by a glob pattern."""
    V, _ = datasets.blob()
    np.savetxt(tmp_path / "scan_0.txt", V)
    np.savetxt(tmp_path / "scan_1.txt", 2 * V)
    frames = io.read_frames([tmp_path / "scan_1.txt"])
    np.testing.assert_allclose(frames[0]().vertices, 2 * V)
    frames = io.read_frames([str(tmp_path / "scan_*.txt")])
    assert [frame().name for frame in frames] == ["scan_0.txt", "scan_1.txt"]


def test_mixed_frame_kinds(tmp_path):
    V, F = datasets.blob()
    io.write_ply(tmp_path / "a.ply", V, F)
    (tmp_path / "b.obj").write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in V.tolist())
                                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F.tolist()))
    P = V + 0.01
    np.savez(tmp_path / "c.npz", points=P, normals=V)
    frames = io.read_frames([tmp_path / "a.ply", tmp_path / "b.obj", tmp_path / "c.npz"])
    kinds = [(f.name, f.faces is None, f.normals is None) for f in (frame() for frame in frames)]
    assert kinds == [("a.ply", False, True), ("b.obj", False, True), ("c.npz", True, False)]
    np.testing.assert_array_equal(frames[1]().faces, F)
    np.testing.assert_allclose(frames[2]().normals, V / np.linalg.norm(V, axis=1, keepdims=True))   # its own, unit


def test_missing_inputs_named(tmp_path):
    assert error([tmp_path / "nope"]) == ("expected an existing file, directory or glob pattern, "
                                          f"got '{tmp_path / 'nope'}': no such file or directory")
    assert error([str(tmp_path / "f_*.ply")]) == ("expected frame files matching the pattern, "
                                                  f"got none for '{tmp_path / 'f_*.ply'}'")
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "readme.txt").write_text("frames go here")
    assert error([tmp_path / "empty"]) == f"expected at least one frame file, got none in ['{tmp_path / 'empty'}']"
