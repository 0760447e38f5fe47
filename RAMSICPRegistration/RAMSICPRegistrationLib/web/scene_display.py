"""How the browser view draws the workflow's nodes: display nodes only, never the workflow's data.

* the CT in the slice views, the segmentation as outlines in the slices, and in the 3D view the IPC model in bone
  colour, drawn as a display copy with a tenth of its triangles (``update_bone_display``: software GL spends most
  of a 3D frame on the IPC's 200,000 triangles) that stays within ``BONE_DISPLAY_TOLERANCE_MM`` of the IPC;
* the probe as a needle model (tip at its origin, shaft back to the probe's origin) under a display transform
  that ``move_needle`` sets to the tip's pose in the world only when it moved: a tracker repeats the same pose 60
  times a second while the probe is still, and every repeat would make every view render, encode and send again;
* the registered probe points as spheres coloured by their residual (green 0 mm to red ``RESIDUAL_SCALE_MM``),
  a model under ``ReferenceToImage`` made from the residual table; the point lists themselves, in reference
  coordinates, are hidden (they would float away from the CT);
* the slices follow the probe tip (``follow_tip``).

Every function takes the scene or node it works on; the nodes it adds are hidden from editors, never saved with
the scene, and carry ``DISPLAY_ATTRIBUTE`` so that they are recognised (and replaced) on the next call.
"""

import logging
from contextlib import contextmanager

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
#: The 3D view's copy of the IPC keeps a tenth of its triangles (quadric decimation): on the demo patient 21,316 of
#: 213,164, 0.067 mm from the IPC at most, made and checked in about 2 s, and a 900 x 880 render of the 3D view in
#: 11.7 ms instead of 26.2 ms (software GL, measured here).
BONE_DISPLAY_REDUCTION = 0.9
#: A copy farther than this (mm) from the IPC, in either direction, is not used: the 3D view draws the IPC itself.
BONE_DISPLAY_TOLERANCE_MM = 0.1
#: Attribute of the display copy naming the IPC node and the state of its surface that it was made from.
BONE_SOURCE_ATTRIBUTE = "RAMSICP.WebDisplay.Source"

logger = logging.getLogger(__name__)


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
        _style_bone(model.GetDisplayNode())
    update_bone_display(parameters.node.GetScene(), model)
    segmentation = parameters.segmentation
    if segmentation is not None and segmentation.GetDisplayNode() is not None:
        display = segmentation.GetDisplayNode()
        display.SetVisibility3D(False)
        display.SetVisibility2DFill(False)
    for node in (parameters.markersPatient, parameters.probePoints, parameters.targetsPatient):
        _hide(node)  # reference coordinates: shown registered as the residual spheres instead


def _style_bone(display):
    display.SetColor(*BONE_COLOUR)
    # Opaque: software GL draws the 200,000 translucent triangles with depth peeling in about 340 ms a frame,
    # opaque in about 55 ms (900 x 880 pixels, measured here).
    display.SetOpacity(1.0)
    display.SetBackfaceCulling(True)  # a closed surface seen from outside: 36 -> 25 ms a frame
    display.SetVisibility2D(False)  # the segmentation's outline shows it; re-cutting 200,000 triangles is slow


def bone_display_surface(poly_data, reduction=BONE_DISPLAY_REDUCTION):
    """A lighter copy of a closed surface (vtkPolyData, mm) for drawing: ``reduction`` of its triangles removed by
    quadric decimation, which keeps the shape and the volume, with smooth point normals so that the fewer, larger
    triangles shade as the surface they approximate rather than as facets."""
    from vtkmodules.vtkFiltersCore import vtkPolyDataNormals, vtkQuadricDecimation

    decimate = vtkQuadricDecimation()
    decimate.SetInputData(poly_data)
    decimate.SetTargetReduction(reduction)
    decimate.VolumePreservationOn()
    normals = vtkPolyDataNormals()
    normals.SetInputConnection(decimate.GetOutputPort())
    normals.SplittingOff()  # a bone has no sharp edges to keep
    normals.ConsistencyOn()
    normals.Update()
    return normals.GetOutput()


def surface_deviation_mm(shown, original):
    """Largest distance (mm) between two surfaces (vtkPolyData), both ways: from each vertex and triangle centre of
    one to the nearest point on the triangles of the other. On a dense surface such as the IPC (a vertex every
    0.5 mm) this is the Hausdorff distance between what is drawn and the data, to a few hundredths of a mm."""
    from vtkmodules.vtkFiltersGeneral import vtkDistancePolyDataFilter

    distance = vtkDistancePolyDataFilter()
    distance.SetInputData(0, shown)
    distance.SetInputData(1, original)
    distance.SignedDistanceOff()
    distance.ComputeSecondDistanceOn()  # from the original to the shown surface too
    distance.ComputeCellCenterDistanceOn()
    distance.Update()
    largest = 0.0
    for port in (0, 1):
        output = distance.GetOutput(port)
        for data in (output.GetPointData(), output.GetCellData()):
            array = data.GetArray("Distance")
            if array is not None and array.GetNumberOfTuples():
                largest = max(largest, float(array.GetRange()[1]))
    return largest


