"""The osteotomy plane placed by four numbers a surgeon can type on a tablet: where along the bone, its two tilts,
and the side the blade enters from; and those numbers read back from any plane.

The numbers are taken in the bone's own frame (``BoneFrame``, from the IPC in image RAS coordinates, mm):

* ``axis``: the bone's long axis (its points' first principal direction), pointing superior (+S), or towards the
  largest of its components when the bone lies across the scanner;
* ``anterior``: RAS anterior (+A) with its part along the axis taken out; ``side`` = ``axis`` x ``anterior``
  (the patient's left, +L, for a bone along S);
* the **level** of a plane is how far below the bone's top (its highest point along the axis) the plane crosses
  the axis line through the bone's centre, mm; the plane's origin is that crossing;
* its **tilts** are the angles (degrees) its normal leans from the axis towards ``anterior`` and towards
  ``side``: ``normal ~ axis + tan(tilt_anterior) anterior + tan(tilt_side) side``, so either reads back exactly;
* its **entry** is the direction around the bone (degrees, 0 anterior, 90 side, 180 posterior) the blade comes
  from: the blade advances across the plane (the plane's depth axis, the y axis of a Slicer markups plane, along
  which ``core.osteotomy`` plans) from that side to the opposite one.

A plane with its normal at 90 degrees or more from the axis (along the bone, not across it) has no level or tilts
in this frame: ``placement_of`` refuses it.
"""

from dataclasses import dataclass

import numpy as np

#: The largest tilt (degrees) either way: beyond it a plane leans more along the bone than across it.
MAX_TILT_DEG = 60.0
#: A surface whose second principal spread is above this share of its first has no axis to measure along (the
#: shipped bones: tibiae 0.13, fibula 0.05, ilium 0.64; a round blob about 1).
MAX_WIDTH_RATIO = 0.85


@dataclass(frozen=True)
class BoneFrame:
    """A long bone's frame in image coordinates (mm): ``centre`` (3,), unit ``axis``, ``anterior`` and ``side``
    (3,) each (a right-handed frame: ``side = axis x anterior``), and ``top_mm``/``bottom_mm``, how far its highest
    and lowest points lie along the axis from the centre."""

    centre: np.ndarray
    axis: np.ndarray
    anterior: np.ndarray
    side: np.ndarray
    top_mm: float
    bottom_mm: float

    @property
    def length_mm(self):
        return self.top_mm - self.bottom_mm


@dataclass(frozen=True)
class PlanePlacement:
    """A cut plane in the bone's frame: ``level_mm`` below the top, ``tilt_anterior_deg`` and ``tilt_side_deg``
    from square to the axis, the blade entering from ``entry_deg`` around the bone (0 anterior, 90 side)."""

    level_mm: float
    tilt_anterior_deg: float = 0.0
    tilt_side_deg: float = 0.0
    entry_deg: float = 0.0

    def to_dict(self):
        return {
            "level_mm": self.level_mm,
            "tilt_anterior_deg": self.tilt_anterior_deg,
            "tilt_side_deg": self.tilt_side_deg,
            "entry_deg": self.entry_deg,
        }


