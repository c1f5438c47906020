"""Mitsuba 3 shape plugin ``loop_subdiv``: a Loop limit surface with differentiable control points.

After :func:`register` (called by :func:`mi_loop.set_variant`), scenes can say::

    <shape type="loop_subdiv">
        <string name="filename" value="blob.ply"/>   <!-- control mesh: PLY, OBJ or OFF -->
        <integer name="level" value="3"/>            <!-- 4**level triangles per control face -->
        <string name="creases" value="0 1, 1 2 2.5"/> <!-- optional sharp edges: pairs [sharpness] -->
        <string name="corners" value="4, 7 1.5"/>    <!-- optional vertex sharpness: vertex [sharpness] -->
        <string name="boundary" value="edge_only"/>  <!-- edge_and_corner (default), edge_only, none -->
        <string name="crease_method" value="chaikin"/> <!-- uniform (default) or chaikin -->
        <bsdf type="diffuse">                        <!-- optional: colours of a PLY control mesh -->
            <texture type="mesh_attribute" name="reflectance">
                <string name="name" value="vertex_color"/>
            </texture>
        </bsdf>
        <transform name="to_world"> ... </transform> <!-- optional, applied to the control points -->
    </shape>

The shape is a triangle mesh (a Python subclass of ``mi.Mesh``) whose vertices
are exact limit points of the control mesh at a uniform tessellation of every
control face and whose vertex normals are the exact limit normals.
``mi.traverse`` exposes ``control_points``, a differentiable flat ``mi.Float``
of length ``3 n`` (xyz interleaved, world space); updating it recomputes the
mesh through the cached :class:`mi_loop.LimitOperator`, with gradients.

Appearance: a shape built with per-control-vertex RGB (``create(..., albedo=)``,
or a PLY control mesh with vertex colours, see :func:`mi_loop.io.write_ply`)
carries them to the tessellation with the same limit operator, as the mesh
attribute ``vertex_color`` (a smooth colour field, 3 numbers per control
vertex; Loop limit weights are non-negative, so colours in [0, 1] stay there).
``mi.traverse`` then also exposes ``control_albedo`` (flat ``mi.Float`` of
length ``3 n``, differentiable), and a ``mesh_attribute`` texture named
``vertex_color`` lets any BSDF use it (the default BSDF of :func:`create`
with ``albedo`` does).

Integrators for optimising the control points: gradients through silhouettes
come only from ``direct_projective`` and ``prb_projective`` (``prb``,
``direct``, ``path`` and ``aov`` miss them). Give those integrators
``"sppi": 0`` unless shadow boundaries carry the signal: ``sppi`` samples the
gradients of *indirect* visibility changes (shadows the shape casts on itself
or on other shapes under area or environment lights) and builds a guiding
structure for them in every render, while silhouettes (``sppp``) and shading
(``sppc``) do not need it; the default costs tens of times more per render
(``bench/bench_iteration.py``, BENCHMARKS.md "What it costs per iteration"). Render views one at a time:
the ``batch`` sensor fails with the projective integrators.
"""
from __future__ import annotations

import re

import numpy as np

__all__ = ["COLOR_ATTRIBUTE", "PLUGIN_NAME", "RADIANCE_ATTRIBUTE", "albedo_bsdf", "create", "mesh_arrays",
           "parse_corner_text", "parse_crease_text", "plain_mesh", "register"]

#: Name of the plugin in scene dictionaries and XML files.
PLUGIN_NAME = "loop_subdiv"

_NUMBER = r"([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?|inf)"
_PAIR = re.compile(r"^\s*(\d+)\s+(\d+)(?:\s+" + _NUMBER + r")?\s*$")
_CORNER = re.compile(r"^\s*(\d+)(?:\s+" + _NUMBER + r")?\s*$")
_CLASSES: dict = {}


def _entries(text: str, pattern, what: str, example: str):
    """Comma- or semicolon-separated entries of ``text`` matched by ``pattern``: list of match groups."""
    entries = [e for e in re.split(r"[,;]", text) if e.strip()]
    out = []
    for k, entry in enumerate(entries):
        match = pattern.match(entry)
        if match is None:
            raise ValueError(f"loop_subdiv: {what} entry {k} is {entry.strip()!r}, expected {example}")
        out.append(match.groups())
    return out


