"""Where marker spheres may be: a Hough transform for balls of the marker's radius, on a coarse grid.

Nothing here assumes which object is the bone, which part of the reference body is brightest, or that the spheres
are above the bone threshold: a sphere is a surface of known radius across which the CT gets brighter inward, so
every edge point votes for the point one radius inward along its gradient (the brighter side), and the votes of a
sphere's surface meet at its centre from every direction. Posts, frame rods, plates, brackets and bone spread
their votes over lines, circles and sheets; a sphere's stay in one place however bright it is against its
surroundings (100 HU plastic or clipped metal in air), whatever touches it, and whatever bright object it is
joined to.

* The grid: block means of the denoised CT, blocks of about ``GRID_MM`` (at least one voxel).
* Edges: gradient magnitude above ``EDGE_HU_PER_MM`` (a step of about 300 HU over the grid's blur); each edge cell
  casts one vote (not weighted by contrast) for the cell nearest its target point.
* Peaks: the votes summed over 3 x 3 x 3 cells; local maxima with at least ``MIN_VOTES`` of the count a whole
  sphere's surface one cell thick would give (a sphere on a post, or with the frame touching it, or a third of it
  cut off by the field of view, keeps more), one per sphere-sized neighbourhood, most votes first.
* Isotropy: the votes' unit directions summed at the peak, over their count: near 0 for a sphere, near 1 for a
  cap-like piece of surface (the curved end of a rod, a bone's curvature); above ``MAX_ONE_SIDEDNESS`` the
  candidate is dropped.

The fit (``marker_spheres``) decides on the full-resolution image; this only says where to look.
"""

from dataclasses import dataclass

import numpy as np

from .morphology import box_max, box_sum
from .parallel import in_slabs

#: The coarse grid's cell (mm, about; 1-2 mm): fine enough to place an 11.5 mm sphere's centre within a cell.
GRID_MM = 1.5
#: An edge: at least this gradient (HU per mm) on the coarse grid.
EDGE_HU_PER_MM = 100.0
#: A candidate has at least this fraction of a whole sphere's votes (a one-cell-thick shell).
MIN_VOTES = 0.3
#: A candidate whose votes come from one side (|mean unit direction| above this) is a cap, not a sphere.
MAX_ONE_SIDEDNESS = 0.55
#: The votes' directions span 3-D: the smallest eigenvalue of their second moment is 1/3 for a sphere (a half one
#: too), 0 for a rod's axis (directions in a plane) or a plate.
MIN_SPREAD = 0.15


@dataclass(frozen=True)
class SphereCandidate:
    """A place to fit a sphere: ``centre`` (3,) RAS mm, ``votes`` (fraction of a whole sphere's), ``one_sidedness``,
    ``spread``."""

    centre: np.ndarray
    votes: float
    one_sidedness: float
    spread: float = 1.0 / 3.0


def block_means(image, block):
    """Means of ``image`` (I, J, K) over blocks of ``block`` (3,) voxels (the edges' partial blocks dropped)."""
    shape = np.array(image.shape) // block
    trimmed = image[: shape[0] * block[0], : shape[1] * block[1], : shape[2] * block[2]]
    if (block == 1).all():
        return np.asarray(trimmed, dtype=np.float32)
    summed = np.zeros(shape, dtype=np.float32)

    # Slabs of whole blocks across the first axis, one per core; in each, the blocks summed offset by offset (a
    # strided view each): a reduction over the reshaped blocks' axes is 3-4 times slower.
    def slab(start, stop):
        rows = trimmed[start * block[0] : stop * block[0]]
        for offset in np.ndindex(*block):
            summed[start:stop] += rows[tuple(slice(o, None, b) for o, b in zip(offset, block))]

    in_slabs(int(shape[0]), slab)
    return summed / np.float32(np.prod(block))


