"""The package as users meet it: what an import loads, Mitsuba's usual order, public names and their docs."""
from __future__ import annotations

import ast
import dataclasses
import importlib
import inspect
import pkgutil
import re
import subprocess
from pathlib import Path

import pytest

import mi_loop

from helpers import REPO, run_python


def modules():
    """Every module of the package except ``__main__`` (which runs the CLI)."""
    names = ["mi_loop"] + [m.name for m in pkgutil.walk_packages(mi_loop.__path__, "mi_loop.")]
    return [n for n in names if not n.endswith("__main__")]


def test_limit_evaluator_and_plugin_need_neither_pymeshlab_nor_matplotlib_nor_tqdm():
    """Block the three fitting-side packages; the limit operator, the plugin and a render still work."""
    code = """
import sys
for name in ("pymeshlab", "matplotlib", "tqdm"):
    sys.modules[name] = None          # any import of them now raises ImportError
import numpy as np, drjit as dr, mitsuba as mi, mi_loop
from mi_loop import datasets, plugin
mi_loop.set_variant("llvm_ad_rgb")
V, F = datasets.blob()
fid, uv, _ = mi_loop.tessellate(F, 2)
W = mi_loop.limit_matrix(F, len(V), fid, uv)
op = mi_loop.LimitOperator(F, len(V), fid, uv)
P = np.array(op.positions(mi.Float(V.astype(np.float32).ravel()))).T
shape = plugin.create(V, F, level=2)
scene = mi.load_dict({"type": "scene", "integrator": {"type": "direct"}, "sensor": {"type": "perspective",
    "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
    "film": {"type": "hdrfilm", "width": 16, "height": 16}}, "emitter": {"type": "constant"}, "shape": shape})
img = mi.render(scene, spp=4)
print(float(np.abs(W @ V - P).max()), float(np.asarray(img).mean()) > 0)
"""
    result = run_python(code)
    assert result.returncode == 0, result.stderr
    err, lit = result.stdout.split()
    assert float(err) < 1e-5 and lit == "True"


def test_mitsubas_usual_order_finds_the_plugin(scenes_dir):
    """``mi.set_variant``, then ``import mi_loop``, then ``mi.load_file``: loop_subdiv is registered."""
    code = f"""
import mitsuba as mi
mi.set_variant("llvm_ad_rgb")
import mi_loop
scene = mi.load_file({str(scenes_dir / 'blob.xml')!r})
shape = [s for s in scene.shapes() if "LoopSubdiv" in type(s).__name__]
print(len(shape), shape[0].face_count())
"""
    result = run_python(code)
    assert result.returncode == 0, result.stderr
    count, faces = result.stdout.split()
    assert count == "1" and int(faces) == 80 * 4 ** 3          # blob.ply: 80 faces, level 3


def test_register_after_a_user_set_variant():
    code = """
import mitsuba as mi, mi_loop
mi.set_variant("llvm_ad_rgb")
cls = mi_loop.register()
print(cls.__name__)
"""
    result = run_python(code)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "LoopSubdivMesh"


def test_register_without_a_jit_variant_is_refused():
    code = """
import mitsuba as mi, mi_loop
mi.set_variant("scalar_rgb")
try:
    mi_loop.register()
except RuntimeError as exc:
    print(exc)
"""
    result = run_python(code)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("register(): expected a Mitsuba llvm_ad_* or cuda_ad_* variant to be set, "
                                    "got 'scalar_rgb'")


@pytest.mark.parametrize("name", modules())
def test_every_module_declares_its_public_names(name):
    module = importlib.import_module(name)
    assert hasattr(module, "__all__"), f"{name} has no __all__"
    missing = [n for n in module.__all__ if not hasattr(module, n)]
    assert not missing, f"{name}.__all__ lists names it does not define: {missing}"


# -- the import graph: what the README's "Layout" promises ---------------------------------------------------------

PACKAGE_ROOT = Path(mi_loop.__file__).resolve().parent
#: Entry points above every layer: the facade (public names loaded lazily from every layer; any module may read
#: ``__version__`` from it, as Python initialises it first) and ``__main__`` (runs the CLI).
ENTRY_POINTS = ("mi_loop", "mi_loop.__main__")


