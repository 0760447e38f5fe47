"""A module's parameter node: what every shell and the controller share, saved with the scene.

The Slicer widget binds its widgets to these names through ``parameterNodeWrapper`` (``SlicerParameterName`` in
the ``.ui``), which stores a node as a node reference and a number, text or choice as a string parameter under the
same name; the controller and the browser view read and write the very same node. ``PARAMETERS`` is the one list
of RAMSICPRegistration's parameters (the OpenIGTLinkBridge module declares its own ``ParameterSet``): a module's
wrapper class must declare exactly these fields (checked by ``Testing/test_module_files``). The node is the
module's singleton parameter node, found and created as ``ScriptedLoadableModuleLogic`` does.
"""

from dataclasses import dataclass

from ..core.hold_still import DEFAULT_STILL_MM, DEFAULT_STILL_S
from ..core.registration import DEFAULT_METHOD, METHODS, POLICIES
from ..core.tool_path import TOOLS

#: Default of ``checkpointLimitMm``: a 1 mm slip of the reference body is caught with margin for a re-touch's
#: spread (a divot touched again at another tilt: the pivot's 0.2-0.3 mm RMS), and no alarm on noise alone.
CHECKPOINT_LIMIT_MM = 0.6

#: The Slicer module's name: the parameter node's singleton tag and its ``ModuleName`` attribute.
MODULE_NAME = "RAMSICPRegistration"

LINEAR_TRANSFORM = "vtkMRMLLinearTransformNode"
FIDUCIALS = "vtkMRMLMarkupsFiducialNode"
PLANE = "vtkMRMLMarkupsPlaneNode"


@dataclass(frozen=True)
class Parameter:
    """One parameter: a node reference (``node_class``, or a tuple of classes any of which will do), a float or int
    within [minimum, maximum], a text, or a choice among ``choices``."""

    name: str
    kind: str  # "node", "float", "int", "text" or "choice"
    description: str
    node_class: str = None
    default: object = None
    minimum: float = None
    maximum: float = None
    choices: tuple = ()


PARAMETERS = (
    # 1. image
    Parameter("ctVolume", "node", "the patient's CT", "vtkMRMLScalarVolumeNode"),
    Parameter("thresholdHU", "float", "bone threshold (HU)", default=200.0, minimum=-1000.0, maximum=3000.0),
    Parameter("segmentation", "node", "bone and marker-sphere segments (written)", "vtkMRMLSegmentationNode"),
    Parameter("ipcModel", "node", "the image point cloud, IPC (written)", "vtkMRMLModelNode"),
    Parameter("markersImage", "node", "marker-sphere centres in the image (written)", FIDUCIALS),
    # 2. tracker
    Parameter("probeTipToProbe", "node", "pivot calibration result (written)", LINEAR_TRANSFORM),
    Parameter("probeToReference", "node", "tracked probe in reference coordinates (eq. 2)", LINEAR_TRANSFORM),
    Parameter("referenceToTracker", "node", "tracked reference body", LINEAR_TRANSFORM),
    # 3. patient points
    Parameter("markersPatient", "node", "marker centres in reference coordinates", FIDUCIALS),
    Parameter("probePoints", "node", "the patient point cloud, PPC (written)", FIDUCIALS),
    Parameter("autoCollectDistanceMm", "float", "auto-collect spacing (mm)", default=5.0, minimum=0.5, maximum=50.0),
    Parameter("holdStillMm", "float", "hold-still radius (mm)", default=DEFAULT_STILL_MM, minimum=0.2, maximum=10.0),
    Parameter("holdStillS", "float", "hold-still time (s)", default=DEFAULT_STILL_S, minimum=0.05, maximum=5.0),
    Parameter(
        "reachableSurface",
        "node",
        "the bone surface the probe can reach, image coordinates (default: the whole IPC)",
        ("vtkMRMLModelNode", FIDUCIALS),
    ),
    Parameter(
        "targetTreMm",
        "float",
        "error the plan allows at its targets (mm): enough touches when all lie below it with 95 % confidence",
        default=1.0,
        minimum=0.05,
        maximum=10.0,
    ),
    Parameter("nextTouch", "node", "the next touch suggested on the bone, image coordinates (written)", FIDUCIALS),
    # 4. register
    Parameter("method", "choice", "registration method", default=DEFAULT_METHOD, choices=METHODS),
    Parameter("policy", "choice", "how the RAMSICP sweep chooses L", default="rms-plateau", choices=POLICIES),
    Parameter("referenceToImage", "node", "registration result (written)", LINEAR_TRANSFORM),
    Parameter("residualTable", "node", "per-point residuals with an include column (written)", "vtkMRMLTableNode"),
    Parameter("sweepChart", "node", "RMS (and TRE) against L (written)", "vtkMRMLPlotChartNode"),
    # 5. verify
    Parameter("targetsImage", "node", "verification targets in the image", FIDUCIALS),
    Parameter("targetsPatient", "node", "verification targets touched on the patient", FIDUCIALS),
    Parameter("checkpoints", "node", "checkpoints on the bone, reference coordinates (written)", FIDUCIALS),
    Parameter(
        "checkpointLimitMm",
        "float",
        "a checkpoint touched again farther than this from where it was stored raises an alarm (mm)",
        default=CHECKPOINT_LIMIT_MM,
        minimum=0.1,
        maximum=5.0,
    ),
    # 6. robot
    Parameter("robotPositions", "node", "calibrator positions in robot-base coordinates", FIDUCIALS),
    Parameter("trackerPositions", "node", "the same positions in tracker coordinates", FIDUCIALS),
    Parameter("robotBaseToTracker", "node", "robot calibration, eq. 3 (written)", LINEAR_TRANSFORM),
    Parameter("imageToRobotBase", "node", "image to robot base, eq. 4 (written)", LINEAR_TRANSFORM),
    # 7. plan and cut
    Parameter("osteotomyPlane", "node", "the planned cut; the blade advances along its y axis", PLANE),
    Parameter(
        "cutExtentMm", "float", "cut width across the bone (mm; 0: all of it)", default=0.0, minimum=0.0, maximum=300.0
    ),
    Parameter(
        "wedgeAngleDeg", "float", "closing-wedge angle (degrees; 0: one cut)", default=0.0, minimum=0.0, maximum=30.0
    ),
    Parameter("wedgePlane", "node", "the wedge's second cut (written)", PLANE),
    Parameter("cuttingTool", "choice", "saw or burr", default="saw", choices=TOOLS),
    Parameter("toolWidthMm", "float", "saw blade width or burr diameter (mm)", default=10.0, minimum=0.5, maximum=50.0),
    Parameter(
        "farMarginMm", "float", "stop this far before the far cortex (mm)", default=2.0, minimum=0.0, maximum=30.0
    ),
    Parameter("cutEndpoints", "node", "the cut's four endpoints on the bone (written)", FIDUCIALS),
    Parameter("toolPath", "node", "the planned tool path, TCP positions (written)", "vtkMRMLModelNode"),
    Parameter("toolToTracker", "node", "tracked cutting tool", LINEAR_TRANSFORM),
    Parameter("toolTipToTool", "node", "the cutting tool's TCP in its marker frame", LINEAR_TRANSFORM),
    Parameter("guidanceDistanceMm", "float", "on plan within (mm)", default=1.0, minimum=0.1, maximum=10.0),
    Parameter("guidanceAngleDeg", "float", "on plan within (degrees)", default=2.0, minimum=0.1, maximum=20.0),
    Parameter("robotHost", "text", "the robot controller's OpenIGTLink address", default="127.0.0.1"),
    Parameter("robotPort", "int", "the robot controller's OpenIGTLink port", default=18945, minimum=1, maximum=65535),
)


