"""The pure core imports numpy and scipy only: no VTK, no MRML, no Qt (DESIGN.md, layer 1)."""

import ast
from pathlib import Path

import RAMSICPRegistrationLib

CORE_MODULES = (
    "validation",
    "transforms",
    "paired_point",
    "surface_index",
    "icp",
    "sweep",
    "metrics",
    "constraint",
    "registration",
    "virtual_patient",
)
ALLOWED = {"numpy", "scipy", "dataclasses", "functools", "logging", "__future__"}  # and standard-library helpers


def test_core_modules_import_only_numpy_and_scipy():
    package = Path(RAMSICPRegistrationLib.__file__).parent
    for name in CORE_MODULES:
        tree = ast.parse((package / f"{name}.py").read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                roots = {alias.name.split(".")[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                roots = {node.module.split(".")[0]}
            else:
                continue
            assert roots <= ALLOWED, f"{name}.py imports {roots - ALLOWED}"


def test_no_print_in_library_code():
    package = Path(RAMSICPRegistrationLib.__file__).parent
    for path in package.glob("*.py"):
        if path.name == "cli.py":
            continue  # the command line owns the console
        tree = ast.parse(path.read_text())
        calls = [
            node
            for node in ast.walk(tree)
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print"
        ]
        assert not calls, f"{path.name} calls print()"
