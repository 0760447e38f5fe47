"""Bone segmentation and the image point cloud (paper, "Data acquisition" (1)).

Denoise (Gaussian), threshold (HU, or automatic by Otsu's method above soft tissue), connected components; the
bone is the largest component, the other bright islands are candidates for the marker spheres. The IPC is the
bone's iso-surface at the threshold (VTK's flying edges: sub-voxel vertices), in RAS millimetres. Marrow
cavities are filled slice by slice first, so that the IPC is the outer bone surface a probe can touch; the
paper's IPC keeps both cortical surfaces, which ``fill_cavities=False`` reproduces. Near metal (an implant, a
pin) the surface is left out: ``metal.py`` says where and why.
"""

import logging
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..io.vtk_arrays import image_data, triangle_arrays
from .hounsfield import DEFAULT_THRESHOLD_HU, METAL_HU
from .metal import find_metal_zone

logger = logging.getLogger(__name__)

#: Gaussian denoising before the threshold (mm): about half the paper's pixel.
DEFAULT_DENOISE_SIGMA_MM = 0.3
#: The half-maximum bone surface needs voxels that resolve the cortex (mm).
HALF_MAX_MAX_VOXEL_MM = 1.0
#: Islands smaller than this (mm^3) are noise, not objects.
MIN_OBJECT_MM3 = 50.0


@dataclass(frozen=True)
class BoneSegmentation:
    """Result of ``segment_bone``.

    Attributes:
        smoothed: (I, J, K) float32 denoised HU.
        threshold_hu: the threshold used.
        labels: (I, J, K) int32 connected components of the thresholded volume (0 = background).
        bone_label: label of the bone.
        object_labels: labels of the other components larger than MIN_OBJECT_MM3 (marker-sphere candidates).
    """

    smoothed: np.ndarray
    threshold_hu: float
    labels: np.ndarray
    bone_label: int
    object_labels: tuple

    @property
    def bone_mask(self):
        return self.labels == self.bone_label

    def labelmap(self, sphere_labels=(), values=None):
        """(I, J, K) uint8 labelmap: 1 for the bone, and for the marker spheres given by their labels in
        ``labels`` the ``values`` given (2, 3, ... in the order given by default)."""
        labelmap = np.zeros(self.labels.shape, dtype=np.uint8)
        labelmap[self.bone_mask] = 1
        values = range(2, 2 + len(sphere_labels)) if values is None else values
        for label, value in zip(sphere_labels, values):
            labelmap[self.labels == label] = value
        return labelmap


def otsu_threshold(values, bins=512):
    """Otsu's threshold of a 1-D array of HU values (the split maximising between-class variance)."""
    histogram, edges = np.histogram(values, bins=bins)
    centres = 0.5 * (edges[:-1] + edges[1:])
    weight_low = np.cumsum(histogram).astype(np.float64)
    weight_high = weight_low[-1] - weight_low
    mean_low = np.cumsum(histogram * centres) / np.maximum(weight_low, 1)
    mean_high = (np.sum(histogram * centres) - np.cumsum(histogram * centres)) / np.maximum(weight_high, 1)
    between = weight_low * weight_high * (mean_low - mean_high) ** 2
    best = np.flatnonzero(between >= between.max() * (1.0 - 1e-9))  # a plateau when the classes are apart
    return float(np.mean(edges[best + 1]))