def find_sphere_candidates(volume, smoothed, origin, radius_mm, limit=40):
    """Candidate sphere centres in a denoised CT, most votes first.

    Args:
        volume: the CTVolume (its geometry).
        smoothed: (I, J, K) denoised HU over a box of the volume whose first voxel is ``origin`` (3,) (indices).
        radius_mm: the spheres' radius.
        limit: at most this many candidates.

    Returns:
        list of SphereCandidate.
    """
    spacing = volume.spacing
    block = np.maximum(1, np.rint(GRID_MM / spacing)).astype(int)
    cell = spacing * block
    coarse = block_means(smoothed, block)
    if min(coarse.shape) < 3:
        return []
    gradients = np.gradient(coarse, *cell)
    magnitude = np.sqrt(gradients[0] ** 2 + gradients[1] ** 2 + gradients[2] ** 2)
    edges = np.flatnonzero(magnitude >= EDGE_HU_PER_MM)
    if len(edges) == 0:
        return []
    shape = np.array(coarse.shape)
    unit = np.stack([g.ravel()[edges] for g in gradients], axis=1) / magnitude.ravel()[edges][:, None]
    # Each edge cell votes for the cell one radius up its gradient. The grid's axes are orthonormal, so index
    # times cell size is a distance-preserving frame (mm).
    source = np.stack(np.unravel_index(edges, coarse.shape), axis=1)
    target = np.rint(source + radius_mm * unit / cell).astype(np.int64)
    inside = np.all((target >= 0) & (target < shape), axis=1)
    target, unit = target[inside], unit[inside]
    flat = np.ravel_multi_index(tuple(target.T), coarse.shape)
    votes = np.bincount(flat, minlength=coarse.size).reshape(coarse.shape).astype(np.float32)
    summed = box_sum(votes)  # whole counts: exact in float32
    whole = 4.0 * np.pi * radius_mm**2 / float(np.mean(cell) ** 2)
    peaks = (summed >= MIN_VOTES * whole) & (summed == box_max(summed))
    indices = np.argwhere(peaks)
    if len(indices) == 0:
        return []
    indices = indices[np.argsort(-summed[peaks], kind="stable")]
    order = np.argsort(flat, kind="stable")
    sorted_flat = flat[order]
    neighbours = np.array(list(np.ndindex(3, 3, 3))) - 1
    candidates = []
    for index in indices[: 4 * limit]:
        around = tuple(slice(max(i - 1, 0), min(i + 2, n)) for i, n in zip(index, shape))
        cells = index + neighbours
        cells = cells[np.all((cells >= 0) & (cells < shape), axis=1)]
        cells = np.ravel_multi_index(tuple(cells.T), coarse.shape)
        starts, ends = np.searchsorted(sorted_flat, cells, "left"), np.searchsorted(sorted_flat, cells, "right")
        directions = unit[np.concatenate([order[a:b] for a, b in zip(starts, ends)])]  # the votes summed here
        one_sided = float(np.linalg.norm(directions.sum(axis=0)) / max(len(directions), 1))
        spread = float(np.linalg.eigvalsh(directions.T @ directions / max(len(directions), 1))[0])
        if one_sided > MAX_ONE_SIDEDNESS or spread < MIN_SPREAD:
            continue
        # The peak's sub-cell position: the vote-weighted mean of its 3 x 3 x 3 cells.
        local = votes[around]
        grid = np.stack(np.meshgrid(*[np.arange(s.start, s.stop) for s in around], indexing="ij"), axis=-1)
        mean_cell = (grid * local[..., None]).reshape(-1, 3).sum(axis=0) / max(float(local.sum()), 1e-6)
        ijk = origin + (mean_cell + 0.5) * block - 0.5
        centre = volume.ijk_to_ras_points(ijk[None])[0]
        if all(np.linalg.norm(centre - other.centre) > radius_mm for other in candidates):
            candidates.append(SphereCandidate(centre, float(summed[tuple(index)] / whole), one_sided, spread))
            if len(candidates) >= limit:
                break
    return candidates
