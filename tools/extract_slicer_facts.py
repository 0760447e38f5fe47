"""Add to Testing/Data/slicer_api.json, for each supported Slicer tag, the facts from Slicer's sources that the
modules' Slicer-only behaviour relies on: the key sequences Slicer binds (``shortcuts``), a few MRML methods
(``mrml``), and what util.py, parameterNodeWrapper, qMRMLTableModel and qSlicerSceneWriter do (``facts``).

    python tools/extract_slicer_facts.py PATH/TO/Slicer.git Testing/Data/slicer_api.json

The first argument is a clone of https://github.com/Slicer/Slicer holding the tags v5.6.0, v5.8.1 and v5.10.0.
"""

import json
import re
import subprocess
import sys

SLICER = sys.argv[1]


def show(tag, path):
    return subprocess.run(
        ["git", "-C", SLICER, "show", f"{tag}:{path}"], capture_output=True, text=True, check=True
    ).stdout


def files(tag):
    out = subprocess.run(
        ["git", "-C", SLICER, "ls-tree", "-r", "--name-only", tag], capture_output=True, text=True
    ).stdout.split()
    return [f for f in out if f.endswith((".cxx", ".ui", ".py")) and "/Testing/" not in f and "Tests/" not in f]


KEYMAP = {
    "ControlModifier": "Ctrl",
    "CTRL": "Ctrl",
    "ShiftModifier": "Shift",
    "SHIFT": "Shift",
    "AltModifier": "Alt",
    "ALT": "Alt",
}
KEYNAMES = {
    "down": "Down",
    "up": "Up",
    "left": "Left",
    "right": "Right",
    "left arrow": "Left",
    "right arrow": "Right",
    "up arrow": "Up",
    "down arrow": "Down",
    "space": "Space",
}
ORDER = {"Ctrl": 0, "Shift": 1, "Alt": 2, "Meta": 3}


def norm(seq):
    parts = [p.strip() for p in re.split(r"\s*\+\s*", seq) if p.strip()]
    parts = [p.capitalize() if p.lower() in ("ctrl", "shift", "alt", "meta") else p for p in parts]
    mods = sorted([p for p in parts if p in ORDER], key=ORDER.get)
    keys = [KEYNAMES.get(p.lower(), p.upper() if len(p) == 1 else p) for p in parts if p not in ORDER]
    return "+".join(mods + keys)


def shortcuts(tag):
    found = set()
    for f in files(tag):
        text = show(tag, f)
        if "hortcut" not in text and "QKeySequence" not in text:
            continue
        for m in re.finditer(
            r'(?:QKeySequence|Shortcuts?)\s*\(\s*(?:\{\s*)?(?:[A-Za-z_:]+::tr\()?\s*"((?:Ctrl|Shift|Alt|Meta)\+[^"]+)"',
            text,
            re.I,
        ):
            found.add(norm(m.group(1)))
        for m in re.finditer(r"Shortcuts?\(\{([^}]*)\}", text):
            for s in re.findall(r'"((?:Ctrl|Shift|Alt|Meta)\+[^"]+)"', m.group(1)):
                found.add(norm(s))
        for m in re.finditer(r'Shortcut\s*\{\s*"((?:Ctrl|Shift|Alt|Meta)\+[^"]+)"', text):
            found.add(norm(m.group(1)))
        for m in re.finditer(r"QKeySequence\(((?:Qt::[A-Za-z]+\s*[+|]\s*)+Qt::Key_([A-Za-z0-9]+))\)", text):
            mods = [KEYMAP.get(x, x) for x in re.findall(r"Qt::([A-Za-z]+)\s*[+|]", m.group(1))]
            found.add(norm("+".join(mods + [m.group(2)])))
        if f.endswith(".ui"):
            for m in re.finditer(r'<property name="shortcut">\s*<string>([^<]+)</string>', text):
                found.add(norm(m.group(1)))
        if f.endswith(".py"):
            for m in re.finditer(r'shortcut="([^"]+\+[^"]+)"', text):
                found.add(norm(m.group(1)))
    doc = show(tag, "Docs/user_guide/user_interface.md")
    for row in re.findall(r"^\|\s*(`[^|]*`)\s*\|", doc, re.M):
        keys = re.findall(r"`([^`]+)`", row.split(" / ")[0])
        if len(keys) == 2 and keys[0] in ("Ctrl", "Shift", "Alt") and not re.search("mouse|click|drag|wheel", keys[1]):
            found.add(norm("+".join(keys)))
    return sorted(found)


