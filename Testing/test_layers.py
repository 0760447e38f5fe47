"""The library's folders are the layers of DESIGN.md, and imports only run downwards.

core < io < image < simulation < navigation < experiments < web < cli: a module may import its own sub-package and
those before it, never one after it. ``core`` imports numpy, scipy and the standard library only (no VTK, no
MRML, no Qt). Only ``cli.py`` prints. The checker itself is tested on a small package built in a temporary
folder, so a core file that imports vtk is shown to fail it.
"""

import ast
import sys
import sysconfig
from pathlib import Path

import pytest

import RAMSICPRegistrationLib

PACKAGE = Path(RAMSICPRegistrationLib.__file__).resolve().parent
LAYERS = ("core", "io", "image", "simulation", "navigation", "experiments", "web", "cli")
CORE_THIRD_PARTY = {"numpy", "scipy"}


def _layer(module):
    """The layer of a module path relative to the package, e.g. ('core', 'icp') -> 'core'; None for the package's
    own ``__init__`` (``from . import __version__``)."""
    if not module:
        return None
    return "cli" if module[0] == "cli" else (module[0] if module[0] in LAYERS else None)


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


def _imports(path, package):
    """(line, layer or None, third-party root or None) for each import in a file of ``package``."""
    relative = path.relative_to(package).with_suffix("").parts
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level > 0:
            base = list(relative[: len(relative) - node.level])
            target = base + (node.module.split(".") if node.module else [])
            if not target:  # "from . import name" at the top: name is a sub-package or module
                for alias in node.names:
                    yield node.lineno, _layer([alias.name]), None
            else:
                yield node.lineno, _layer(target), None
        elif isinstance(node, ast.ImportFrom):
            parts = node.module.split(".")
            if parts[0] == package.name:
                yield node.lineno, _layer(parts[1:]), None
            else:
                yield node.lineno, None, parts[0]
        elif isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                if parts[0] == package.name:
                    yield node.lineno, _layer(parts[1:]), None
                else:
                    yield node.lineno, None, parts[0]


def layer_violations(package):
    """Every import in ``package`` that breaks the layering, as readable lines (empty when all is well)."""
    problems = []
    for path in sorted(package.rglob("*.py")):
        relative = path.relative_to(package)
        own = "cli" if relative.parts == ("cli.py",) else (relative.parts[0] if len(relative.parts) > 1 else None)
        if own is None:
            continue  # the package's __init__ re-exports the public API from every layer
        for line, layer, root in _imports(path, package):
            where = f"{relative}:{line}"
            if layer is not None and LAYERS.index(layer) > LAYERS.index(own):
                problems.append(f"{where}: {own} imports {layer}, a layer above it")
            if own == "core" and root is not None and root not in CORE_THIRD_PARTY and not _is_standard_library(root):
                problems.append(f"{where}: core imports {root}; core may use numpy, scipy and the standard library")
    return problems


def print_calls(package):
    """Files other than cli.py that call print()."""
    found = []
    for path in sorted(package.rglob("*.py")):
        if path.relative_to(package).parts == ("cli.py",):
            continue  # the command line owns the console
        tree = ast.parse(path.read_text(encoding="utf-8"))
        if any(
            isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print"
            for node in ast.walk(tree)
        ):
            found.append(str(path.relative_to(package)))
    return found


def test_every_module_lives_in_a_layer():
    stray = [p.name for p in PACKAGE.glob("*.py") if p.name not in ("__init__.py", "cli.py")]
    assert not stray, f"modules outside the layer folders: {stray}"
    assert sorted(p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()) == sorted(LAYERS[:-1])


def test_imports_run_only_downwards_and_core_is_numpy_and_scipy_only():
    assert layer_violations(PACKAGE) == []


def test_no_print_in_library_code():
    assert print_calls(PACKAGE) == []


def _toy_package(tmp_path, files):
    package = tmp_path / "RAMSICPRegistrationLib"
    for name, text in {"__init__.py": "", "cli.py": "", **files}.items():
        path = package / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    for layer in LAYERS[:-1]:
        (package / layer).mkdir(exist_ok=True)
        (package / layer / "__init__.py").touch()
    return package


@pytest.mark.parametrize(
    "files, expected",
    [
        ({"core/icp.py": "import vtk\n"}, "core/icp.py:1: core imports vtk"),
        ({"core/icp.py": "from vtkmodules.vtkCommonCore import vtkPoints\n"}, "core imports vtkmodules"),
        ({"core/icp.py": "def f():\n    import slicer\n"}, "core/icp.py:2: core imports slicer"),
        ({"core/icp.py": "from ..io.point_files import read_points\n"}, "core imports io, a layer above it"),
        ({"io/point_files.py": "from ..image import volume_io\n"}, "io imports image, a layer above it"),
        ({"image/x.py": "from RAMSICPRegistrationLib.navigation.navigation import f\n"}, "image imports navigation"),
        ({"simulation/x.py": "from ..experiments.demo import run_demo\n"}, "simulation imports experiments"),
    ],
)
def test_the_checker_catches_each_kind_of_violation(tmp_path, files, expected):
    problems = layer_violations(_toy_package(tmp_path, files))
    assert any(expected in problem for problem in problems), problems


def test_the_checker_accepts_downward_and_standard_library_imports(tmp_path):
    package = _toy_package(
        tmp_path,
        {
            "core/icp.py": "import logging\nfrom dataclasses import dataclass\nimport numpy as np\n"
            "from scipy.spatial import cKDTree\nfrom .transforms import apply_transform\n",
            "navigation/x.py": "import vtk\nfrom ..core.icp import icp\nfrom ..simulation import ct_phantom\n",
            "cli.py": "from .experiments.demo import run_demo\nprint('the command line may print')\n",
        },
    )
    assert layer_violations(package) == []
    assert print_calls(package) == []
    (package / "image" / "y.py").write_text("print('no')\n")
    assert print_calls(package) == ["image/y.py"]


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
