"""PLY files (ASCII and binary, either byte order): every element and property, as stored (NumPy).

Faces may mix triangles, quads and larger polygons in any encoding; list
properties come back as ``(counts, items)`` so that nothing is triangulated
or reordered here. Mesh and point-cloud readers build on :func:`read_ply`.
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from mi_loop.errors import fail

__all__ = ["PLY_TYPES", "read_ply"]

#: PLY scalar type names (both spellings) -> NumPy type codes.
PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
             "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
             "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def read_ply(path, func: str = "read_ply") -> dict:
    """Read every element of a PLY file.

    Parameters
    ----------
    path : str or os.PathLike
        An existing PLY file (``ascii``, ``binary_little_endian`` or ``binary_big_endian``).
    func : str, optional
        Name of the calling public function, for messages.

    Returns
    -------
    dict
        ``{element name: {property name: values}}`` in file order; a scalar
        property is an ``(c,)`` NumPy array of its stored type, a list
        property a tuple ``(counts (c,) int64, items (sum counts,))``.

    Raises
    ------
    ValueError
        Not a PLY file, a malformed header, an unknown type, or data that
        ends early or does not parse; the message names the file and the
        element (and the line, in ASCII files).

    Examples
    --------
    >>> import tempfile, os
    >>> text = ("ply\\nformat ascii 1.0\\nelement vertex 4\\nproperty float x\\nproperty float y\\n"
    ...         "property float z\\nelement face 1\\nproperty list uchar int vertex_indices\\nend_header\\n"
    ...         "0 0 0\\n1 0 0\\n1 1 0\\n0 1 0\\n4 0 1 2 3\\n")
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = os.path.join(d, "quad.ply")
    ...     _ = open(p, "w").write(text)
    ...     ply = read_ply(p)
    >>> ply["vertex"]["x"].tolist(), [a.tolist() for a in ply["face"]["vertex_indices"]]
    ([0.0, 1.0, 1.0, 0.0], [[4], [0, 1, 2, 3]])
    """
    path = Path(path)
    where = f"'{path}'"
    try:
        data = path.read_bytes()
    except OSError as exc:
        fail(func, f"a readable PLY file {where}", f"{type(exc).__name__}: {exc.strerror or exc}")
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        fail(func, f"a PLY file (a header from 'ply' to 'end_header') in {where}",
             f"a file starting {data[:16]!r}" if data else "an empty file")
    body = data.index(b"\n", end) + 1 if b"\n" in data[end:] else len(data)
    fmt, elements = _header(data[:end].decode("ascii", errors="replace"), where, func)
    out = {}
    if fmt == "ascii":
        first = data[:body].count(b"\n") + 1          # file line number of the first data line
        text = data[body:].decode("ascii", errors="replace").splitlines()
        lines = [(k, t) for k, t in enumerate(text, start=first) if t.strip()]
        line = 0
        for name, count, props in elements:
            out[name], line = _ascii_element(lines, line, name, count, props, where, func)
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        pos = body
        for name, count, props in elements:
            out[name], pos = _binary_element(data, pos, order, name, count, props, where, func)
    return out


def _header(text: str, where: str, func: str):
    """``(format, [(element, count, [(property, type, count type or None)]), ...])``."""
    fmt, elements = None, []
    for k, line in enumerate(text.splitlines()[1:], start=2):
        tok = line.split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        try:
            if tok[0] == "format":
                fmt = tok[1]
                if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
                    raise ValueError
            elif tok[0] == "element":
                elements.append((tok[1], int(tok[2]), []))
            elif tok[0] == "property" and tok[1] == "list":
                elements[-1][2].append((tok[4], PLY_TYPES[tok[3]], PLY_TYPES[tok[2]]))
            elif tok[0] == "property":
                elements[-1][2].append((tok[2], PLY_TYPES[tok[1]], None))
            else:
                raise ValueError
        except (ValueError, IndexError, KeyError):
            fail(func, f"a valid PLY header in {where}", f"header line {k} = {line.strip()!r}")
    if fmt is None:
        fail(func, f"a 'format' line in the PLY header of {where}", "none")
    return fmt, elements


def _ascii_element(lines, line, name, count, props, where, func):
    """Parse ``count`` non-empty ``(line number, text)`` lines of element ``name``; return it and the next line."""
    rows = lines[line:line + count]
    if len(rows) < count:
        fail(func, f"{count} '{name}' lines in {where}", f"{len(rows)} (the file ends early)")
    if all(c is None for _, _, c in props):
        try:
            A = np.array([r.split()[:len(props)] for _, r in rows], dtype=np.float64).reshape(count, len(props))
        except ValueError:
            k, r = next((k, r) for k, r in rows if not _numbers(r.split()[:len(props)], len(props)))
            fail(func, f"{len(props)} numbers per '{name}' line in {where}", f"line {k} = {r.strip()!r}")
        return {p: A[:, i].astype(t) for i, (p, t, _) in enumerate(props)}, line + count
    values = {p: [] for p, _, _ in props}
    for k, r in rows:
        tok = r.split()
        try:
            at = 0
            for p, _, c in props:
                if c is None:
                    values[p].append(float(tok[at]))
                    at += 1
                else:
                    n = int(tok[at])
                    values[p].append([float(x) for x in tok[at + 1:at + 1 + n]])
                    if len(values[p][-1]) != n:
                        raise IndexError
                    at += 1 + n
        except (ValueError, IndexError):
            fail(func, f"'{name}' lines as the header declares them in {where}", f"line {k} = {r.strip()!r}")
    out = {}
    for p, t, c in props:
        if c is None:
            out[p] = np.array(values[p]).astype(t)
        else:
            counts = np.array([len(v) for v in values[p]], dtype=np.int64)
            out[p] = (counts, np.array([x for v in values[p] for x in v]).astype(t))
    return out, line + count


def _numbers(tokens, n) -> bool:
    try:
        return len([float(t) for t in tokens]) == n
    except ValueError:
        return False


def _binary_element(data, pos, order, name, count, props, where, func):
    """Parse element ``name`` at byte ``pos``; return its properties and the next byte."""
    if all(c is None for _, _, c in props):
        dtype = np.dtype([(p, order + t) for p, t, _ in props])
        if pos + count * dtype.itemsize > len(data):
            fail(func, f"{count} '{name}' records ({count * dtype.itemsize} bytes) in {where}",
                 f"{len(data) - pos} bytes left (the file ends early)")
        A = np.frombuffer(data, dtype, count=count, offset=pos)
        return {p: A[p].astype(t) for p, t, _ in props}, pos + count * dtype.itemsize
    fixed = _fixed_lists(data, pos, order, count, props)
    if fixed is not None:
        return fixed
    values = {p: [] for p, _, _ in props}
    counts = {p: [] for p, _, c in props if c is not None}
    try:
        for _ in range(count):
            for p, t, c in props:
                if c is None:
                    (x,), pos = struct.unpack_from(order + _STRUCT[t], data, pos), pos + int(t[1])
                    values[p].append(x)
                else:
                    (n,), pos = struct.unpack_from(order + _STRUCT[c], data, pos), pos + int(c[1])
                    values[p].append(np.frombuffer(data, order + t, count=n, offset=pos))
                    counts[p].append(n)
                    pos += n * int(t[1])
    except (struct.error, ValueError):
        fail(func, f"{count} '{name}' records in {where}", "fewer bytes (the file ends early)")
    out = {}
    for p, t, c in props:
        if c is None:
            out[p] = np.array(values[p], dtype=t)
        else:
            items = np.concatenate(values[p]) if values[p] else np.zeros(0)
            out[p] = (np.array(counts[p], dtype=np.int64), items.astype(t))
    return out, pos


_STRUCT = {"i1": "b", "u1": "B", "i2": "h", "u2": "H", "i4": "i", "u4": "I", "f4": "f", "f8": "d"}


def _fixed_lists(data, pos, order, count, props):
    """Fast path: every record's lists have the first record's lengths (one structured read), else None."""
    fields, p0 = [], pos
    try:
        for p, t, c in props:
            if c is None:
                fields.append((p, order + t))
                p0 += int(t[1])
            else:
                (n,) = struct.unpack_from(order + _STRUCT[c], data, p0)
                fields += [(p + "\0count", order + c), (p, order + t, (n,))]
                p0 += int(c[1]) + n * int(t[1])
    except struct.error:
        return None
    dtype = np.dtype(fields)
    if count == 0 or pos + count * dtype.itemsize > len(data):
        return None
    A = np.frombuffer(data, dtype, count=count, offset=pos)
    out = {}
    for p, t, c in props:
        if c is None:
            out[p] = A[p].astype(t)
        else:
            n = A[p + "\0count"].astype(np.int64)
            if not (n == n[0]).all():
                return None
            out[p] = (n, A[p].reshape(-1).astype(t))
    return out, pos + count * dtype.itemsize
