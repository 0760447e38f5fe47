"""The osteotomy plan in image space: a cut plane, the bone's section in it and the cut's four endpoints.

The paper's ORS plans the osteotomy on the CT and measures its result at "four distinct endpoints on the resected
surface" (Fig. 6b, the targets of eq. 11). A cut here is a plane in image (RAS) coordinates, mm:

* ``origin`` (3,) a point of the plane, the middle of the cut; ``normal`` (3,) its unit normal;
* ``depth`` (3,) the in-plane direction along which the blade advances, from its entry side to the far cortex;
* ``across`` (3,) = depth x normal, the width of the cut, so that (across, depth, normal) is right-handed;
* ``extent_mm``: the cut's width across the bone, centred on the origin, or None to cut across the whole bone.

The bone's **section** in the plane comes from the IPC: exactly, where the plane crosses the surface's triangles
when the IPC is a mesh. A point cloud has no triangles: each of its points near the plane (within
``SECTION_HALF_THICKNESS_MM`` or two median point spacings, whichever is larger) is carried onto the plane along
its local surface (a quadric fitted to its neighbours, ``core.cloud_surface``) to where that surface crosses the
cut: on the cut plane exactly and on the cloud's surface to within its own noise. A whole-bone end of a point
cloud's section is the top of a parabola fitted to the section's points near it (the section's curve is flat
there); a corner of a limited cut is where the side line itself crosses the local surfaces of the cloud's points
near it.
The four **endpoints** (4, 3) are where the cut meets the bone's surface:

* a cut across the whole bone: the section's ends along +across, -across, +depth (the far end) and -depth (the
  entry end). A tibia cut horizontally with across medial and depth anterior gives the medial, lateral, anterior
  and posterior ends of a high tibial osteotomy, the demo's targets;
* a cut limited to ``extent_mm``: the corners where its two side lines (across = -extent/2 and +extent/2) enter
  and leave the bone, in the order (-side, entry), (-side, far), (+side, entry), (+side, far).

A closing wedge (high tibial osteotomy) is two such cuts meeting at a hinge line: ``wedge_plane`` turns a cut about
a line across it at a chosen depth. Both cuts then stop at the hinge (``hinge_depth_mm``), which stays uncut; their
endpoints remain where their planes meet the bone, so the far ones lie beyond the hinge.
"""

from dataclasses import dataclass

import numpy as np

from .cloud_surface import CloudSurface
from .transforms import rotation_about_axis
from .validation import as_points

#: IPC points this close to the plane (mm), or within one median point spacing when the cloud is sparser, are carried
#: onto it to make a point cloud's section (a mesh's section is exact).
SECTION_HALF_THICKNESS_MM = 0.3
#: A point whose tangent plane is this close to parallel to the cut (the sine of the angle between their normals) is
#: not carried onto it: there the surface runs along the plane and does not cross it.
MIN_CROSSING_SINE = 0.3
#: A point cloud's section is fitted by a parabola over its points this close (mm) to an end, and the end taken on it.
END_FIT_RADIUS_MM = 2.0
#: Crossings of a cut's side line with a point cloud's surface farther apart than this (mm) are different walls.
WALL_GAP_MM = 1.0
#: Half-width (mm) of the strip of a point cloud's section read as the bone's depth at one position across.
STRIP_HALF_WIDTH_MM = 0.5
#: Positions across the cut are sampled this far apart (mm) when the far cortex is sought under a blade.
SPAN_STEP_MM = 0.5

WHOLE_BONE_LABELS = ("+across end", "-across end", "far end", "entry end")
EXTENT_LABELS = ("-side entry", "-side far", "+side entry", "+side far")