def node_classes(parameter):
    """The node classes (tuple) a node parameter accepts."""
    classes = parameter.node_class
    return (classes,) if isinstance(classes, str) else tuple(classes)


class ParameterSet:
    """The parameters of one module, and its singleton parameter node in a scene."""

    def __init__(self, module_name, parameters):
        self.module_name = module_name
        self.parameters = tuple(parameters)
        self.by_name = {parameter.name: parameter for parameter in self.parameters}

    def find_node(self, scene):
        """The module's singleton parameter node in ``scene``, or None (as ``ScriptedLoadableModuleLogic``)."""
        node = scene.GetSingletonNode(self.module_name, "vtkMRMLScriptedModuleNode")
        if node is not None and node.GetAttribute("ModuleName") != self.module_name:
            node.SetAttribute("ModuleName", self.module_name)  # a scene close removes it
        return node

    def get_node(self, scene):
        """The module's singleton parameter node, created the way ``ScriptedLoadableModuleLogic`` creates it."""
        node = self.find_node(scene)
        if node is None:
            node = scene.CreateNodeByClass("vtkMRMLScriptedModuleNode")
            node.UnRegister(None)  # the Python variable owns it now
            node.SetSingletonTag(self.module_name)
            node.SetAttribute("ModuleName", self.module_name)
            node.SetName(self.module_name)
            node = scene.AddNode(node)
        return node

    def on(self, node):
        """Typed access (``Parameters``) to a parameter node of this module."""
        return Parameters(node, self)


REGISTRATION = ParameterSet(MODULE_NAME, PARAMETERS)


def get_parameter_node(scene):
    """RAMSICPRegistration's singleton parameter node (created when missing)."""
    return REGISTRATION.get_node(scene)


class Parameters:
    """Typed access to a parameter node: ``parameters.probeToReference``, ``parameters.thresholdHU`` ...

    Reading a value that was never set gives its default, as ``parameterNodeWrapper`` would write it. Setting a
    node writes a node reference (None clears it); a number or a choice is checked against its range.
    """

    def __init__(self, node, parameter_set=REGISTRATION):
        object.__setattr__(self, "node", node)
        object.__setattr__(self, "parameter_set", parameter_set)

    def _parameter(self, name):
        try:
            return self.parameter_set.by_name[name]
        except KeyError:
            known = ", ".join(self.parameter_set.by_name)
            raise AttributeError(f"no parameter {name!r}; parameters are {known}") from None

    def __getattr__(self, name):
        parameter = self._parameter(name)
        if parameter.kind == "node":
            return self.node.GetNodeReference(name)
        text = self.node.GetParameter(name)
        if not text:
            return parameter.default
        return {"float": float, "int": int}.get(parameter.kind, str)(text)

    def __setattr__(self, name, value):
        parameter = self._parameter(name)
        if parameter.kind == "node":
            classes = node_classes(parameter)
            if value is not None and not any(value.IsA(node_class) for node_class in classes):
                raise TypeError(f"{name}: expected a {' or '.join(classes)}, got {value.GetClassName()}")
            self.node.SetParameter(name, "")  # as parameterNodeWrapper writes a node
            self.node.SetNodeReferenceID(name, None if value is None else value.GetID())
            return
        if parameter.kind in ("float", "int"):
            value = float(value) if parameter.kind == "float" else int(value)
            if not parameter.minimum <= value <= parameter.maximum:
                raise ValueError(f"{name} = {value:g}: must lie in [{parameter.minimum:g}, {parameter.maximum:g}]")
        elif parameter.kind == "choice" and value not in parameter.choices:
            raise ValueError(f"{name} = {value!r}: choose one of {', '.join(parameter.choices)}")
        self.node.SetParameter(name, str(value))
