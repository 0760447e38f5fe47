"""The libraries' folders are the layers of DESIGN.md: imports only run downwards, and never in a cycle.

core < io < image < simulation < navigation < bridge (OpenIGTLinkBridgeLib) < experiments < web < commands: a module
may import its own layer and those before it, never one after it. ``core`` imports numpy, scipy and the standard
library only (no VTK, no MRML, no Qt). No two modules import each other, directly or round a loop, counting the
imports made inside functions (lazy imports) too. Only the command-line programs print. The checker itself is
tested on small packages built in a temporary folder, so a core file that imports vtk, or a lazy import that closes
a loop, is shown to fail it.
"""

import ast
import sys
import sysconfig
from pathlib import Path

import pytest

import OpenIGTLinkBridgeLib
import RAMSICPRegistrationLib

REGISTRATION = "RAMSICPRegistrationLib"
BRIDGE = "OpenIGTLinkBridgeLib"
PACKAGES = {
    REGISTRATION: Path(RAMSICPRegistrationLib.__file__).resolve().parent,
    BRIDGE: Path(OpenIGTLinkBridgeLib.__file__).resolve().parent,
}
LAYERS = ("core", "io", "image", "simulation", "navigation", "bridge", "experiments", "web", "commands")
CORE_THIRD_PARTY = {"numpy", "scipy"}
#: The modules that own a console (command-line programs): they alone may print.
PRINTING = ("RAMSICPRegistrationLib.commands", "OpenIGTLinkBridgeLib.tracker_server")


def modules(packages):
    """{dotted module name: file} for every module of ``packages`` ({package name: folder})."""
    found = {}
    for name, folder in packages.items():
        for path in sorted(folder.rglob("*.py")):
            parts = path.relative_to(folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join((name, *parts))] = path
    return found


def layer(module):
    """The layer of a dotted module name; None for a package's own ``__init__`` (it re-exports the public API)."""
    parts = module.split(".")
    if parts[0] == BRIDGE:
        return "bridge"
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def imports(module, path, known):
    """(line, imported first-party module or None, third-party root or None) for each import in ``path``, those
    inside functions included. ``from a import b`` names module ``a.b`` when ``b`` is a module, else ``a``."""
    is_package = path.name == "__init__.py"
    package = module.split(".") if is_package else module.split(".")[:-1]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1] + (node.module.split(".") if node.module else [])
            else:
                base = node.module.split(".")
            target = ".".join(base)
            for alias in node.names:
                yield node.lineno, *_resolve(f"{target}.{alias.name}" if f"{target}.{alias.name}" in known else target)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, *_resolve(alias.name)


def _resolve(name):
    root = name.split(".")[0]
    return (name, None) if root in (REGISTRATION, BRIDGE) else (None, root)


def import_graph(packages):
    """{module: {imported first-party module: first line}} over ``packages``."""
    known = modules(packages)
    graph = {}
    for module, path in known.items():
        edges = graph.setdefault(module, {})
        for line, target, _ in imports(module, path, known):
            if target is not None and target != module:
                edges.setdefault(target, line)
    return graph


def layer_violations(packages):
    """Every import that breaks the layering, as readable lines (empty when all is well)."""
    problems = []
    known = modules(packages)
    for module, path in known.items():
        own = layer(module)
        if own is None:
            continue
        for line, target, root in imports(module, path, known):
            where = f"{module}:{line}"
            theirs = None if target is None else layer(target)
            if theirs is not None and LAYERS.index(theirs) > LAYERS.index(own):
                problems.append(f"{where}: {own} imports {theirs} ({target}), a layer above it")
            if own == "core" and root is not None and root not in CORE_THIRD_PARTY and not _is_standard_library(root):
                problems.append(f"{where}: core imports {root}; core may use numpy, scipy and the standard library")
    return problems