@dataclass(frozen=True)
class CutPlane:
    """A cut plane in image coordinates (mm): see the module docstring for the axes."""

    origin: np.ndarray
    normal: np.ndarray
    depth: np.ndarray

    @property
    def across(self):
        """(3,) the cut's width direction: depth x normal."""
        return np.cross(self.depth, self.normal)

    @property
    def axes(self):
        """(3, 3) columns across, depth, normal."""
        return np.column_stack((self.across, self.depth, self.normal))

    def to_plane(self, points):
        """(N, 3) image points -> (N, 3) plane coordinates (across, depth, height above the plane), mm."""
        return (np.asarray(points, dtype=np.float64) - self.origin) @ self.axes

    def from_plane(self, coordinates):
        """(N, 2) or (N, 3) plane coordinates (across, depth[, height]) -> (N, 3) image points, mm."""
        coordinates = np.asarray(coordinates, dtype=np.float64)
        return self.origin + coordinates @ self.axes[:, : coordinates.shape[1]].T

    def to_dict(self):
        return {
            "origin": self.origin.tolist(),
            "normal": self.normal.tolist(),
            "across": self.across.tolist(),
            "depth": self.depth.tolist(),
        }


@dataclass(frozen=True)
class Section:
    """The bone's section in a cut plane: ``points`` (K, 3) on the surface and their ``uv`` (K, 2) plane
    coordinates (across, depth). From a mesh, consecutive pairs of points are the crossing segments (``exact``);
    from a point cloud they are the IPC points near the plane carried onto it along their tangent planes."""

    points: np.ndarray
    uv: np.ndarray
    exact: bool

    def depth_range_at(self, across_mm):
        """(entry depth, far depth) in mm of the section along the line across = ``across_mm``; None off the bone."""
        entry, far = self._envelope(np.array([float(across_mm)]))
        return None if np.isnan(far[0]) else (float(entry[0]), float(far[0]))

    def span_depth_range(self, low_mm, high_mm):
        """(entry, far) depth in mm under a blade covering across = [low_mm, high_mm]: the nearest entry and the
        nearest far cortex over the span, so that no part of the blade's edge passes either; None off the bone.

        A mesh's section is piecewise linear between its vertices, so looking at the span's ends and at every
        vertex within it finds both exactly; a point cloud's is looked at every ``SPAN_STEP_MM``.
        """
        count = max(2, int(np.ceil((high_mm - low_mm) / SPAN_STEP_MM)) + 1)
        positions = np.linspace(low_mm, high_mm, count)
        if self.exact:
            inside = self.uv[(self.uv[:, 0] > low_mm) & (self.uv[:, 0] < high_mm), 0]
            positions = np.concatenate((positions, inside))
        entry, far = self._envelope(positions)
        hit = ~np.isnan(far)
        return None if not hit.any() else (float(entry[hit].min()), float(far[hit].min()))

    def nearest(self, points):
        """(N, 3) the section's points nearest to each of ``points`` (N, 3): on its segments for a mesh's section,
        among its IPC points for a point cloud's. Where a cut's edge passes a point of the bone, mm."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if not self.exact:
            return self.points[np.argmin(np.linalg.norm(points[:, None] - self.points[None], axis=2), axis=1)]
        first, second = self.points[0::2], self.points[1::2]
        along = second - first
        length2 = np.maximum(np.einsum("ij,ij->i", along, along), 1e-300)
        fraction = np.clip(np.einsum("nsj,sj->ns", points[:, None] - first[None], along) / length2, 0.0, 1.0)
        candidates = first[None] + fraction[..., None] * along[None]
        best = np.argmin(np.linalg.norm(candidates - points[:, None], axis=2), axis=1)
        return candidates[np.arange(len(points)), best]

    @property
    def across_range(self):
        """(lowest, highest) across coordinate of the section, mm."""
        return float(self.uv[:, 0].min()), float(self.uv[:, 0].max())

    def _envelope(self, positions):
        """(entry, far) depths (mm), each (P,), of the section along the lines across = ``positions`` (P,); NaN
        where a line misses the bone."""
        entry, far = np.full(len(positions), np.nan), np.full(len(positions), np.nan)
        for index, position in enumerate(positions) if not self.exact else ():
            depths = self._depths_at(position)[0]
            if depths.size:
                entry[index], far[index] = depths.min(), depths.max()
        if self.exact:
            first, second = self.uv[0::2], self.uv[1::2]
            offset_first = first[None, :, 0] - positions[:, None]  # (P, S)
            offset_second = second[None, :, 0] - positions[:, None]
            crossing = (offset_first * offset_second <= 0.0) & (offset_first != offset_second)
            with np.errstate(divide="ignore", invalid="ignore"):
                fraction = offset_first / (offset_first - offset_second)
            depths = first[None, :, 1] + fraction * (second[None, :, 1] - first[None, :, 1])
            hit = crossing.any(axis=1)
            entry[hit] = np.where(crossing, depths, np.inf)[hit].min(axis=1)
            far[hit] = np.where(crossing, depths, -np.inf)[hit].max(axis=1)
        return entry, far

    def _depths_at(self, across_mm):
        """Depths (mm) and image points where the section crosses the line across = ``across_mm``."""
        if not self.exact:
            near = np.abs(self.uv[:, 0] - across_mm) <= STRIP_HALF_WIDTH_MM
            return self.uv[near, 1], self.points[near]
        first, second = self.uv[0::2], self.uv[1::2]
        offset_first, offset_second = first[:, 0] - across_mm, second[:, 0] - across_mm
        crossing = (offset_first * offset_second <= 0.0) & (offset_first != offset_second)
        fraction = offset_first[crossing] / (offset_first[crossing] - offset_second[crossing])
        depths = first[crossing, 1] + fraction * (second[crossing, 1] - first[crossing, 1])
        points_first, points_second = self.points[0::2][crossing], self.points[1::2][crossing]
        return depths, points_first + fraction[:, None] * (points_second - points_first)


@dataclass(frozen=True)
class CutPlan:
    """One planned cut: its plane, its width across the bone (None: the whole bone), the bone's section in it, the
    four endpoints (4, 3) in image coordinates (mm) with their labels, and for a wedge's cut the depth of its hinge
    (mm along ``depth`` from the origin; None: the cut may reach the far cortex)."""

    plane: CutPlane
    extent_mm: object
    section: Section
    endpoints: np.ndarray
    endpoint_labels: tuple
    hinge_depth_mm: object = None

    @property
    def endpoint_directions(self):
        """The patient's directions (RAS words) each endpoint lies towards, e.g. 'anterior' or 'posterior, medial'
        ('left'/'right' for R-L, since medial and lateral depend on the side)."""
        across, depth = self.plane.across, self.plane.depth
        if self.endpoint_labels == WHOLE_BONE_LABELS:
            return tuple(direction_word(vector) for vector in (across, -across, depth, -depth))
        return tuple(
            f"{direction_word(side * across)}, {direction_word(end * depth)}" for side in (-1, 1) for end in (-1, 1)
        )

    def to_dict(self):
        """JSON-ready: ``plane``, ``extent_mm``, ``endpoints`` (4 x 3), ``endpoint_labels``, ``hinge_depth_mm``."""
        return {
            "plane": self.plane.to_dict(),
            "extent_mm": self.extent_mm,
            "endpoints": self.endpoints.tolist(),
            "endpoint_labels": list(self.endpoint_labels),
            "endpoint_directions": list(self.endpoint_directions),
            "hinge_depth_mm": self.hinge_depth_mm,
        }


def cut_plane(origin, normal, depth=None):
    """A CutPlane from an origin (3,) and a normal (3,) in image coordinates (mm); ``depth`` (3,) is projected
    into the plane. Without ``depth`` a provisional in-plane axis is used (``plan_cut`` chooses a better one).

    Raises:
        ValueError: NaN, a zero normal, or a depth direction along the normal.
    """
    origin, normal = _vector3(origin, "cut plane origin"), _vector3(normal, "cut plane normal")
    length = np.linalg.norm(normal)
    if length < 1e-9:
        raise ValueError("cut plane normal is (0, 0, 0); give the direction the plane faces, e.g. 0 0 1")
    normal = normal / length
    if depth is None:
        axis = np.eye(3)[np.argmin(np.abs(normal))]  # the coordinate axis least along the normal
        depth = np.cross(normal, np.cross(axis, normal))
    else:
        given = _vector3(depth, "cut depth direction")
        depth = given - (given @ normal) * normal
        if np.linalg.norm(depth) <= 1e-6 * np.linalg.norm(given):
            raise ValueError("the cut's depth direction lies along the plane's normal; give a direction in the plane")
    return CutPlane(origin=origin, normal=normal, depth=depth / np.linalg.norm(depth))


def bone_section(plane, points, triangles=None, half_thickness_mm=None, cloud=None):
    """The bone's Section in ``plane``: the crossing of the mesh (``points`` (V, 3) vertices, ``triangles`` (K, 3))
    with the plane, or, when no triangles are given, where the local surfaces of the IPC ``points`` (N, 3) within
    ``half_thickness_mm`` of it cross it (default: ``SECTION_HALF_THICKNESS_MM`` or two of the cloud's median
    spacings, the larger; module docstring). ``cloud``: the points' ``CloudSurface`` when already built.

    Raises:
        ValueError: the plane does not cross the bone.
    """
    points = np.asarray(points, dtype=np.float64)
    if triangles is not None and len(triangles):
        heights = (points - plane.origin) @ plane.normal
        crossing = _mesh_crossing(points, np.asarray(triangles), heights)
        exact = True
    else:
        cloud = CloudSurface(points) if cloud is None else cloud
        if half_thickness_mm is None:
            half_thickness_mm = _band(cloud)
        crossing = cloud.plane_crossing(plane.origin, plane.normal, half_thickness_mm, MIN_CROSSING_SINE)
        exact = False
    if len(crossing) == 0:
        within = "" if exact else f" (no IPC point lies within {half_thickness_mm:.2g} mm of it)"
        raise ValueError(
            f"the cut plane through {_vector(plane.origin)} facing {_vector(plane.normal)} does not cross the "
            f"bone{within}; move the plane onto the bone"
        )
    return Section(points=crossing, uv=plane.to_plane(crossing)[:, :2], exact=exact)


def plan_cut(points, origin, normal, depth=None, extent_mm=None, triangles=None):
    """Plan one cut on the bone: its plane, section and four endpoints (module docstring).

    Args:
        points: (N, 3) IPC in image coordinates (mm): the mesh's vertices with ``triangles`` (K, 3), or a cloud.
        origin, normal: (3,) a point of the plane (the cut's middle) and its normal.
        depth: (3,) the direction the blade advances, entry to far cortex (projected into the plane). Default:
            along the section's narrowest width (the shortest reach for the blade), the sign making the largest of
            its R, A, S components positive.
        extent_mm: the cut's width across the bone, centred on the origin; None for the whole bone.

    Raises:
        ValueError: bad numbers, a plane off the bone, or an extent whose one side only reaches past the bone.
    """
    if extent_mm is not None and not (np.isfinite(extent_mm) and extent_mm > 0):
        raise ValueError(f"cut extent {extent_mm} mm: give a width above 0 mm, or none to cut across the whole bone")
    points = as_points(points, "IPC", min_count=3)
    plane = cut_plane(origin, normal, depth)
    cloud = None if triangles is not None and len(triangles) else CloudSurface(points)
    section = bone_section(plane, points, triangles, cloud=cloud)
    if depth is None:
        plane = CutPlane(plane.origin, plane.normal, _narrowest_direction(plane, section.uv))
        section = Section(section.points, plane.to_plane(section.points)[:, :2], section.exact)
    low, high = section.across_range
    if extent_mm is None or (-extent_mm / 2.0 <= low and extent_mm / 2.0 >= high):
        endpoints = _whole_bone_ends(section, plane)
        labels = WHOLE_BONE_LABELS
    else:
        endpoints = _extent_corners(section, extent_mm, plane, cloud)
        labels = EXTENT_LABELS
    return CutPlan(plane, None if extent_mm is None else float(extent_mm), section, endpoints, labels)


def wedge_plane(plan, angle_deg, hinge_depth_mm):
    """The second cut of a closing wedge: ``plan``'s plane turned by ``angle_deg`` about the hinge line (across,
    through depth ``hinge_depth_mm`` of the first cut), so that on the entry side it lies on the first cut's
    +normal side; the wedge between the two cuts is removed and the bone closes on the hinge.

    Returns (origin, normal, depth) of the second plane, its origin as far before the hinge as the first's.
    """
    if not (np.isfinite(angle_deg) and 0.0 < angle_deg < 90.0):
        raise ValueError(f"wedge angle {angle_deg} degrees: give an angle between 0 and 90 degrees")
    plane = plan.plane
    turn = rotation_about_axis(plane.across, -np.radians(angle_deg))
    hinge = plane.origin + hinge_depth_mm * plane.depth
    depth = turn @ plane.depth
    return hinge - hinge_depth_mm * depth, turn @ plane.normal, depth


def _mesh_crossing(vertices, triangles, heights):
    """(2S, 3) the end points of the segments where the triangles cross the plane, pair by pair."""
    above = heights[triangles] >= 0.0
    crossing = above.any(axis=1) & ~above.all(axis=1)
    corners, levels, sides = vertices[triangles[crossing]], heights[triangles[crossing]], above[crossing]
    ends = []
    for first, second in ((0, 1), (1, 2), (2, 0)):
        cut = sides[:, first] != sides[:, second]
        with np.errstate(divide="ignore", invalid="ignore"):  # edges that are not cut are masked out below
            fraction = levels[:, first] / (levels[:, first] - levels[:, second])
            point = corners[:, first] + fraction[:, None] * (corners[:, second] - corners[:, first])
        ends.append(np.where(cut[:, None], point, np.nan))
    ends = np.stack(ends, axis=1)  # (S, 3 edges, 3): exactly two edges of a crossing triangle are cut
    return ends[~np.isnan(ends[:, :, 0])].reshape(-1, 3)


def _narrowest_direction(plane, uv):
    """The in-plane unit direction (3,) of the section's smallest spread, its largest component made positive."""
    centred = uv - uv.mean(axis=0)
    _, vectors = np.linalg.eigh(centred.T @ centred)
    direction = plane.axes[:, :2] @ vectors[:, 0]
    return direction if direction[np.argmax(np.abs(direction))] > 0 else -direction