#: Raised when the display copy's recipe changes in a way its key (the IPC's triangles, the reduction) does not show.
DISPLAY_COPY_VERSION = 1


def cached_display_copy(surface, reduction=BONE_DISPLAY_REDUCTION, directory=None):
    """(copy, deviation): ``bone_display_surface(surface)`` and its ``surface_deviation_mm`` from ``surface``, read
    from the user's cache (``simulation.phantom_cache.cache_directory``; the same IPC is shown at every start of
    ``ramsicp web --demo``) when this surface was drawn before, else made (7 s for the demo's IPC on a loaded
    machine) and cached: one ``.npz`` named by the SHA-256 of the surface's vertices and triangles and the
    reduction, written atomically; a damaged file is made again, an unwritable cache costs only time."""
    import hashlib
    import zipfile
    from pathlib import Path

    from ..io.atomic_files import atomic_path
    from ..io.vtk_arrays import triangle_arrays
    from ..simulation.phantom_cache import cache_directory

    vertices, triangles = triangle_arrays(surface)
    digest = hashlib.sha256(f"display copy v{DISPLAY_COPY_VERSION} reduction {reduction!r}".encode())
    for array in (vertices, triangles):
        digest.update(np.ascontiguousarray(array).tobytes())
    path = (cache_directory() if directory is None else Path(directory)) / f"display-copy-{digest.hexdigest()[:32]}.npz"
    try:
        with np.load(path, allow_pickle=False) as stored:
            copy = _with_normals(poly_data(stored["vertices"], stored["triangles"]), stored["normals"])
            return copy, float(stored["deviation_mm"])
    except FileNotFoundError:
        pass
    except (OSError, ValueError, KeyError, IndexError, EOFError, zipfile.BadZipFile) as error:
        logger.warning("the cached display copy %s is damaged (%s): making it again", path, error)
    copy = bone_display_surface(surface, reduction)
    deviation = surface_deviation_mm(copy, surface)
    from vtkmodules.util.numpy_support import vtk_to_numpy

    shown_vertices, shown_triangles = triangle_arrays(copy)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as temporary, open(temporary, "wb") as stream:
            np.savez(
                stream,
                vertices=shown_vertices,
                triangles=shown_triangles,
                normals=vtk_to_numpy(copy.GetPointData().GetNormals()),
                deviation_mm=deviation,
            )
    except OSError as error:
        logger.info("the display copy could not be cached in %s (%s)", path, error)
    return copy, deviation


def _with_normals(surface, normals):
    """``surface`` with (M, 3) point ``normals`` (the shading of ``bone_display_surface``)."""
    from vtkmodules.util.numpy_support import numpy_to_vtk

    if len(normals) != surface.GetNumberOfPoints():
        raise ValueError(f"{len(normals)} normals for {surface.GetNumberOfPoints()} points")
    array = numpy_to_vtk(np.ascontiguousarray(normals), deep=True)
    array.SetName("Normals")
    surface.GetPointData().SetNormals(array)
    return surface


def update_bone_display(scene, ipc_model):
    """Draw the IPC (``ipc_model``, a vtkMRMLModelNode, or None) in the 3D view by a display copy (``BoneDisplay``,
    made by ``bone_display_surface`` when the IPC or its surface changes) and hide the IPC's own display node in
    3D, when the copy lies within ``BONE_DISPLAY_TOLERANCE_MM`` of the IPC; otherwise draw the IPC itself. Returns
    the copy, or None when the IPC itself is drawn (or there is none). Cheap when nothing changed."""
    surface = None if ipc_model is None else ipc_model.GetPolyData()
    if surface is None or surface.GetNumberOfCells() == 0:
        node = _find(scene, "BoneDisplay")
        if node is not None:
            _show_bone_source(scene, node, True)
            scene.RemoveNode(node)
        return None
    source = f"{ipc_model.GetID()} {surface.GetMTime()} {ipc_model.GetTransformNodeID()}"
    node = _display_node(scene, "BoneDisplay", "vtkMRMLModelNode")
    if node.GetAttribute(BONE_SOURCE_ATTRIBUTE) != source:
        _show_bone_source(scene, node, True)  # the IPC it was made from, if another
        node.SetAttribute(BONE_SOURCE_ATTRIBUTE, source)
        shown, deviation = cached_display_copy(surface)
        usable = deviation <= BONE_DISPLAY_TOLERANCE_MM
        logger.log(
            logging.INFO if usable else logging.WARNING,
            "the IPC's display copy has %d of its %d triangles and lies %.3f mm from it at most: %s",
            shown.GetNumberOfCells(),
            surface.GetNumberOfCells(),
            deviation,
            "the 3D view draws the copy" if usable else f"more than {BONE_DISPLAY_TOLERANCE_MM} mm, the IPC is drawn",
        )
        node.SetAndObservePolyData(shown if usable else None)
        node.SetAndObserveTransformNodeID(ipc_model.GetTransformNodeID())
        _style_bone(node.GetDisplayNode())
    usable = node.GetPolyData() is not None
    node.GetDisplayNode().SetVisibility(usable)
    _show_bone_source(scene, node, not usable)
    return node if usable else None


