"""The Slicer modules' files, checked without Slicer: against the controller and against Slicer's own sources.

3D Slicer's application cannot run here, so the widget code is checked statically:

* the modules compile and have the template's classes; user-visible texts are translatable;
* each module's ``parameterNodeWrapper`` class declares exactly the controller's parameters (same names, kinds,
  node classes, ranges, choices and defaults): the GUI and the controller share one parameter node;
* every ``self.ui.<name>`` exists in the ``.ui``; every signal given to ``connect()`` exists for that widget class;
  every ``SlicerParameterName`` has ``stdset="0"``, names a field, and sits on a widget class that Slicer's
  parameterNodeWrapper can bind to that field's type in **every** supported release;
* every ``slicer.util``, ``slicer.i18n`` and ``slicer.parameterNodeWrapper`` name used exists in every supported
  release. ``Testing/Data/slicer_api.json`` lists those names, extracted from Slicer's sources at tags v5.6.0,
  v5.8.1 and v5.10.0 (see ``Testing/Data/README.md``);
* the ``.ui`` files declare their custom widgets (containers flagged), connect each MRML widget to
  ``mrmlSceneChanged``, give every control a tooltip and keep labelmaps out of the CT selector;
* CMake lists every file the libraries need when installed, and a Slicer-style install works from those alone;
* what only Slicer's own process shows (issue 24), checked against facts taken from Slicer's sources at the same
  tags: one parameter-node wrapper per node, bound to the GUI once (``connectGui`` adds an observer that
  ``disconnectGui`` never removes); the robot link serviced by a timer the logic owns; saving through the
  controller (Slicer's .mrml writer only commits the XML); a modal CT progress dialog (``createProgressDialog``
  leaves it modeless); a collect shortcut free in Slicer and in the operating systems; the tracker's Python found
  as Slicer finds it; every MRML method the changes call declared in every release.
"""

import ast
import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from RAMSICPRegistrationLib.navigation.parameters import REGISTRATION

ROOT = Path(__file__).resolve().parents[1]
MODULES = ("RAMSICPRegistration", "OpenIGTLinkBridge")
SLICER_API = json.loads((ROOT / "Testing" / "Data" / "slicer_api.json").read_text())
SUPPORTED_TAGS = ("v5.6.0", "v5.8.1", "v5.10.0")


def _parameter_set(name):
    if name == "RAMSICPRegistration":
        return REGISTRATION
    from OpenIGTLinkBridgeLib.bridge_controller import BRIDGE

    return BRIDGE


def _source(name):
    return (ROOT / name / f"{name}.py").read_text()


def _tree(name):
    return ast.parse(_source(name))


def _classes(tree):
    return {node.name: node for node in tree.body if isinstance(node, ast.ClassDef)}


def _ui(name):
    return ET.parse(ROOT / name / "Resources" / "UI" / f"{name}.ui")


def _ui_widgets(name):
    """{widget name: class} of a module's .ui."""
    return {widget.get("name"): widget.get("class") for widget in _ui(name).iter("widget")}


def _module_constant(tree, constant):
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == constant for t in node.targets):
            return ast.literal_eval(node.value)
    return None


@pytest.mark.parametrize("name", MODULES)
def test_module_compiles_and_has_the_template_classes(name):
    source = _source(name)
    compile(source, f"{name}.py", "exec")
    classes = _classes(ast.parse(source))
    bases = {class_name: [ast.unparse(base) for base in node.bases] for class_name, node in classes.items()}
    assert bases[name] == ["ScriptedLoadableModule"]
    assert bases[f"{name}Widget"] == ["ScriptedLoadableModuleWidget", "VTKObservationMixin"]
    assert bases[f"{name}Logic"] == ["ScriptedLoadableModuleLogic"]
    assert bases[f"{name}Test"] == ["ScriptedLoadableModuleTest"]
    decorators = [ast.unparse(d) for d in classes[f"{name}ParameterNode"].decorator_list]
    assert decorators == ["parameterNodeWrapper"]


