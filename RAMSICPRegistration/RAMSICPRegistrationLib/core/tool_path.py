"""The tool path of a planned cut: the tool-centre-point (TCP) poses that sweep it, in image coordinates, and the
same poses in robot-base coordinates through ``ImageToRobotBase`` (paper eq. 4: "all surgical tool poses planned in
image space should be eventually transmitted to the robot controller").

A **pose** is ``PlannedToolToImage`` (4, 4): its origin is the TCP (the middle of a saw blade's cutting edge, or a
burr's tip), its z axis the direction the tool advances (the cut's ``depth``), its y axis the blade's normal (the
plane's ``normal``) and its x axis = y x z (= -across). Every pose of one cut has the same orientation, so the blade
stays in the planned plane, and every TCP lies on it.

The cut is swept in **passes**, one per position across: the blade (``width_mm`` wide) enters ``clearance_mm``
before the nearest bone, advances to ``far_margin_mm`` before the far cortex under the whole width of its edge,
comes back out along the same line, and moves across, outside the bone, to the next pass; a wedge's cut stops at
its hinge when that comes first. The passes overlap by ``overlap`` of the width and keep the blade within the cut's
extent (or the bone's width for a whole-bone cut). Along a pass the poses are at most ``spacing_mm`` apart; a robot
moves linearly between them.
"""

from dataclasses import dataclass, replace

import numpy as np

from .osteotomy import CutPlan, plan_cut, wedge_plane
from .transforms import apply_transform
from .validation import as_transform

TOOLS = ("saw", "burr")
DEFAULT_TOOL_WIDTH_MM = {"saw": 10.0, "burr": 4.0}
DEFAULT_FAR_MARGIN_MM = 2.0
DEFAULT_CLEARANCE_MM = 5.0
DEFAULT_SPACING_MM = 2.0
DEFAULT_OVERLAP = 0.2


@dataclass(frozen=True)
class ToolPath:
    """TCP poses (P, 4, 4) sweeping one or more cuts, the pass (P,) and cut (P,) each pose belongs to, the frame
    they are in ('image' or 'robot base') and the tool's settings (mm)."""

    poses: np.ndarray
    pass_index: np.ndarray
    cut_index: np.ndarray
    frame: str
    tool: str
    width_mm: float
    far_margin_mm: float
    clearance_mm: float

    @property
    def positions(self):
        """(P, 3) TCP positions, mm."""
        return self.poses[:, :3, 3]

    @property
    def length_mm(self):
        """Length of the TCP's polyline, mm."""
        return float(np.linalg.norm(np.diff(self.positions, axis=0), axis=1).sum())

    @property
    def passes(self):
        """Number of passes over all cuts."""
        return int(len(np.unique(np.stack((self.cut_index, self.pass_index)), axis=1).T))

    def in_robot_base(self, image_to_robot_base):
        """The same path in robot-base coordinates: ``ImageToRobotBase @ PlannedToolToImage`` for every pose."""
        if self.frame != "image":
            raise ValueError(f"the tool path is already in {self.frame} coordinates")
        matrix = as_transform(image_to_robot_base, "ImageToRobotBase")
        return replace(self, poses=matrix @ self.poses, frame="robot base")

    def then(self, other):
        """This path followed by ``other`` (the next cut of a wedge), its cuts numbered after these."""
        if other.frame != self.frame:
            raise ValueError("join paths in the same frame")
        return replace(
            self,
            poses=np.concatenate((self.poses, other.poses)),
            pass_index=np.concatenate((self.pass_index, other.pass_index)),
            cut_index=np.concatenate((self.cut_index, other.cut_index + self.cut_index.max() + 1)),
        )

    def to_dict(self):
        return {
            "frame": self.frame,
            "tool": self.tool,
            "width_mm": self.width_mm,
            "far_margin_mm": self.far_margin_mm,
            "clearance_mm": self.clearance_mm,
            "poses": len(self.poses),
            "passes": self.passes,
            "length_mm": self.length_mm,
        }


