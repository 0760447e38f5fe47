"""Connected components slab by slab: the very labels, counts, sizes and boxes of ``scipy.ndimage`` on one core.

The image side's objects are numbered by ``ndimage.label``'s order, and the recognition walks them in that order: the
slabs must give the same numbers, not just the same partition. Drawn at random: shapes from one row to several
slabs, blobs of every size, the empty and the full volume, and components that join only several slabs on (a helix
through every slab, a U whose arms meet in the last slab).
"""

import numpy as np
import pytest
from scipy import ndimage

from RAMSICPRegistrationLib.image.components import MIN_SLAB_ROWS, boxes_and_sizes, label_components


def _random_foregrounds(count, seed):
    rng = np.random.default_rng(seed)
    for draw in range(count):
        shape = tuple(int(n) for n in rng.integers(1, 5 * MIN_SLAB_ROWS, size=3))
        noise = ndimage.gaussian_filter(rng.normal(size=shape), rng.uniform(0.5, 4.0))
        foreground = noise > rng.normal(scale=0.05)
        if draw % 9 == 0:
            foreground[:] = draw % 2 == 0  # the empty and the full volume
        yield foreground


def _reference(foreground):
    labels, count = ndimage.label(foreground)
    sizes = np.bincount(labels[foreground], minlength=count + 1)
    sizes[0] = 0
    return labels, count, sizes


@pytest.mark.parametrize("threads", ["1", "2", "5"])
def test_the_same_labels_counts_and_sizes_as_ndimage_label(monkeypatch, threads):
    monkeypatch.setenv("RAMSICP_THREADS", threads)  # 5: up to five slabs on volumes of 80 rows
    for foreground in _random_foregrounds(40, seed=int(threads)):
        labels, count, sizes = label_components(foreground)
        expected_labels, expected_count, expected_sizes = _reference(foreground)
        assert labels.dtype == np.int32 and count == expected_count
        np.testing.assert_array_equal(labels, expected_labels)
        np.testing.assert_array_equal(sizes, expected_sizes)


def test_components_joined_only_slabs_later_keep_the_number_of_their_first_voxel(monkeypatch):
    monkeypatch.setenv("RAMSICP_THREADS", "4")
    rows = 4 * MIN_SLAB_ROWS
    foreground = np.zeros((rows, 40, 40), dtype=bool)
    # A U: two arms from the first row that meet only in the last slab; between them, a blob starting in slab 2.
    foreground[:, 5, 5] = True
    foreground[:, 5, 30] = True
    foreground[-1, 5, 5:31] = True
    foreground[2 * MIN_SLAB_ROWS : 2 * MIN_SLAB_ROWS + 3, 20:23, 15:18] = True
    # A helix through every slab, starting after the U in the first row.
    angle = np.arange(rows) * 0.4
    j, k = np.rint(30 + 6 * np.cos(angle)).astype(int), np.rint(20 + 6 * np.sin(angle)).astype(int)
    foreground[0, j[0], k[0]] = True
    for row in range(1, rows):  # in each row, from where the row before ended to this row's point, face to face
        (j0, j1), (k0, k1) = sorted(j[row - 1 : row + 1]), sorted(k[row - 1 : row + 1])
        foreground[row, j0 : j1 + 1, k[row - 1]] = True
        foreground[row, j[row], k0 : k1 + 1] = True
    labels, count, sizes = label_components(foreground)
    assert count == 3
    np.testing.assert_array_equal(labels, ndimage.label(foreground)[0])
    assert labels[0, 5, 5] == labels[0, 5, 30] == 1  # the U: one object, numbered by its first voxel
    assert sizes[1] == 2 * rows + 24  # two arms and the bar between them (26 voxels, 2 of them the arms')


@pytest.mark.parametrize("threads", ["1", "3"])
def test_boxes_and_sizes_are_find_objects_and_the_voxel_counts(monkeypatch, threads):
    monkeypatch.setenv("RAMSICP_THREADS", threads)
    for draw, foreground in enumerate(_random_foregrounds(30, seed=10 + int(threads))):
        labels = ndimage.label(foreground)[0].astype(np.int32)
        if draw % 4 == 0 and labels.max() > 2:
            labels[labels == 2] = 0  # a label no voxel has any more
        boxes, sizes = boxes_and_sizes(labels)
        assert boxes == ndimage.find_objects(labels)
        np.testing.assert_array_equal(sizes, np.bincount(labels[labels > 0], minlength=int(labels.max()) + 1))