@pytest.mark.parametrize("name", MODULES)
def test_user_visible_texts_are_translatable_and_the_help_links_the_documentation(name):
    module_class = _classes(_tree(name))[name]
    module_init = next(node for node in module_class.body if getattr(node, "name", None) == "__init__")
    assigned = {ast.unparse(node.targets[0]): node.value for node in module_init.body if isinstance(node, ast.Assign)}
    for field in ("self.parent.title", "self.parent.acknowledgementText"):
        assert ast.unparse(assigned[field]).startswith("_("), field
    assert ast.unparse(assigned["self.parent.categories"]) == "[translate('qSlicerAbstractCoreModule', 'IGT')]"
    help_text = ast.unparse(assigned["self.parent.helpText"])
    assert help_text.startswith("_(") and "DOCUMENTATION_URL" in help_text
    homepage = re.search(r'EXTENSION_HOMEPAGE "([^"#]+)', (ROOT / "CMakeLists.txt").read_text()).group(1)
    assert _module_constant(_tree(name), "DOCUMENTATION_URL").startswith(homepage)


def _wrapper_fields(name):
    """{field: (annotation source, default source or None)} of the module's parameterNodeWrapper class."""
    body = _classes(_tree(name))[f"{name}ParameterNode"].body
    return {
        node.target.id: (ast.unparse(node.annotation), None if node.value is None else ast.unparse(node.value))
        for node in body
        if isinstance(node, ast.AnnAssign)
    }


@pytest.mark.parametrize("name", MODULES)
def test_the_widgets_parameter_node_declares_exactly_the_controllers_parameters(name):
    from RAMSICPRegistrationLib.core.hold_still import DEFAULT_STILL_MM, DEFAULT_STILL_S
    from RAMSICPRegistrationLib.core.registration import DEFAULT_METHOD, METHODS, POLICIES
    from RAMSICPRegistrationLib.core.tool_path import TOOLS

    fields = _wrapper_fields(name)
    parameters = _parameter_set(name).parameters
    assert list(fields) == [parameter.name for parameter in parameters]
    known = {"DEFAULT_METHOD": DEFAULT_METHOD, "list(METHODS)": list(METHODS), "list(POLICIES)": list(POLICIES)}
    known.update(DEFAULT_STILL_MM=DEFAULT_STILL_MM, DEFAULT_STILL_S=DEFAULT_STILL_S)
    known["list(TOOLS)"] = list(TOOLS)
    if name == "OpenIGTLinkBridge":
        from OpenIGTLinkBridgeLib.bridge_controller import SOURCES

        known["list(SOURCES)"] = list(SOURCES)
    for parameter in parameters:
        annotation, default = fields[parameter.name]
        value = None if default is None else known.get(default, None if default in known else ast.literal_eval(default))
        if parameter.kind == "node":
            classes = parameter.node_class  # a tuple: any of them (parameterNodeWrapper's UnionSerializer)
            expected = classes if isinstance(classes, str) else f"Union[{', '.join(classes)}]"
            assert annotation == expected and default is None, parameter.name
            continue
        assert value == parameter.default, parameter.name
        if parameter.kind in ("float", "int"):
            python_type = "float" if parameter.kind == "float" else "int"
            match = re.fullmatch(rf"Annotated\[{python_type}, WithinRange\((.+), (.+)\)\]", annotation)
            assert match, (parameter.name, annotation)
            assert (float(match.group(1)), float(match.group(2))) == (parameter.minimum, parameter.maximum)
        elif parameter.kind == "choice":
            choices = re.fullmatch(r"Annotated\[str, Choice\((.+)\)\]", annotation).group(1)
            assert known[choices] == list(parameter.choices), parameter.name
        else:
            assert annotation == "str", parameter.name