def tool_orientation(plan):
    """(3, 3) rotation of every pose of ``plan``'s path: columns x = -across, y = normal, z = depth."""
    plane = plan.plane
    return np.column_stack((-plane.across, plane.normal, plane.depth))


def plan_tool_path(
    plan,
    tool="saw",
    width_mm=None,
    far_margin_mm=DEFAULT_FAR_MARGIN_MM,
    clearance_mm=DEFAULT_CLEARANCE_MM,
    spacing_mm=DEFAULT_SPACING_MM,
    overlap=DEFAULT_OVERLAP,
):
    """The TCP poses that sweep ``plan``'s cut (module docstring), in image coordinates.

    Args:
        plan: a ``CutPlan``.
        tool: 'saw' (a blade ``width_mm`` wide, default 10 mm) or 'burr' (``width_mm`` its diameter, default 4 mm).
        far_margin_mm: the tool stops this far before the far cortex (>= 0).
        clearance_mm: each pass starts and ends this far before the nearest bone (> 0).
        spacing_mm: longest step between poses along a pass.
        overlap: fraction of the width by which neighbouring passes overlap, in [0, 0.9].

    Raises:
        ValueError: a setting out of range, or a cut narrower than the tool.
    """
    if not isinstance(plan, CutPlan):
        raise TypeError(f"plan: expected a CutPlan, got {type(plan).__name__}")
    if tool not in TOOLS:
        raise ValueError(f"tool {tool!r}: use one of {', '.join(TOOLS)}")
    width_mm = DEFAULT_TOOL_WIDTH_MM[tool] if width_mm is None else float(width_mm)
    for name, value, low in (("width", width_mm, 0.0), ("clearance", clearance_mm, 0.0), ("spacing", spacing_mm, 0.0)):
        if not (np.isfinite(value) and value > low):
            raise ValueError(f"tool path {name} {value} mm: give a value above {low:g} mm")
    if not (np.isfinite(far_margin_mm) and far_margin_mm >= 0.0):
        raise ValueError(f"far-cortex margin {far_margin_mm} mm: give 0 mm or more")
    if not 0.0 <= overlap <= 0.9:
        raise ValueError(f"pass overlap {overlap}: give a fraction from 0 to 0.9")
    low, high = plan.section.across_range
    if plan.extent_mm is not None:
        low, high = max(low, -plan.extent_mm / 2.0), min(high, plan.extent_mm / 2.0)
    if high - low < width_mm:
        raise ValueError(
            f"the cut is {high - low:.1f} mm wide, narrower than the {width_mm:g} mm {tool}; use a narrower tool or a "
            "wider extent"
        )
    passes = int(np.ceil((high - low - width_mm) / (width_mm * (1.0 - overlap)) - 1e-9)) + 1
    centres = np.linspace(low + width_mm / 2.0, high - width_mm / 2.0, passes)
    spans = [plan.section.span_depth_range(centre - width_mm / 2.0, centre + width_mm / 2.0) for centre in centres]
    kept = [(centre, span) for centre, span in zip(centres, spans) if span is not None]
    if not kept:
        raise ValueError("the IPC is too sparse along the cut to find the bone's depth; give it as a surface (mesh)")
    # One entry line for every pass, outside the bone under all of them: moving across between passes stays clear.
    entry = min(span[0] for _, span in kept) - clearance_mm
    coordinates, pass_index = [], []
    for number, (centre, (_, far)) in enumerate(kept):
        stop = far - far_margin_mm if plan.hinge_depth_mm is None else min(far - far_margin_mm, plan.hinge_depth_mm)
        steps = max(1, int(np.ceil((stop - entry) / spacing_mm))) if stop > entry else 0
        depths = np.linspace(entry, stop, steps + 1) if steps else np.array([entry])
        depths = np.concatenate((depths, depths[-2::-1]))  # in, then back out along the same line
        coordinates += [(centre, depth) for depth in depths]
        pass_index += [number] * len(depths)
    positions = plan.plane.from_plane(np.array(coordinates))
    poses = np.tile(np.eye(4), (len(positions), 1, 1))
    poses[:, :3, :3] = tool_orientation(plan)
    poses[:, :3, 3] = positions
    return ToolPath(
        poses=poses,
        pass_index=np.array(pass_index),
        cut_index=np.zeros(len(poses), dtype=int),
        frame="image",
        tool=tool,
        width_mm=width_mm,
        far_margin_mm=float(far_margin_mm),
        clearance_mm=float(clearance_mm),
    )