def _band(cloud):
    """Half-thickness (mm) of the band of a point cloud's points carried onto a cut plane or a side line."""
    return max(SECTION_HALF_THICKNESS_MM, 2.0 * cloud.spacing_mm)


def _whole_bone_ends(section, plane):
    directions = ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0))
    if section.exact:  # a polygon's extreme lies at one of its vertices
        return np.array([section.points[np.argmax(section.uv @ d)] for d in directions])
    return plane.from_plane(np.array([_cloud_extreme(section.uv, np.array(d)) for d in directions]))


def _cloud_extreme(uv, direction):
    """(2,) the farthest point along ``direction`` (2,) of a point cloud's section curve (uv (K, 2), mm): the vertex
    of a parabola fitted to the section's points within ``END_FIT_RADIUS_MM`` of the farthest one; that point itself
    when the parabola does not open away from the direction or its vertex lies beyond half the radius."""
    sideways = np.array([-direction[1], direction[0]])
    best = int(np.argmax(uv @ direction))
    near = np.linalg.norm(uv - uv[best], axis=1) < END_FIT_RADIUS_MM
    offset = (uv[near] - uv[best]) @ sideways
    height = uv[near] @ direction
    vertex = _parabola_vertex(offset, height)
    if vertex is None or height.max() - vertex[1] > END_FIT_RADIUS_MM / 4.0:
        return uv[best]
    return uv[best] + (vertex[1] - uv[best] @ direction) * direction + vertex[0] * sideways