def _ui_names_used(tree):
    """Every name of a .ui widget the module's code uses: ``self.ui.<name>`` and the keys of its button tables."""
    used = set(re.findall(r"self\.ui\.(\w+)", ast.unparse(tree)))
    for table in ("BUTTON_ACTIONS", "ENABLED_BY"):
        used |= set(_module_constant(tree, table) or {})
    return used


@pytest.mark.parametrize("name", MODULES)
def test_every_widget_the_code_uses_is_in_the_ui(name):
    widgets = _ui_widgets(name)
    used = _ui_names_used(_tree(name))
    assert used and used <= set(widgets), f"missing in the .ui: {sorted(used - set(widgets))}"


def _connections(tree, widgets):
    """(widget class, signal) of every ``<receiver>.connect("signal", ...)`` in the module's code."""
    tables = {table: _module_constant(tree, table) or {} for table in ("BUTTON_ACTIONS",)}
    owned = {"self._timer": "QTimer", "self._serviceTimer": "QTimer", "self._shortcut": "QShortcut"}
    found = []
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Call) and getattr(node.func, "attr", None) == "connect" and node.args):
            continue
        if not isinstance(node.args[0], ast.Constant):
            continue  # Python-side signal objects (none in these modules)
        receiver, signal = ast.unparse(node.func.value), node.args[0].value
        if receiver.startswith("self.ui."):
            classes = [widgets[receiver[len("self.ui.") :]]]
        elif receiver == "getattr(self.ui, button)":
            classes = [widgets[button] for button in tables["BUTTON_ACTIONS"]]
        else:
            classes = [owned[receiver]]
        found += [(widget_class, signal) for widget_class in classes]
    return found


@pytest.mark.parametrize("name", MODULES)
def test_every_connected_signal_exists_for_its_widget_class(name):
    connections = _connections(_tree(name), _ui_widgets(name))
    assert len(connections) >= 4
    for tag in SUPPORTED_TAGS:
        signals = {**SLICER_API["qt"]["signals"], **SLICER_API["tags"][tag]["signals"]}
        for widget_class, signal in connections:
            assert signal in signals[widget_class], f"{widget_class} has no signal {signal} (Slicer {tag})"


def _connector_widgets(tag, kind):
    """Widget classes Slicer's parameterNodeWrapper binds to a parameter kind, in release ``tag``."""
    connectors = SLICER_API["tags"][tag]["guiConnectors"]
    by_kind = {
        "node": ["qMRMLNodeComboBoxToNodeConnector"],
        "float": [c for c in connectors if "ToFloat" in c],
        "int": [c for c in connectors if "ToInt" in c or "FloatInt" in c],
        "text": ["QLineEditToStrConnector", "QTextEditPlainTextToStrConnector"],
        "choice": ["QComboBoxToStringableConnector"],
    }[kind]
    return {widget for connector in by_kind for widget in connectors.get(connector, [])}


@pytest.mark.parametrize("name", MODULES)
def test_every_parameter_binding_names_a_field_on_a_widget_every_supported_slicer_can_bind(name):
    parameters = _parameter_set(name).by_name
    bound = []
    for widget in _ui(name).iter("widget"):
        for prop in widget.findall("property"):
            if prop.get("name") == "SlicerParameterName":
                assert prop.get("stdset") == "0", f'{widget.get("name")}: SlicerParameterName needs stdset="0"'
                bound.append((widget.get("class"), prop.find("string").text))
    assert bound
    for widget_class, parameter in bound:
        assert parameter in parameters, f"unknown parameter in the .ui: {parameter}"
        for tag in SUPPORTED_TAGS:
            supported = _connector_widgets(tag, parameters[parameter].kind)
            assert widget_class in supported, f"Slicer {tag} cannot bind a {widget_class} to {parameter}"
    if name == "RAMSICPRegistration":
        essentials = {"ctVolume", "thresholdHU", "probeToReference", "probePoints", "method", "policy"}
        assert essentials <= {parameter for _, parameter in bound}