def bone_frame(points):
    """The BoneFrame of a bone's (M, 3) surface points (image RAS, mm); a sample of 20,000 is enough for the axis.

    Raises:
        ValueError: fewer than 10 points, or points that do not span a long shape (no axis).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) < 10 or not np.isfinite(points).all():
        raise ValueError(f"the bone's frame needs its surface: {len(points)} finite points given, at least 10 needed")
    centre = points.mean(axis=0)
    sample = points[:: max(1, len(points) // 20000)] - centre
    _, spread, directions = np.linalg.svd(sample, full_matrices=False)
    if spread[0] <= 1e-9 or spread[1] / spread[0] > MAX_WIDTH_RATIO:
        raise ValueError("the surface has no long axis (as wide as it is long); the plane's level needs a long bone")
    axis = directions[0]
    up = 2 if abs(axis[2]) >= 0.5 else int(np.argmax(np.abs(axis)))
    axis = axis if axis[up] > 0 else -axis
    anterior = np.array([0.0, 1.0, 0.0]) - axis[1] * axis
    if np.linalg.norm(anterior) < 0.1:  # a bone along A-P: measure around it from R instead
        anterior = np.array([1.0, 0.0, 0.0]) - axis[0] * axis
    anterior /= np.linalg.norm(anterior)
    heights = (points - centre) @ axis
    return BoneFrame(centre, axis, anterior, np.cross(axis, anterior), float(heights.max()), float(heights.min()))


def placed_plane(frame, placement):
    """(origin, normal, depth) (3,) each, image RAS mm, of the plane a PlanePlacement describes in ``frame``:
    the origin on the axis line at the level, the normal tilted from the axis, the depth axis (the way the blade
    advances) in the plane, from the entry side across the bone.

    Raises:
        ValueError: a tilt beyond ``MAX_TILT_DEG``, or a number that is not finite.
    """
    values = np.array(
        [placement.level_mm, placement.tilt_anterior_deg, placement.tilt_side_deg, placement.entry_deg], float
    )
    if not np.isfinite(values).all():
        raise ValueError(f"plane placement {placement}: every number must be finite")
    for name, tilt in (("anterior", placement.tilt_anterior_deg), ("side", placement.tilt_side_deg)):
        if abs(tilt) > MAX_TILT_DEG:
            raise ValueError(f"tilt {name} {tilt:g} degrees: give at most {MAX_TILT_DEG:g} degrees either way")
    origin = frame.centre + (frame.top_mm - placement.level_mm) * frame.axis
    normal = (
        frame.axis
        + np.tan(np.radians(placement.tilt_anterior_deg)) * frame.anterior
        + np.tan(np.radians(placement.tilt_side_deg)) * frame.side
    )
    normal /= np.linalg.norm(normal)
    first, second = _in_plane(frame, normal)
    entry = np.radians(placement.entry_deg)
    depth = -(np.cos(entry) * first + np.sin(entry) * second)  # from the entry side towards the opposite one
    return origin, normal, depth


def placement_of(frame, origin, normal, depth):
    """The PlanePlacement of a plane (``origin``, ``normal``, ``depth`` (3,) each, image RAS mm) in ``frame``: the
    inverse of ``placed_plane`` (a normal pointing down the bone is turned round first; the depth axis is taken
    in the plane).

    Raises:
        ValueError: a plane along the bone (its normal 90 degrees or more from the axis has no level).
    """
    normal = np.asarray(normal, dtype=np.float64) / np.linalg.norm(normal)
    along = float(normal @ frame.axis)
    if along < 0:
        normal, along = -normal, -along
    if along < np.cos(np.radians(89.0)):
        raise ValueError("the plane runs along the bone, not across it: it has no level below the bone's top")
    crossing = float((np.asarray(origin, float) - frame.centre) @ normal) / along  # along the axis line
    first, second = _in_plane(frame, normal)
    depth = np.asarray(depth, dtype=np.float64)
    entry = np.degrees(np.arctan2(-(depth @ second), -(depth @ first))) % 360.0
    return PlanePlacement(
        level_mm=float(frame.top_mm - crossing),
        tilt_anterior_deg=float(np.degrees(np.arctan((normal @ frame.anterior) / along))),
        tilt_side_deg=float(np.degrees(np.arctan((normal @ frame.side) / along))),
        entry_deg=float(entry),
    )


def placement_through(frame, point, tilt_anterior_deg=0.0, tilt_side_deg=0.0):
    """The PlanePlacement of the plane with the given tilts through ``point`` (3,), image RAS mm (a probe tip on
    the bone where the cut should begin), the blade entering from the side of the bone ``point`` lies on.

    Raises:
        ValueError: a point on the axis line (no side to enter from), a tilt beyond ``MAX_TILT_DEG``.
    """
    tilted = placed_plane(frame, PlanePlacement(0.0, tilt_anterior_deg, tilt_side_deg, 0.0))
    normal = tilted[1]
    offset = np.asarray(point, dtype=np.float64) - frame.centre
    crossing = float(offset @ normal) / float(normal @ frame.axis)
    radial = offset - crossing * frame.axis
    radial -= (radial @ normal) * normal
    if np.linalg.norm(radial) < 1e-6:
        raise ValueError("the point lies on the bone's axis: touch the bone's surface where the blade should enter")
    first, second = _in_plane(frame, normal)
    return PlanePlacement(
        level_mm=float(frame.top_mm - crossing),
        tilt_anterior_deg=float(tilt_anterior_deg),
        tilt_side_deg=float(tilt_side_deg),
        entry_deg=float(np.degrees(np.arctan2(radial @ second, radial @ first)) % 360.0),
    )


def _in_plane(frame, normal):
    """Two unit directions (3,) spanning the plane of ``normal``: ``anterior`` and ``side`` tilted with it."""
    first = frame.anterior - (frame.anterior @ normal) * normal
    first /= np.linalg.norm(first)
    return first, np.cross(normal, first)
