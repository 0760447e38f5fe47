"""An offscreen picture of the live guidance of a cut (VTK), what the surgeon sees while the robot cuts: the bone,
the planned cut plane, the tool path, the cut's endpoints, the saw blade where the tracker sees it, and the guidance
numbers in a green (on plan) or red (off plan) panel. Every coordinate is image RAS, mm."""

import numpy as np

from ..core.guidance import DEFAULT_ANGLE_TOLERANCE_DEG, DEFAULT_DISTANCE_TOLERANCE_MM
from ..io.vtk_arrays import polyline_data
from .scene_render import (
    TARGET_COLOUR,
    _annotations,
    _frame,
    _glyph_actor,
    _surface_actor,
    check_writable_png,
    data_actor,
    patch_actor,
    use_offscreen_rendering,
    write_png,
)

PLAN_COLOUR = (0.93, 0.30, 0.25)
PATH_COLOUR = (0.98, 0.85, 0.35)
BLADE_COLOUR = (0.80, 0.84, 0.90)
ON_PLAN_COLOUR = (0.18, 0.49, 0.20)
OFF_PLAN_COLOUR = (0.78, 0.16, 0.16)
#: Drawn blade: its length behind the cutting edge and its thickness (mm).
BLADE_LENGTH_MM, BLADE_THICKNESS_MM = 70.0, 1.3


def render_guidance(
    path,
    vertices,
    triangles,
    plans,
    tool_pose,
    guidance,
    tool_width_mm,
    path_positions=None,
    size=(1000, 760),
    view_direction=(-1.0, -0.6, 0.9),
    title="Live guidance of the cut",
    tolerances=(DEFAULT_DISTANCE_TOLERANCE_MM, DEFAULT_ANGLE_TOLERANCE_DEG),
):
    """Write the guidance picture to ``path`` (PNG).

    Args:
        vertices, triangles: the bone's surface (V, 3), (K, 3).
        plans: the CutPlan(s); tool_pose: (4, 4) the blade's TCP pose (x across its width, y its normal, z the
            direction it advances); guidance: its ``core.guidance.CutGuidance``.
        path_positions: optional (P, 3) tool path.
        tolerances: (mm, degrees) within which the panel is green, as the guidance was computed.
    """
    check_writable_png(path)
    use_offscreen_rendering()
    import vtkmodules.vtkRenderingFreeType  # noqa: F401  (text)
    import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (the OpenGL back end)
    from vtkmodules.vtkRenderingCore import vtkRenderer

    renderer = vtkRenderer()
    renderer.SetBackground(0.12, 0.13, 0.16)
    legend = [("bone", (0.89, 0.85, 0.75), "square")]
    bone = _surface_actor(vertices, triangles)
    bone.GetProperty().SetOpacity(0.55)
    renderer.AddActor(bone)
    for plan in plans:
        renderer.AddActor(_plane_actor(plan))
    legend.append(("planned cut", PLAN_COLOUR, "square"))
    if path_positions is not None:
        line = data_actor(polyline_data(path_positions), PATH_COLOUR)
        line.GetProperty().SetLineWidth(1.5)
        renderer.AddActor(line)
        legend.append(("tool path (TCP)", PATH_COLOUR, "square"))
    endpoints = np.vstack([plan.endpoints for plan in plans])
    renderer.AddActor(_glyph_actor(endpoints, 1.5, colour=TARGET_COLOUR, cube=True))
    legend.append(("the cut's endpoints", TARGET_COLOUR, "cube"))
    renderer.AddActor(_blade_actor(tool_pose, tool_width_mm))
    legend.append(("saw blade, tracked", BLADE_COLOUR, "square"))

    blade_corners = tool_pose[:3, 3] - BLADE_LENGTH_MM / 2.0 * tool_pose[:3, 2]
    framed = np.vstack((endpoints, plans[0].section.points, blade_corners[None]))
    camera = renderer.GetActiveCamera()
    _frame(camera, framed, view_direction, size, margin_mm=10.0)
    renderer.ResetCameraClippingRange()
    for prop in _annotations(title, legend, None, size, camera.GetParallelScale()):
        renderer.AddViewProp(prop)
    renderer.AddViewProp(_guidance_panel(guidance, size, tolerances))
    write_png(path, renderer, size)


def _plane_actor(plan, margin_mm=6.0):
    """A translucent patch of the planned plane over the bone's section (and a margin)."""
    low, high = plan.section.uv.min(axis=0) - margin_mm, plan.section.uv.max(axis=0) + margin_mm
    corners = plan.plane.from_plane([low, (high[0], low[1]), (low[0], high[1])])
    return patch_actor(*corners, PLAN_COLOUR, 0.35)


def _blade_actor(pose, width_mm):
    """The blade as a thin box: its cutting edge centred on the TCP, reaching back along -z."""
    from vtkmodules.vtkCommonTransforms import vtkTransform
    from vtkmodules.vtkFiltersSources import vtkCubeSource

    box = vtkCubeSource()
    box.SetXLength(width_mm)
    box.SetYLength(BLADE_THICKNESS_MM)
    box.SetZLength(BLADE_LENGTH_MM)
    box.SetCenter(0.0, 0.0, -BLADE_LENGTH_MM / 2.0)
    box.Update()
    transform = vtkTransform()
    transform.SetMatrix(np.asarray(pose, dtype=np.float64).ravel().tolist())
    actor = data_actor(box.GetOutput(), BLADE_COLOUR)
    actor.SetUserTransform(transform)
    actor.GetProperty().SetSpecular(0.4)
    return actor


def _guidance_panel(guidance, size, tolerances):
    """The numbers in a panel on the right: green on plan, red off plan."""
    from vtkmodules.vtkRenderingCore import vtkTextActor

    far = (
        "not over the bone"
        if guidance.depth_to_far_cortex_mm is None
        else f"{guidance.depth_to_far_cortex_mm:5.1f} mm to the far cortex"
    )
    lines = [
        "ON PLAN" if guidance.on_plan else "OFF PLAN",
        f"tip   {round(guidance.distance_mm, 1) + 0.0:+5.1f} mm from the plane",
        f"edge  {guidance.edge_distance_mm:5.1f} mm from the plane",
        f"angle {guidance.angle_deg:5.1f} deg",
        far,
        f"(green within {tolerances[0]:g} mm, {tolerances[1]:g} deg)",
    ]
    if guidance.cuts > 1:
        lines.insert(1, f"cut {guidance.cut + 1} of {guidance.cuts}")
    panel = vtkTextActor()
    panel.SetInput("\n".join(lines))
    text = panel.GetTextProperty()
    text.SetFontSize(22)
    text.SetFontFamilyToCourier()
    text.BoldOn()
    text.SetColor(1.0, 1.0, 1.0)
    text.SetBackgroundColor(*(ON_PLAN_COLOUR if guidance.on_plan else OFF_PLAN_COLOUR))
    text.SetBackgroundOpacity(0.92)
    text.SetFrame(True)
    text.SetFrameColor(1.0, 1.0, 1.0)
    panel.SetPosition(size[0] - 430, size[1] - 236)
    return panel