def import_cycles(packages):
    """Each group of modules that import one another round a loop (Tarjan's strongly connected components), as a
    readable line naming the imports that close it; empty when there is none."""
    graph = import_graph(packages)
    index, low, stack, on_stack, groups = {}, {}, [], set(), []

    def visit(module):  # recursive Tarjan: the graphs are a few hundred modules deep at most
        index[module] = low[module] = len(index)
        stack.append(module)
        on_stack.add(module)
        for target in graph.get(module, {}):
            if target not in graph:
                continue
            if target not in index:
                visit(target)
                low[module] = min(low[module], low[target])
            elif target in on_stack:
                low[module] = min(low[module], index[target])
        if low[module] == index[module]:
            group = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                group.append(member)
                if member == module:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return [
        "cycle: "
        + "; ".join(
            f"{source} imports {target} (line {graph[source][target]})"
            for source in group
            for target in group
            if target in graph[source]
        )
        for group in groups
    ]


def print_calls(packages):
    """Modules outside the command-line programs that call print()."""
    found = []
    for module, path in modules(packages).items():
        if module.startswith(PRINTING):
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        if any(
            isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print"
            for node in ast.walk(tree)
        ):
            found.append(module)
    return found


def _is_standard_library(root):
    names = getattr(sys, "stdlib_module_names", None)  # Python >= 3.10
    if names is not None:
        return root in names or root == "__future__"
    if root in sys.builtin_module_names or root == "__future__":
        return True
    import importlib.util

    spec = importlib.util.find_spec(root)
    origin = getattr(spec, "origin", None) or ""
    return origin.startswith(sysconfig.get_paths()["stdlib"]) and "site-packages" not in origin


def test_every_module_lives_in_a_layer():
    folder = PACKAGES[REGISTRATION]
    stray = [p.name for p in folder.glob("*.py") if p.name != "__init__.py"]
    assert not stray, f"modules outside the layer folders: {stray}"
    sub_packages = sorted(p.name for p in folder.iterdir() if (p / "__init__.py").is_file())
    assert sub_packages == sorted(name for name in LAYERS if name != "bridge")


def test_imports_run_only_downwards_and_core_is_numpy_and_scipy_only():
    assert layer_violations(PACKAGES) == []


def test_no_module_imports_itself_round_a_loop():
    assert import_cycles(PACKAGES) == []


def test_no_print_in_library_code():
    assert print_calls(PACKAGES) == []


def _toy_packages(tmp_path, files):
    """A toy RAMSICPRegistrationLib (every layer folder) and OpenIGTLinkBridgeLib with ``files`` {path: text},
    paths relative to tmp_path and starting with the package's name."""
    for name in (REGISTRATION, BRIDGE):
        (tmp_path / name).mkdir()
        (tmp_path / name / "__init__.py").touch()
    for name in LAYERS:
        if name != "bridge":
            (tmp_path / REGISTRATION / name).mkdir()
            (tmp_path / REGISTRATION / name / "__init__.py").touch()
    for name, text in files.items():
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return {name: tmp_path / name for name in (REGISTRATION, BRIDGE)}


@pytest.mark.parametrize(
    "files, expected",
    [
        ({"RAMSICPRegistrationLib/core/icp.py": "import vtk\n"}, "core.icp:1: core imports vtk"),
        (
            {"RAMSICPRegistrationLib/core/icp.py": "from vtkmodules.vtkCommonCore import vtkPoints\n"},
            "core imports vtkmodules",
        ),
        ({"RAMSICPRegistrationLib/core/icp.py": "def f():\n    import slicer\n"}, "core.icp:2: core imports slicer"),
        (
            {"RAMSICPRegistrationLib/core/icp.py": "from ..io.point_files import read_points\n"},
            "core imports io (RAMSICPRegistrationLib.io.point_files), a layer above it",
        ),
        ({"RAMSICPRegistrationLib/io/point_files.py": "from ..image import volume_io\n"}, "io imports image"),
        (
            {"RAMSICPRegistrationLib/image/x.py": "from RAMSICPRegistrationLib.navigation.navigation import f\n"},
            "image imports navigation",
        ),
        (
            {"RAMSICPRegistrationLib/simulation/x.py": "from ..experiments.demo import run_demo\n"},
            "simulation imports experiments",
        ),
        (
            {"RAMSICPRegistrationLib/navigation/x.py": "def f():\n    from OpenIGTLinkBridgeLib.robot_link import R\n"},
            "navigation.x:2: navigation imports bridge",
        ),
        (
            {"OpenIGTLinkBridgeLib/server.py": "from RAMSICPRegistrationLib.web.app import App\n"},
            "OpenIGTLinkBridgeLib.server:1: bridge imports web",
        ),
    ],
)
def test_the_checker_catches_each_kind_of_violation(tmp_path, files, expected):
    problems = layer_violations(_toy_packages(tmp_path, files))
    assert any(expected in problem for problem in problems), problems