@pytest.mark.parametrize("name", MODULES)
def test_every_slicer_api_used_exists_in_every_supported_release(name):
    tree = _tree(name)
    used_util = set(re.findall(r"slicer\.util\.(\w+)", ast.unparse(tree)))
    imported = {}
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("slicer."):
            imported.setdefault(node.module, set()).update(alias.name for alias in node.names)
    self_calls = set(re.findall(r"self\.(\w+)\(", ast.unparse(_classes(tree)[f"{name}Widget"])))
    assert used_util and imported
    for tag in SUPPORTED_TAGS:
        api = SLICER_API["tags"][tag]
        missing = used_util - set(api["slicer.util"])
        assert not missing, f"not in slicer.util of {tag}: {missing}"
        for module, names in imported.items():
            available = api[module] if module != "slicer.util" else api["slicer.util"]
            if module == "slicer.ScriptedLoadableModule":
                available = list(api[module])
            assert names <= set(available), f"{module} of {tag} lacks {names - set(available)}"
        widget_base = set(api["slicer.ScriptedLoadableModule"]["ScriptedLoadableModuleWidget"])
        own = {n.name for n in _classes(tree)[f"{name}Widget"].body if isinstance(n, ast.FunctionDef)}
        mixin = {"addObserver", "removeObserver", "removeObservers"}
        assert self_calls <= own | widget_base | mixin, self_calls - own - widget_base - mixin


@pytest.mark.parametrize("name", MODULES)
def test_ui_declares_custom_widgets_connects_mrml_widgets_and_explains_every_control(name):
    tree = _ui(name)
    custom = {entry.find("class").text: entry for entry in tree.iter("customwidget")}
    used_classes = {widget.get("class") for widget in tree.iter("widget")}
    for widget_class in used_classes:
        if widget_class.startswith(("qMRML", "ctk")):
            assert widget_class in custom, f"{widget_class} is not declared in <customwidgets>"
            assert custom[widget_class].find("header").text == f"{widget_class}.h"
    for container in ("qMRMLWidget", "ctkCollapsibleButton"):
        if container in custom:
            assert custom[container].findtext("container") == "1", f"{container} must be a <container>"
    connected = {
        connection.findtext("receiver")
        for connection in tree.iter("connection")
        if connection.findtext("signal") == "mrmlSceneChanged(vtkMRMLScene*)"
        and connection.findtext("slot") == "setMRMLScene(vtkMRMLScene*)"
        and connection.findtext("sender") == name
    }
    for widget in tree.iter("widget"):
        widget_class, widget_name = widget.get("class"), widget.get("name")
        if widget_class in ("qMRMLNodeComboBox", "qMRMLTableView"):
            assert widget_name in connected, f"{widget_name} is not connected to mrmlSceneChanged"
            for tag in SUPPORTED_TAGS:
                assert "setMRMLScene(vtkMRMLScene*)" in SLICER_API["tags"][tag]["slots"][widget_class]
        if widget_class not in ("QLabel", "ctkCollapsibleButton", "qMRMLWidget"):
            tips = [p for p in widget.findall("property") if p.get("name") == "toolTip"]
            assert tips and tips[0].findtext("string"), f"{widget_name} has no tooltip"


def test_the_ct_selector_offers_scalar_volumes_but_not_labelmaps():
    selector = next(w for w in _ui("RAMSICPRegistration").iter("widget") if w.get("name") == "ctVolumeSelector")
    props = {p.get("name"): p for p in selector.findall("property")}
    assert [s.text for s in props["nodeTypes"].iter("string")] == ["vtkMRMLScalarVolumeNode"]
    assert props["showChildNodeTypes"].findtext("bool") == "false"  # vtkMRMLLabelMapVolumeNode is a child class


