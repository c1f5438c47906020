"""Bake a glTF 2.0 animation (skinned or node-animated meshes) into a sequence of meshes in correspondence.

The file is read by :class:`mi_loop.io.gltf.GltfFile` (GLB, or ``.gltf``
JSON with embedded or relative buffers) and posed in NumPy as the glTF 2.0
specification says: node TRS or matrix transforms, animation channels with
LINEAR (quaternions by slerp), STEP and CUBICSPLINE (Hermite) interpolation,
linear-blend skinning with ``JOINTS_n`` / ``WEIGHTS_n`` and the skin's
inverse bind matrices, and morph targets (``POSITION`` deltas weighted by the
animated ``weights``, else the node's or the mesh's default weights, applied
before skinning: the form :func:`mi_loop.io.glb.write_glb_sequence` writes).
Every mesh node of the scene is posed (skinned ones by their joints, whose
space they live in; the others by their node's global transform) and all
their primitives are concatenated, so vertex ``i`` is the same material point
in every frame. Sparse accessors are not supported.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mi_loop.errors import fail
from mi_loop.io.gltf import GltfFile, base_colors

__all__ = ["BakedAnimation", "animation_names", "bake_animation"]

_EPS_T = 1e-6      # seconds: a frame this close past the last keyframe is kept (key times are float32)


@dataclass(frozen=True)
class BakedAnimation:
    """Frames of one glTF animation as meshes with one connectivity.

    Parameters
    ----------
    names : list of str
        One name per frame, ``'Fox.glb[Walk#3@0.125s]'``.
    vertices : (T, V, 3) float64 numpy array
        Posed vertex positions of every frame, in the scene's (world) frame.
    faces : (F, 3) int64 numpy array
        Triangles, the same in every frame.
    times : (T,) float64 numpy array
        Sample time of every frame, in seconds from the animation's start.
    animation : str
        Name of the baked animation.
    fps : float
        Frames per second between consecutive samples.
    colors : (V, 3) float64 numpy array or None
        Linear RGB base colour in [0, 1] per vertex, or None when the meshes
        have no material colour, texture or ``COLOR_0``.
    """

    names: list
    vertices: np.ndarray
    faces: np.ndarray
    times: np.ndarray
    animation: str
    fps: float
    colors: np.ndarray | None


def animation_names(path) -> list[str]:
    """List the animations of a glTF file, in file order.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.glb`` or ``.gltf`` file.

    Returns
    -------
    list of str
        Their names; an unnamed animation ``k`` is called ``'animation_k'``.

    Raises
    ------
    ValueError
        Missing file, a file that is not glTF 2.0.
    """
    return _names(GltfFile(path, "animation_names").doc)


def bake_animation(path, animation: str | None = None, fps: float = 24.0, frames: int | None = None,
                   weld: bool = True) -> BakedAnimation:
    """Sample an animation of a glTF file as posed meshes with one connectivity.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.glb`` or ``.gltf`` file with at least one mesh and one animation.
    animation : str, optional
        Name of the animation (see :func:`animation_names`); default the first.
    fps : float, optional
        Frames are taken at ``t = k / fps``, ``k = 0, 1, ...`` while ``t`` does
        not pass the duration (the largest keyframe time of the animation;
        1 microsecond of slack, as key times are float32): ``floor(duration
        fps) + 1`` frames, the start included.
    frames : int, optional
        Instead of ``fps``: this many frames evenly spaced over ``[0, duration)``,
        ``t = k duration / frames`` (one period of a looping clip, whose last
        keyframe repeats its first; ``fps`` is then ``frames / duration``).
    weld : bool, optional
        Merge the vertices of a mesh node at identical rest positions (glTF
        splits them at UV seams), keeping the order of first appearance and
        dropping triangles that collapse; colours are averaged over merged
        vertices. ``False`` keeps the file's vertices as they are.

    Returns
    -------
    BakedAnimation

    Raises
    ------
    ValueError
        Missing file, not a glTF 2.0 file, no animations, an unknown animation
        name (the message lists the file's), ``fps`` not finite and positive,
        ``frames < 1``, no mesh in the scene, a primitive that is not
        triangles, a vertex whose skin weights do not sum to a positive value,
        a malformed file.
    TypeError
        ``animation`` not a string, ``fps`` not a number, ``frames`` not an integer.

    Notes
    -----
    A skinned vertex at rest position :math:`p` is placed at
    :math:`\\sum_i w_i \\, G_{j_i} B_{j_i} p` (weights normalised to sum 1),
    :math:`G_j` the global transform of joint :math:`j` at time :math:`t` and
    :math:`B_j` its inverse bind matrix; the mesh node's own transform is
    ignored (glTF 2.0, section 3.7.3). Times before the first or after the
    last keyframe take the first or last value.

    ``frames=24`` on the Fox's ``'Walk'`` reproduces the shared
    ``fox_walk_24f.npz`` (welded, in another vertex order).

    References
    ----------
    The Khronos Group, *glTF 2.0 Specification*, sections 3.5 (nodes), 3.7.3
    (skins), 3.11 (animations) and appendix C (interpolation).
    """
    func = "bake_animation"
    if animation is not None and not isinstance(animation, str):
        fail(func, "an animation name (str) or None", f"{type(animation).__name__} {animation!r}", TypeError)
    if isinstance(fps, bool) or not isinstance(fps, (int, float, np.integer, np.floating)):
        fail(func, "fps as a number", f"{type(fps).__name__} {fps!r}", TypeError)
    if not (np.isfinite(fps) and fps > 0):
        fail(func, "fps finite and > 0", float(fps))
    if frames is not None:
        if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)):
            fail(func, "frames as an int or None", f"{type(frames).__name__} {frames!r}", TypeError)
        if frames < 1:
            fail(func, "frames >= 1", int(frames))
    gltf = GltfFile(path, func)
    try:
        return _bake(gltf, animation, float(fps), frames, bool(weld))
    except (KeyError, IndexError, TypeError, ValueError, OSError) as exc:   # OSError: a missing .bin, a bad image
        if isinstance(exc, ValueError) and str(exc).startswith(f"{func}():"):
            raise
        fail(func, f"a valid glTF 2.0 file '{gltf.path}'", f"{type(exc).__name__}: {exc}")


def _names(doc: dict) -> list:
    return [a.get("name") or f"animation_{k}" for k, a in enumerate(doc.get("animations", []))]


def _bake(gltf: GltfFile, animation, fps: float, frames, weld: bool) -> BakedAnimation:
    func, path, doc = gltf.func, gltf.path, gltf.doc
    names = _names(doc)
    if not names:
        fail(func, f"an animation in '{path}'", "none (the file has no 'animations')")
    if animation is None:
        animation = names[0]
    if animation not in names:
        fail(func, f"an animation named one of {names} in '{path}'", repr(animation))
    clip = doc["animations"][names.index(animation)]
    duration = max(float(gltf.accessor(s["input"]).max()) for s in clip["samplers"])
    if frames is None:
        times = np.arange(int(np.floor((duration + _EPS_T) * fps)) + 1) / fps
    else:
        if frames > 1 and duration <= 0:
            fail(func, f"an animation longer than 0 s for frames = {frames}", f"'{animation}', one pose at t = 0")
        fps = frames / duration if frames > 1 else fps
        times = np.arange(int(frames)) * (duration / frames)
    instances = _mesh_nodes(doc)
    if not instances:
        fail(func, f"a mesh in the scene of '{path}'", "no node with a mesh")
    G = _global_transforms(gltf, _local_transforms(gltf, clip, times))
    Vs, F, C, keys, offset = [], [], [], [], 0
    for n, node in enumerate(instances):
        weights = _morph_weights(gltf, clip, times, node)
        for prim in doc["meshes"][doc["nodes"][node]["mesh"]]["primitives"]:
            X, P, Fp, Cp = _posed_primitive(gltf, node, prim, G, weights)
            Vs.append(X)
            F.append(Fp + offset)
            C.append(Cp)
            keys.append(np.c_[np.full(len(P), n), P])     # welding merges within one mesh node only
            offset += len(P)
    has_color = any(c is not None for c in C)
    C = np.concatenate([np.ones((X.shape[1], 3)) if c is None else c for X, c in zip(Vs, C)])
    Vs, F = np.concatenate(Vs, axis=1), np.concatenate(F)
    if weld:
        Vs, F, C = _weld(Vs, F, C, np.concatenate(keys))
    labels = [f"{path.name}[{animation}#{k}@{t:.3f}s]" for k, t in enumerate(times)]
    return BakedAnimation(labels, Vs, F.astype(np.int64), times, animation, float(fps),
                          C if has_color else None)


def _local_transforms(gltf: GltfFile, clip: dict, times) -> np.ndarray:
    """``(T, N, 4, 4)`` local matrices of all nodes at ``times``: rest TRS, animated channels substituted."""
    nodes = gltf.doc.get("nodes", [])
    T, N = len(times), len(nodes)
    trs = {"translation": np.zeros((T, N, 3)), "rotation": np.tile([0.0, 0.0, 0.0, 1.0], (T, N, 1)),
           "scale": np.ones((T, N, 3))}
    for n, node in enumerate(nodes):
        for key, value in trs.items():
            if key in node:
                value[:, n] = node[key]
    for channel in clip["channels"]:
        target = channel["target"]
        if target.get("path") not in trs or "node" not in target:     # morph weights, extensions
            continue
        s = clip["samplers"][channel["sampler"]]
        trs[target["path"]][:, target["node"]] = _sample(
            gltf, gltf.accessor(s["input"])[:, 0], gltf.accessor(s["output"]), times,
            s.get("interpolation", "LINEAR"), target["path"] == "rotation")
    L = np.zeros((T, N, 4, 4))
    L[..., :3, :3] = _quat_matrix(trs["rotation"]) * trs["scale"][..., None, :]
    L[..., :3, 3] = trs["translation"]
    L[..., 3, 3] = 1.0
    for n, node in enumerate(nodes):
        if "matrix" in node:                                          # column-major
            L[:, n] = np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T
    return L


def _sample(gltf: GltfFile, t_key, values, times, interpolation: str, rotation: bool) -> np.ndarray:
    """Evaluate one animation sampler at ``times`` (glTF 2.0 appendix C); ``(T, k)``."""
    K = len(t_key)
    if interpolation not in ("LINEAR", "STEP", "CUBICSPLINE"):
        fail(gltf.func, f"sampler interpolation LINEAR, STEP or CUBICSPLINE in '{gltf.path}'", repr(interpolation))
    if interpolation == "CUBICSPLINE":
        a, v, b = np.moveaxis(values.reshape(K, 3, -1), 1, 0)        # in-tangent, value, out-tangent
    else:
        v = values.reshape(K, -1)
    slack = _EPS_T if interpolation == "STEP" else 0.0       # a frame at a (float32) keyframe time takes its value
    k = np.clip(np.searchsorted(t_key, times + slack, side="right") - 1, 0, K - 1)    # last keyframe <= t
    if interpolation == "STEP" or K == 1:
        out = v[k]
    else:
        k = np.minimum(k, K - 2)
        dt = t_key[k + 1] - t_key[k]
        s = np.clip(np.where(dt > 0, (times - t_key[k]) / np.where(dt > 0, dt, 1.0), 0.0), 0.0, 1.0)[:, None]
        if interpolation == "CUBICSPLINE":
            s2, s3, dt = s * s, s * s * s, dt[:, None]
            out = ((2 * s3 - 3 * s2 + 1) * v[k] + dt * (s3 - 2 * s2 + s) * b[k]
                   + (-2 * s3 + 3 * s2) * v[k + 1] + dt * (s3 - s2) * a[k + 1])
        elif rotation:
            out = _slerp(v[k], v[k + 1], s)
        else:
            out = (1 - s) * v[k] + s * v[k + 1]
    return out / np.linalg.norm(out, axis=1, keepdims=True) if rotation else out


def _slerp(q0, q1, s) -> np.ndarray:
    """Spherical interpolation of unit quaternions ``(T, 4)`` along the shorter arc."""
    d = np.sum(q0 * q1, axis=1, keepdims=True)
    q1, d = np.where(d < 0, -q1, q1), np.abs(d)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    sin = np.sin(theta)
    close = sin < 1e-9
    w0 = np.where(close, 1 - s, np.sin((1 - s) * theta) / np.where(close, 1.0, sin))
    w1 = np.where(close, s, np.sin(s * theta) / np.where(close, 1.0, sin))
    return w0 * q0 + w1 * q1


def _quat_matrix(q) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of quaternions ``(..., 4)`` stored ``(x, y, z, w)``."""
    x, y, z, w = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
                     np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
                     np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)