def module_sources():
    """``{module name: source path}`` of every module of the package (a package's ``__init__`` under its own name)."""
    found = {}
    for path in sorted(PACKAGE_ROOT.rglob("*.py")):
        parts = path.relative_to(PACKAGE_ROOT.parent).with_suffix("").parts
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def imported_modules(name, source, known, is_package=False):
    """Modules among ``known`` that module ``name`` imports anywhere in ``source`` (module level, inside
    functions, under ``if TYPE_CHECKING``), read with ``ast``; names taken from the facade resolve to the
    module that defines them."""
    package = name if is_package else name.rpartition(".")[0]
    lazy = {**mi_loop._LAZY, **mi_loop._MODULES}
    targets = []
    for node in ast.walk(ast.parse(source, name)):
        if isinstance(node, ast.Import):
            targets += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                head = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(head + ([node.module] if node.module else []))
            for alias in node.names:
                full = f"{base}.{alias.name}"
                targets.append(full if full in known else lazy.get(alias.name, base) if base == "mi_loop" else base)
    found = set()
    for target in targets:
        while target and target not in known:      # ``import mi_loop.a.b`` of a name inside a module
            target = target.rpartition(".")[0]
        if target and target != name:
            found.add(target)
    return found


def import_graph():
    """``{module: modules of the package it imports}``, entry points left out."""
    sources = module_sources()
    return {name: imported_modules(name, path.read_text(), sources, path.name == "__init__.py") - set(ENTRY_POINTS)
            for name, path in sources.items() if name not in ENTRY_POINTS}


def import_cycle(graph):
    """One cycle ``[a, b, ..., a]`` of ``graph``, or None (depth-first search)."""
    state = {}                                       # 1 on the current path, 2 done
    path = []

    def visit(node):
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def readme_layers():
    """Sub-packages in the order of the README's "Layout" table (each may import only from those before it)."""
    layout = re.search(r"^## Layout\n(.*?)(?=^## |\Z)", (REPO / "README.md").read_text(), re.S | re.M)
    assert layout, "README has no '## Layout' section"
    return re.findall(r"^\| `mi_loop\.(\w+)` \|", layout.group(1), re.M)


def test_the_import_graph_finds_cycles_and_imports_inside_functions():
    """The helpers the two tests below rely on, on a made-up graph and a made-up module."""
    assert import_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert import_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None
    known = {"mi_loop", "mi_loop.io", "mi_loop.io.fake", "mi_loop.io.glb", "mi_loop.render.plugin",
             "mi_loop.subdiv.limit"}
    source = ("import numpy as np\n"
              "def f():\n"
              "    from mi_loop import plugin, __version__\n"
              "    from . import glb\n"
              "    import mi_loop.subdiv.limit\n")
    assert imported_modules("mi_loop.io.fake", source, known) == {
        "mi_loop", "mi_loop.io.glb", "mi_loop.render.plugin", "mi_loop.subdiv.limit"}
    assert imported_modules("mi_loop.io", "from .glb import write_glb\n", known, is_package=True) == {
        "mi_loop.io.glb"}


def test_no_module_imports_a_module_that_imports_it_back():
    """No import cycle among the package's modules, imports inside functions included (they hide cycles that
    Python resolves only by the order in which the modules happen to load)."""
    cycle = import_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_sub_packages_import_only_from_the_layers_above_them_in_the_readme():
    """README, "Layout": sub-packages by layer, "each imports only from the layers above it in this table";
    the top-level modules (``errors``, ``metrics``, ...) are shared by the layers and kept acyclic above."""
    layers = readme_layers()
    packages = sorted(p.name for p in PACKAGE_ROOT.iterdir() if (p / "__init__.py").is_file())
    assert sorted(layers) == packages, f"README's Layout table lists {layers}, the package has {packages}"
    rank = {f"mi_loop.{name}": i for i, name in enumerate(layers)}

    def layer(module):
        return rank.get(".".join(module.split(".")[:2]))

    upward = [f"{a} -> {b}" for a, targets in sorted(import_graph().items()) for b in sorted(targets)
              if layer(a) is not None and layer(b) is not None and layer(b) > layer(a)]
    assert not upward, f"imports against the layer order {' -> '.join(layers)}: {upward}"


