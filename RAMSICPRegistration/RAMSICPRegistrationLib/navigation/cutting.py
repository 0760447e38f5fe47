"""Step 7 of the workflow on MRML nodes, plan and cut: the planned cut from a markups plane, its endpoints and tool
path written into the scene, the tracked tool's TCP in the image. ``controller.NavigationController`` drives it.

The surgeon places a markups plane (``vtkMRMLMarkupsPlaneNode``) on the bone in the CT: its centre is the middle
of the cut, its normal the cut's normal, its **y axis** the direction in which the blade advances (it enters from
the -y side; the plane's interaction handles turn it about the normal). The plan (``core.osteotomy``) takes the
bone's section from the IPC model (exactly, from its triangles), the cut's width from ``cutExtentMm`` (0: across
the whole bone) and, for a closing wedge (``wedgeAngleDeg`` > 0), a second cut turned about a hinge line across the
first at its far end. It writes the four endpoints of each cut (``CutEndpoints``: E1-E4, W1-W4 for the wedge's cut),
the tool path's TCP positions as a polyline model (``ToolPath``) and the wedge's plane (``OsteotomyWedgePlane``),
and sizes the plane to the cut.
"""

from dataclasses import dataclass

import numpy as np

from ..core.tool_path import plan_osteotomy
from ..io.vtk_arrays import triangle_arrays
from . import mrml_nodes
from .navigation import matrix_of


@dataclass(frozen=True)
class PlannedCut:
    """What ``plan_cut`` produced: the CutPlan of each cut, the tool path in image coordinates, and ``inputs``, the
    plane and settings it was planned from (a different ``cut_inputs`` means the plan is out of date)."""

    plans: tuple
    path: object
    inputs: tuple

    @property
    def endpoints(self):
        """(4 x cuts, 3) every cut's endpoints, image RAS mm."""
        return np.vstack([plan.endpoints for plan in self.plans])


def plane_geometry(plane_node, name="osteotomy plane"):
    """(origin, normal, depth) (3,) each of a markups plane, in world (RAS) coordinates: centre, z and y axes."""
    if plane_node is None:
        raise ValueError(f"{name}: no plane selected; place the plane on the bone first")
    if not _placed(plane_node):
        raise ValueError(f"{name} {plane_node.GetName()!r} is not placed yet; place it on the bone in the CT")
    origin, x_axis, y_axis, z_axis = [0.0] * 3, [0.0] * 3, [0.0] * 3, [0.0] * 3
    plane_node.GetOriginWorld(origin)
    plane_node.GetAxesWorld(x_axis, y_axis, z_axis)
    return np.array(origin), np.array(z_axis), np.array(y_axis)


def cut_inputs(parameters):
    """The plane's geometry and the cut's settings as one comparable tuple (None when no plane is placed)."""
    plane = parameters.osteotomyPlane
    if plane is None or not _placed(plane):
        return None
    geometry = tuple(np.concatenate(plane_geometry(plane)).round(9))
    ipc = parameters.ipcModel
    ipc_key = None if ipc is None or ipc.GetPolyData() is None else (ipc.GetID(), ipc.GetPolyData().GetMTime())
    settings = (
        parameters.cutExtentMm,
        parameters.wedgeAngleDeg,
        parameters.cuttingTool,
        parameters.toolWidthMm,
        parameters.farMarginMm,
    )
    return geometry + settings + (ipc_key,)


def plan_from_nodes(parameters):
    """The PlannedCut of the selected plane on the selected IPC model with the parameter node's settings."""
    origin, normal, depth = plane_geometry(parameters.osteotomyPlane)
    vertices, triangles = _ipc_mesh(parameters.ipcModel)
    plans, path = plan_osteotomy(
        vertices,
        origin,
        normal,
        depth=depth,
        extent_mm=parameters.cutExtentMm or None,
        wedge_deg=parameters.wedgeAngleDeg,
        triangles=triangles,
        tool=parameters.cuttingTool,
        width_mm=parameters.toolWidthMm,
        far_margin_mm=parameters.farMarginMm,
    )
    return PlannedCut(plans, path, cut_inputs(parameters))