def _global_transforms(gltf: GltfFile, L) -> np.ndarray:
    """``(T, N, 4, 4)`` global matrices: every node's local matrix after its parents'."""
    nodes = gltf.doc.get("nodes", [])
    parent = {c: p for p, node in enumerate(nodes) for c in node.get("children", [])}
    G, done = np.empty_like(L), np.zeros(len(nodes), dtype=bool)
    for n in range(len(nodes)):
        chain = []
        while n is not None and not done[n]:
            chain.append(n)
            n = parent.get(n)
            if len(chain) > len(nodes):
                fail(gltf.func, f"a node hierarchy without cycles in '{gltf.path}'", f"a cycle through node {n}")
        for m in reversed(chain):
            p = parent.get(m)
            G[:, m] = L[:, m] if p is None else G[:, p] @ L[:, m]
            done[m] = True
    return G


def _mesh_nodes(doc: dict) -> list:
    """The nodes with a mesh in the default scene (all root nodes without one), depth first."""
    nodes = doc.get("nodes", [])
    if doc.get("scenes"):
        roots = doc["scenes"][doc.get("scene", 0)].get("nodes", [])
    else:
        children = {c for node in nodes for c in node.get("children", [])}
        roots = [n for n in range(len(nodes)) if n not in children]
    found, seen, stack = [], set(), list(reversed(roots))
    while stack:
        n = stack.pop()
        if n in seen:                     # a node listed twice, or a cycle (refused by _global_transforms)
            continue
        seen.add(n)
        if "mesh" in nodes[n]:
            found.append(n)
        stack += reversed(nodes[n].get("children", []))
    return found


