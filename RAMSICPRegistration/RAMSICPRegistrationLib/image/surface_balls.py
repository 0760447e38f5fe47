"""Balls of a given radius on a surface mesh (the IPC): a Hough transform on the mesh's own normals.

A marker sphere sunk into a plate brighter than itself shows no edge of its own in the CT where the plate holds it
(``sphere_candidates`` looks for surfaces brighter inward, ``thick_spots`` for spots a ball thick, and a plate nearly
as thick as the ball is a plateau), but the caps that stand out of the plate on both sides are the object's outer
surface: when that object is taken for bone, they are in the IPC (family seed 40192 with wide brackets: two
1,037 HU spheres sunk into a 7.7 mm plate of 1,381 HU, their caps 1.9 mm high, two more cut by the field of view).

Each vertex votes one radius along its normal, both ways (the mesh's orientation is not needed); the votes of a
ball's surface meet at its centre from every direction its surface is seen, while a plate's or a shaft's spread over
sheets and lines. The votes are counted on a grid of ``GRID_MM`` cells, sparse (only the cells voted for: a whole
bone's IPC spans hundreds of mm), summed over each cell's 3 x 3 x 3 neighbourhood; a peak with at least
``MIN_VOTES`` of the count a whole ball's surface would give (the surface's own density of vertices), from directions
that span 3-D and balance along every axis, is a ball's centre, at the vote-weighted mean of its neighbourhood.
Whether the surface holds enough of the ball is for the caller to say (``ipc_self_check``).
"""

import numpy as np

#: The vote grid's cell (mm).
GRID_MM = 1.0
#: A ball's centre gets at least this fraction of a whole ball's votes: two caps 1.9 mm high of a 5.75 mm ball give
#: a third of its surface, and 0.25-0.27 of the votes (40192).
MIN_VOTES = 0.2
#: The votes at a ball's centre span 3-D: the smallest eigenvalue of their directions' second moment is 1/3 for a
#: whole ball, 0.14 for spheres sunk into a plate two thirds their diameter thick on a mesh built by hand and
#: 0.073-0.082 in a CT's blur (family seed 40192), 0.06-0.07 in a plate 9.5 mm thick; 0-0.02 on a shaft's axis (the
#: votes of a shaft as thick as the ball meet there from directions in a plane) ...
MIN_SPREAD = 0.05
#: ... and they come from both sides along each principal axis of that moment (|mean| over RMS of the directions'
#: components along it at most this): 0-0.05 for a ball seen whole, on a post or sunk into a plate (its two caps), on
#: meshes built by hand; 0.25-0.41 where a flat-ended shaft as thick as the ball ends (the ring of its side and its
#: end's face), 0.74-0.76 at a rod's rounded end (a half ball and the ring next to it). The peaks with enough votes
#: on the family's bones came from one side (|mean direction| 0.58-0.84: their ends).
MAX_IMBALANCE = 0.15
#: At most this many balls, most votes first.
MAX_BALLS = 16

_NEIGHBOURS = np.array(list(np.ndindex(3, 3, 3))) - 1


def vertex_normals(points, triangles):
    """(N, 3) unit normals of a mesh's vertices (``points`` (N, 3) mm, ``triangles`` (T, 3) indices): the sum of
    the normals of the triangles round each, weighted by their areas (a vertex in no triangle: zero)."""
    corners = [points[triangles[:, k]] for k in range(3)]
    faces = np.cross(corners[1] - corners[0], corners[2] - corners[0])  # twice the area, along the normal
    normals = np.zeros(points.shape)
    for axis in range(3):
        for k in range(3):
            normals[:, axis] += np.bincount(triangles[:, k], weights=faces[:, axis], minlength=len(points))
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)


def find_balls(points, triangles, radius_mm):
    """(K, 3) mm: centres of balls of ``radius_mm`` whose surface the mesh holds in part (the module docstring), most
    votes first; (0, 3) when there is none."""
    points = np.asarray(points, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if len(points) == 0 or len(triangles) == 0:
        return np.zeros((0, 3))
    corners = [points[triangles[:, k]] for k in range(3)]
    area = 0.5 * float(np.linalg.norm(np.cross(corners[1] - corners[0], corners[2] - corners[0]), axis=1).sum())
    if area <= 0.0:
        return np.zeros((0, 3))
    whole = 4.0 * np.pi * radius_mm**2 * len(points) / area  # the votes a whole ball's surface would give
    normals = vertex_normals(points, triangles)
    voters = np.linalg.norm(normals, axis=1) > 0
    # Each vote's direction: from its vertex to where it lands (towards a ball's centre for the ball's surface).
    directions = np.concatenate([-normals[voters], normals[voters]])
    votes = np.concatenate([points[voters], points[voters]]) + radius_mm * directions
    low = votes.min(axis=0) - 2 * GRID_MM  # a margin, so that every neighbour of a cell voted for is on the grid
    cells = np.floor((votes - low) / GRID_MM).astype(np.int64)
    shape = cells.max(axis=0) + 3
    vote_keys = np.ravel_multi_index(cells.T, shape)
    order = np.argsort(vote_keys, kind="stable")
    sorted_keys = vote_keys[order]
    keys, counts = np.unique(sorted_keys, return_counts=True)
    where = np.stack(np.unravel_index(keys, shape), axis=1)

    def around(values, rows):
        """(len(rows), 27): ``values`` (one per cell voted for) at the 27 neighbours of the cells ``rows`` (0 where
        none was voted for)."""
        found = np.zeros((len(rows), len(_NEIGHBOURS)), dtype=values.dtype)
        for n, step in enumerate(_NEIGHBOURS):
            neighbour = np.ravel_multi_index((where[rows] + step).T, shape)
            at = np.minimum(np.searchsorted(keys, neighbour), len(keys) - 1)
            hit = keys[at] == neighbour
            found[hit, n] = values[at[hit]]
        return found

    counts = counts.astype(np.int32)
    summed = around(counts, np.arange(len(keys))).sum(axis=1)
    strong = np.flatnonzero(summed >= MIN_VOTES * whole)
    if not len(strong):
        return np.zeros((0, 3))
    peaks = strong[summed[strong] >= around(summed, strong).max(axis=1)]
    peaks = peaks[np.argsort(-summed[peaks], kind="stable")]
    centres = []
    for peak in peaks:
        near = np.ravel_multi_index((where[peak] + _NEIGHBOURS).T, shape)
        starts, ends = np.searchsorted(sorted_keys, near, "left"), np.searchsorted(sorted_keys, near, "right")
        seen = directions[order[np.concatenate([np.arange(a, b) for a, b in zip(starts, ends)])]]
        moments, axes = np.linalg.eigh(seen.T @ seen / len(seen))
        if moments[0] < MIN_SPREAD:
            continue  # a shaft's axis: the votes' directions in a plane
        along = seen @ axes
        if (np.abs(along.mean(axis=0)) > MAX_IMBALANCE * np.sqrt(moments)).any():
            continue  # from one side along an axis: a rod's end, a ball's cap seen alone
        weights = around(counts, [peak])[0].astype(float)
        cell = where[peak] + weights @ _NEIGHBOURS / weights.sum()  # the vote-weighted mean of the neighbourhood
        centre = low + (cell + 0.5) * GRID_MM
        if all(np.linalg.norm(centre - other) > radius_mm for other in centres):
            centres.append(centre)
            if len(centres) == MAX_BALLS:
                break
    return np.array(centres).reshape(-1, 3)