def _show_bone_source(scene, bone_display, visible):
    """Show or hide in 3D the IPC that the display copy ``bone_display`` was made from (when it still exists)."""
    source = (bone_display.GetAttribute(BONE_SOURCE_ATTRIBUTE) or "").split(" ")[0]
    model = scene.GetNodeByID(source) if source else None
    if model is not None and model.GetDisplayNode() is not None:
        model.GetDisplayNode().SetVisibility3D(visible)


@contextmanager
def bone_as_saved(scene):
    """While the scene is written: the IPC shown in 3D by its own display node, as Slicer will show the saved scene
    (the display copy is never saved); hidden again afterwards."""
    node = _find(scene, "BoneDisplay")
    if node is None or node.GetPolyData() is None:  # the IPC is drawn itself
        yield
        return
    _show_bone_source(scene, node, True)
    try:
        yield
    finally:
        _show_bone_source(scene, node, False)


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
    _mark_display_only(node)
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


#: A slice whose plane would move by less than this (mm) stays where it is (and is not cut again).
SLICE_STILL_MM = 1e-3


def follow_tip(scene, position, volume=None):
    """Move every slice (axial, coronal, sagittal) through ``position`` (3,) RAS mm, as Slicer's reslice driver
    does, onto the nearest voxel plane of ``volume`` (the CT) as Slicer's slice offset slider does: the slice shows
    the CT's own voxels rather than values interpolated between two planes, and is cut again only when the tip
    crosses a voxel plane (each cut re-samples the CT, the costliest part of a slice's frame). A slice oblique to
    the volume's axes, or a volume under a transform, gets the exact position. Returns the number of slices moved.
    """
    point = np.asarray(position, dtype=np.float64)
    ijk_to_ras = _ijk_to_ras(volume)
    moved = 0
    for index in range(scene.GetNumberOfNodesByClass("vtkMRMLSliceNode")):
        node = scene.GetNthNodeByClass(index, "vtkMRMLSliceNode")
        slice_to_ras = node.GetSliceToRAS()
        normal = np.array([slice_to_ras.GetElement(row, 2) for row in range(3)])
        normal /= np.linalg.norm(normal)
        origin = np.array([slice_to_ras.GetElement(row, 3) for row in range(3)])
        target = _on_voxel_plane(point, normal, ijk_to_ras)
        if abs(normal @ (target - origin)) < SLICE_STILL_MM:
            continue
        node.JumpSliceByOffsetting(*(float(value) for value in target))
        moved += 1
    return moved


def _ijk_to_ras(volume):
    """(4, 4) IJK-to-RAS matrix of a volume node not under a transform; None otherwise."""
    if volume is None or volume.GetParentTransformNode() is not None:
        return None
    from vtkmodules.vtkCommonMath import vtkMatrix4x4

    matrix = vtkMatrix4x4()
    volume.GetIJKToRASMatrix(matrix)
    return np.array([[matrix.GetElement(row, column) for column in range(4)] for row in range(4)])


def _on_voxel_plane(point, normal, ijk_to_ras):
    """``point`` (3,) RAS moved along ``normal`` onto the nearest plane of voxel centres of the volume whose axis is
    parallel to ``normal``; ``point`` itself when no axis is (or there is no volume)."""
    if ijk_to_ras is None:
        return point
    axes = ijk_to_ras[:3, :3] / np.linalg.norm(ijk_to_ras[:3, :3], axis=0)
    parallel = np.flatnonzero(np.abs(normal @ axes) > 0.9999)
    if parallel.size == 0:
        return point
    ijk = np.linalg.solve(ijk_to_ras, np.append(point, 1.0))
    ijk[parallel[0]] = np.round(ijk[parallel[0]])
    return (ijk_to_ras @ ijk)[:3]


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
        _mark_display_only(node)
        if display:
            node.CreateDefaultDisplayNodes()
            for index in range(node.GetNumberOfDisplayNodes()):
                node.GetNthDisplayNode(index).SetSaveWithScene(False)
    return node


def _mark_display_only(node):
    """What only this view draws: hidden from editors and never written into a saved scene."""
    node.SetAttribute(DISPLAY_ATTRIBUTE, "1")
    node.SetHideFromEditors(True)
    node.SetSaveWithScene(False)