def _morph_weights(gltf: GltfFile, clip: dict, times, n: int):
    """``(T, targets)`` morph weights of mesh node ``n`` at ``times``: animated, else the node's or mesh's defaults."""
    node = gltf.doc["nodes"][n]
    default = node.get("weights", gltf.doc["meshes"][node["mesh"]].get("weights"))
    W = None if default is None else np.tile(np.asarray(default, dtype=np.float64), (len(times), 1))
    for channel in clip["channels"]:
        if channel["target"].get("path") == "weights" and channel["target"].get("node") == n:
            s = clip["samplers"][channel["sampler"]]
            W = _sample(gltf, gltf.accessor(s["input"])[:, 0], gltf.accessor(s["output"]), times,
                        s.get("interpolation", "LINEAR"), False)
    return W


def _posed_primitive(gltf: GltfFile, n: int, prim: dict, G, weights):
    """One primitive of mesh node ``n``: posed ``(T, k, 3)``, rest ``(k, 3)``, faces, colours or None."""
    node = gltf.doc["nodes"][n]
    if prim.get("mode", 4) != 4:
        fail(gltf.func, f"triangle primitives (mode 4) in '{gltf.path}'",
             f"mode {prim['mode']} in mesh {node['mesh']}")
    attrs = prim["attributes"]
    P = gltf.accessor(attrs["POSITION"])
    F = (gltf.accessor(prim["indices"], floats=False) if "indices" in prim else np.arange(len(P))).reshape(-1, 3)
    if F.size and (F.min() < 0 or F.max() >= len(P)):
        fail(gltf.func, f"triangle indices below the {len(P)} vertices of mesh {node['mesh']} in '{gltf.path}'",
             f"index {int(F.max())}")
    M = np.broadcast_to(P, (len(G), *P.shape))                      # morphed rest positions, per frame
    targets = prim.get("targets", [])
    if targets:
        W = np.zeros((len(G), len(targets))) if weights is None else weights
        if W.shape[1] != len(targets):
            fail(gltf.func, f"one morph weight per target ({len(targets)}) of mesh {node['mesh']} in '{gltf.path}'",
                 f"{W.shape[1]} weights")
        D = np.stack([gltf.accessor(t["POSITION"]) if "POSITION" in t else np.zeros_like(P) for t in targets])
        M = P + np.einsum("tj,jvi->tvi", W, D)
    if "skin" in node:
        X = _skin(gltf, gltf.doc["skins"][node["skin"]], attrs, M, G)
    else:
        X = np.einsum("tij,tvj->tvi", G[:, n, :3, :3], M) + G[:, n, None, :3, 3]
    return X, P, F, base_colors(gltf, prim, len(P))