def public_callables():
    """``(qualified name, object)`` of every function and class listed in an ``__all__``."""
    seen = {}
    for name in modules():
        module = importlib.import_module(name)
        for attr in getattr(module, "__all__", []):
            obj = getattr(module, attr, None)
            if (inspect.isfunction(obj) or inspect.isclass(obj)) and obj.__module__ == name:
                seen[f"{name}.{attr}"] = obj
    return sorted(seen.items())


def _parameters(obj):
    target = obj.__init__ if inspect.isclass(obj) else obj
    try:
        params = inspect.signature(target).parameters
    except (TypeError, ValueError):
        return []
    return [p for p in params if p not in ("self", "cls", "args", "kwargs")]


@pytest.mark.parametrize("qualname, obj", public_callables(), ids=[q for q, _ in public_callables()])
def test_public_names_have_numpydoc_parameters(qualname, obj):
    """Every public function or class with parameters documents them in a numpydoc Parameters section."""
    doc = inspect.getdoc(obj) or ""
    assert doc, f"{qualname} has no docstring"
    if inspect.isclass(obj) and not _parameters(obj):
        return
    if _parameters(obj):
        section = "Attributes\n----------" if dataclasses.is_dataclass(obj) else "Parameters\n----------"
        assert section in doc or "Parameters\n----------" in doc, \
            f"{qualname} has no numpydoc {section.split()[0]} section"
        undocumented = [p for p in _parameters(obj) if not any(
            line.split(":")[0].strip().split(",")[0].strip() == p or p in [s.strip() for s in
            line.split(":")[0].split(",")] for line in doc.splitlines())]
        assert not undocumented, f"{qualname} does not document {undocumented}"


def test_the_public_api_of_0_1_keeps_working():
    """``limit_matrix``, ``subdivision_matrix``, ``LimitOperator(...).positions/evaluate/normals``
    with a flat ``mi.Float``, ``plugin.create`` and ``set_variant``, as 0.1 documented them."""
    import drjit as dr
    import mitsuba as mi
    import numpy as np

    from mi_loop import datasets, plugin

    mi_loop.set_variant("llvm_ad_rgb")
    V, F = datasets.blob()
    fid, uv, _ = mi_loop.tessellate(F, 2)
    W = mi_loop.limit_matrix(F, len(V), fid, uv)
    S, F_fine = mi_loop.subdivision_matrix(F, len(V))
    op = mi_loop.LimitOperator(F, len(V), fid, uv)
    x = mi.Float(V.astype(np.float32).ravel())
    P = np.array(op.positions(x)).T
    P2, du, dv = (np.array(a).T for a in op.evaluate(x))
    N = np.array(op.normals(x)).T
    np.testing.assert_allclose(P, W @ V, atol=1e-5)
    np.testing.assert_array_equal(P, P2)
    np.testing.assert_allclose(N, np.cross(du, dv) / np.linalg.norm(np.cross(du, dv), axis=1, keepdims=True),
                               atol=1e-5)
    assert S.shape[1] == len(V) and len(F_fine) == 4 * len(F)
    np.testing.assert_allclose(np.asarray(S.sum(axis=1)).ravel(), 1.0)     # affine: rows sum to one
    shape = plugin.create(V, F, level=2)
    assert dr.width(mi.traverse(shape)["control_points"]) == 3 * len(V)


@pytest.mark.slow
def test_pip_install_alone_gives_a_working_mi_loop(tmp_path):
    """``pip install .`` into a fresh virtual environment (this machine has a libLLVM >= 16):
    ``mi-loop --version`` and the demo fit run from outside the repository."""
    import venv

    venv.create(tmp_path / "env", with_pip=True)
    python, cli = tmp_path / "env" / "bin" / "python", tmp_path / "env" / "bin" / "mi-loop"
    install = subprocess.run([str(python), "-m", "pip", "install", "-q", "--disable-pip-version-check",
                              str(REPO)], capture_output=True, text=True, timeout=900, cwd=tmp_path)
    assert install.returncode == 0, install.stderr[-2000:]
    version = subprocess.run([str(cli), "--version"], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert version.stdout.startswith(f"mi-loop {mi_loop.__version__} (mitsuba "), version.stdout + version.stderr
    demo = subprocess.run([str(cli), "fit", "--demo", "-o", "out", "--quiet", "--iterations", "40"],
                          capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert demo.returncode == 0, demo.stderr[-2000:]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "control.ply", "limit.glb", "limit.ply", "loss.png", "render.png", "report.html", "report.json"]
