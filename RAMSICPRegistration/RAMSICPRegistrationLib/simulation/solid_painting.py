"""Painting solids (``solids``) into a CT grid, with a choice of how partial volume is formed, and scanning it.

Three partial-volume models, so that an image side tested on them is not tuned to one (CTs made by other software
form their edges their own way):

* ``ramp``: the fraction inside is a linear ramp of the signed distance, one mean voxel wide (``ct_painting``'s);
* ``supersample``: voxels within half a voxel diagonal of the surface are sampled at 2 x 2 x 2 points;
* ``sharp``: a voxel is inside or not by its centre (the blur alone makes the edge).

``scan`` then blurs (Gaussian, in-plane and across slices apart), adds noise (white, or spatially correlated),
clips to the 12-bit CT range and pads the outside of a round reconstruction.
"""

import numpy as np
from scipy import ndimage

PARTIAL_VOLUME_MODELS = ("ramp", "supersample", "sharp")


def occupancy(solid, ras, signed, offset, model, volume):
    """Partial-volume fraction (float32, shape of ``signed``) of voxels inside the solid's surface moved ``offset``
    mm outward; ``ras`` (..., 3) their centres and ``signed`` the solid's signed distance there."""
    level = signed - offset
    spacing = volume.spacing
    if model == "sharp":
        return (level < 0).astype(np.float32)
    if model == "ramp":
        return np.clip(0.5 - level / float(np.mean(spacing)), 0.0, 1.0).astype(np.float32)
    fraction = (level < 0).astype(np.float32)
    band = np.abs(level) < 0.5 * float(np.linalg.norm(spacing))
    if band.any():
        points = ras[band]
        count = np.zeros(len(points), dtype=np.float32)
        for corner in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")).reshape(3, -1).T:
            shift = volume.direction @ (0.25 * corner * spacing)
            count += solid.signed_distance(points + shift) - offset < 0
        fraction[band] = count / 8.0
    return fraction


def paint(volume, solid, layers, model, signed_on_grid=None, pad_mm=2.0):
    """Blend a solid into ``volume.voxels`` (float32, in place), later on top of earlier.

    Args:
        layers: [(offset mm, HU)], painted in order: the solid's surface moved outward by each offset (a soft-tissue
            layer round a bone, the bone, its inside moved inward).
        signed_on_grid: optional callable (volume, box, ras) -> signed distance over the box, for a solid whose
            distance far from its surface needs the grid (a mesh).

    Returns:
        (box, fraction of the last layer) or (None, None) when the solid is outside the volume.
    """
    reach = max([offset for offset, _ in layers] + [0.0]) + pad_mm
    low, high = solid.bounds()
    box, ras = volume.voxels_within(low - reach, high + reach)
    if box is None:
        return None, None
    signed = signed_on_grid(volume, box, ras) if signed_on_grid else solid.signed_distance(ras)
    fraction = None
    for offset, hu in layers:
        fraction = occupancy(solid, ras, signed, offset, model, volume)
        volume.voxels[box] = fraction * np.float32(hu) + (1.0 - fraction) * volume.voxels[box]
    return box, fraction


def mesh_signed_on_grid(solid):
    """``signed_on_grid`` for a ``solids.MeshSolid``: inside from a stencil, distance from the distance transform,
    exact (the solid's own signed distance) within two voxels of the surface."""

    def signed(volume, box, ras):
        inside = solid.inside_on_grid(volume, box)
        spacing = volume.spacing
        distance = np.where(
            inside,
            -ndimage.distance_transform_edt(inside, sampling=spacing),
            ndimage.distance_transform_edt(~inside, sampling=spacing),
        )
        band = np.abs(distance) < 2.0 * spacing.max()
        distance[band] = solid.signed_distance(ras[band])
        return distance

    return signed


def scan(volume, blur_mm, noise_hu, rng, correlation_voxels=0.0, outside_cylinder=None, padding_hu=-1024.0):
    """The scanner: blur, noise, the 12-bit range, padding outside a round field of view; int16 HU.

    Args:
        blur_mm: (in-plane, across slices) Gaussian sigmas (mm).
        noise_hu: the noise's standard deviation; ``correlation_voxels`` > 0 correlates it (Gaussian, voxels).
        outside_cylinder: (I, J) booleans of the in-plane positions outside the reconstruction, or None.
    """
    sigma = np.array([blur_mm[0], blur_mm[0], blur_mm[1]]) / volume.spacing
    voxels = ndimage.gaussian_filter(volume.voxels, sigma, truncate=3.0)
    noise = rng.normal(size=voxels.shape).astype(np.float32)
    if correlation_voxels > 0:
        noise = ndimage.gaussian_filter(noise, correlation_voxels)
        noise /= max(float(noise.std()), 1e-6)
    voxels += np.float32(noise_hu) * noise
    voxels = np.clip(voxels, -1024.0, 3071.0)
    if outside_cylinder is not None:
        voxels[outside_cylinder] = padding_hu
    return np.round(voxels).astype(np.int16)
