"""The Slicer module's files, checked without Slicer: Python compiles, classes exist, the .ui matches the code."""

import ast
import re
import xml.etree.ElementTree as ET
from pathlib import Path

MODULE = Path(__file__).resolve().parents[1] / "RAMSICPRegistration"
SOURCE = (MODULE / "RAMSICPRegistration.py").read_text()
TREE = ast.parse(SOURCE)
UI = ET.parse(MODULE / "Resources" / "UI" / "RAMSICPRegistration.ui")


def _classes():
    return {node.name: node for node in TREE.body if isinstance(node, ast.ClassDef)}


def test_module_compiles_and_has_the_template_classes():
    compile(SOURCE, "RAMSICPRegistration.py", "exec")
    classes = _classes()
    bases = {name: [ast.unparse(base) for base in node.bases] for name, node in classes.items()}
    assert bases["RAMSICPRegistration"] == ["ScriptedLoadableModule"]
    assert bases["RAMSICPRegistrationWidget"] == ["ScriptedLoadableModuleWidget", "VTKObservationMixin"]
    assert bases["RAMSICPRegistrationLogic"] == ["ScriptedLoadableModuleLogic"]
    assert bases["RAMSICPRegistrationTest"] == ["ScriptedLoadableModuleTest"]
    decorators = [ast.unparse(d) for d in classes["RAMSICPRegistrationParameterNode"].decorator_list]
    assert decorators == ["parameterNodeWrapper"]


def test_every_widget_the_code_uses_is_in_the_ui():
    names = {widget.get("name") for widget in UI.iter("widget")}
    used = set(re.findall(r"self\.ui\.(\w+)", SOURCE))
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


def test_cmake_lists_every_library_file_and_only_existing_files():
    cmake = (MODULE / "CMakeLists.txt").read_text()
    listed = set(re.findall(r"\$\{MODULE_NAME\}Lib/(\w+\.py)", cmake))
    present = {path.name for path in (MODULE / "RAMSICPRegistrationLib").glob("*.py")}
    assert listed == present
    for resource in re.findall(r"(Resources/\S+|\$\{MODULE_NAME\}Lib/data/\S+)", cmake):
        assert (MODULE / resource.replace("${MODULE_NAME}", "RAMSICPRegistration")).is_file(), resource
    top = (MODULE.parent / "CMakeLists.txt").read_text()
    assert "add_subdirectory(RAMSICPRegistration)" in top and 'EXTENSION_CATEGORY "IGT"' in top
