"""How the browser view draws the workflow's nodes: display nodes only, never the workflow's data.

* the CT in the slice views, the IPC model in bone colour (3D only), the segmentation as outlines in the slices;
* the probe as a needle model (tip at its origin, shaft back to the probe's origin) under a display transform
  that ``move_needle`` sets to the tip's pose in the world only when it moved: a tracker repeats the same pose 60
  times a second while the probe is still, and every repeat would make every view render, encode and send again;
* the registered probe points as spheres coloured by their residual (green 0 mm to red ``RESIDUAL_SCALE_MM``),
  a model under ``ReferenceToImage`` made from the residual table; the point lists themselves, in reference
  coordinates, are hidden (they would float away from the CT);
* the slices follow the probe tip (``follow_tip``).

Every function takes the scene or node it works on; the nodes it adds are hidden from editors and carry
``DISPLAY_ATTRIBUTE`` so that they are recognised (and replaced) on the next call.
"""

import numpy as np

from ..io.vtk_arrays import poly_data
from ..navigation.navigation import matrix_of, set_matrix
from ..navigation.scene_render import RESIDUAL_SCALE_MM

#: Attribute marking the display-only nodes this module adds.
DISPLAY_ATTRIBUTE = "RAMSICP.WebDisplay"
NEEDLE_RADIUS_MM = 1.2
TIP_RADIUS_MM = 2.0
RESIDUAL_SPHERE_RADIUS_MM = 1.5
BONE_COLOUR = (0.89, 0.85, 0.75)
NEEDLE_COLOUR = (0.25, 0.75, 1.0)
#: CT window and level (HU) for the slices: bone and soft tissue both readable.
CT_WINDOW_LEVEL = (1800.0, 300.0)


def style_workflow_nodes(parameters):
    """Colours and visibility of the workflow's nodes as the surgeon wants them in the browser."""
    ct = parameters.ctVolume
    if ct is not None:
        if ct.GetDisplayNode() is None:
            ct.CreateDefaultDisplayNodes()
        display = ct.GetDisplayNode()
        display.SetAutoWindowLevel(False)
        display.SetWindowLevel(*CT_WINDOW_LEVEL)
    model = parameters.ipcModel
    if model is not None:
        if model.GetDisplayNode() is None:
            model.CreateDefaultDisplayNodes()
        display = model.GetDisplayNode()
        display.SetColor(*BONE_COLOUR)
        # Opaque: software GL draws the 200,000 translucent triangles with depth peeling in about 340 ms a frame,
        # opaque in about 55 ms (900 x 880 pixels, measured here).
        display.SetOpacity(1.0)
        display.SetBackfaceCulling(True)  # a closed surface seen from outside: 36 -> 25 ms a frame
        display.SetVisibility2D(False)  # the segmentation's outline shows it; re-cutting 200,000 triangles is slow
    segmentation = parameters.segmentation
    if segmentation is not None and segmentation.GetDisplayNode() is not None:
        display = segmentation.GetDisplayNode()
        display.SetVisibility3D(False)
        display.SetVisibility2DFill(False)
    for node in (parameters.markersPatient, parameters.probePoints, parameters.targetsPatient):
        _hide(node)  # reference coordinates: shown registered as the residual spheres instead


def _hide(node):
    if node is None:
        return
    if node.GetDisplayNode() is None:
        node.CreateDefaultDisplayNodes()
    node.GetDisplayNode().SetVisibility(False)