def test_the_widgets_hold_no_workflow_state_or_observers():
    """Behaviour belongs to the controller: the widget observes only the scene (as the template does)."""
    for name in MODULES:
        widget = _classes(_tree(name))[f"{name}Widget"]
        text = ast.unparse(widget)
        observed = re.findall(r"self\.addObserver\(([^,]+),", text)
        assert set(observed) == {"slicer.mrmlScene"}, observed
        assert "TransformModifiedEvent" not in text and "ModifiedEvent" not in text
        assert "pip_install" not in ast.unparse(next(n for n in widget.body if getattr(n, "name", "") == "setup"))
    assert "ensure_requirements" not in _source("RAMSICPRegistration")


def test_the_modules_have_their_own_icons():
    icons = [(ROOT / name / "Resources" / "Icons" / f"{name}.png").read_bytes() for name in MODULES]
    assert icons[0] != icons[1]


def test_extension_metadata_is_ready_for_the_index():
    top = (ROOT / "CMakeLists.txt").read_text()
    assert re.search(r"cmake_minimum_required\(VERSION 3\.16\.3\.\.\.3\.22\.6 FATAL_ERROR\)", top)
    assert 'set(EXTENSION_LICENSE_FILE "${CMAKE_CURRENT_SOURCE_DIR}/LICENSE")' in top
    assert 'set(EXTENSION_README_FILE "${CMAKE_CURRENT_SOURCE_DIR}/README.md")' in top
    for field in ("EXTENSION_HOMEPAGE", "EXTENSION_ICONURL", "EXTENSION_SCREENSHOTURLS"):
        assert re.search(rf'set\({field} "https://example\.invalid/', top), f"{field}: a clearly marked placeholder"
    description = json.loads((ROOT / "RAMSICPNavigator.json").read_text())
    # slicer-extension-catalog-entry-schema v1.0.1: required $schema, category, scm_url; no other keys
    schema_keys = {"$schema", "category", "scm_url", "scm_revision", "scm_type", "build_dependencies"}
    schema_keys |= {"build_subdirectory", "enabled", "tier"}
    assert description["$schema"].endswith("slicer-extension-catalog-entry-schema-v1.0.1.json#")
    assert set(description) <= schema_keys and {"$schema", "category", "scm_url"} <= set(description)
    assert description["category"] == "IGT" and description["scm_type"] == "git" and 1 <= description["tier"] <= 5
    assert "add_test(NAME RAMSICPNavigatorPytest" in top


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
    assert f"add_subdirectory({name})" in top


def _cmake_listed_files(name):
    cmake = (ROOT / name / "CMakeLists.txt").read_text()
    listed = re.findall(r"^\s+(\S+)\s*$", cmake.split("slicerMacroBuildScriptedModule")[0], flags=re.MULTILINE)
    return [entry.replace("${MODULE_NAME}", name) for entry in listed if "Lib/" in entry]


def test_a_slicer_style_install_imports_and_finds_its_data(tmp_path):
    """Copy only the files CMake lists (as a Slicer extension install does) and use the libraries from there."""
    import os
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
        env={**os.environ, "PYTHONPATH": str(tmp_path)},
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "True"


# -- what only Slicer's own process shows (issue 24) ---------------------------------------------------------
def _method(tree, class_name, method):
    return next(node for node in _classes(tree)[class_name].body if getattr(node, "name", None) == method)


def _facts(tag):
    return SLICER_API["tags"][tag]["facts"]