def segment_bone(volume, threshold_hu=DEFAULT_THRESHOLD_HU, denoise_sigma_mm=DEFAULT_DENOISE_SIGMA_MM):
    """Denoise, threshold and split a CT into the bone and other bright objects.

    Args:
        volume: CTVolume in HU.
        threshold_hu: a number, or ``'auto'`` for Otsu's threshold over the voxels above -200 HU (tissue and
            bone, not air).
        denoise_sigma_mm: Gaussian sigma (mm); 0 turns denoising off.

    Raises:
        ValueError: no voxel above the threshold, or an unknown threshold.
    """
    smoothed = volume.voxels.astype(np.float32)
    if denoise_sigma_mm > 0:
        smoothed = ndimage.gaussian_filter(smoothed, denoise_sigma_mm / volume.spacing, truncate=3.0)
    if threshold_hu == "auto":
        body = smoothed[smoothed > -200.0]
        if body.size == 0:
            raise ValueError("automatic threshold: no voxel above -200 HU; is this a CT in Hounsfield units?")
        threshold_hu = otsu_threshold(body[:: max(1, body.size // 2_000_000)])
        logger.info("automatic bone threshold: %.0f HU", threshold_hu)
    try:
        threshold_hu = float(threshold_hu)
    except (TypeError, ValueError):
        raise ValueError(f"threshold {threshold_hu!r}: give a number of HU or 'auto'") from None
    foreground = smoothed >= threshold_hu
    if not foreground.any():
        raise ValueError(
            f"no voxel is above the threshold of {threshold_hu:.0f} HU (the CT's maximum is "
            f"{float(smoothed.max()):.0f} HU); lower the threshold or check that the CT is in HU"
        )
    labels, count = ndimage.label(foreground)
    sizes = np.bincount(labels[foreground], minlength=count + 1)  # the foreground only: a few % of the CT
    sizes[0] = 0
    bone_label = int(np.argmax(sizes))
    voxel_mm3 = float(np.prod(volume.spacing))
    objects = tuple(int(label) for label in np.flatnonzero(sizes * voxel_mm3 >= MIN_OBJECT_MM3) if label != bone_label)
    logger.info(
        "threshold %.0f HU: bone %.0f mm^3, %d other objects", threshold_hu, sizes[bone_label] * voxel_mm3, len(objects)
    )
    return BoneSegmentation(
        smoothed=smoothed,
        threshold_hu=threshold_hu,
        labels=labels.astype(np.int32, copy=False),
        bone_label=bone_label,
        object_labels=objects,
    )


@dataclass(frozen=True)
class BoneSurface:
    """The IPC: ``points`` (M, 3) RAS mm, and the iso-surface ``triangles`` (K, 3) over them.

    ``metal`` is the MetalZone of the CT; ``left_out`` the number of surface points dropped in it.
    """

    points: np.ndarray
    triangles: np.ndarray
    metal: object = None
    left_out: int = 0


def bone_surface(volume, segmentation, fill_cavities=True, level="half-max", leave_out_metal=True):
    """The bone's outer iso-surface in RAS mm (the IPC).

    Args:
        volume: the CTVolume that was segmented (for its geometry).
        segmentation: BoneSegmentation.
        fill_cavities: fill the marrow cavity slice by slice so only the outer surface remains.
        level: ``'half-max'`` (default) puts the surface half-way between the cortex and the tissue just outside
            it, both measured in this CT, which removes the blur's outward bias of a low threshold (0.6 mm on
            the phantoms at 200 HU). It needs voxels that resolve the cortex (at most ``HALF_MAX_MAX_VOXEL_MM``);
            coarser CTs get the threshold surface. ``'threshold'`` uses the segmentation threshold; or a number.
        leave_out_metal: drop the surface in the metal zone (``metal.find_metal_zone``); False keeps it, to
            see what the metal does.
    """
    full_mask = segmentation.bone_mask
    low, high = _bounding_box(full_mask, pad=4)
    box = tuple(slice(a, b) for a, b in zip(low, high))
    mask = full_mask[box]
    image = segmentation.smoothed[box].copy()
    level = _surface_level(image, mask, segmentation.threshold_hu, level, volume.spacing)
    if fill_cavities:
        # Everything darker than the surface level that the bone encloses, slice by slice, is cavity: raising
        # it removes the inner (marrow) wall and leaves the outer edge, which is open to the outside, alone.
        axis = fill_axis(full_mask, volume.spacing)
        in_slice = np.zeros((3, 3, 3), dtype=bool)
        in_slice[tuple(1 if a == axis else slice(None) for a in range(3))] = True
        bright = (image >= level) & ndimage.binary_dilation(mask, iterations=2)
        cavity = ndimage.binary_fill_holes(bright, structure=in_slice) & ~bright
        image[cavity] = level + 100.0
        mask = mask | cavity
    # Other objects (marker spheres, a bracket touching the bone) must not add surface to the IPC.
    image[~ndimage.binary_dilation(mask, iterations=2)] = min(float(image.min()), level - 1000.0)
    vertices_ijk, triangles = iso_surface(image, level)
    if len(vertices_ijk) == 0:
        raise ValueError("the bone has no surface at the threshold; check the threshold")
    metal = find_metal_zone(volume, segmentation.smoothed, near=(low, high))
    spoilt = metal.contains_ijk(vertices_ijk + low) if leave_out_metal else np.zeros(len(vertices_ijk), dtype=bool)
    if spoilt.any():
        vertices_ijk, triangles = _without_vertices(vertices_ijk, triangles, spoilt)
        logger.info("%d bone-surface points next to metal left out", int(spoilt.sum()))
    if len(vertices_ijk) == 0:
        raise ValueError("all of the bone's surface lies next to metal; no IPC can be taken from this CT")
    return BoneSurface(
        points=volume.ijk_to_ras_points(vertices_ijk + low),
        triangles=triangles,
        metal=metal,
        left_out=int(spoilt.sum()),
    )


def _without_vertices(vertices, triangles, drop):
    """A mesh without the vertices flagged in ``drop`` (M,) and the triangles that use them, re-indexed."""
    keep = ~drop
    new_index = np.cumsum(keep) - 1
    kept_triangles = triangles[keep[triangles].all(axis=1)]
    return vertices[keep], new_index[kept_triangles]


def fill_axis(mask, spacing):
    """The axis (0, 1, 2) across whose slices the cavities are filled: the one the field of view cuts the bone along.

    Where the scan ends inside the bone, its cavity (marrow, or the cancellous core between an ilium's two
    cortical tables) is open to the volume's edge in slices along that axis and enclosed only in the slices across
    it. A bone that the field of view does not cut is filled across its longest extent.
    """
    cut = [int(np.take(mask, 0, axis).sum() + np.take(mask, -1, axis).sum()) for axis in range(3)]
    if max(cut) > 0:
        return int(np.argmax(cut))
    present = [np.flatnonzero(mask.any(axis=tuple(b for b in range(3) if b != a))) for a in range(3)]
    return int(np.argmax([(p[-1] - p[0] + 1) * s for p, s in zip(present, spacing)]))


def _surface_level(image, mask, threshold, level, spacing):
    if level == "threshold":
        return threshold
    if level != "half-max":
        return float(level)
    if spacing.max() > HALF_MAX_MAX_VOXEL_MM:
        logger.info("voxels of %.1f mm do not resolve the cortex: bone surface at the threshold", spacing.max())
        return threshold
    # The cortex's brightness, read just beneath the blurred edge (1 to 4 voxels deep), metal left out.
    rim = ndimage.binary_erosion(mask, iterations=1) & ~ndimage.binary_erosion(mask, iterations=4)
    rim_values = image[rim]
    cortex = float(np.percentile(rim_values[rim_values < METAL_HU], 95))
    outside = float(
        np.median(image[ndimage.binary_dilation(mask, iterations=4) & ~ndimage.binary_dilation(mask, iterations=2)])
    )
    logger.info(
        "bone surface at half-max %.0f HU (cortex %.0f HU, outside %.0f HU)", (cortex + outside) / 2, cortex, outside
    )
    return 0.5 * (cortex + outside)


def iso_surface(image, level):
    """Iso-surface of a 3-D array at ``level`` (VTK flying edges): vertices (M, 3) in index units, triangles (K, 3)."""
    from vtkmodules.vtkFiltersCore import vtkFlyingEdges3D

    edges = vtkFlyingEdges3D()
    edges.SetInputData(image_data(image))
    edges.SetValue(0, float(level))
    edges.ComputeNormalsOff()
    edges.ComputeGradientsOff()
    edges.ComputeScalarsOff()
    edges.Update()
    return triangle_arrays(edges.GetOutput())


def resample_points(points, spacing_mm):
    """Thin a point cloud to about one point per ``spacing_mm`` cube: the point nearest each occupied cube's mean."""
    if spacing_mm <= 0 or not np.isfinite(spacing_mm):
        raise ValueError(f"point spacing {spacing_mm} mm: give a positive number (e.g. 0.5)")
    cells = np.floor((points - points.min(axis=0)) / spacing_mm).astype(np.int64)
    _, cell_of_point = np.unique(cells, axis=0, return_inverse=True)
    cell_of_point = cell_of_point.ravel()
    count = np.bincount(cell_of_point)
    means = np.stack([np.bincount(cell_of_point, weights=points[:, a]) / count for a in range(3)], axis=1)
    distance = np.linalg.norm(points - means[cell_of_point], axis=1)
    order = np.lexsort((distance, cell_of_point))
    first = np.concatenate(([True], np.diff(cell_of_point[order]) != 0))
    return points[order[first]]


def _bounding_box(mask, pad):
    present = [np.flatnonzero(mask.any(axis=tuple(b for b in range(3) if b != a))) for a in range(3)]
    low = np.array([max(p[0] - pad, 0) for p in present])
    high = np.array([min(p[-1] + pad + 1, n) for p, n in zip(present, mask.shape)])
    return low, high