def parse_crease_text(text: str):
    """Parse the ``creases`` property: comma- or semicolon-separated vertex pairs, each with an optional sharpness.

    Parameters
    ----------
    text : str
        E.g. ``"0 1, 1 2 2.5; 2 3 inf"``: a pair without a sharpness is
        infinitely sharp. Blank means no creases.

    Returns
    -------
    tuple ``((c, 2) int64 NumPy array, (c,) float64 NumPy array)`` or None
        Crease edges as control-vertex pairs and their sharpness, None if
        ``text`` is blank.

    Raises
    ------
    ValueError
        If an entry is not two non-negative integers and an optional sharpness.

    Examples
    --------
    >>> E, s = parse_crease_text("0 1, 1 2 2.5")
    >>> E.tolist(), s.tolist()
    ([[0, 1], [1, 2]], [inf, 2.5])
    >>> parse_crease_text("  ") is None
    True
    """
    entries = _entries(text, _PAIR, "creases",
                       "two vertex indices and an optional sharpness such as '0 1' or '0 1 2.5'")
    if not entries:
        return None
    E = np.asarray([(int(a), int(b)) for a, b, _ in entries], dtype=np.int64)
    return E, np.asarray([float(x) if x else np.inf for _, _, x in entries])


def parse_corner_text(text: str):
    """Parse the ``corners`` property: comma- or semicolon-separated vertices, each with an optional sharpness.

    Parameters
    ----------
    text : str
        E.g. ``"4, 7 1.5"``: a vertex without a sharpness is an infinitely
        sharp corner. Blank means none.

    Returns
    -------
    tuple ``((c,) int64 NumPy array, (c,) float64 NumPy array)`` or None

    Raises
    ------
    ValueError
        If an entry is not a non-negative integer and an optional sharpness.

    Examples
    --------
    >>> ids, s = parse_corner_text("4, 7 1.5")
    >>> ids.tolist(), s.tolist()
    ([4, 7], [inf, 1.5])
    """
    entries = _entries(text, _CORNER, "corners", "a vertex index and an optional sharpness such as '4' or '4 1.5'")
    if not entries:
        return None
    return (np.asarray([int(v) for v, _ in entries], dtype=np.int64),
            np.asarray([float(x) if x else np.inf for _, x in entries]))


# The one place that knows Mitsuba's mesh-buffer names (``mi.traverse`` keys of a mesh).
_POSITIONS, _NORMALS, _FACES = "vertex_positions", "vertex_normals", "faces"
#: The mesh attribute holding per-vertex colours (read by a ``mesh_attribute`` texture).
COLOR_ATTRIBUTE = "vertex_color"
#: Mesh attribute of the emitted radiance of a shape built with ``radiance=`` (:func:`create`).
RADIANCE_ATTRIBUTE = "vertex_radiance"