@pytest.mark.parametrize("name", MODULES)
def test_one_parameter_node_wrapper_is_bound_to_the_gui_once_per_parameter_node(name):
    """Slicer's parameterNodeWrapper adds an observer to the parameter node at every ``connectGui`` and
    ``disconnectGui`` does not remove it (v5.6.0 to v5.10.0): the logic keeps one wrapper while the node is the
    same, the widget binds it only when it is a different one, and leaving the module does not unbind it."""
    for tag in SUPPORTED_TAGS:
        assert _facts(tag)["connectGuiAddsAnObserver"] and not _facts(tag)["disconnectGuiRemovesIt"]
        assert "parameterNode" in _facts(tag)["parameterNodeWrapperInstance"]
    tree = _tree(name)
    logic = ast.unparse(_method(tree, f"{name}Logic", "getParameterNode"))
    guard = "if self._parameterNode is None or self._parameterNode.parameterNode is not node:"
    assert guard in logic and logic.count(f"{name}ParameterNode(") == 1
    assert logic.index(guard) < logic.index(f"{name}ParameterNode(")
    initialize = ast.unparse(_method(tree, f"{name}Widget", "initializeParameterNode"))
    assert "if parameterNode is not self._parameterNode:" in initialize
    assert "setParameterNode" not in ast.unparse(_method(tree, f"{name}Widget", "exit"))
    widget = ast.unparse(_classes(tree)[f"{name}Widget"])
    assert len(re.findall(r"\.connectGui\(", widget)) == 1
    assert ".connectGui(self.ui)" in ast.unparse(_method(tree, f"{name}Widget", "setParameterNode"))


def test_the_robot_link_is_serviced_by_a_timer_the_logic_owns():
    """A widget's timer stops when the surgeon switches module (exit()); the robot controller drops a client that
    has not read for 2 s, and the robot stops mid-cut. The logic's timer runs from its creation to close()."""
    tree = _tree("RAMSICPRegistration")
    logic = ast.unparse(_method(tree, "RAMSICPRegistrationLogic", "__init__"))
    for line in (
        "self._serviceTimer = qt.QTimer()",
        "self._serviceTimer.setInterval(ROBOT_SERVICE_INTERVAL_MS)",
        "self._serviceTimer.connect('timeout()', self.controller.service)",
        "self._serviceTimer.start()",
    ):
        assert line in logic, line
    assert _module_constant(tree, "ROBOT_SERVICE_INTERVAL_MS") <= 200
    assert "_serviceTimer" not in ast.unparse(_classes(tree)["RAMSICPRegistrationWidget"])
    assert "self._serviceTimer.stop()" in ast.unparse(_method(tree, "RAMSICPRegistrationLogic", "close"))
    assert "self.logic.close()" in ast.unparse(_method(tree, "RAMSICPRegistrationWidget", "cleanup"))


def test_the_module_saves_through_the_controller():
    """Slicer's scene writer commits only the XML for .mrml and calls vtkMRMLScene::WriteToMRB for .mrb (v5.6.0
    to v5.10.0): the module saves through the controller, whose save writes both with their data (tested in
    test_navigation.py)."""
    for tag in SUPPORTED_TAGS:
        assert (_facts(tag)["sceneWriterMrml"], _facts(tag)["sceneWriterMrb"]) == ("Commit", "WriteToMRB")
    save = ast.unparse(_method(_tree("RAMSICPRegistration"), "RAMSICPRegistrationWidget", "onSave"))
    assert "self.run('save', path)" in save and "saveScene" not in save
    assert "(*.mrb)" in save and "(*.mrml)" in save


def test_the_ct_progress_dialog_is_modal():
    """``slicer.util.createProgressDialog`` leaves the dialog modeless (v5.6.0 to v5.10.0) and the progress
    callback processes events: the module makes it modal before the run starts."""
    for tag in SUPPORTED_TAGS:
        assert not _facts(tag)["createProgressDialogSetsModality"]
    process = ast.unparse(_method(_tree("RAMSICPRegistration"), "RAMSICPRegistrationWidget", "onProcessCT"))
    modal = "dialog.setWindowModality(qt.Qt.WindowModal)"
    assert modal in process and process.index(modal) < process.index("self.run('process_ct'")