def needle_poly_data(tip_in_probe):
    """Needle (tube and tip ball) in the tip's frame: from the tip (origin) back to the probe's origin, which lies
    at ``-tip_in_probe`` (3,) mm, since ``ProbeTipToProbe`` is a translation by ``tip_in_probe``."""
    from vtkmodules.vtkFiltersCore import vtkAppendPolyData, vtkTubeFilter
    from vtkmodules.vtkFiltersSources import vtkLineSource, vtkSphereSource

    line = vtkLineSource()
    line.SetPoint1(0.0, 0.0, 0.0)
    line.SetPoint2(*(-np.asarray(tip_in_probe, dtype=np.float64)))
    tube = vtkTubeFilter()
    tube.SetInputConnection(line.GetOutputPort())
    tube.SetRadius(NEEDLE_RADIUS_MM)
    tube.SetNumberOfSides(16)
    tube.CappingOn()
    ball = vtkSphereSource()
    ball.SetRadius(TIP_RADIUS_MM)
    ball.SetThetaResolution(16)
    ball.SetPhiResolution(16)
    append = vtkAppendPolyData()
    append.AddInputConnection(tube.GetOutputPort())
    append.AddInputConnection(ball.GetOutputPort())
    append.Update()
    return append.GetOutput()


#: A tip pose that moved less than this (mm, and radians for the rotation) is the same picture.
NEEDLE_STILL_MM = 0.01
NEEDLE_STILL_RAD = 1e-4


def update_needle(scene, probe_tip_to_probe):
    """The probe needle model for the tip offset in ``probe_tip_to_probe`` (a pivot result), placed at the tip's
    current pose; None removes it."""
    node = _display_node(scene, "ProbeNeedle", "vtkMRMLModelNode")
    if probe_tip_to_probe is None:
        scene.RemoveNode(node)
        return None
    node.SetAndObservePolyData(needle_poly_data(matrix_of(probe_tip_to_probe, "ProbeTipToProbe")[:3, 3]))
    pose = _display_node(scene, "ProbeNeedlePose", "vtkMRMLLinearTransformNode", display=False)
    node.SetAndObserveTransformNodeID(pose.GetID())
    move_needle(scene, probe_tip_to_probe)
    display = node.GetDisplayNode()
    display.SetColor(*NEEDLE_COLOUR)
    display.SetVisibility2D(True)
    display.SetSliceIntersectionThickness(3)
    return node


def move_needle(scene, probe_tip_to_probe):
    """Put the needle at the tip's pose in the world (ProbeTipToProbe -> ... -> world) when it moved by more than
    ``NEEDLE_STILL_MM`` / ``NEEDLE_STILL_RAD``; returns True when it moved (and the views will render)."""
    from vtkmodules.vtkCommonMath import vtkMatrix4x4

    pose = _find(scene, "ProbeNeedlePose")
    if pose is None or probe_tip_to_probe is None:
        return False
    world = vtkMatrix4x4()
    probe_tip_to_probe.GetMatrixTransformToWorld(world)
    target = np.array([[world.GetElement(row, column) for column in range(4)] for row in range(4)])
    shown = matrix_of(pose, "ProbeNeedlePose")
    moved = np.abs(target[:3, 3] - shown[:3, 3]).max() > NEEDLE_STILL_MM
    turned = np.abs(target[:3, :3] - shown[:3, :3]).max() > NEEDLE_STILL_RAD
    if not (moved or turned):
        return False
    set_matrix(pose, target)
    return True


def residual_points(table_node):
    """(points (N, 3) reference mm, residuals (N,) mm, included (N,) bool) of a residual table."""
    table = table_node.GetTable()
    rows = table.GetNumberOfRows()

    def column(name):
        array = table.GetColumnByName(name)
        return np.array([array.GetValue(row) for row in range(rows)], dtype=np.float64)

    points = np.stack([column(axis) for axis in ("x", "y", "z")], axis=1).reshape(-1, 3)
    return points, column("residual_mm"), column("include").astype(bool)