def plan_document(plans, path, image_to_robot_base=None):
    """The plan as a JSON-ready dict, image (RAS) coordinates in mm.

    Keys: ``frame``; ``plane``, ``extent_mm``, ``endpoints`` (4 x 3) and ``endpoint_labels`` of the (first) cut;
    ``tool_path`` (list of 4 x 4 PlannedToolToImage) with ``tool_path_cut`` and ``tool_path_pass`` (each pose's cut
    and pass) and the tool's settings under ``tool``; a wedge's second cut under ``wedge`` (its ``plane``,
    ``extent_mm``, ``endpoints``, ``endpoint_labels``); with ``image_to_robot_base`` (4, 4), ``robot_base``: that
    matrix and the ``endpoints`` (of every cut) and ``tool_path`` in robot-base coordinates (eq. 4).
    """
    document = {"frame": "image (RAS), mm", **plans[0].to_dict()}
    document["tool_path"] = path.poses.tolist()
    document["tool_path_cut"] = path.cut_index.tolist()
    document["tool_path_pass"] = path.pass_index.tolist()
    document["tool"] = path.to_dict()
    if len(plans) > 1:
        document["wedge"] = plans[1].to_dict()
    if image_to_robot_base is not None:
        matrix = as_transform(image_to_robot_base, "ImageToRobotBase")
        document["robot_base"] = {
            "image_to_robot_base": matrix.tolist(),
            "endpoints": apply_transform(matrix, np.vstack([plan.endpoints for plan in plans])).tolist(),
            "tool_path": path.in_robot_base(matrix).poses.tolist(),
        }
    return document


def plan_osteotomy(
    points,
    origin,
    normal,
    depth=None,
    extent_mm=None,
    wedge_deg=0.0,
    triangles=None,
    tool="saw",
    width_mm=None,
    far_margin_mm=DEFAULT_FAR_MARGIN_MM,
):
    """A whole osteotomy: the cut (``osteotomy.plan_cut``), for a closing wedge (``wedge_deg`` > 0) the second cut
    turned about a hinge across the first, ``far_margin_mm`` before the far cortex under the plane's centre (both
    cuts stop there), and the tool path sweeping the cuts in turn. Returns (plans, path): a tuple of 1 or 2 CutPlan
    and a ToolPath."""
    plans = [plan_cut(points, origin, normal, depth=depth, extent_mm=extent_mm, triangles=triangles)]
    if wedge_deg:
        half = (DEFAULT_TOOL_WIDTH_MM[tool] if width_mm is None else width_mm) / 2.0
        far = plans[0].section.span_depth_range(-half, half)
        if far is None:
            raise ValueError("the wedge's hinge lies under the plane's centre, which is off the bone; move the plane")
        hinge = far[1] - far_margin_mm
        second = wedge_plane(plans[0], wedge_deg, hinge)
        plans.append(plan_cut(points, second[0], second[1], depth=second[2], extent_mm=extent_mm, triangles=triangles))
        plans = [replace(plan, hinge_depth_mm=float(hinge)) for plan in plans]
    paths = [plan_tool_path(plan, tool, width_mm, far_margin_mm) for plan in plans]
    return tuple(plans), paths[0] if len(paths) == 1 else paths[0].then(paths[1])
