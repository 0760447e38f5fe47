"""The Slicer module's files, checked without Slicer: Python compiles, classes exist, the .ui matches the code."""

import ast
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MODULES = ("RAMSICPRegistration", "OpenIGTLinkBridge")
MODULE = ROOT / "RAMSICPRegistration"
SOURCE = (MODULE / "RAMSICPRegistration.py").read_text()
TREE = ast.parse(SOURCE)
UI = ET.parse(MODULE / "Resources" / "UI" / "RAMSICPRegistration.ui")


def _classes(tree=TREE):
    return {node.name: node for node in tree.body if isinstance(node, ast.ClassDef)}


@pytest.mark.parametrize("name", MODULES)
def test_module_compiles_and_has_the_template_classes(name):
    source = (ROOT / name / f"{name}.py").read_text()
    compile(source, f"{name}.py", "exec")
    classes = _classes(ast.parse(source))
    bases = {class_name: [ast.unparse(base) for base in node.bases] for class_name, node in classes.items()}
    assert bases[name] == ["ScriptedLoadableModule"]
    assert bases[f"{name}Widget"] == ["ScriptedLoadableModuleWidget", "VTKObservationMixin"]
    assert bases[f"{name}Logic"] == ["ScriptedLoadableModuleLogic"]
    assert bases[f"{name}Test"] == ["ScriptedLoadableModuleTest"]


def test_registration_parameter_node_is_a_wrapper():
    decorators = [ast.unparse(d) for d in _classes()["RAMSICPRegistrationParameterNode"].decorator_list]
    assert decorators == ["parameterNodeWrapper"]


@pytest.mark.parametrize("name", MODULES)
def test_every_widget_the_code_uses_is_in_the_ui(name):
    source = (ROOT / name / f"{name}.py").read_text()
    names = {widget.get("name") for widget in ET.parse(ROOT / name / "Resources" / "UI" / f"{name}.ui").iter("widget")}
    used = set(re.findall(r"self\.ui\.(\w+)", source))
    assert used and used <= names, f"missing in the .ui: {sorted(used - names)}"


def test_every_parameter_binding_names_a_parameter_node_field():
    fields = {
        node.target.id
        for node in _classes()["RAMSICPRegistrationParameterNode"].body
        if isinstance(node, ast.AnnAssign)
    }
    bound = {prop.find("string").text for prop in UI.iter("property") if prop.get("name") == "SlicerParameterName"}
    assert bound and bound <= fields, f"unknown parameters in the .ui: {sorted(bound - fields)}"
    assert {"ctVolume", "probeToReference", "probePoints", "method", "policy"} <= bound


def test_button_actions_are_wrapped_for_error_display():
    widget = _classes()["RAMSICPRegistrationWidget"]
    for method in widget.body:
        if isinstance(method, ast.FunctionDef) and method.name in ("onProcessCT", "onRegister", "onRobot", "onCollect"):
            assert "tryWithErrorDisplay" in ast.unparse(method), method.name


@pytest.mark.parametrize("name", MODULES)
def test_cmake_lists_every_library_file_and_only_existing_files(name):
    """An extension installs only what CMake lists: every module, sub-package and data file of the Lib."""
    module = ROOT / name
    cmake = (module / "CMakeLists.txt").read_text()
    library = module / f"{name}Lib"
    listed = set(re.findall(r"\$\{MODULE_NAME\}Lib/(\S+\.py)\b", cmake))
    present = {str(path.relative_to(library)) for path in library.rglob("*.py")}
    assert listed == present
    listed_data = set(re.findall(r"\$\{MODULE_NAME\}Lib/(\S*data/\S+)", cmake))
    present_data = {
        str(path.relative_to(library)) for path in library.rglob("*") if path.is_file() and "data" in path.parts
    }
    assert listed_data == present_data
    for resource in re.findall(r"(Resources/\S+|\$\{MODULE_NAME\}Lib/\S*data/\S+)", cmake):
        assert (module / resource.replace("${MODULE_NAME}", name)).is_file(), resource
    top = (ROOT / "CMakeLists.txt").read_text()
    assert f"add_subdirectory({name})" in top and 'EXTENSION_CATEGORY "IGT"' in top


def _cmake_listed_files(name):
    cmake = (ROOT / name / "CMakeLists.txt").read_text()
    listed = re.findall(r"^\s+(\S+)\s*$", cmake.split("slicerMacroBuildScriptedModule")[0], flags=re.MULTILINE)
    return [entry.replace("${MODULE_NAME}", name) for entry in listed if "Lib/" in entry]


def test_a_slicer_style_install_imports_and_finds_its_data(tmp_path):
    """Copy only the files CMake lists (as a Slicer extension install does) and use the libraries from there."""
    import shutil
    import subprocess
    import sys

    for name in MODULES:
        for relative in _cmake_listed_files(name):
            target = tmp_path / relative
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(ROOT / name / relative, target)
    script = """
import importlib, pkgutil, sys
import RAMSICPRegistrationLib as lib, OpenIGTLinkBridgeLib
assert lib.__file__.startswith(sys.argv[1]), lib.__file__
assert OpenIGTLinkBridgeLib.__file__.startswith(sys.argv[1]), OpenIGTLinkBridgeLib.__file__
for package in (lib, OpenIGTLinkBridgeLib):
    for module in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
        if module.name.endswith(("scenarios", "mrml_nodes", "navigation.navigation", "live_demo", "receiver",
                                 "live_scenario")):
            continue  # these need slicer (MRML), which a plain install lacks; Slicer has it
        importlib.import_module(module.name)
from RAMSICPRegistrationLib.simulation.package_data import BONES, bone_mesh
from RAMSICPRegistrationLib.io.ndi_tools import tool_marker_geometry, tool_rom_path
for bone in BONES:
    vertices, triangles = bone_mesh(bone)
    assert len(vertices) > 1000 and len(triangles) > 1000, bone
assert tool_marker_geometry("8700339").shape == (4, 3)
assert tool_rom_path("8700339").stat().st_size == tool_rom_path("8700340").stat().st_size == 752
print(sorted(lib.__all__) == lib.__all__ and all(getattr(lib, name) is not None for name in lib.__all__))
"""
    result = subprocess.run(
        [sys.executable, "-c", script, str(tmp_path)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**__import__("os").environ, "PYTHONPATH": str(tmp_path)},
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "True"