def _parabola_vertex(x, y):
    """(x, y) of the top of the least-squares parabola through points (x, y), or None: too few points (< 6), a
    parabola that does not open downwards, or a top beyond half ``END_FIT_RADIUS_MM`` from x = 0."""
    if len(x) < 6:
        return None
    c2, c1, c0 = np.polyfit(x, y, 2)
    if c2 >= 0.0:
        return None
    top = -c1 / (2.0 * c2)
    return None if abs(top) > END_FIT_RADIUS_MM / 2.0 else np.array([top, c0 + c1 * top + c2 * top**2])


def _extent_corners(section, extent_mm, plane, cloud=None):
    low, high = section.across_range
    corners = []
    for side in (-extent_mm / 2.0, extent_mm / 2.0):
        if not low <= side <= high:
            raise ValueError(
                f"the cut's side at {side:+.1f} mm across lies off the bone (the bone spans {low:+.1f} to {high:+.1f} "
                "mm across the plane's origin); centre the plane on the bone or change the extent"
            )
        if cloud is None:
            depths, points = section._depths_at(side)
            corners += [points[np.argmin(depths)], points[np.argmax(depths)]]
            continue
        depths = _cloud_side_depths(cloud, plane, side)
        if depths is None:
            raise ValueError(
                f"the IPC has no point within {2.0 * _band(cloud):.2g} mm of the cut's side at {side:+.1f} mm; give "
                "the IPC as a surface (mesh) or a denser point cloud"
            )
        corners += [plane.origin + side * plane.across + depth * plane.depth for depth in depths]
    return np.array(corners)