def update_residual_points(scene, table_node, reference_to_image):
    """Spheres at the included probe points, under ``reference_to_image``, coloured by residual (mm)."""
    node = _display_node(scene, "ProbePointResiduals", "vtkMRMLModelNode")
    if table_node is None or reference_to_image is None:
        scene.RemoveNode(node)
        return None
    from vtkmodules.vtkCommonCore import vtkDoubleArray
    from vtkmodules.vtkFiltersCore import vtkGlyph3D
    from vtkmodules.vtkFiltersSources import vtkSphereSource

    points, residuals, included = residual_points(table_node)
    keep = included & np.isfinite(residuals)
    centres = poly_data(points[keep])
    scalars = vtkDoubleArray()
    scalars.SetName("residual_mm")
    for value in residuals[keep]:
        scalars.InsertNextValue(float(value))
    centres.GetPointData().SetScalars(scalars)
    sphere = vtkSphereSource()
    sphere.SetRadius(RESIDUAL_SPHERE_RADIUS_MM)
    glyphs = vtkGlyph3D()  # each sphere's points carry its centre's residual
    glyphs.SetInputData(centres)
    glyphs.SetSourceConnection(sphere.GetOutputPort())
    glyphs.ScalingOff()
    glyphs.SetColorModeToColorByScalar()
    glyphs.Update()
    node.SetAndObservePolyData(glyphs.GetOutput())
    node.SetAndObserveTransformNodeID(reference_to_image.GetID())
    display = node.GetDisplayNode()
    display.SetActiveScalarName("residual_mm")
    display.SetAndObserveColorNodeID(_residual_colours(scene).GetID())
    display.SetScalarRangeFlag(display.UseManualScalarRange)
    display.SetScalarRange(0.0, RESIDUAL_SCALE_MM)
    display.SetScalarVisibility(True)
    display.SetVisibility2D(False)
    return node


def _residual_colours(scene):
    """A green-to-red colour table (residual 0 to ``RESIDUAL_SCALE_MM``), added once."""
    node = _find(scene, "ResidualColours")
    if node is not None:
        return node
    node = scene.AddNewNodeByClass("vtkMRMLColorTableNode", "ResidualColours")
    node.SetAttribute(DISPLAY_ATTRIBUTE, "1")
    node.SetHideFromEditors(True)
    node.SetTypeToUser()
    steps = 64
    node.SetNumberOfColors(steps)
    for index in range(steps):
        fraction = index / (steps - 1)
        node.SetColor(
            index, f"{fraction * RESIDUAL_SCALE_MM:.2f} mm", min(1.0, 2 * fraction), min(1.0, 2 - 2 * fraction), 0.1
        )
    return node


#: Displayable managers that draw transform nodes' own display nodes (none in this view) and ask their view to
#: render on every update of any transform in the scene.
TRANSFORM_MANAGERS = (
    "vtkMRMLTransformsDisplayableManager2D",
    "vtkMRMLTransformsDisplayableManager3D",
    "vtkMRMLLinearTransformsDisplayableManager",
)


def quiet_transform_managers(displayable_manager_group):
    """Detach a view's transform displayable managers from the scene, so that a view renders when what it shows
    changes, not whenever a tracker updates a transform: with three transforms streamed at 60 Hz, every view
    would otherwise render, encode and send pictures without pause. Returns the number detached."""
    detached = 0
    for name in TRANSFORM_MANAGERS:
        manager = displayable_manager_group.GetDisplayableManagerByClassName(name)
        if manager is not None:
            manager.SetMRMLScene(None)
            detached += 1
    return detached


def follow_tip(scene, position):
    """Move every slice (axial, coronal, sagittal) through ``position`` (3,) RAS mm, as Slicer's reslice driver."""
    x, y, z = (float(value) for value in position)
    for index in range(scene.GetNumberOfNodesByClass("vtkMRMLSliceNode")):
        scene.GetNthNodeByClass(index, "vtkMRMLSliceNode").JumpSliceByOffsetting(x, y, z)


def _find(scene, name):
    for index in range(scene.GetNumberOfNodesByClass("vtkMRMLNode")):
        node = scene.GetNthNodeByClass(index, "vtkMRMLNode")
        if node.GetAttribute(DISPLAY_ATTRIBUTE) and node.GetName() == name:
            return node
    return None


def _display_node(scene, name, node_class, display=True):
    node = _find(scene, name)
    if node is None:
        node = scene.AddNewNodeByClass(node_class, name)
        node.SetAttribute(DISPLAY_ATTRIBUTE, "1")
        node.SetHideFromEditors(True)
        if display:
            node.CreateDefaultDisplayNodes()
    return node
