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
    module = ROOT / name
    cmake = (module / "CMakeLists.txt").read_text()
    listed = set(re.findall(r"\$\{MODULE_NAME\}Lib/(\w+\.py)", cmake))
    present = {path.name for path in (module / f"{name}Lib").glob("*.py")}
    assert listed == present
    for resource in re.findall(r"(Resources/\S+|\$\{MODULE_NAME\}Lib/data/\S+)", cmake):
        assert (module / resource.replace("${MODULE_NAME}", name)).is_file(), resource
    top = (ROOT / "CMakeLists.txt").read_text()
    assert f"add_subdirectory({name})" in top and 'EXTENSION_CATEGORY "IGT"' in top
