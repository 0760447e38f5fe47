"""Live guidance of a cut: where a tracked cutting tool is relative to the planned cut plane.

From the tool's TCP pose in image coordinates (``ToolTipToImage``, the axes of ``core.tool_path``: y the blade's
normal, z the direction it advances, x across its width) and the plan, the surgeon sees:

* ``distance_mm``: the TCP's signed distance from the planned plane (+ on the normal's side), and for a saw the
  distance of the blade edge's farther corner (``edge_distance_mm``);
* ``angle_deg``: for a saw, the angle between the blade's plane and the planned plane; for a burr, the angle
  between its axis and the plane (a burr may spin in any way about its axis);
* ``depth_to_far_cortex_mm``: how far the tool may still advance along the cut before its edge reaches the far
  cortex, over its whole width (negative: past it); None when the tool is not over the bone's section; for a
  wedge's cut also ``depth_to_hinge_mm``, to the hinge line where the cut stops;
* ``on_plan``: both distances within ``distance_tolerance_mm`` and the angle within ``angle_tolerance_deg``
  (green; 1 mm and 2 degrees by default).

With a wedge (two cuts) the guidance is to the cut whose plane the tool is nearest.
"""

from dataclasses import dataclass

import numpy as np

from .validation import as_transform

DEFAULT_DISTANCE_TOLERANCE_MM = 1.0
DEFAULT_ANGLE_TOLERANCE_DEG = 2.0


@dataclass(frozen=True)
class CutGuidance:
    """The guidance numbers for one tool pose (module docstring); mm and degrees."""

    cut: int
    cuts: int
    distance_mm: float
    edge_distance_mm: float
    angle_deg: float
    across_mm: float
    depth_mm: float
    depth_to_far_cortex_mm: object
    in_extent: bool
    on_plan: bool
    depth_to_hinge_mm: object = None

    @property
    def text(self):
        """One line for the surgeon."""
        cut = f"cut {self.cut + 1} of {self.cuts}: " if self.cuts > 1 else ""
        far = (
            "not over the bone"
            if self.depth_to_far_cortex_mm is None
            else f"{self.depth_to_far_cortex_mm:.1f} mm to the far cortex"
        )
        if self.depth_to_hinge_mm is not None:
            far += f", {self.depth_to_hinge_mm:.1f} mm to the hinge"
        extent = "" if self.in_extent else ", outside the planned extent"
        verdict = "on plan" if self.on_plan else "OFF PLAN"
        return (
            f"{cut}tip {round(self.distance_mm, 1) + 0.0:+.1f} mm (edge {self.edge_distance_mm:.1f} mm), angle "
            f"{self.angle_deg:.1f} deg, {far}{extent}: {verdict}"
        )

    def to_dict(self):
        return dict(self.__dict__)


def cut_guidance(
    plans,
    tool_tip_to_image,
    tool="saw",
    width_mm=10.0,
    distance_tolerance_mm=DEFAULT_DISTANCE_TOLERANCE_MM,
    angle_tolerance_deg=DEFAULT_ANGLE_TOLERANCE_DEG,
):
    """CutGuidance of the tool at ``tool_tip_to_image`` (4, 4) to the nearest of ``plans`` (CutPlan or a sequence).

    Args:
        tool: 'saw' (the blade's plane matters) or 'burr' (its axis must lie in the plane).
        width_mm: blade width or burr diameter.
    """
    plans = list(plans) if isinstance(plans, (list, tuple)) else [plans]
    pose = as_transform(tool_tip_to_image, "ToolTipToImage")
    tip, width_axis, blade_normal, advance = pose[:3, 3], pose[:3, 0], pose[:3, 1], pose[:3, 2]
    heights = [(tip - plan.plane.origin) @ plan.plane.normal for plan in plans]
    cut = int(np.argmin(np.abs(heights)))
    plan, distance = plans[cut], float(heights[cut])
    plane = plan.plane
    if tool == "saw":
        angle = np.degrees(np.arccos(np.clip(abs(blade_normal @ plane.normal), 0.0, 1.0)))
        edge = max(abs(distance + side * width_mm / 2.0 * (width_axis @ plane.normal)) for side in (-1.0, 1.0))
    else:
        angle = np.degrees(np.arcsin(np.clip(abs(advance @ plane.normal), 0.0, 1.0)))
        edge = abs(distance)
    across, depth = plane.to_plane(tip[None])[0, :2]
    span = plan.section.span_depth_range(across - width_mm / 2.0, across + width_mm / 2.0)
    far = None if span is None else float(span[1] - depth)
    in_extent = plan.extent_mm is None or abs(across) + width_mm / 2.0 <= plan.extent_mm / 2.0
    return CutGuidance(
        cut=cut,
        cuts=len(plans),
        distance_mm=distance,
        edge_distance_mm=float(edge),
        angle_deg=float(angle),
        across_mm=float(across),
        depth_mm=float(depth),
        depth_to_far_cortex_mm=far,
        in_extent=bool(in_extent),
        on_plan=bool(max(abs(distance), edge) <= distance_tolerance_mm and angle <= angle_tolerance_deg),
        depth_to_hinge_mm=None if plan.hinge_depth_mm is None else float(plan.hinge_depth_mm - depth),
    )
