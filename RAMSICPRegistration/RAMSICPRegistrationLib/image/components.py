"""Connected components of a thresholded CT box, one slab per core: the same labels as ``scipy.ndimage.label``.

``ndimage.label`` runs on one core (0.12 s on the 34-million-voxel box of the speed benchmark's CT, a tenth of the
image side's serial time). Here each slab of rows across the first axis is labelled on its own core; the pieces that
touch across a slab's boundary (the same voxel position in its last row and the next slab's first: the
6-connected cross, ``label``'s default) are joined; and the components are numbered by the first voxel of each in
C order, as ``ndimage.label`` numbers them. The slabs come in C order, and within a slab ``label`` numbers its
pieces by their first voxels, so a component's first voxel is that of its lowest-numbered piece: the pieces'
numbers, offset slab by slab, sorted by the lowest of each component, give ``label``'s numbering.
"""

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph

from .parallel import in_slabs, slab_cuts

#: A slab holds at least this many rows: thinner ones are not worth their joins.
MIN_SLAB_ROWS = 16


def label_components(foreground):
    """Label the 6-connected components of ``foreground`` (I, J, K) booleans.

    Returns:
        labels (I, J, K) int32 (0 the background, components 1..count numbered as ``ndimage.label`` numbers them),
        count, and sizes (count + 1,) int64 voxels per label (0 for the background).
    """
    length = len(foreground)
    starts = [int(start) for start in slab_cuts(length, MIN_SLAB_ROWS)[:-1]]
    labels = np.empty(foreground.shape, dtype=np.int32)
    counts, piece_sizes = {}, {}

    def label_slab(start, stop):
        counts[start] = ndimage.label(foreground[start:stop], output=labels[start:stop])
        # Over the foreground alone (a few % of a CT's box): a count over every voxel takes 6 times as long.
        pieces = labels[start:stop][foreground[start:stop]]
        piece_sizes[start] = np.bincount(pieces, minlength=counts[start] + 1)[1:]

    in_slabs(length, label_slab, MIN_SLAB_ROWS)
    offsets = np.cumsum([0] + [counts[start] for start in starts])
    total = int(offsets[-1])
    # The pieces' numbers, offset slab by slab: piece p of the slab from starts[s] is offsets[s] + p.
    pairs = []
    for s, start in enumerate(starts[1:], start=1):
        below, above = labels[start - 1], labels[start]
        touching = (below > 0) & (above > 0)
        if touching.any():
            pairs.append(
                np.unique(np.stack([below[touching] + offsets[s - 1], above[touching] + offsets[s]], axis=1), axis=0)
            )
    lookup = np.zeros(total + 1, dtype=np.int32)
    sizes = np.zeros(1, dtype=np.int64)
    if total:
        joined = np.concatenate(pairs) if pairs else np.zeros((0, 2), dtype=np.int64)
        graph = sparse.coo_matrix((np.ones(len(joined)), (joined[:, 0] - 1, joined[:, 1] - 1)), shape=(total, total))
        count, component = csgraph.connected_components(graph, directed=False)
        lowest = np.full(count, total, dtype=np.int64)
        np.minimum.at(lowest, component, np.arange(total))
        rank = np.empty(count, dtype=np.int32)
        rank[np.argsort(lowest, kind="stable")] = np.arange(1, count + 1, dtype=np.int32)
        lookup[1:] = rank[component]
        all_piece_sizes = np.concatenate([piece_sizes[start] for start in starts])
        sizes = np.bincount(lookup[1:], weights=all_piece_sizes, minlength=count + 1).astype(np.int64)
    else:
        count = 0

    def renumber(start, stop):
        s = starts.index(start)
        slab_lookup = lookup[offsets[s] : offsets[s] + counts[start] + 1].copy()
        slab_lookup[0] = 0  # the background (the slice starts at the slab before's last piece)
        if not np.array_equal(slab_lookup, np.arange(len(slab_lookup))):  # the first slab's often is
            inside = foreground[start:stop]
            labels[start:stop][inside] = slab_lookup[labels[start:stop][inside]]

    if len(starts) > 1:  # one slab is numbered as ``label`` numbers it already
        in_slabs(length, renumber, MIN_SLAB_ROWS)
    sizes[0] = 0
    return labels, int(count), sizes


def boxes_and_sizes(labels):
    """Each label's box and voxel count in ``labels`` (I, J, K) integers, slab by slab as ``label_components``.

    Returns:
        boxes: list (one per label 1..max) of 3 slices, None for a label not present (``ndimage.find_objects``),
        and sizes (max + 1,) int64 voxels per label (0 for the background).
    """

    def look(start, stop):
        slab = labels[start:stop]
        return ndimage.find_objects(slab), np.bincount(slab[slab > 0])

    found = in_slabs(len(labels), look, MIN_SLAB_ROWS)
    starts = slab_cuts(len(labels), MIN_SLAB_ROWS)[:-1]
    count = max(len(slab_boxes) for slab_boxes, _ in found)  # the highest label
    found = [(slab_boxes + [None] * (count - len(slab_boxes)), slab_sizes) for slab_boxes, slab_sizes in found]
    sizes = np.zeros(count + 1, dtype=np.int64)
    for _, slab_sizes in found:
        sizes[: len(slab_sizes)] += slab_sizes
    sizes[0] = 0
    boxes = []
    for label in range(count):
        parts = [(start, slab_boxes[label]) for start, (slab_boxes, _) in zip(starts, found) if slab_boxes[label]]
        if not parts:
            boxes.append(None)
            continue
        first = min(start + box[0].start for start, box in parts)
        last = max(start + box[0].stop for start, box in parts)
        rest = [slice(min(box[a].start for _, box in parts), max(box[a].stop for _, box in parts)) for a in (1, 2)]
        boxes.append((slice(int(first), int(last)), *rest))
    return boxes, sizes