def test_the_checker_accepts_downward_and_standard_library_imports(tmp_path):
    packages = _toy_packages(
        tmp_path,
        {
            "RAMSICPRegistrationLib/core/icp.py": "import logging\nfrom dataclasses import dataclass\n"
            "import numpy as np\nfrom scipy.spatial import cKDTree\nfrom .transforms import apply_transform\n",
            "RAMSICPRegistrationLib/core/transforms.py": "import numpy as np\n",
            "RAMSICPRegistrationLib/navigation/x.py": "import vtk\nfrom ..core.icp import icp\n"
            "from ..simulation import ct_phantom\n",
            "OpenIGTLinkBridgeLib/server.py": "from RAMSICPRegistrationLib.navigation.x import f\n",
            "RAMSICPRegistrationLib/web/app.py": "from OpenIGTLinkBridgeLib.server import s\n",
            "RAMSICPRegistrationLib/commands/demo.py": "from ..experiments.demo import run_demo\n"
            "print('the command line may print')\n",
        },
    )
    assert layer_violations(packages) == []
    assert import_cycles(packages) == []
    assert print_calls(packages) == []
    (tmp_path / REGISTRATION / "image" / "y.py").write_text("print('no')\n")
    assert print_calls(packages) == ["RAMSICPRegistrationLib.image.y"]


def test_the_checker_finds_a_loop_closed_by_a_lazy_import(tmp_path):
    packages = _toy_packages(
        tmp_path,
        {
            "OpenIGTLinkBridgeLib/server.py": "def main():\n    from .replay import ReplaySource\n",
            "OpenIGTLinkBridgeLib/replay.py": "from .scenario import Scene\n",
            "OpenIGTLinkBridgeLib/scenario.py": "from . import server\n",
            "OpenIGTLinkBridgeLib/plain.py": "from .server import main\n",
        },
    )
    assert layer_violations(packages) == []
    (cycle,) = import_cycles(packages)
    assert "OpenIGTLinkBridgeLib.server imports OpenIGTLinkBridgeLib.replay (line 2)" in cycle
    assert "OpenIGTLinkBridgeLib.scenario imports OpenIGTLinkBridgeLib.server (line 1)" in cycle
    assert "plain" not in cycle


def test_public_api_resolves_from_the_top_and_the_core_alone_needs_no_vtk():
    """``from RAMSICPRegistrationLib import register, read_points, ...`` works, and loads only what it needs."""
    import subprocess

    script = (
        "import sys\n"
        "from RAMSICPRegistrationLib import SurfaceIndex, fit_rigid_transform, register\n"
        "assert 'vtk' not in sys.modules and 'vtkmodules' not in sys.modules, 'the core pulled in VTK'\n"
        "import RAMSICPRegistrationLib as lib\n"
        "from RAMSICPRegistrationLib.core.registration import register as deep\n"
        "assert register is deep\n"
        "missing = [name for name in lib.__all__ if getattr(lib, name, None) is None]\n"
        "assert not missing, missing\n"
        "from RAMSICPRegistrationLib import read_points, read_surface_points, write_points, load_volume\n"
        "print(len(lib.__all__))\n"
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert int(result.stdout) == len(RAMSICPRegistrationLib.__all__) >= 40