def test_the_collect_shortcut_is_free_in_slicer_and_in_every_operating_system():
    """Ctrl+Space was Spotlight on macOS (Qt reads Ctrl as Cmd there) and the input-method switch elsewhere."""
    tree = _tree("RAMSICPRegistration")
    shortcut = _module_constant(tree, "COLLECT_SHORTCUT")
    assert "qt.QKeySequence(COLLECT_SHORTCUT)" in ast.unparse(
        _method(tree, "RAMSICPRegistrationWidget", "installShortcut")
    )
    for tag in SUPPORTED_TAGS:
        assert shortcut not in SLICER_API["tags"][tag]["shortcuts"], f"Slicer {tag} uses {shortcut}"
        assert "Ctrl+Shift+Space" in SLICER_API["tags"][tag]["shortcuts"]  # the extraction found Slicer's own
    systems = json.loads((ROOT / "Testing" / "Data" / "system_shortcuts.json").read_text())
    for system in ("macOS", "Windows", "Linux"):
        assert shortcut not in systems[system]["sequences"], f"{system} takes {shortcut}"
    assert "Ctrl+Space" in systems["macOS"]["sequences"]  # the old choice: Spotlight
    collect = next(w for w in _ui("RAMSICPRegistration").iter("widget") if w.get("name") == "collectButton")
    texts = [prop.findtext("string") for prop in collect.findall("property")]
    assert any(shortcut in text for text in texts) and not any("Ctrl+Space" in text for text in texts)


def test_the_bridge_starts_the_tracker_with_slicers_python_and_its_self_test_takes_a_free_port():
    """PythonSlicer, found as slicer.util._executePythonModule finds it (v5.6.0 to v5.10.0); the self-test asks
    for any free port instead of a fixed one that may be taken."""
    for tag in SUPPORTED_TAGS:
        assert _facts(tag)["executePythonModuleFinds"] == 'shutil.which("PythonSlicer")'
    tree = _tree("OpenIGTLinkBridge")
    logic = ast.unparse(_method(tree, "OpenIGTLinkBridgeLogic", "__init__"))
    assert "tracker_python=shutil.which('PythonSlicer')" in logic
    self_test = ast.unparse(_classes(tree)["OpenIGTLinkBridgeTest"])
    assert "start_tracker(port=0)" in self_test and not re.search(r"\b(1[0-9]{4}|[2-6][0-9]{4})\b", self_test)
    assert "self.ui.trackerLogTextEdit.plainText" in ast.unparse(_classes(tree)["OpenIGTLinkBridgeWidget"])


#: The MRML methods the libraries call that issue 24 added, by the class that declares them.
MRML_METHODS = {
    "vtkMRMLScene": ("WriteToMRB", "ReadFromMRB"),
    "vtkMRMLTransformNode": ("IsTransformToWorldLinear", "GetMatrixTransformToWorld"),
    "vtkMRMLTransformableNode": ("GetParentTransformNode",),
}


def test_every_mrml_method_the_libraries_call_for_saving_and_the_ct_geometry_exists_in_every_release():
    library = "".join(
        path.read_text()
        for folder in ("RAMSICPRegistration", "OpenIGTLinkBridge")
        for path in (ROOT / folder).rglob("*.py")
    )
    for cls, methods in MRML_METHODS.items():
        for method in methods:
            assert f".{method}(" in library, method
            for tag in SUPPORTED_TAGS:
                assert method in SLICER_API["tags"][tag]["mrml"][cls], f"{cls}::{method} not in Slicer {tag}"


def test_the_residual_tables_include_column_is_the_kind_slicer_shows_as_tick_boxes():
    for tag in SUPPORTED_TAGS:
        assert _facts(tag)["tableViewTickBoxColumn"] == "vtkBitArray"
        assert _facts(tag)["tableViewTickWrites"] == "vtkVariant(checked)"
    navigation = (ROOT / "RAMSICPRegistration" / "RAMSICPRegistrationLib" / "navigation" / "navigation.py").read_text()
    assert "included = vtkBitArray()" in navigation