def mesh_arrays(mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Copy a Mitsuba mesh's vertex positions, vertex normals and faces to NumPy.

    Parameters
    ----------
    mesh : mi.Mesh
        Any Mitsuba mesh, e.g. a ``loop_subdiv`` shape.

    Returns
    -------
    P : (k, 3) float32 NumPy array
        Vertex positions.
    N : (k, 3) float32 NumPy array
        Vertex normals (zeros if the mesh has none).
    F : (t, 3) uint32 NumPy array
        Triangles.
    """
    import mitsuba as mi

    params = mi.traverse(mesh)
    P = np.asarray(params[_POSITIONS], dtype=np.float32).reshape(-1, 3)
    N = (np.asarray(params[_NORMALS], dtype=np.float32).reshape(-1, 3)
         if _NORMALS in params else np.zeros_like(P))
    F = np.asarray(params[_FACES], dtype=np.uint32).reshape(-1, 3)
    return P, N, F


def _write_mesh_buffers(mesh, positions, normals, faces=None) -> None:
    """Write flat buffers into a Mitsuba mesh through ``mi.traverse``.

    Parameters
    ----------
    mesh : mi.Mesh
        Destination mesh (its vertex and face counts are fixed).
    positions : mi.Float, shape (3 k,)
        Vertex positions, xyz interleaved; gradients are kept.
    normals : mi.Float, shape (3 k,)
        Unit vertex normals, xyz interleaved.
    faces : mi.UInt32, shape (3 t,), optional
        Triangle vertex indices; only needed once.
    """
    import mitsuba as mi

    params = mi.traverse(mesh)
    params[_POSITIONS] = positions
    params[_NORMALS] = normals
    if faces is not None:
        params[_FACES] = faces
    params.update()


def _shape_class(variant: str):
    """Build (once per variant) the ``mi.Mesh`` subclass behind ``loop_subdiv``."""
    if variant in _CLASSES:
        return _CLASSES[variant]
    import drjit as dr
    import mitsuba as mi

    from mi_loop import io
    from mi_loop.ad.operator import LimitOperator
    from mi_loop.mesh.topology import sharp_topology, validate_mesh
    from mi_loop.subdiv.tessellation import tessellate

    class LoopSubdivMesh(mi.Mesh):
        """Loop limit surface of a control mesh, tessellated uniformly.

        Parameters
        ----------
        props : mi.Properties
            ``filename`` (str, control mesh, resolved against the scene's
            file resolver), ``level`` (int >= 0, default 3), ``creases``
            (str, see :func:`parse_crease_text`), ``corners`` (str, see
            :func:`parse_corner_text`), ``boundary`` and ``crease_method``
            (str, see :func:`mi_loop.subdivision_matrix`), ``to_world``
            (transform), plus the usual shape children (bsdf, emitter, ...).
            Under ``boundary = 'none'`` the holes are left out of the mesh.
            Without a ``creases`` property, the creases of a PLY control
            mesh's ``edge`` element are used (:func:`mi_loop.io.read_creases`).
        control_mesh : ((n, 3) float, (m, 3) int) NumPy arrays, optional
            Control vertices and faces given directly instead of ``filename``.
        model : dict, optional
            Crease model given directly (keywords ``creases``, ``corners``,
            ``boundary``, ``crease_method`` of :class:`mi_loop.LimitOperator`);
            the properties of the same names override it.
        albedo : (n, 3) float array, optional
            Per-control-vertex linear RGB given directly (else the control
            mesh file's vertex colours, if it has any).
        emission : bool, optional
            Add the mesh attribute :data:`RADIANCE_ATTRIBUTE` (zeros), the
            radiance of an area emitter set by the caller; needs ``albedo``.
        """

        def __init__(self, props, control_mesh=None, model=None, albedo=None, emission=False):
            level = props.get("level", 3)
            if not isinstance(level, int) or level < 0:
                raise ValueError(f"loop_subdiv: expected an integer level >= 0, got {level!r}")
            model = dict(model or {})
            if "creases" in props:
                model["creases"] = parse_crease_text(props.get("creases"))
            if "corners" in props:
                model["corners"] = parse_corner_text(props.get("corners"))
            for key in ("boundary", "crease_method"):
                if key in props:
                    model[key] = props.get(key)
            if control_mesh is None:
                if "filename" not in props:
                    raise ValueError("loop_subdiv: missing the 'filename' property (control mesh PLY/OBJ/OFF)")
                path = str(mi.file_resolver().resolve(props.get("filename")))
                control_mesh = io.read_mesh(path)
                if albedo is None:
                    albedo = io.read_vertex_colors(path)
                if "creases" not in props and model.get("creases") is None:
                    model["creases"] = io.read_creases(path)      # a control.ply written by mi-loop fit
            V, F = (np.asarray(a) for a in control_mesh)
            validate_mesh(V, F)
            albedo = _check_albedo(albedo, len(V))
            if "to_world" in props:
                T = np.asarray(props.get("to_world").matrix, dtype=np.float64)
                V = V @ T[:3, :3].T + T[:3, 3]
            topo = sharp_topology(F, len(V), "loop_subdiv", **model)
            if topo.hole.all():
                raise ValueError(f"loop_subdiv: every one of the {len(F)} control faces is a hole under "
                                 "boundary 'none' (each has a vertex on a boundary that is not an infinitely "
                                 "sharp crease); nothing to show")
            face_ids, uv, F_tess = tessellate(F, level, np.flatnonzero(~topo.hole))
            super().__init__(props.id() or PLUGIN_NAME, len(uv), len(F_tess), props,
                             has_vertex_normals=True)
            self._level = level
            self._n = len(V)
            self._operator = LimitOperator(F, len(V), face_ids, uv, **model)
            self._x = mi.Float(V.astype(np.float32).ravel())
            self._c = self._field = self._normals = None
            if emission and albedo is None:
                raise ValueError("loop_subdiv: an emitted radiance needs a per-control-vertex albedo")
            self._update_geometry(faces=mi.UInt32(np.asarray(F_tess, dtype=np.uint32).ravel()))
            if albedo is not None:
                self._c = mi.Float(albedo.ravel())
                self.add_attribute(COLOR_ATTRIBUTE, 3, [0.0] * (3 * len(uv)))
                if emission:
                    self.add_attribute(RADIANCE_ATTRIBUTE, 3, [0.0] * (3 * len(uv)))
                self._update_colors()

        @property
        def operator(self):
            """The cached :class:`mi_loop.LimitOperator` of this shape."""
            return self._operator

        @property
        def level(self) -> int:
            """Tessellation level: 4**level triangles per control face."""
            return self._level

        def _update_geometry(self, faces=None) -> None:
            if dr.width(self._x) != 3 * self._n:
                raise ValueError(f"loop_subdiv: control_points must hold 3 * {self._n} values, "
                                 f"got {dr.width(self._x)}")
            P, N = self._operator.positions_normals(self._x)
            self._normals = N
            _write_mesh_buffers(self, dr.ravel(P), dr.ravel(N), faces)

        def _update_colors(self) -> None:
            if dr.width(self._c) != 3 * self._n:
                raise ValueError(f"loop_subdiv: control_albedo must hold 3 * {self._n} values, "
                                 f"got {dr.width(self._c)}")
            self._field = self._operator.positions(self._c)
            params = mi.traverse(self)
            params[COLOR_ATTRIBUTE] = dr.ravel(self._field)
            params.update()

        @property
        def limit_normals(self):
            """Unit limit normals at the tessellation's vertices (Dr.Jit 3-vector, with the control points'
            gradients), as last computed."""
            return self._normals

        @property
        def limit_albedo(self):
            """The limit of the albedo field at the tessellation's vertices (Dr.Jit 3-vector, with the albedo's
            gradients), as last computed; None without an albedo."""
            return self._field

        @property
        def has_albedo(self) -> bool:
            """Whether the shape carries per-control-vertex colours (``control_albedo``)."""
            return self._c is not None

        def traverse(self, cb):
            super().traverse(cb)
            cb.put("control_points", self._x,
                   mi.ParamFlags.Differentiable | mi.ParamFlags.Discontinuous)
            if self._c is not None:
                cb.put("control_albedo", self._c, mi.ParamFlags.Differentiable)

        def parameters_changed(self, keys=()):
            ours = {"control_points", "control_albedo"}
            if not keys or "control_points" in keys:
                self._update_geometry()
            if self._c is not None and (not keys or "control_albedo" in keys):
                self._update_colors()
            if keys and not set(keys) <= ours:
                super().parameters_changed([k for k in keys if k not in ours])

        def to_string(self):
            return (f"LoopSubdivMesh[control_points={self._n}, level={self._level}, "
                    f"albedo={'per control vertex' if self._c is not None else 'none'}, "
                    f"vertices={self.vertex_count()}, faces={self.face_count()}]")

    _CLASSES[variant] = LoopSubdivMesh
    return LoopSubdivMesh


def register():
    """Register the ``loop_subdiv`` shape plugin for the current Mitsuba variant.

    Returns
    -------
    type
        The ``mi.Mesh`` subclass implementing the plugin (also usable through
        :func:`create`).

    Raises
    ------
    RuntimeError
        If no Mitsuba variant is set or the variant is not a JIT AD variant
        (``llvm_ad_*`` or ``cuda_ad_*``).
    """
    import mitsuba as mi

    cls = _current_class("register")
    mi.register_shape(PLUGIN_NAME, lambda props: cls(props))
    return cls


def _current_class(caller: str):
    """Return the plugin class for the current variant, checking that it is a JIT AD one."""
    import mitsuba as mi

    variant = mi.variant()
    if variant is None or not variant.startswith(("llvm_ad_", "cuda_ad_")):
        raise RuntimeError(f"{caller}: needs a Mitsuba llvm_ad_* or cuda_ad_* variant, current is "
                           f"{variant!r}; call mi_loop.set_variant() first")
    return _shape_class(variant)


def create(V, F, level: int = 3, creases=None, bsdf=None, albedo=None, *, corners=None,
           boundary: str = "edge_and_corner", crease_method: str = "uniform", emission: bool = False):
    """Build a ``loop_subdiv`` shape from control-mesh arrays (no file needed).

    Parameters
    ----------
    V : (n, 3) float NumPy array
        Control points.
    F : (m, 3) int NumPy array
        Control triangles.
    level : int, optional
        Tessellation level (4**level triangles per control face).
    creases : None, (c, 2) int array or (E, sharpness), optional
        Sharp edges, as accepted by :class:`mi_loop.LimitOperator`.
    corners, boundary, crease_method : optional
        The rest of the crease model, as in :func:`mi_loop.subdivision_matrix`.
    bsdf : mi.BSDF, optional
        Surface material (if None: :func:`albedo_bsdf` with ``albedo``, else
        Mitsuba's default diffuse).
    albedo : (n, 3) float NumPy array, optional
        Per-control-vertex linear RGB, exposed as ``control_albedo`` and
        carried to the mesh attribute :data:`COLOR_ATTRIBUTE`.
    emission : bool, optional
        Make the shape an area emitter whose radiance is the mesh attribute
        :data:`RADIANCE_ATTRIBUTE` (zeros until the caller sets it through
        ``mi.traverse``, e.g. from ``shape.limit_albedo`` and
        ``shape.limit_normals``); needs ``albedo``. Rendered at path depth 1,
        the shape then shows exactly this radiance (:mod:`mi_loop.render.lighting`).

    Returns
    -------
    mi.Mesh
        The shape; put it in a scene dictionary as a value.

    Raises
    ------
    RuntimeError
        If no suitable Mitsuba variant is set.
    ValueError
        If the control mesh is invalid.
    """
    import mitsuba as mi

    cls = _current_class("create")
    props = mi.Properties(PLUGIN_NAME)
    props["level"] = int(level)
    if bsdf is None and albedo is not None:
        bsdf = mi.load_dict(albedo_bsdf())
    if bsdf is not None:
        props["bsdf"] = bsdf
    if emission:
        props["emitter"] = mi.load_dict({"type": "area",
                                         "radiance": {"type": "mesh_attribute", "name": RADIANCE_ATTRIBUTE}})
    model = dict(creases=creases, corners=corners, boundary=boundary, crease_method=crease_method)
    return cls(props, control_mesh=(V, F), model=model, albedo=albedo, emission=emission)


def albedo_bsdf() -> dict:
    """Scene dictionary of a diffuse BSDF whose reflectance is the shape's :data:`COLOR_ATTRIBUTE`.

    Returns
    -------
    dict
        ``{"type": "diffuse", "reflectance": {"type": "mesh_attribute", "name": "vertex_color"}}``.
    """
    return {"type": "diffuse", "reflectance": {"type": "mesh_attribute", "name": COLOR_ATTRIBUTE}}


def _check_albedo(albedo, n: int):
    """Per-control-vertex colours as a (n, 3) float32 array in [0, 1], or None."""
    if albedo is None:
        return None
    A = np.asarray(albedo, dtype=np.float32)
    if A.shape != (n, 3):
        raise ValueError(f"loop_subdiv: expected albedo of shape ({n}, 3) (one RGB per control vertex), "
                         f"got shape {A.shape}")
    if not np.isfinite(A).all() or A.min() < 0 or A.max() > 1:
        bad = int(np.flatnonzero(~(np.isfinite(A) & (A >= 0) & (A <= 1)).all(axis=1))[0])
        raise ValueError(f"loop_subdiv: expected albedo in [0, 1], got {A[bad].tolist()} at control vertex {bad}")
    return A


def plain_mesh(V, F, normals=None, bsdf=None, colors=None, emitter=None):
    """Build an ordinary Mitsuba triangle mesh from arrays (e.g. a target to compare with).

    Parameters
    ----------
    V : (k, 3) float NumPy array
        Vertex positions.
    F : (t, 3) int NumPy array
        Triangles.
    normals : (k, 3) float NumPy array, optional
        Vertex normals (flat shading without them).
    bsdf : mi.BSDF, optional
        Surface material.
    colors : (k, 3) float NumPy array, optional
        Per-vertex linear RGB, as the attribute :data:`COLOR_ATTRIBUTE` (see :func:`albedo_bsdf`).
    emitter : mi.Emitter, optional
        Area emitter of the mesh (its radiance may be the attribute ``colors``).

    Returns
    -------
    mi.Mesh
    """
    import mitsuba as mi

    V = np.asarray(V, dtype=np.float32)
    F = np.asarray(F, dtype=np.uint32)
    props = mi.Properties()
    if bsdf is not None:
        props["bsdf"] = bsdf
    if emitter is not None:
        props["emitter"] = emitter
    mesh = mi.Mesh("plain", len(V), len(F), props, has_vertex_normals=normals is not None)
    params = mi.traverse(mesh)
    params[_POSITIONS] = mi.Float(V.ravel())
    params[_FACES] = mi.UInt32(F.ravel())
    if normals is not None:
        params[_NORMALS] = mi.Float(np.asarray(normals, dtype=np.float32).ravel())
    params.update()
    if colors is not None:
        colors = np.asarray(colors, dtype=np.float32)
        if colors.shape != V.shape:
            raise ValueError(f"plain_mesh(): expected colors of shape {V.shape}, got shape {colors.shape}")
        mesh.add_attribute(COLOR_ATTRIBUTE, 3, colors.ravel().tolist())
    return mesh