MRML = {
    "Libs/MRML/Core/vtkMRMLScene.h": ("vtkMRMLScene", ["WriteToMRB", "ReadFromMRB", "Commit", "Import"]),
    "Libs/MRML/Core/vtkMRMLTransformNode.h": (
        "vtkMRMLTransformNode",
        ["IsTransformToWorldLinear", "GetMatrixTransformToWorld", "IsLinear"],
    ),
    "Libs/MRML/Core/vtkMRMLTransformableNode.h": (
        "vtkMRMLTransformableNode",
        ["GetParentTransformNode", "SetAndObserveTransformNodeID"],
    ),
    "Libs/MRML/Core/vtkMRMLVolumeNode.h": ("vtkMRMLVolumeNode", ["GetIJKToRASMatrix"]),
}


def mrml(tag):
    found = {}
    for path, (cls, names) in MRML.items():
        header = show(tag, path)
        found[cls] = sorted(n for n in names if re.search(rf"\b{n}\s*\(", header))
    return found


def facts(tag):
    util = show(tag, "Base/Python/slicer/util.py")
    execute = util[util.index("def _executePythonModule") : util.index("def pip_install")]
    progress = util[util.index("def createProgressDialog") :]
    progress = progress[: progress.index("\ndef ")]
    wrapper = show(tag, "Base/Python/slicer/parameterNodeWrapper/wrapper.py")
    connect = wrapper[wrapper.index("def _connectParametersToGui") : wrapper.index("def findChildWidgetForParameter")]
    disconnect = wrapper[wrapper.index("def _disconnectGui") :]
    disconnect = disconnect[: disconnect.index("\ndef ")]
    instance = sorted(
        set(re.findall(r'checkedSetAttr\(classtype, "(\w+)"', wrapper))
        | set(re.findall(r"^    self\.(parameterNode) = parameterNode", wrapper, re.M))
    )
    model = show(tag, "Libs/MRML/Widgets/qMRMLTableModel.cxx")
    writer = show(tag, "Modules/Loadable/Data/qSlicerSceneWriter.cxx")
    to_mrml = writer[
        writer.index("bool qSlicerSceneWriter::writeToMRML") : writer.index("bool qSlicerSceneWriter::writeToMRB")
    ]
    to_mrb = writer[writer.index("bool qSlicerSceneWriter::writeToMRB") :]
    to_mrb = to_mrb[: to_mrb.index("\n}\n")]
    return {
        "executePythonModuleFinds": 'shutil.which("PythonSlicer")'
        if 'shutil.which("PythonSlicer")' in execute
        else None,
        "createProgressDialogSetsModality": "Modality" in progress or "modal =" in progress,
        "parameterNodeWrapperInstance": instance,
        "connectGuiAddsAnObserver": "self.AddObserver(" in connect,
        "disconnectGuiRemovesIt": "RemoveObserver" in disconnect,
        "tableViewTickBoxColumn": "vtkBitArray"
        if "vtkBitArray::SafeDownCast(columnArray)" in model and "setCheckable(true)" in model
        else None,
        "tableViewTickWrites": "vtkVariant(checked)"
        if "table->SetValue(tableRow, tableCol, vtkVariant(checked))" in model
        else None,
        "sceneWriterMrml": "Commit"
        if "Commit()" in to_mrml
        and "WriteToMRB" not in to_mrml
        and "SaveSceneToSlicerDataBundleDirectory" not in to_mrml
        else None,
        "sceneWriterMrb": "WriteToMRB" if "WriteToMRB(" in to_mrb else None,
    }


path = sys.argv[2]
api = json.load(open(path))
for tag in ("v5.6.0", "v5.8.1", "v5.10.0"):
    api["tags"][tag]["shortcuts"] = shortcuts(tag)
    api["tags"][tag]["mrml"] = mrml(tag)
    api["tags"][tag]["facts"] = facts(tag)
ADDED_SOURCES = (
    "; shortcuts: every key sequence Slicer's .ui, .cxx and .py files bind and Docs/user_guide/user_interface.md "
    "lists; mrml: Libs/MRML/Core/vtkMRML{Scene,TransformNode,TransformableNode,VolumeNode}.h; facts: util.py "
    "(_executePythonModule, createProgressDialog), parameterNodeWrapper/wrapper.py, "
    "Libs/MRML/Widgets/qMRMLTableModel.cxx, Modules/Loadable/Data/qSlicerSceneWriter.cxx"
)
if ADDED_SOURCES not in api["source"]:
    api["source"] = api["source"].rstrip(".") + ADDED_SOURCES
json.dump(api, open(path, "w"), indent=1, sort_keys=True)
open(path, "a").write("\n")