def _skin(gltf: GltfFile, skin: dict, attrs: dict, M, G) -> np.ndarray:
    """Linear-blend skinning of (morphed) rest positions ``M`` ``(T, k, 3)`` by the joints' transforms ``G``."""
    joints = np.asarray(skin["joints"], dtype=np.int64)
    if "inverseBindMatrices" in skin:
        B = gltf.accessor(skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)
    else:
        B = np.tile(np.eye(4), (len(joints), 1, 1))
    joint = G[:, joints] @ B                                        # (T, J, 4, 4) joint matrices
    sets = [k for k in range(8) if f"JOINTS_{k}" in attrs and f"WEIGHTS_{k}" in attrs]
    if not sets:
        fail(gltf.func, f"JOINTS_0 and WEIGHTS_0 on every skinned primitive in '{gltf.path}'",
             f"attributes {sorted(attrs)}")
    J = np.hstack([gltf.accessor(attrs[f"JOINTS_{k}"], floats=False) for k in sets])
    W = np.hstack([gltf.accessor(attrs[f"WEIGHTS_{k}"]) for k in sets])
    total = W.sum(axis=1)
    bad = np.flatnonzero(~(total > 0))
    if len(bad):
        fail(gltf.func, f"skin weights with a positive sum at every vertex in '{gltf.path}'",
             f"vertex {bad[0]} with weights {W[bad[0]].tolist()} ({len(bad)} such vertices)")
    wrong = (W != 0) & ((J < 0) | (J >= len(joints)))
    if wrong.any():
        v = int(np.flatnonzero(wrong.any(axis=1))[0])
        fail(gltf.func, f"joint indices below the skin's {len(joints)} joints in '{gltf.path}'",
             f"vertex {v} with joints {J[v].tolist()}")
    W, J = W / total[:, None], np.where(W != 0, J, 0)
    A = np.zeros((len(G), M.shape[1], 3, 4))
    for i in range(J.shape[1]):
        A += W[:, i, None, None] * joint[:, J[:, i], :3, :]
    return np.einsum("tvij,tvj->tvi", A[..., :3], M) + A[..., 3]


def _weld(Vs, F, C, keys):
    """Merge vertices with equal ``keys`` rows (first appearance's order); drop collapsed triangles."""
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty(len(first), dtype=np.int64)
    rank[order] = np.arange(len(first))
    new = rank[inverse.ravel()]                                      # new index of every old vertex
    counts = np.bincount(new, minlength=len(first))[:, None]
    C = np.stack([np.bincount(new, weights=C[:, c], minlength=len(first)) for c in range(3)], axis=1) / counts
    F = new[F]
    keep = (F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])
    return Vs[:, first[order]], F[keep], C
