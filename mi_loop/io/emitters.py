"""The lighting of a capture: a Mitsuba XML file that holds only emitters.

``mi-loop fit-images --emitters lights.xml`` reads the capture's lighting
from a Mitsuba 3 scene file whose ``<scene>`` holds ``<emitter>`` elements (and
``<default>`` parameters) and nothing else, in the photos' world frame::

    <scene version="3.0.0">
        <emitter type="envmap"><string name="filename" value="studio.exr"/></emitter>
        <emitter type="point"><point name="position" x="0" y="4" z="2"/>
            <rgb name="intensity" value="20"/></emitter>
    </scene>

Without the option the lighting is :data:`DEFAULT_EMITTERS`: a uniform
``constant`` environment of radiance 1 (a light box or an overcast sky), in
which a diffuse albedo ``a`` shows as radiance ``a`` times its ambient occlusion.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

from mi_loop.errors import fail

__all__ = ["DEFAULT_EMITTERS", "read_emitters"]

#: The lighting assumed when a capture gives none: uniform white environment, radiance 1.
DEFAULT_EMITTERS = ({"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},)


def read_emitters(path) -> list:
    """Load the emitters of a Mitsuba XML file that holds nothing else.

    Parameters
    ----------
    path : str or os.PathLike
        The XML file (relative paths inside it resolve against its folder).

    Returns
    -------
    list of mi.Emitter
        The file's emitters, in file order (a Mitsuba variant must be set).

    Raises
    ------
    ValueError
        A missing file, malformed XML, a root that is not ``<scene>``, an
        element other than ``<emitter>`` or ``<default>`` (named with its
        position), no emitter, or a file Mitsuba refuses (its first line).
    """
    import mitsuba as mi

    func, path = "read_emitters", Path(path)
    if not path.is_file():
        fail(func, "an existing Mitsuba XML file of emitters", f"'{path}': no such file")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as error:
        fail(func, f"well-formed XML in '{path}'", str(error))
    if root.tag != "scene":
        fail(func, f"a <scene> root element in '{path}'", f"<{root.tag}>")
    children = list(root)
    for k, child in enumerate(children):
        if child.tag not in ("emitter", "default"):
            fail(func, f"only <emitter> (and <default>) elements in '{path}'",
                 f"<{child.tag}> as element {k} (the lighting file must not hold shapes, sensors or integrators)")
    if not any(child.tag == "emitter" for child in children):
        fail(func, f"at least one <emitter> in '{path}'", "none")
    try:
        scene = mi.load_file(str(path))
    except Exception as error:   # Mitsuba reports parse and plugin errors as RuntimeError
        fail(func, f"a Mitsuba scene file in '{path}'", str(error).strip().splitlines()[0][:300])
    return list(scene.emitters())