def write_plan_nodes(scene, parameters, planned):
    """Write the plan into the scene: endpoints, tool path model, the wedge's plane; size the plane(s) to the cut."""
    labels = [f"{'EW'[cut]}{number + 1}" for cut in range(len(planned.plans)) for number in range(4)]
    endpoints = parameters.cutEndpoints
    if endpoints is None:
        endpoints = scene.AddNewNodeByClass("vtkMRMLMarkupsFiducialNode", "CutEndpoints")
        endpoints.CreateDefaultDisplayNodes()
    endpoints.RemoveAllControlPoints()
    for point, label in zip(planned.endpoints, labels):
        endpoints.AddControlPoint(point.tolist(), label)
    endpoints.SetLocked(True)
    parameters.cutEndpoints = endpoints
    old_path = parameters.toolPath
    path_node = mrml_nodes.polyline_model(scene, planned.path.positions, "ToolPath")
    parameters.toolPath = path_node
    if old_path is not None:
        scene.RemoveNode(old_path)
    wedge = parameters.wedgePlane
    if len(planned.plans) > 1:
        if wedge is None:
            wedge = scene.AddNewNodeByClass("vtkMRMLMarkupsPlaneNode", "OsteotomyWedgePlane")
            wedge.CreateDefaultDisplayNodes()
        plane = planned.plans[1].plane
        wedge.SetOriginWorld(plane.origin.tolist())
        wedge.SetAxesWorld(plane.across.tolist(), plane.depth.tolist(), plane.normal.tolist())
        wedge.SetLocked(True)
        parameters.wedgePlane = wedge
    elif wedge is not None:
        parameters.wedgePlane = None
        scene.RemoveNode(wedge)
    for plan, node in zip(planned.plans, (parameters.osteotomyPlane, parameters.wedgePlane)):
        _size_to_cut(node, plan, planned.path.clearance_mm)


def tool_tip_to_image(parameters):
    """(4, 4) the tracked tool's TCP in the image: ReferenceToImage @ inv(ReferenceToTracker) @ ToolToTracker @
    ToolTipToTool (eq. 2 for the tool); None when one of them is not selected."""
    nodes = (
        parameters.referenceToImage,
        parameters.referenceToTracker,
        parameters.toolToTracker,
        parameters.toolTipToTool,
    )
    if any(node is None for node in nodes):
        return None
    reference_to_image, reference_to_tracker, tool_to_tracker, tip_to_tool = (matrix_of(node) for node in nodes)
    return reference_to_image @ np.linalg.inv(reference_to_tracker) @ tool_to_tracker @ tip_to_tool


def _placed(plane_node):
    """True once the plane is fully defined (``vtkMRMLMarkupsPlaneNode::GetIsPlaneValid``, in Slicer 5.6 to 5.10 and
    slicer-core alike)."""
    return bool(plane_node.GetIsPlaneValid())


def _ipc_mesh(ipc_node):
    if ipc_node is None:
        raise ValueError("no IPC model selected; build the IPC from the CT (step 1) or select one")
    data = ipc_node.GetPolyData()
    if data is None or data.GetNumberOfPoints() == 0:
        raise ValueError(f"IPC model {ipc_node.GetName()!r} has no points; build the IPC from the CT first")
    if data.GetNumberOfPolys() == 0:
        from vtkmodules.util.numpy_support import vtk_to_numpy

        return vtk_to_numpy(data.GetPoints().GetData()).astype(np.float64), None
    return triangle_arrays(data)


def _size_to_cut(node, plan, clearance_mm):
    """Show the plane over the cut's width and the bone's depth (with the tool's clearance before it)."""
    low, high = plan.section.across_range
    if plan.extent_mm is not None:
        low, high = max(low, -plan.extent_mm / 2.0), min(high, plan.extent_mm / 2.0)
    depths = plan.section.uv[:, 1]
    node.SetSizeMode(node.SizeModeAbsolute)
    node.SetSize(2.0 * max(abs(low), abs(high)), 2.0 * (max(abs(depths.min()), abs(depths.max())) + clearance_mm))