def _cloud_side_depths(cloud, plane, side):
    """(entry, far) depths (mm) where the side line across = ``side`` enters and leaves a point cloud's surface, or
    None: the crossings of the line with the local surfaces of the cloud's points near it (``CloudSurface``), split
    into walls where consecutive ones are more than ``WALL_GAP_MM`` apart; the median of the first and the last."""
    # Points within 4 spacings of the line: 11 on average where it crosses a randomly sampled surface head on.
    radius = 2.0 * _band(cloud)
    crossings = np.sort(cloud.line_crossings(plane.origin + side * plane.across, plane.depth, radius))
    if len(crossings) == 0:
        return None
    gaps = np.diff(crossings)
    if gaps.size == 0 or gaps.max() <= WALL_GAP_MM:
        return float(np.median(crossings)), float(np.median(crossings))
    # More than two walls (an IPC with inner surfaces): the entry is the nearest group, the far the farthest.
    walls = np.split(crossings, np.flatnonzero(gaps > WALL_GAP_MM) + 1)
    first, last = walls[0], walls[-1]
    return float(np.median(first)), float(np.median(last))


def direction_word(vector):
    """The patient's direction (RAS) a vector (3,) points most along: 'right', 'anterior', 'inferior', ..."""
    axis = int(np.argmax(np.abs(vector)))
    return (("left", "right"), ("posterior", "anterior"), ("inferior", "superior"))[axis][int(vector[axis] > 0)]


def _vector3(values, name):
    """(3,) float64 from 3 finite numbers; ValueError naming ``name`` otherwise."""
    try:
        vector = np.array(values, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        vector = np.zeros(0)
    if vector.shape != (3,) or not np.isfinite(vector).all():
        raise ValueError(f"{name}: give 3 finite numbers (x, y, z), got {values!r}")
    return vector


def _vector(values):
    return "(" + ", ".join(f"{value:.1f}" for value in values) + ")"
