"""Bone segmentation and the image point cloud (paper, "Data acquisition" (1)).

Denoise (Gaussian), threshold (HU, or automatic by Otsu's method above soft tissue), connected components; which
component is the bone is decided by what bone is, not by its size (``bone_recognition``): the object that holds
no marker spheres, with a cortex round a dimmer inside, cut off the reference body when a bracket joins them. The
IPC is the bone's iso-surface (VTK's flying edges: sub-voxel vertices), in RAS millimetres. Marrow cavities are
filled slice by slice first, so that the IPC is the outer bone surface a probe can touch; the paper's IPC keeps
both cortical surfaces, which ``fill_cavities=False`` reproduces. Near metal (an implant, a pin) the surface is
left out: ``metal.py`` says where and why; next to a bracket cut off the bone, too.

Only the box of the CT that holds something other than air (and a margin) is denoised and searched: a C-arm CT of
a specimen is mostly air.
"""

import logging
from dataclasses import dataclass, replace
from functools import partial

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from . import dim_parts
from .beyond_metal import beyond_metal
from .bone_recognition import CORTEX_CONTRAST_HU, MAX_CELLS, recognise_bone
from .bracket_stub import MAX_RADIUS_MM, bracket_line_beyond, bracket_stub
from .components import label_components
from .envelope import bone_envelope
from .hounsfield import DEFAULT_THRESHOLD_HU, METAL_HU
from .iso_surface import iso_surface
from .marker_spheres import detect_marker_spheres
from .metal import METAL_EDGE_MM, find_metal_zone
from .morphology import (
    all_behind,
    any_ahead,
    any_behind,
    bounding_box,
    dilate,
    erode,
    labelled,
    open_by_cube,
    reaching_no_side,
)
from .parallel import in_parallel, in_slabs
from .plugs import PLUG_MM, between_sides, inside_pieces
from .rod_stub import rod_stub
from .thin_appendages import wires_on_bone

logger = logging.getLogger(__name__)

__all__ = ["iso_surface"]  # also here for the callers that import it from this module

#: Gaussian denoising before the threshold (mm): about half the paper's pixel.
DEFAULT_DENOISE_SIGMA_MM = 0.3
#: The half-maximum bone surface needs voxels that resolve the cortex (mm).
HALF_MAX_MAX_VOXEL_MM = 1.0
#: Islands smaller than this (mm^3) are noise, not objects.
MIN_OBJECT_MM3 = 50.0
#: Voxels above this (HU) are something other than air (tissue, bone, any part of a reference body, a plastic
#: sphere); the box holding them, with BOX_MARGIN_MM more, is the part of the CT the image side works on.
SOMETHING_HU = -500.0
BOX_MARGIN_MM = 10.0
#: The look for that box samples the CT about this coarsely (mm): nothing the image side needs is thinner.
BOX_LOOK_MM = 2.0


@dataclass(frozen=True)
class BoneSegmentation:
    """Result of ``threshold_ct`` and ``segment_bone``, over the ``box`` of the CT that holds something.

    Attributes:
        smoothed: (I', J', K') float32 denoised HU over ``box``.
        threshold_hu: the threshold used.
        labels: (I', J', K') int32 connected components of the thresholded box (0 = background).
        bone_label: label of the bone (0 before it is recognised).
        object_labels: labels of the other components larger than MIN_OBJECT_MM3.
        box: 3 slices into the CT's voxels; ``volume_shape`` the CT's shape.
        body: (I', J', K') booleans of the reference body's voxels in the bone's component (a bracket joins them),
            or None; IPC points within ``body_margin_mm`` of those an opening cut off are left out.
        body_followed: (I', J', K') booleans, the voxels of ``body`` its material took from what the opening kept
            with the bone (``bone_recognition``), or None; their edge is a plateau's, and IPC points within
            FOLLOWED_MARGIN_MM of them are left out. Only the IPC's making reads them: a cached result
            (``image_side_cache``) has None.
        recognition: the ``bone_recognition.BoneRecognition`` (what each object was taken for, and why).
    """

    smoothed: np.ndarray
    threshold_hu: float
    labels: np.ndarray
    bone_label: int
    object_labels: tuple
    box: tuple = None
    volume_shape: tuple = None
    body: np.ndarray = None
    body_margin_mm: float = 0.0
    recognition: object = None
    body_followed: np.ndarray = None

    @property
    def origin(self):
        """(3,) index of the box's first voxel in the CT."""
        return np.array([0, 0, 0] if self.box is None else [s.start for s in self.box])

    def body_cut_off(self):
        """(I', J', K') booleans, the voxels of ``body`` an opening cut off (without ``body_followed``), or None."""
        if self.body is None or self.body_followed is None:
            return self.body
        return self.body & ~self.body_followed

    def bone_mask_in_box(self):
        """(I', J', K') booleans of the bone over ``box``: its component without the reference body's voxels."""
        mask = self.labels == self.bone_label
        return mask if self.body is None else mask & ~self.body

    @property
    def bone_mask(self):
        """(I, J, K) booleans of the bone over the whole CT."""
        return self._whole(self.bone_mask_in_box())

    def labelmap(self, sphere_labels=(), values=None):
        """(I, J, K) uint8 labelmap of the whole CT: 1 for the bone, and for the marker spheres given by their
        labels in ``labels`` the ``values`` given (2, 3, ... in the order given by default)."""
        labelmap = np.zeros(self.labels.shape, dtype=np.uint8)
        labelmap[self.bone_mask_in_box()] = 1
        values = range(2, 2 + len(sphere_labels)) if values is None else values
        for label, value in zip(sphere_labels, values):
            labelmap[self.labels == label] = value
        return self._whole(labelmap)

    def _whole(self, array):
        if self.box is None or tuple(array.shape) == tuple(self.volume_shape):
            return array
        whole = np.zeros(self.volume_shape, dtype=array.dtype)
        whole[self.box] = array
        return whole


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


def segment_bone(volume, threshold_hu=DEFAULT_THRESHOLD_HU, denoise_sigma_mm=DEFAULT_DENOISE_SIGMA_MM, spheres=None):
    """Denoise, threshold and split a CT into objects, and recognise the bone among them.

    Args:
        volume: CTVolume in HU.
        threshold_hu: a number, or ``'auto'`` for Otsu's threshold over the voxels above -200 HU (tissue and
            bone, not air).
        denoise_sigma_mm: Gaussian sigma (mm); 0 turns denoising off.
        spheres: the marker spheres found in this CT (``marker_spheres.MarkerSphere``); looked for when None.

    Raises:
        ValueError: no voxel above the threshold, an unknown threshold, or no object that is plausibly bone
            (``bone_recognition.recognise_bone`` says what was found).
    """
    segmentation = threshold_ct(volume, threshold_hu, denoise_sigma_mm)
    if spheres is None:
        spheres = reference_body_spheres(detect_marker_spheres(volume, segmentation))
    return with_bone(volume, segmentation, spheres)


def reference_body_spheres(detection):
    """The spheres that make a reference body, for the bone's recognition: those paired with the tool when it could
    be paired (a round bump of bone that fits a sphere is not one of them), else those at the tool's distances from
    one another (``MarkerDetection.tied``: too few in view or too sunk into the frame to number, but the body's),
    else the clean ones if there are at least 3 (a reference body has 3 markers or more; one sphere-like spot is
    no body)."""
    if detection.pairing is not None:
        return [sphere for sphere in detection.spheres if sphere.number > 0]
    if detection.tied:
        return list(detection.tied)
    clean = [sphere for sphere in detection.spheres if sphere.status == "ok"]
    return clean if len(clean) >= 3 else []


def with_bone(volume, segmentation, spheres, spheres_sure=True, max_cells=MAX_CELLS):
    """The segmentation with its bone recognised (``bone_recognition``), knowing the marker spheres found
    (``spheres_sure``: False when they are only tied by the tool's distances, ``recognise_bone``; ``max_cells``:
    the most cells of an object's grid)."""
    recognition = recognise_bone(volume, segmentation, spheres, spheres_sure, max_cells)
    others = tuple(label for label in segmentation.object_labels if label != recognition.label)
    return replace(
        segmentation,
        bone_label=recognition.label,
        object_labels=others,
        body=recognition.body,
        body_margin_mm=recognition.body_margin_mm,
        recognition=recognition,
        body_followed=recognition.body_followed,
    )


def threshold_ct(volume, threshold_hu=DEFAULT_THRESHOLD_HU, denoise_sigma_mm=DEFAULT_DENOISE_SIGMA_MM):
    """Denoise and threshold the box of a CT that holds something, and label its connected components.

    Returns:
        BoneSegmentation with ``bone_label`` 0 and every component larger than MIN_OBJECT_MM3 in
        ``object_labels``.

    Raises:
        ValueError: no voxel above the threshold, or an unknown threshold.
    """
    box = region_of_interest(volume)
    raw = volume.voxels[box]
    if raw.dtype.itemsize > 2 or raw.dtype.kind not in "iu":  # values float32 may not hold exactly: as float32 first
        raw = raw.astype(np.float32)
    smoothed = _denoised(raw, denoise_sigma_mm / volume.spacing) if denoise_sigma_mm > 0 else raw.astype(np.float32)
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
            f"{float(volume.voxels.max()):.0f} HU); lower the threshold or check that the CT is in HU"
        )
    labels, count, sizes = label_components(foreground)
    voxel_mm3 = float(np.prod(volume.spacing))
    objects = tuple(int(label) for label in np.flatnonzero(sizes * voxel_mm3 >= MIN_OBJECT_MM3))
    logger.info("threshold %.0f HU: %d objects over %.0f mm^3", threshold_hu, len(objects), voxel_mm3)
    return BoneSegmentation(
        smoothed=smoothed,
        threshold_hu=threshold_hu,
        labels=labels,
        bone_label=0,
        object_labels=objects,
        box=box,
        volume_shape=tuple(volume.voxels.shape),
    )


#: The Gaussian's kernel reaches this many sigmas (SciPy's ``truncate``).
DENOISE_TRUNCATE = 3.0


def _denoised(image, sigma):
    """(I, J, K) float32: ``image`` (float32, or integers float32 holds exactly: the CT's own int16, cast in the
    slabs) blurred by a Gaussian of ``sigma`` (3,) voxels, in slabs across the first axis that overlap by the
    kernel's reach, one per core: the same values as one ``gaussian_filter`` over the whole cast to float32 (its
    first pass reads the values as doubles either way)."""
    reach = int(DENOISE_TRUNCATE * float(sigma[0]) + 0.5)  # gaussian_filter's kernel radius along the axis
    denoised = np.empty(image.shape, dtype=np.float32)

    def slab(start, stop):
        low, high = max(start - reach, 0), min(stop + reach, len(image))
        blurred = ndimage.gaussian_filter(image[low:high], sigma, output=np.float32, truncate=DENOISE_TRUNCATE)
        denoised[start:stop] = blurred[start - low : stop - low]

    in_slabs(len(image), slab, min_rows=4 * reach + 4)
    return denoised


def region_of_interest(volume):
    """The box (3 slices) of a CT that holds every voxel above SOMETHING_HU, with BOX_MARGIN_MM around it.

    The CT is looked at every ``BOX_LOOK_MM`` or so; a CT of nothing but air gives the whole volume.
    """
    shape = np.array(volume.voxels.shape)
    stride = np.maximum(1, np.floor(BOX_LOOK_MM / volume.spacing)).astype(int)
    something = volume.voxels[:: stride[0], :: stride[1], :: stride[2]] > SOMETHING_HU
    if not something.any():
        return tuple(slice(0, n) for n in shape)
    margin = np.ceil(BOX_MARGIN_MM / volume.spacing).astype(int) + stride
    box = []
    for axis in range(3):
        present = np.flatnonzero(something.any(axis=tuple(a for a in range(3) if a != axis)))
        low = max(int(present[0]) * stride[axis] - margin[axis], 0)
        high = min(int(present[-1]) * stride[axis] + margin[axis] + 1, shape[axis])
        box.append(slice(low, high))
    return tuple(box)


@dataclass(frozen=True)
class BoneSurface:
    """The IPC: ``points`` (M, 3) RAS mm, and the iso-surface ``triangles`` (K, 3) over them.

    ``metal`` is the MetalZone of the CT; ``left_out`` the number of surface points dropped in it;
    ``left_out_body`` those dropped next to a reference body joined to the bone (a bracket); ``left_out_base`` those
    dropped round the base of a wire or a bracket's stub cut off the bone (``CUT_BASE_MM``).
    """

    points: np.ndarray
    triangles: np.ndarray
    metal: object = None
    left_out: int = 0
    left_out_body: int = 0
    left_out_base: int = 0


def bone_surface(volume, segmentation, fill_cavities=True, level="half-max", leave_out_metal=True, own_half_max=None):
    """The bone's outer iso-surface in RAS mm (the IPC).

    Args:
        volume: the CTVolume that was segmented (for its geometry).
        segmentation: BoneSegmentation with its bone recognised (``segment_bone``).
        fill_cavities: fill the marrow cavity slice by slice so only the outer surface remains.
        level: ``'half-max'`` (default) puts the surface half-way between the cortex and the tissue just outside
            it, both measured in this CT, which removes the blur's outward bias of a low threshold (0.6 mm on
            the phantoms at 200 HU). It needs voxels that resolve the cortex (at most ``HALF_MAX_MAX_VOXEL_MM``);
            coarser CTs get the threshold surface. ``'threshold'`` uses the segmentation threshold; or a number.
        leave_out_metal: drop the surface in the metal zone (``metal.find_metal_zone``) and on what a metal bracket
            joins to the bone (``beyond_metal``); False keeps it, to see what the metal does.
        own_half_max: move the points that touch something brighter than the rest of the surface touches (a dim
            bracket resting on the bone) up the gradient to their own half-max (``_to_own_half_max``); None: with
            the ``'half-max'`` level.
    """
    if segmentation.bone_label <= 0:
        raise ValueError("the segmentation has no bone recognised yet; make it with segment_bone")
    bone = segmentation.bone_mask_in_box()
    low, high = bounding_box(bone, pad=4)
    box = tuple(slice(a, b) for a, b in zip(low, high))
    mask = bone[box]
    image = segmentation.smoothed[box].copy()
    half_max = level == "half-max"
    if own_half_max is None:
        own_half_max = half_max
    fine = volume.spacing.max() <= HALF_MAX_MAX_VOXEL_MM + 1e-6  # voxels that resolve the cortex
    # A level read as a half-max or given (not the threshold), on such voxels: a cortex's edge.
    resolved = level != "threshold" and fine
    # The metal zone (below) depends on nothing else here: measured beside the level.
    level, metal = in_parallel(
        partial(_surface_level, image, mask, segmentation.threshold_hu, level, volume.spacing),
        partial(find_metal_zone, volume, segmentation.smoothed, near=(low, high), origin=segmentation.origin),
    )
    # The other objects: those the bone's recognition weighed (not specks of noise above the threshold, which the
    # bone's inside may hold, nor clutter too small to be anything).
    objects = np.zeros(int(segmentation.labels.max()) + 1, dtype=bool)
    verdicts = segmentation.recognition.objects if segmentation.recognition is not None else ()
    weighed = [verdict.label for verdict in verdicts if verdict.verdict != "too small"]
    objects[[label for label in weighed if label != segmentation.bone_label]] = True
    other = objects[segmentation.labels[box]] & ~mask
    if segmentation.body is not None:  # the reference body's part of the bone's object: its bracket, cut off
        other |= segmentation.body[box]
    raw_box = tuple(slice(b.start + a, b.start + c) for b, a, c in zip(segmentation.box, low, high))
    padding = outside_reconstruction(volume.voxels[raw_box])
    if fill_cavities:
        # Everything darker than the surface level that the bone encloses is its inside (marrow, cancellous bone,
        # noise holes): raising it removes the inner walls and leaves the outer edge alone. Other objects (a
        # bracket through the cortex, cut off the bone) are walls: the inside does not leak out along them.
        walls = other.copy()  # specks of noise in the bone's inside are no walls: they would split it up
        if padding is not None:  # the field of view's round edge, where the scan cuts the bone, is no outside
            walls |= padding[:, :, None]
        inside = _enclosed(
            image,
            (level, segmentation.threshold_hu),
            walls,
            segmentation.origin + low,
            segmentation.origin + high,
            volume,
        )
        if inside is None:  # the bone fills the field of view: enclosed in slices across the axis it is cut along
            axis = fill_axis(bone, volume.spacing)
            in_slice = np.zeros((3, 3, 3), dtype=bool)
            in_slice[tuple(1 if a == axis else slice(None) for a in range(3))] = True
            bright = (image >= level) & dilate(mask, iterations=2)
            inside = ndimage.binary_fill_holes(bright, structure=in_slice) & ~bright
        image[inside] = level + 100.0
        mask = mask | inside
    if level < segmentation.threshold_hu:
        # Below the threshold and above the surface level, the bone's voxels joined to it (cancellous bone about as
        # bright as the threshold) are the bone's too: wiped with the other objects, they would make a surface.
        # Only inside the bone (enclosed by it along the grid's lines) or at its edge: a dim bracket fixed into a bone
        # in air is above a surface level that low too, and it is no bone.
        near = dilate(mask, iterations=2)
        if fine:
            near |= _enclosed_along_lines(mask, _on_ct_edge(segmentation, low, high, volume), volume.spacing, padding)
        mask = mask | (_joined_above(image >= level, mask, other) & near)
    # What a metal bracket joins to the bone: its surface goes with the metal's (below). It stays in the mask: a piece
    # of the bone's inside that a pin's edge cuts off is no outside (family seed 25054: wiped, it left 10 IPC points
    # on its walls 6-16 mm inside the bone).
    # And a wire joined to the bone: another object.
    joined, wire = in_parallel(
        partial(beyond_metal, mask, image, volume.spacing) if leave_out_metal else _nothing,
        partial(wires_on_bone, mask, volume.spacing, own=bone[box]),
    )
    if wire.any():
        mask, other = mask & ~wire, other | wire
    cut_off = wire  # the parts cut off the bone's object: their base stays with it (``CUT_BASE_MM``)
    line = None
    if segmentation.body is not None:  # the bracket's stub the cut left on the bone (filled) is the body's too
        # A long stub (the cut went through the bracket far from the bone) is the body's before its line is read:
        # the line then runs from the bracket's true end into the bone.
        body = segmentation.body_cut_off()  # a plateau the body's material took has no stub: its edge is exact
        body_in_box = body[box]
        rod = rod_stub(mask, body_in_box, volume.spacing, segmentation.smoothed[box])
        if rod.any():
            body = body.copy()
            body[box] |= rod
        line = bracket_line_beyond(mask & ~rod, body, low, volume.spacing, segmentation.smoothed)
        stub = bracket_stub(mask, body_in_box, volume.spacing) | rod
        if stub.any():
            mask, other = mask & ~stub, other | stub
            cut_off = cut_off | stub
            logger.info("the bracket's stub on the bone (%.0f mm^3) left out", stub.sum() * np.prod(volume.spacing))
    # Other objects (marker spheres, a bracket touching the bone) must not add surface to the IPC, nor their blurred
    # rim where they come within two voxels of the bone.
    by_other = dilate(other, iterations=2) & ~mask if other.any() else None
    wiped = ~dilate(mask, iterations=2)
    if by_other is not None:
        wiped |= by_other
    image[wiped] = min(float(image.min()), level - 1000.0)
    vertices_ijk, triangles = iso_surface(image, level)
    if len(vertices_ijk) == 0:
        raise ValueError("the bone has no surface at the threshold; check the threshold")
    if by_other is not None:  # the surface in a gap of a voxel or two to another object is not the bone's
        between = dilate(by_other)[tuple(np.rint(vertices_ijk).astype(int).T)]
        if between.any():
            vertices_ijk, triangles = without_vertices(vertices_ijk, triangles, between)
            logger.info("%d IPC points in a gap to another object left out", int(between.sum()))
    # Down the gradient of the surfaced image, from the bone to what is outside it: where the checks below look.
    down = downhill(image, vertices_ijk, volume.spacing)
    original = segmentation.smoothed[box]  # the CT as it was, denoised
    # A part about as bright as the surface level, joined to the bone (a dim bracket resting on it), has a surface
    # at that level too, with no cortex under it. Only at a cortex's edge: at the threshold, and on voxels that blur
    # the cortex away, dim cancellous bone has no cortex under its surface either (a pelvis at 3 mm: 4,839 of its
    # 49,493 IPC points).
    dim = np.zeros(len(vertices_ijk), dtype=bool)
    corner = np.zeros(len(vertices_ijk), dtype=bool)  # where a dim part meets the bone: left out after the mouths
    contrast = _surface_contrast(original, vertices_ijk, down, level, volume.spacing) if resolved else None
    if contrast is not None:
        dim, corner = _without_cortex(original, vertices_ijk, down, level, volume.spacing, contrast)
    if level < segmentation.threshold_hu:
        # Between the surface level and the threshold, a dim part (a plastic bracket fixed into a bone in air) is
        # kept where it is joined to the bone, two voxels round it: the surface there is the stub's, not the bone's.
        dim |= _on_a_dim_stub(original, vertices_ijk, down, level, segmentation.threshold_hu, volume.spacing)
    bone_and_inside = mask
    if fill_cavities:
        # An inner wall left (a cortex too thin to stay above the level all round the inside, a hole a bracket
        # made in it): its outside, a little way down the gradient, is still the bone's, or enclosed by it along
        # the grid's lines, or in its envelope with such holes plugged (with voxels that resolve the cortex:
        # coarser ones merge bones a few mm apart).
        if fine:
            on_edge = _on_ct_edge(segmentation, low, high, volume)
            open_sides = _open_sides(segmentation.origin + low, segmentation.origin + high, volume)
            enclosed, envelope = in_parallel(
                partial(_enclosed_along_lines, mask, on_edge, volume.spacing, padding),
                partial(bone_envelope, mask, open_sides, volume.spacing, padding),
            )
            bone_and_inside = mask | enclosed
            if envelope is not None:
                bone_and_inside |= envelope
    # Where a part dimmer than the bone meets it (a plastic bracket resting on it or entering it), the corner they
    # make lifts the surface off the bone: near there (``dim_parts``), the points that touch something brighter by
    # CORNER_BRIGHTER_HU than the rest of the surface touches are the corner's. Where those parts are, and the inside
    # they let out (``_dim_parts_and_holes``), is looked for beside the inner walls.
    corners_looked_for = contrast is not None and fine
    parts = partial(tuple, (None, None))  # no contacts, nothing plugged
    if corners_looked_for:
        holes = (original, (level, segmentation.threshold_hu), walls if fill_cavities else None, padding)
        parts = partial(_dim_parts_and_holes, segmentation, volume, bone_and_inside, low, high, *holes)
    inner, (contacts, plugged) = in_parallel(
        partial(_inner_walls, vertices_ijk, triangles, down, dim, bone_and_inside, volume.spacing, fine)
        if fill_cavities
        else partial(np.zeros, len(vertices_ijk), dtype=bool),
        parts,
    )
    if plugged is not None and plugged.any():
        logger.info(
            "%.0f mm^3 of the bone's inside joined to the outside through a dim part's hole",
            plugged.sum() * np.prod(volume.spacing),
        )
        inner |= _inner_walls(vertices_ijk, triangles, down, dim, bone_and_inside | plugged, volume.spacing, fine)
    if corners_looked_for:
        near = np.zeros(len(vertices_ijk), dtype=bool)
        if len(contacts):
            near = _near(vertices_ijk + low, contacts, volume.spacing, dim_parts.MARGIN_MM)
        near = np.nonzero(near & ~corner)[0]
        if len(near):
            beyond = _beyond(original, vertices_ijk[near], down[near], volume.spacing)
            corner[near] = beyond > contrast[1] + CORNER_BRIGHTER_HU
    if dim.any():
        logger.info("%d IPC points on a dim part without a cortex under it left out", int(dim.sum()))
    if (inner & ~dim).any():
        logger.info("%d IPC points on inner walls left out", int((inner & ~dim).sum()))
    corner &= ~(dim | inner)
    if contrast is not None and own_half_max:
        # Not beside an inner wall: a hole's mouth moved is its wall (family seed 19085: 10 IPC points on a 138 HU
        # bracket 0.5-0.9 mm inside the bone, up to 1.3 mm from the wall left out; within 0.5 mm of the bone's
        # surface before).
        movable = ~(dim | inner | corner)
        moved = 0
        if movable.any():
            vertices_ijk[movable], moved = _to_own_half_max(
                original, vertices_ijk[movable], down[movable], level, volume.spacing, contrast[1], vertices_ijk[inner]
            )
        if moved:
            logger.info("%d IPC points touching something brighter than the rest moved to their own half-max", moved)
    if corner.any():
        logger.info("%d IPC points in the corner a dim part makes with the bone left out", int(corner.sum()))
    if (dim | inner | corner).any():
        vertices_ijk, triangles = without_vertices(vertices_ijk, triangles, dim | inner | corner)
    # Where the field of view cuts the bone, the blur of the scan and of the denoising runs into its edge: the
    # surface within PADDING_MARGIN_MM of the volume's sides or of the padding is not the bone's.
    in_ct = vertices_ijk + segmentation.origin + low
    to_side = np.minimum(in_ct, np.array(volume.voxels.shape) - 1 - in_ct) * volume.spacing
    capped = to_side.min(axis=1) <= PADDING_MARGIN_MM
    if padding is not None:
        capped |= _near_padding(padding, vertices_ijk, volume.spacing)
    if capped.any():
        vertices_ijk, triangles = without_vertices(vertices_ijk, triangles, capped)
        logger.info("%d IPC points at the edge of the field of view left out", int(capped.sum()))
    origin = segmentation.origin + low  # the crop's first voxel in the CT
    spoilt = metal.contains_ijk(vertices_ijk + origin) if leave_out_metal else np.zeros(len(vertices_ijk), bool)
    if joined is not None and joined.any():
        spoilt |= _within(joined, vertices_ijk, volume.spacing, JOINED_MARGIN_VOXELS * float(volume.spacing.max()))
    if spoilt.any():
        vertices_ijk, triangles = without_vertices(vertices_ijk, triangles, spoilt)
        logger.info("%d bone-surface points next to metal left out", int(spoilt.sum()))
    if len(vertices_ijk) == 0:
        raise ValueError("all of the bone's surface lies next to metal; no IPC can be taken from this CT")
    at_base = np.zeros(len(vertices_ijk), dtype=bool)
    if cut_off.any():
        at_base = _within(cut_off, vertices_ijk, volume.spacing, CUT_BASE_MM)
        if at_base.any():
            vertices_ijk, triangles = without_vertices(vertices_ijk, triangles, at_base)
            logger.info("%d IPC points round the base of a wire or stub cut off the bone left out", int(at_base.sum()))
    by_body = _next_to_body(volume, segmentation, vertices_ijk + low)
    if line is not None:
        by_body |= line.contains(vertices_ijk * volume.spacing)
    if by_body.any():
        vertices_ijk, triangles = without_vertices(vertices_ijk, triangles, by_body)
        logger.info("%d bone-surface points next to the reference body's bracket left out", int(by_body.sum()))
    if len(vertices_ijk) == 0:
        raise ValueError(
            "all of the bone's surface found lies next to the reference body joined to it (its bracket); no IPC can "
            "be taken from this CT: check that the bone is in the field of view"
        )
    if half_max and fine:
        local, fall = _local_half_max(segmentation.smoothed[box], vertices_ijk, volume.spacing) or (level, 1.0)
        if abs(local - level) > max(LEVEL_TOLERANCE_HU, LEVEL_TOLERANCE_MM * fall):
            # The level read off the whole bone's rim and band is off where the surface is (a thin layer of soft
            # tissue with air beyond it in the band, a cortex thinner than the blur): once more at the level read
            # across the surface itself.
            logger.info(
                "bone surface at half-max %.0f HU read across the surface (%.0f HU round the bone, %.2f mm apart)",
                local,
                level,
                abs(local - level) / max(fall, 1e-6),
            )
            return bone_surface(volume, segmentation, fill_cavities, local, leave_out_metal, own_half_max)
    return BoneSurface(
        points=volume.ijk_to_ras_points(vertices_ijk + origin),
        triangles=triangles,
        metal=metal,
        left_out=int(spoilt.sum()),
        left_out_body=int(by_body.sum()),
        left_out_base=int(at_base.sum()),
    )


#: The reconstruction's padding is told from air over at least this many slices (a column of one value, the CT's
#: lowest, in every slice: air has noise).
PADDING_MIN_SLICES = 16
#: IPC points closer than this (mm) to the padding lie on the cap the field of view's edge makes (the denoising
#: blurs the padding's edge in).
PADDING_MARGIN_MM = 1.5
#: The surface of a part a metal bracket joins to the bone (``beyond_metal``) lies within this many voxels (the
#: largest spacing) of its voxels: a surface level below the threshold lies out in the blur.
JOINED_MARGIN_VOXELS = 2.0
#: A wire's or a bracket's stub cut off the bone's object (``wires_on_bone``, ``bracket_stub``) leaves its first
#: millimetres with the bone (within a grid cell of what the cut keeps, and the blur): IPC points within this (mm) of
#: the part cut off are its base's, or the ring round where it enters the bone, which it hides. Family seeds 15097
#: and 19089: 18 and 32 IPC points on a 5.7 and a 10.8 mm bracket, 1.0-2.6 and 0.7-2.1 mm from the part cut off;
#: the bone loses 57 and 292 points within 3 mm of it.
CUT_BASE_MM = 3.0
#: IPC points within this (mm) of the body's voxels its material took from what an opening kept with the bone
#: (``BoneSegmentation.body_followed``) are left out: the edge of a plateau, a cell of the recognition's grid, and the
#: corner the blur fills where it meets the bone (wide seed 40254: a 10.5 mm bar of 2,251 HU resting on a flat bone
#: left 24 points there without it).
FOLLOWED_MARGIN_MM = 2.5


def outside_reconstruction(voxels):
    """(I, J) booleans over a box of raw CT voxels (I, J, K): in-plane positions outside the reconstruction
    cylinder, padded with one value at or below -1024 HU (the CT's lowest) in all of the box's slices; None when
    there is none (or the box has too few slices to tell padding from air)."""
    if voxels.shape[2] < PADDING_MIN_SLICES:
        return None
    lowest = voxels.min()
    if lowest > -1024:
        return None
    # Column by column, a few slices first (most columns differ there), the rest only where they did not.
    padding = (voxels[:, :, :: max(1, voxels.shape[2] // 8)] == lowest).all(axis=2)
    if not padding.any():
        return None
    rows, columns = np.nonzero(padding)
    padding[rows, columns] = (voxels[rows, columns, :] == lowest).all(axis=1)
    return padding if padding.any() else None


def _joined_above(above, mask, others):
    """(I, J, K) booleans: the ``above`` voxels joined to ``mask`` (the bone) other than those of ``others`` (other
    objects) and the two voxels round them (their blurred rim)."""
    if others.any():
        above = above & ~dilate(others, iterations=2)
    labels, _ = ndimage.label(above)
    return labelled(labels, np.unique(labels[mask & above]))


def _near_padding(padding, vertices, spacing):
    """(M,) booleans: vertices (indices (M, 3) in the box) within PADDING_MARGIN_MM of the padding (I, J)."""
    distance = ndimage.distance_transform_edt(~padding, sampling=spacing[:2])
    return ndimage.map_coordinates(distance, vertices[:, :2].T, order=1, mode="nearest") <= PADDING_MARGIN_MM


#: A surface point whose outside this far (mm, and at least a voxel) down the gradient is still the bone's is an
#: inner wall.
INNER_WALL_MM = 1.5


#: The mouth of a hole in the cortex: the surface within this far (mm, along it) of an inner wall. The envelope's
#: closing plugs a hole up to 1-2.5 mm under the bone's outer surface (its cube cannot reach further into a hole
#: narrower than it), and the hole's wall above that stays in the IPC: family seeds 13011, 19085, 17065, 20030, 14026
#: (dim brackets of 120-160 HU, 6-11 mm wide, inserted into the bone): 30-102 IPC points each, 0.5-2.4 mm inside the
#: bone, all within 2.3 mm of the inner wall along the surface.
MOUTH_MM = 3.0
#: ... of an inner wall at least this large (mm^2, the piece of it the mesh joins): a hole's wall round a bracket
#: 4-12 mm wide is larger; specks of the outer surface taken for inner walls (in a notch the envelope fills: up to
#: 1,348 pieces of 1-78 vertices in family seeds 17094 and 18063) are not, and a mouth round each took 69-85 % of
#: their IPC.
MIN_WALL_MM2 = 20.0
#: ... that faces the way the wall does (the cosine of the angle between their directions down the gradient at least
#: this): the hole's wall up to its rim, not the bone's outer surface round it (13011: 61 IPC points on the bone
#: round the mouth left out with it, 306 without this rule).
MOUTH_FACING = 0.5
#: ... and the mouth of one wall is at most this large (mm^2): the ring round the widest bracket (MAX_RADIUS_MM) up to
#: MOUTH_MM from its hole's wall. The holes of 6-11 mm brackets in the family CTs above: 21-59 mm^2. A wall with more
#: surface round it facing as it does is no hole's (family seed 17021: 740 mm^2 round 5,455 mm^2 of dark streaks in
#: a tibia's cortex next to a metal bracket, the bone's whole IPC; seeds 13045, 18030: 230-591 mm^2, no bracket).
MAX_MOUTH_MM2 = 2.0 * np.pi * MAX_RADIUS_MM * MOUTH_MM
#: ... and at least this share of the surface within MOUTH_MM of the wall faces away from it (its rim, turning to the
#: bone's outer surface): family CTs with dim brackets' holes 24-84 % (13011: 60 %, 19085: 62 %). Where all of it
#: faces as the wall does (0-6 % away), the wall is a patch of the outer surface taken for an inner wall (its corner
#: with a dim rod resting on a tube: 60 mm^2 round 25 mm^2; family seeds 14097, 17032, 16096: 53-79 mm^2 each).
RIM_SHARE = 0.2


def _mouths(vertices, triangles, inner, down, spacing):
    """(M,) booleans: the mouths of the holes whose walls are the ``inner`` vertices (M,) booleans of a mesh
    ((M, 3) vertex indices, (T, 3) triangles, ``down`` (M, 3) unit vectors down the gradient, ``spacing`` (3,) mm):
    the vertices within MOUTH_MM along the mesh's edges of an inner wall of at least MIN_WALL_MM2 that face within
    MOUTH_FACING of the wall's vertex nearest to them, when they are a hole's mouth: at most MAX_MOUTH_MM2, with a
    rim (RIM_SHARE of the surface near the wall facing away). Another sheet of the surface (not joined to the wall
    through the mesh) is not reached."""
    count = len(vertices)
    # Each triangle's edges as they go round it: in a mesh oriented throughout, each edge once each way, so that the
    # graph taken both ways holds its length (a sparse matrix would sum an edge given twice the same way).
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    # The inner walls' pieces and their areas (a third of each triangle's to each of its vertices).
    both = inner[edges[:, 0]] & inner[edges[:, 1]]
    joined = sparse.coo_matrix((np.ones(both.sum()), (edges[both, 0], edges[both, 1])), shape=(count, count))
    _, piece = csgraph.connected_components(joined, directed=False)
    vertex_area = _vertex_areas(vertices * spacing, triangles)
    piece_area = np.bincount(piece[inner], weights=vertex_area[inner], minlength=piece.max() + 1)
    walls = inner & (piece_area[piece] >= MIN_WALL_MM2)
    # Measured from the walls' edge: their vertices next to a vertex that is no inner wall.
    leaving = np.unique(np.concatenate([edges[walls[edges[:, k]] & ~inner[edges[:, 1 - k]], k] for k in (0, 1)]))
    if len(leaving) == 0:
        return np.zeros(count, dtype=bool)
    # Along the mesh is no shorter than straight: only the vertices within MOUTH_MM of the edge can be reached (and
    # a way through a wall leaves it again at its edge, no nearer), so the graph is made of them alone.
    others = np.flatnonzero(~walls)
    reach = MOUTH_MM + 1e-6  # the tree's bound is strict, the graph's limit is not
    band = np.zeros(count, dtype=bool)
    band[others[_near(vertices[others], vertices[leaving], spacing, reach)]] = True
    band[leaving] = True
    edges = edges[band[edges[:, 0]] & band[edges[:, 1]]]
    lengths = np.linalg.norm((vertices[edges[:, 0]] - vertices[edges[:, 1]]) * spacing, axis=1)
    graph = sparse.coo_matrix((lengths, (edges[:, 0], edges[:, 1])), shape=(count, count)).tocsr()
    distance, _, nearest = csgraph.dijkstra(
        graph, directed=False, indices=leaving, min_only=True, limit=MOUTH_MM, return_predecessors=True
    )
    near = np.flatnonzero(np.isfinite(distance) & ~inner)
    wall = piece[nearest[near]]
    facing = np.sum(down[near] * down[nearest[near]], axis=1) >= MOUTH_FACING
    # Per wall: the surface near it, and its part facing as the wall does. A hole's mouth is a ring round a bracket
    # (a wall with a larger one is no hole's), and its rim turns away to the bone's outer surface (a wall the surface
    # round it all faces as it does is a patch of that surface).
    near_area = np.bincount(wall, weights=vertex_area[near], minlength=len(piece_area))
    mouth_area = np.bincount(wall[facing], weights=vertex_area[near[facing]], minlength=len(piece_area))
    hole = (mouth_area <= MAX_MOUTH_MM2) & (mouth_area <= (1.0 - RIM_SHARE) * near_area)
    mouth = np.zeros(count, dtype=bool)
    mouth[near[facing & hole[wall]]] = True
    return mouth


def _inner_walls(vertices, triangles, down, dim, bone_and_inside, spacing, fine):
    """(M,) booleans: the surface's vertices (M, 3) (indices in the bone's box) on an inner wall left after the
    cavities were filled (``_facing_inward``: their outside, ``down`` the gradient, is ``bone_and_inside``), and, on
    voxels that resolve the cortex (``fine``), on the mouth of a hole whose wall it is (``_mouths``). ``dim`` (M,):
    the vertices on a dim part without a cortex under it."""
    inner = _facing_inward(vertices, down, bone_and_inside, spacing)
    if inner.any() and fine:
        # The wall of a hole in the cortex (a dim bracket's) goes on up to the bone's outer surface, where the envelope
        # does not plug it: its mouth (the surface near the wall along the mesh, facing as it does) goes too. (On
        # coarser voxels no envelope is made, and a hole's mouth is not resolved.) On the mesh without the dim part's
        # points, but with the wall's: the wall of a dim bracket's hole may have no cortex under it either (family
        # seed 14026: without those points the wall left was too small to have a mouth, 21 IPC points stayed on the
        # bracket, 6 before), and the dim part beside a wall is no mouth (14007: with it, the mouth was too large to
        # be a hole's, and 23 points on the bracket stayed, 3 before).
        beside = dim & ~inner
        kept, kept_triangles = without_vertices(vertices, triangles, beside)
        inner[~beside] |= _mouths(kept, kept_triangles, inner[~beside], down[~beside], spacing)
    return inner


def _nothing():
    """A step with nothing to do (``in_parallel``'s place for a step not taken)."""
    return None


def _vertex_areas(points, triangles):
    """(M,) mm^2: a third of the area of each triangle ((T, 3) indices) to each of its corners (``points`` (M, 3)
    mm). The cross product is written out: ``np.cross`` on the mesh's 400,000 triangles took twice as long."""
    a = points[triangles[:, 1]] - points[triangles[:, 0]]
    b = points[triangles[:, 2]] - points[triangles[:, 0]]
    cross = [
        a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
        a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
        a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
    ]
    thirds = np.sqrt(cross[0] ** 2 + cross[1] ** 2 + cross[2] ** 2) / 6.0
    return np.bincount(triangles.ravel(), weights=np.repeat(thirds, 3), minlength=len(points))


def _facing_inward(vertices, down, mask, spacing):
    """(M,) booleans: iso-surface vertices (M, 3) (indices in ``mask``'s box) whose dimmer side, INNER_WALL_MM away
    ``down`` the gradient ((M, 3) unit vectors, ``downhill``), lies in the bone's ``mask`` (its voxels above the
    threshold and its filled inside)."""
    reach = max(INNER_WALL_MM, float(spacing.max()))
    # Past the box's side the bone goes on where the field of view cuts it (else the box ends beyond the bone).
    outside = np.clip(np.rint(vertices + reach * down / spacing).astype(int), 0, np.array(mask.shape) - 1)
    return mask[tuple(outside.T)]


def _on_a_dim_stub(original, vertices, down, level, threshold, spacing):
    """(M,) booleans: iso-surface vertices (M, 3) on a dim part's stub, ``down`` ((M, 3), ``downhill``) the gradient
    of the image surfaced (the CT with what is not the bone's wiped): where the CT as it was (``original``) is still
    at or above ``level`` INNER_WALL_MM (at least a voxel) down the gradient (the surface only closes off what was
    wiped), or where nothing reaches the threshold within LOCAL_INSIDE_MM up it (no cortex under the surface: the
    stub's sides)."""
    reach = max(INNER_WALL_MM, float(spacing.max()))
    outside = ndimage.map_coordinates(original, (vertices + reach * down / spacing).T, order=1, mode="nearest")
    peak = along_gradient(original, vertices, down, spacing, _UP_TO_THE_PEAK_MM).max(axis=0)
    return (outside >= level) | (peak < threshold)


#: A surface point has no cortex under it where the surface level lies beyond this share of the rise from what it
#: touches to the brightest value under it: a cortex's half-max lies half-way up (0.5; above 0.85 on 95 of the 4.3
#: million IPC points on the bone in 200 family CTs, thin and blurred cortices included), a part about as bright as
#: the level near the top.
NO_CORTEX_SHARE = 0.85
#: ... when the level is the half-max of the surface's cortex: its share of the rise is about a half, at most this
#: (the median over up to LOCAL_SAMPLES of the surface's points).
HALF_WAY_MAX = 0.65
#: The CT this far (mm) under a surface point, the brighter of the two: a floor for the peak under it.
UNDER_MM = (0.5, 1.0)
#: ... and where it rises above the level by less than this share of the cortex's rise above it (the median peak of
#: the points crossing a cortex, less the level), there is no cortex under the point: a part a few hundred HU above
#: a low level (family seed 25043: a 194 HU bracket resting on a tibia, the level -34 HU, 180 IPC points on it up to
#: 10 mm off the bone; 22051, 16058, 25047 alike), or the corner a dim bracket makes with the bone, the cortex's
#: peak deeper under it (17012, 17043: 40-50 points each, 1-2.3 mm off the bone). Over 76 family CTs, 63 of 1.9
#: million IPC points on the bone were below 0.3, and 38-86 % of those the rules before left on dim brackets (7 CTs).
DIM_PEAK_SHARE = 0.3
#: ... and below this share, the rest of such corners (26087: 60 IPC points on a 153 HU bracket, 23093: 33), where
#: what lies beyond is brighter by CORNER_BRIGHTER_HU than what the bone's surface touches: the dim part. They are
#: left out after the mouths of holes are found (``_mouths``), from which the points below DIM_PEAK_SHARE are kept
#: out (0.45 for both split 18080's mouth: 1 -> 31 points on the bracket). Over the 59 of 1,300 family CTs with
#: points on the body, 232 of their 555 are below 0.45 (177 below 0.4, 290 below 0.5); over 140 CTs drawn from the
#: other 1,241, 78 of 3.25 million points on the bone, 50 of them more than 2 mm from the body. With the brighter
#: beyond: 194 and 16 (3); the 1,300 CTs' run gave 555 -> 361 points on the body, 14 CTs with none left, and 557
#: fewer of the 27.3 million on the bone, at most 39 in one CT.
CORNER_PEAK_SHARE = 0.45
#: ... the brighter beyond (HU). Bone surface where a thin or dim cortex rises less than CORNER_PEAK_SHARE touches
#: the same tissue or air as the rest (family seed 12042: 1,280 of 68,049 IPC points of a thin 1,990 HU cortex under
#: 15 mm of tissue without it, none with it).
CORNER_BRIGHTER_HU = 50.0
#: ... and below this share within CORNER_EDGE_MM (mm) of a point without a cortex or in a corner, and within
#: CORNER_EDGE_FREE_MM (mm) of the bone's surface with a cortex under it (at or above this share), where what lies
#: beyond is brighter by CORNER_BRIGHTER_HU: the corner's edge, where the dim part's blur still lifts the surface
#: 0.5-2 mm off the bone (family seeds 23093: 15 IPC points at the end of a 154 HU bracket resting on a fibula,
#: 0.45-0.70; 25047: 9, 0.47-0.63; 18026, 14097: 7 each where a dim bracket enters the bone). Not farther from that
#: surface: under the middle of a wide dim block resting on the bone, the surface is moved to its own half-max
#: (``_to_own_half_max``): 1.07 mm and more from it in the test's block (from 0.88 mm turned 30 degrees). Over 159
#: family CTs (the 30 with points on the body and 129 drawn from the rest), 32 of their 92 points on the body fall
#: under the rule (48 without the last condition); 179 of their 3.6 million IPC points on the bone do (219), at
#: most 26 in one CT, 9 of them more than 5 mm from the body. The bone's surface far from a dim part lies above 0.8
#: of the rise (23093: 9,677 of 9,677 points).
CORNER_EDGE_SHARE = 0.7
CORNER_EDGE_MM = 1.0
CORNER_EDGE_FREE_MM = 1.0


def _across_surface(original, vertices, down, spacing):
    """The CT (``original``, the denoised HU) across the surface at vertices (M, 3) (indices in it), ``down`` ((M, 3),
    ``downhill``) the way out of the bone: the brightest value within LOCAL_INSIDE_MM up the gradient (the cortex's
    peak, ``_peak_under``) and what the bone touches (``_beyond``), (M,) HU each."""
    return _peak_under(original, vertices, down, spacing), _beyond(original, vertices, down, spacing)


def _peak_under(original, vertices, down, spacing):
    """(M,) HU: the cortex's peak under vertices (M, 3), the brightest value of the CT (``original``) within
    LOCAL_INSIDE_MM up the gradient (``down``, (M, 3))."""
    return along_gradient(original, vertices, down, spacing, _UP_TO_THE_PEAK_MM).max(axis=0)


def _beyond(original, vertices, down, spacing):
    """(M,) HU: what the bone touches at vertices (M, 3), the median of the CT (``original``) LOCAL_OUTSIDE_MM down
    the gradient (``down``, (M, 3))."""
    return np.median(along_gradient(original, vertices, down, spacing, _BEYOND_MM), axis=0)


def along_gradient(original, vertices, down, spacing, distances, start=0.0):
    """(D, M): the CT (``original``) at ``distances`` (mm; negative: up the gradient, into the bone) from vertices
    (M, 3) along ``down`` ((M, 3)), counted from ``start`` (mm along it: a number, or (M,) one per vertex)."""
    start = np.reshape(start, (-1, 1))
    steps = [
        partial(ndimage.map_coordinates, original, (vertices + (start + t) * down / spacing).T, order=1, mode="nearest")
        for t in distances
    ]
    return np.array(in_parallel(*steps))


def _surface_contrast(original, vertices, down, level, spacing):
    """The cortex's peak and what the bone touches (HU), read across the surface (vertices (M, 3), ``down`` (M, 3)
    the way out of the bone) in the CT (``original``): their medians over up to LOCAL_SAMPLES of its points that
    cross a cortex (a rise of CORTEX_CONTRAST_HU). None when none does, or when the surface ``level`` (HU) is not
    the half-max of that cortex (the share of their rise it lies at, its median, above HALF_WAY_MAX): a level read
    off a rim brighter than the cortex (a bracket's or a pin's in it: family seeds 13023, 17021) lies near the top of
    every point's rise, and the surface is taken again at the level read across it (``_local_half_max``)."""
    if len(vertices) == 0:
        return None
    every = slice(None, None, max(1, len(vertices) // LOCAL_SAMPLES))
    peak, beyond = _across_surface(original, vertices[every], down[every], spacing)
    rise = peak - beyond
    crossing = rise >= CORTEX_CONTRAST_HU
    if not crossing.any() or np.median((level - beyond[crossing]) / rise[crossing]) > HALF_WAY_MAX:
        return None
    return float(np.median(peak[crossing])), float(np.median(beyond[crossing]))


def _without_cortex(original, vertices, down, level, spacing, contrast):
    """Two (M,) booleans, ``dim`` and ``corner``. ``dim``: surface points (vertices (M, 3), ``down`` (M, 3) the way
    out of the bone) with no cortex under them in the CT (``original``): the surface ``level`` (HU) above
    NO_CORTEX_SHARE of the rise from what lies beyond the point to the peak under it (``_across_surface``). That is
    a part about as bright as the level joined to the bone: family seed 19027, a 271 HU bracket resting on a fibula
    at a 251 HU level, 1,287 IPC points on it 1 mm inside the bracket; 19077, a 202 HU bracket's stub on a flat bone
    in air at 63 HU, 103 points. Where the bone touches something brighter than the level (its neighbour across a
    narrow gap) there is no rise to measure, and the point is kept. A point where the CT UNDER_MM under it rises
    above the level by less than DIM_PEAK_SHARE of the cortex's rise above it (``contrast``: the cortex's peak and
    what the bone touches, ``_surface_contrast``) has no cortex under it either, whatever lies beyond. ``corner``:
    the points not ``dim`` where that rise is less than CORNER_PEAK_SHARE and what lies beyond is brighter by
    CORNER_BRIGHTER_HU than what the bone touches: where a dim part meets the bone; and its edge, the points below
    CORNER_EDGE_SHARE within CORNER_EDGE_MM of the ``dim`` or ``corner`` ones and within CORNER_EDGE_FREE_MM of the
    surface with a cortex under it (at or above that share), that touch something as bright.

    The whole profile is read only where the CT UNDER_MM under the point is no brighter than the peak of a point
    without a cortex can be, whatever lies beyond it (the CT's lowest value at worst): a cortex under the point rules
    it out."""
    cortex, touches = contrast
    under = along_gradient(original, vertices, down, spacing, [-t for t in UNDER_MM]).max(axis=0)
    cortex_rise = cortex - level
    dim = under < level + DIM_PEAK_SHARE * cortex_rise
    below_corner = under < level + CORNER_PEAK_SHARE * cortex_rise
    corner = below_corner & ~dim
    if corner.any():  # ... where the point touches something brighter than what the bone's surface touches
        candidates = np.nonzero(corner)[0]
        corner[candidates] = _beyond(original, vertices[candidates], down[candidates], spacing) > (
            touches + CORNER_BRIGHTER_HU
        )
    lowest = float(original.min())
    highest_peak = level + (1.0 / NO_CORTEX_SHARE - 1.0) * (level - lowest)
    maybe = np.nonzero((under <= highest_peak) & ~dim)[0]
    if len(maybe):
        peak, beyond = _across_surface(original, vertices[maybe], down[maybe], spacing)
        dim[maybe] = (level > beyond) & (level - beyond > NO_CORTEX_SHARE * (peak - beyond))
    corner &= ~dim
    # The corner's edge: between the corner and the bone's surface with its cortex under it (not under the middle
    # of a wide dim part, whose surface is moved to its own half-max: ``_to_own_half_max``). Only the points from
    # CORNER_PEAK_SHARE up: below it, the corner's check has read what lies beyond them already.
    below = under < level + CORNER_EDGE_SHARE * cortex_rise
    taken = dim | corner
    free = ~(below | taken)
    edge = np.nonzero(below & ~below_corner & ~dim)[0]
    if len(edge) and taken.any() and free.any():
        edge = edge[_near(vertices[edge], vertices[taken], spacing, CORNER_EDGE_MM)]
        if len(edge):
            edge = edge[_near(vertices[edge], vertices[free], spacing, CORNER_EDGE_FREE_MM)]
        if len(edge):
            corner[edge] = _beyond(original, vertices[edge], down[edge], spacing) > touches + CORNER_BRIGHTER_HU
    return dim, corner


#: Where a surface point touches something brighter by CORNER_BRIGHTER_HU than what the bone's surface touches (a dim
#: bracket resting on it, tissue where the rest is in air) but dimmer than the surface level, that level, read round
#: the bone, lies low on the point's rise, out in the blur: the point is moved up the gradient to its own half-max
#: (half-way between the peak under it and what lies beyond), looked for within this far (mm; not found: the point
#: stays). Family seed 26087: 53 IPC points 0.5-1 mm off a flat bone in air, in a 153 HU bracket resting on it.
OWN_HALF_MAX_REACH_MM = 1.5
#: ... read this finely (mm) along the gradient, linearly in between.
OWN_HALF_MAX_STEP_MM = 0.1
#: ... not within this far (mm) of an inner wall.
OWN_HALF_MAX_WALL_MM = 2.0


def _to_own_half_max(original, vertices, down, level, spacing, touches, walls):
    """Vertices (M, 3) (indices in ``original``, the denoised CT) with those that touch something brighter than
    ``touches`` (HU, what the bone's surface touches) by CORNER_BRIGHTER_HU, and dimmer than the surface ``level``,
    moved up the gradient (``down``, (M, 3), the way out of the bone) to where the CT reaches their own half-max,
    and how many were moved. Not those within OWN_HALF_MAX_WALL_MM of an inner wall's vertices (W, 3)."""
    beyond = _beyond(original, vertices, down, spacing)
    candidates = np.nonzero((beyond > touches + CORNER_BRIGHTER_HU) & (beyond < level))[0]
    if len(candidates) and len(walls):
        candidates = candidates[~_near(vertices[candidates], walls, spacing, OWN_HALF_MAX_WALL_MM)]
    if len(candidates) == 0:
        return vertices, 0
    at, way = vertices[candidates], down[candidates]
    own = 0.5 * (_peak_under(original, at, way, spacing) + beyond[candidates])
    depths = np.arange(0.0, OWN_HALF_MAX_REACH_MM + 1e-6, OWN_HALF_MAX_STEP_MM)
    profile = along_gradient(original, at, way, spacing, -depths)  # (D, C), into the bone
    reached = profile >= own
    first = reached.argmax(axis=0)
    movable = (own > level) & reached.any(axis=0) & (first > 0)
    columns = np.nonzero(movable)[0]
    if len(columns) == 0:
        return vertices, 0
    before, after = profile[first[columns] - 1, columns], profile[first[columns], columns]
    fraction = (own[columns] - before) / np.maximum(after - before, 1e-6)
    depth = depths[first[columns] - 1] + fraction * OWN_HALF_MAX_STEP_MM
    moved = vertices.copy()
    moved[candidates[columns]] -= depth[:, None] * way[columns] / spacing
    return moved, len(columns)


#: The half-max read across the surface: the cortex's peak within this far (mm) inside each sampled surface point,
#: what lies beyond it this far out (mm, past the blur, within a thin layer of soft tissue), at most this many points.
LOCAL_INSIDE_MM = 2.5
LOCAL_OUTSIDE_MM = (1.0, 2.0)
LOCAL_SAMPLES = 4000
#: ... where the cortex's edge, its steepest fall (between samples this far apart, mm), is looked for between its peak
#: and this far (mm) beyond the sampled point: a surface at too low a level lies up to 0.9 mm out (family seed
#: 41008), and the edge of the air beyond 3 mm of tissue 1.3 mm farther.
LOCAL_STEP_MM = 0.25
LOCAL_EDGE_BEYOND_MM = 1.0
#: Where the cortex's peak under a surface point is looked for (mm along the gradient; negative: into the bone).
_UP_TO_THE_PEAK_MM = tuple(-np.arange(0.0, LOCAL_INSIDE_MM + 1e-6, 0.5))
#: ... and what it touches (mm down the gradient).
_BEYOND_MM = tuple(np.arange(LOCAL_OUTSIDE_MM[0], LOCAL_OUTSIDE_MM[1] + 1e-6, 0.5))
#: ... and the IPC is taken again at that level when it is this far (HU) from the one read round the bone, and moves
#: the surface this far (mm, by the cortex's steepest fall): a level read off a dim bracket's HU (wide seeds 40138,
#: 40014: 0.03-0.05 mm apart) brings the walls of the hole it makes in the cortex into the IPC (0 -> 117 and 1 IPC
#: points on the body), a thin layer of tissue with air beyond puts the surface 0.55 mm out (41008).
LEVEL_TOLERANCE_HU = 40.0
LEVEL_TOLERANCE_MM = 0.1


def _local_half_max(image, vertices, spacing):
    """(level HU, fall HU/mm): the surface level read across the surface through up to LOCAL_SAMPLES surface points
    (indices (M, 3) in ``image``, the denoised CT), the median over them of the CT where the cortex falls most
    steeply along the gradient (``_cortex_edge``), and the median of that fall (how far a change of level moves the
    surface). None when fewer than 100 of them cross a cortex (a rise of CORTEX_CONTRAST_HU from the median
    LOCAL_OUTSIDE_MM beyond that edge to the brightest value within LOCAL_INSIDE_MM inside).

    Where a blurred step (a symmetric point spread) falls most steeply is its edge, and the CT there is half-way
    between the cortex and what it touches, whatever lies beyond: a thin layer of soft tissue with air beyond it, or a
    cortex thinner than the blur. Half-way between the peak and what lies 1-2 mm beyond the points, as read before,
    took the air's edge for what a right ilium's 1.8 mm cortex under 3 mm of tissue touches: its surface lay 0.42 mm
    out (median), 83 % of the IPC within 0.5 mm of the bone (family seed 41008; 77 % at 62 HU of noise, now 99.9 %)."""
    points = vertices[:: max(1, len(vertices) // LOCAL_SAMPLES)]
    out = downhill(image, points, spacing)
    peak, edge, at_edge, fall = _cortex_edge(image, points, out, spacing)
    outside = np.arange(LOCAL_OUTSIDE_MM[0], LOCAL_OUTSIDE_MM[1] + 1e-6, LOCAL_STEP_MM)
    beyond = np.median(along_gradient(image, points, out, spacing, outside, edge), axis=0)
    crossing = (peak - beyond >= CORTEX_CONTRAST_HU) & (beyond > BELOW_AIR_HU)
    if crossing.sum() < 100:
        return None
    return float(np.median(at_edge[crossing])), float(np.median(fall[crossing]))


def _cortex_edge(image, points, out, spacing):
    """Across the cortex at points (M, 3) (indices in ``image``) along ``out`` ((M, 3), ``downhill``): its peak (M,)
    HU, the brightest value within LOCAL_INSIDE_MM inside; its edge (M,) mm from the points, the steepest fall
    between the peak and LOCAL_EDGE_BEYOND_MM beyond the point (between samples LOCAL_STEP_MM apart, placed on the
    parabola through the falls either side); the CT at the edge (M,) HU; and the steepest fall (M,) HU/mm."""
    along = np.arange(-LOCAL_INSIDE_MM, LOCAL_EDGE_BEYOND_MM + 1e-6, LOCAL_STEP_MM)
    profile = along_gradient(image, points, out, spacing, along)  # (D, M)
    columns = np.arange(len(points))
    peak_at = np.argmax(np.where(along[:, None] <= 0.0, profile, -np.inf), axis=0)
    fall = np.diff(profile, axis=0)  # (D - 1, M): from sample i to i + 1, half-way between them
    past_peak = np.arange(len(along) - 1)[:, None] >= peak_at[None, :]
    steepest = np.argmin(np.where(past_peak, fall, np.inf), axis=0)
    before = fall[np.maximum(steepest - 1, 0), columns]
    middle = fall[steepest, columns]
    after = fall[np.minimum(steepest + 1, len(along) - 2), columns]
    curvature = before - 2.0 * middle + after
    vertex = np.clip(0.5 * (before - after) / np.maximum(curvature, 1e-6), -0.5, 0.5)
    at = steepest + 0.5 + np.where(curvature > 1e-6, vertex, 0.0)  # in samples
    lower = np.minimum(np.floor(at).astype(int), len(along) - 2)
    fraction = at - lower
    at_edge = (1.0 - fraction) * profile[lower, columns] + fraction * profile[lower + 1, columns]
    return profile[peak_at, columns], along[0] + at * LOCAL_STEP_MM, at_edge, -middle / LOCAL_STEP_MM


def downhill(image, vertices, spacing):
    """(M, 3) unit vectors down the image's gradient at vertices (M, 3) (indices in ``image``), in mm along the grid's
    axes (central differences of its trilinear values a voxel either side): from the bone to what is outside it."""
    steps = [partial(_difference_along, image, vertices, step) for step in np.eye(3)]
    gradient = np.stack(in_parallel(*steps), axis=1) / (2.0 * spacing)
    return -gradient / np.maximum(np.linalg.norm(gradient, axis=1, keepdims=True), 1e-9)


def _difference_along(image, vertices, step):
    """(M,) the image's (trilinear) value a ``step`` (3,) voxels ahead of each vertex (M, 3) less that behind it."""
    ahead = ndimage.map_coordinates(image, (vertices + step).T, order=1, mode="nearest")
    return ahead - ndimage.map_coordinates(image, (vertices - step).T, order=1, mode="nearest")


def _on_ct_edge(segmentation, low, high, volume):
    """Per axis, whether the low and high sides of a box (``low``, ``high``: corners in the segmentation's box) are
    the CT's own sides."""
    first, last = segmentation.origin + low, segmentation.origin + high
    return [(first[a] == 0, last[a] == volume.voxels.shape[a]) for a in range(3)]


#: A marrow cavity is at most this wide (mm) along a grid line: a wider space the bone surrounds (a pelvic ring's)
#: is outside it.
MAX_CAVITY_MM = 30.0


def _enclosed_along_lines(mask, on_edge, spacing, padding=None):
    """(I, J, K) booleans over a box: the voxels outside ``mask`` (the bone with its filled inside) that the bone
    encloses along the grid's lines through them: along two of the three axes at least, the line meets the bone on
    both sides within MAX_CAVITY_MM in all, and along the third the bone on one side within MAX_CAVITY_MM, or the
    bone or the CT's edge on both sides (``on_edge``: per axis, whether the box's low and high sides are the CT's;
    ``padding`` (I, J): outside a round field of view), as in a marrow cavity the field of view cuts.

    This finds the marrow that a hole in the cortex (a bracket's, a pin's, a cortex thinner than the voxels) joins
    to the outside, where the 3-D fill fails, and the hole itself: across it the cortex round the hole is near on
    two axes, and the opposite cortex along the third. No line through a point outside a convex bone meets it on
    both sides; a pit in a bone's surface narrower than MAX_CAVITY_MM is taken for its inside too (its surface is
    lost to the IPC, no false point is added).
    """
    along = in_parallel(
        *[partial(_enclosed_along_axis, mask, axis, on_edge[axis], spacing, padding) for axis in range(3)]
    )
    narrow = sum(both.view(np.uint8) for both, _ in along)  # along how many axes the bone is on both sides, near
    closed = along[0][1] & along[1][1] & along[2][1]  # ... and along every other one near on a side, or closed on both
    return ~mask & closed & (narrow >= 2)


def _enclosed_along_axis(mask, axis, on_edge, spacing, padding):
    """``_enclosed_along_lines`` along one ``axis``: (I, J, K) booleans of the voxels with the bone on both sides
    within MAX_CAVITY_MM in all, and of those with the bone on a side within MAX_CAVITY_MM or the bone or the CT's
    edge (``on_edge``: the box's low and high sides on the CT's, ``padding``) on both sides.

    Where the box's side is the CT's, the bone's cross-section there (its slice with the holes filled: the cortex
    and the marrow it rings) walls the lines that end in it, one slice beyond the box: the field of view cuts the
    bone there, and its marrow goes on beyond."""
    walls = [_cut_face(mask, axis, side) if on_side else None for side, on_side in zip((0, -1), on_edge)]
    start, length = int(walls[0] is not None), mask.shape[axis]  # where the box's own slices are, between the walls
    mask = np.concatenate([part for part in (walls[0], mask, walls[1]) if part is not None], axis=axis)
    if padding is not None and axis < 2:  # the padding's rows go on into the walls
        padding = np.pad(
            padding, [(start, int(walls[1] is not None)) if a == axis else (0, 0) for a in range(2)], "edge"
        )
    shape = [1, 1, 1]
    shape[axis] = mask.shape[axis]
    index = np.arange(mask.shape[axis]).reshape(shape)
    reach = int(MAX_CAVITY_MM / spacing[axis])  # voxels
    both = _between_near(mask, axis, reach)
    near = any_behind(mask, axis, reach + 1) | any_ahead(mask, axis, reach + 1)
    # Bone somewhere before (at or before the voxel along its line) and after it.
    first = np.where(mask.any(axis=axis), np.argmax(mask, axis=axis), mask.shape[axis])
    last = np.where(mask.any(axis=axis), mask.shape[axis] - 1 - np.argmax(np.flip(mask, axis), axis=axis), -1)
    before = index >= np.expand_dims(first, axis)
    after = index <= np.expand_dims(last, axis)
    edge_before, edge_after = on_edge
    if padding is not None and axis < 2:
        edge_before = edge_before | np.logical_or.accumulate(padding, axis=axis)[:, :, None]
        edge_after = edge_after | np.flip(np.logical_or.accumulate(np.flip(padding, axis), axis=axis), axis)[:, :, None]
    closed = near | ((edge_before | before) & (edge_after | after))
    inside = tuple(slice(start, start + length) if a == axis else slice(None) for a in range(3))
    return both[inside], closed[inside]


def _cut_face(mask, axis, side):
    """(I, J, K) booleans, one slice thick along ``axis``: the mask's slice at ``side`` (0 or -1) with its holes filled
    in the slice."""
    return np.expand_dims(ndimage.binary_fill_holes(np.take(mask, side, axis=axis)), axis)


def _between_near(mask, axis, reach):
    """(I, J, K) booleans: the voxels of ``mask`` and those between two of its voxels at most ``reach`` apart along
    ``axis`` (a closing by a segment of ``reach`` voxels: every such segment through the voxel meets the mask)."""
    padded_shape = list(mask.shape)
    padded_shape[axis] += reach  # segments may start before the volume (there is no mask)
    padded = np.zeros(padded_shape, dtype=bool)
    inside = tuple(slice(reach, None) if a == axis else slice(None) for a in range(3))
    padded[inside] = mask
    meets = any_ahead(padded, axis, reach)  # the segment starting at each voxel meets the mask
    return all_behind(meets, axis, reach)[inside]  # ... and so do those starting up to reach - 1 voxels before


#: The dark regions round a thin cortex are told apart once opened by a cube about this wide (mm).
OPENING_MM = 2.0


def _enclosed(image, levels, walls, low, high, volume):
    """(I, J, K) booleans over a box (``low``, ``high``: its corners in the CT's indices) round the bone: its
    voxels darker than the surface level (``levels[0]``) that the bone encloses.

    The box reaches beyond the bone on every side except where the field of view cuts the bone, so a dark region
    that touches a side of the box not on the CT's edge is outside the bone; the others (marrow, the cancellous
    core between a flat bone's tables, open only where the scan cuts them) are inside. ``walls`` (other objects, a
    bracket through the cortex) are not dark. Two things keep a thin cortex from leaking: the regions are told apart
    once opened by a cube about ``OPENING_MM`` wide (a hole a few voxels wide through it joins nothing), and below
    the threshold (``levels[1]``), which a cortex that dips under the surface level still stands above (the
    marrow); the inside found is grown back two voxels into the dark. None when every side of the box is on the
    CT's edge (the bone fills the field of view), so that none can be told.
    """
    open_sides = _open_sides(low, high, volume)
    if not open_sides:
        return None
    size = max(1, int(round(OPENING_MM / float(volume.spacing.max())))) | 1  # odd, at least 1
    inside = in_parallel(*[partial(_enclosed_below, image, level, walls, open_sides, size) for level in levels])
    return dilate(np.logical_or.reduce(inside), 2, within=(image < levels[0]) & ~walls)


def _dim_parts_and_holes(segmentation, volume, bone_and_inside, low, high, original, levels, walls, padding):
    """(contacts, plugged): where dim parts meet the bone's blur (``dim_parts.dim_parts_at_bone``: (N, 3) indices in
    the segmentation's box) and the inside they let out of the bone (``_plugged_inside``, None when there is none to
    look for: no part below the surface level ``levels[0]``, or ``walls`` None, the cavities not filled).

    A dim part entering the bone (a plastic bracket inserted into it) joins its inside to the outside through the hole
    it makes, below the level: where the bone is wider than the envelope's plug (a tibia's metaphysis, a flat bone cut
    by the field of view), the inner walls stay. Plugged where the part meets the bone's blur (where the CT there is
    below the level: a part above it is no way out), what the bone then encloses is its inside too."""
    contacts = dim_parts.dim_parts_at_bone(segmentation.smoothed, bone_and_inside, low, volume.spacing)
    if walls is None or not len(contacts):
        return contacts, None
    at = np.clip(np.rint(contacts - low).astype(int), 0, np.array(original.shape) - 1)
    leaking = (contacts - low)[original[tuple(at.T)] < levels[0]]
    if not len(leaking):
        return contacts, None
    sides = (_on_ct_edge(segmentation, low, high, volume), padding)
    corners = segmentation.origin + low, segmentation.origin + high
    return contacts, _plugged_inside(original, levels, walls, leaking, bone_and_inside, *sides, *corners, volume)


def _plugged_inside(image, levels, walls, contacts, bone, on_edge, padding, low, high, volume):
    """(I, J, K) booleans over the bone's box (``low``, ``high``: its corners in the CT's indices): the inside of the
    ``bone`` (booleans: its voxels and the inside found so far) that it encloses (``_enclosed``) once the voxels within
    ``plugs.PLUG_MM`` of ``contacts`` ((N, 3) indices in the box, where dim parts meet the bone's blur) are walls too,
    in pieces large enough that lie between the bone's sides (``plugs.inside_pieces``; ``on_edge`` and ``padding`` as
    for ``_enclosed_along_lines``), grown into the plug; None when the box has no side off the CT's edge or no hole
    leads in."""
    plug = np.zeros(image.shape, dtype=bool)
    reach = np.ceil(PLUG_MM / volume.spacing).astype(int)
    first = np.maximum(np.floor(contacts.min(axis=0)).astype(int) - reach, 0)
    last = np.minimum(np.ceil(contacts.max(axis=0)).astype(int) + reach + 1, image.shape)
    seeds = np.ones(tuple(last - first), dtype=bool)
    at = np.clip(np.rint(contacts).astype(int) - first, 0, last - first - 1)
    seeds[tuple(at.T)] = False
    near = ndimage.distance_transform_edt(seeds, sampling=volume.spacing) <= PLUG_MM
    around = tuple(slice(a, b) for a, b in zip(first, last))
    plug[around] = near
    # A hole leads in where the plug holds dark voxels between the bone's sides that are not its inside found so far:
    # else there is nothing to enclose (the bench CT's pin and aluminium bracket), and the fill is not made again.
    local = between_sides(bone, on_edge, padding, around) >= 2
    if not (local & near & (image[around] < levels[0]) & ~bone[around] & ~walls[around]).any():
        return None
    # At the surface level alone: the threshold's fill (a cortex that dips under the level) was made before.
    inside = _enclosed(image, levels[:1], walls | plug, low, high, volume)
    if inside is None:
        return None
    inside &= ~bone
    if not inside.any():
        return inside
    between = between_sides(bone, on_edge, padding) >= 2
    inside = inside_pieces(inside, between, np.prod(volume.spacing))
    if not inside.any():
        return inside
    # The plug reaches into the hole and under the cortex round it: the inside goes on into it there, between the
    # bone's sides (up to the hole's mouth, whose walls ``_mouths`` leaves out too), not round the bone's outside.
    return dilate(inside, int(reach.max()), within=plug & (image < levels[0]) & ~bone & between)


def _open_sides(low, high, volume):
    """[(axis, 0 or -1)]: the sides of a box (``low``, ``high``: its corners in the CT's indices) off the CT's edge."""
    return [
        (axis, side)
        for axis in range(3)
        for side, on_edge in ((0, low[axis] == 0), (-1, high[axis] == volume.voxels.shape[axis]))
        if not on_edge
    ]


def _enclosed_below(image, level, walls, open_sides, size):
    """``_enclosed`` at one ``level``: the regions darker than it, opened by a cube ``size`` voxels wide, that reach
    none of the box's ``open_sides``."""
    return reaching_no_side(open_by_cube((image < level) & ~walls, size), open_sides)


def _next_to_body(volume, segmentation, vertices_ijk):
    """(M,) booleans: IPC vertices (indices in the segmentation's box) within ``body_margin_mm`` of the voxels of
    the reference body joined to the bone (its bracket's stub, and the corner the blur fills round it)."""
    if segmentation.body is None:
        return np.zeros(len(vertices_ijk), dtype=bool)
    near = _within(segmentation.body_cut_off(), vertices_ijk, volume.spacing, segmentation.body_margin_mm)
    if segmentation.body_followed is not None:
        near |= _within(segmentation.body_followed, vertices_ijk, volume.spacing, FOLLOWED_MARGIN_MM)
    return near


def _within(voxels, vertices_ijk, spacing, margin):
    """(M,) booleans: the vertices (M, 3) (voxel indices in the frame of ``voxels``, booleans) within ``margin``
    (mm) of a voxel set; ``spacing`` (3,) mm."""
    if len(vertices_ijk) == 0 or not voxels.any():
        return np.zeros(len(vertices_ijk), dtype=bool)
    reach = np.ceil(margin / spacing).astype(int) + 1
    low = np.maximum(np.floor(vertices_ijk.min(axis=0)).astype(int) - reach, 0)
    high = np.minimum(np.ceil(vertices_ijk.max(axis=0)).astype(int) + reach + 1, voxels.shape)
    where = np.argwhere(voxels[tuple(slice(a, b) for a, b in zip(low, high))]) + low
    if len(where) == 0:
        return np.zeros(len(vertices_ijk), dtype=bool)
    return _near(vertices_ijk, where, spacing, margin)


def _near(points_ijk, others_ijk, spacing, reach):
    """(M,) booleans: the points (M, 3) closer than ``reach`` (mm) to any of ``others_ijk`` (N, 3, N > 0), both in
    voxel indices (fractional or not) of a grid of ``spacing`` (3,) mm."""
    # The grid's axes are orthogonal: index times spacing is a distance-preserving frame (mm).
    distance, _ = cKDTree(others_ijk * spacing).query(points_ijk * spacing, distance_upper_bound=reach)
    return np.isfinite(distance)


def without_vertices(vertices, triangles, drop):
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


#: Denoised values below this (HU) are no air: a round field of view's padding, blurred.
BELOW_AIR_HU = -1100.0


def _surface_level(image, mask, threshold, level, spacing):
    if level == "threshold":
        return threshold
    if level != "half-max":
        return float(level)
    if spacing.max() > HALF_MAX_MAX_VOXEL_MM + 1e-6:
        logger.info("voxels of %.1f mm do not resolve the cortex: bone surface at the threshold", spacing.max())
        return threshold
    # The cortex's brightness, read just beneath the blurred edge (1 to 4 voxels deep), metal left out.
    under_edge = erode(mask)
    rim = under_edge & ~erode(under_edge, 3)
    metal = image >= METAL_HU
    if metal.any():  # a pin or screw through the bone: its blurred edge, brighter than cortex, left out too
        reach = int(np.ceil(METAL_EDGE_MM / float(spacing.min())))
        rim &= ~dilate(metal, iterations=reach)
    rim_values = image[rim]
    if rim_values.size == 0:
        return threshold
    cortex = float(np.percentile(rim_values, 95))
    beyond_blur = dilate(mask, 2)
    band = image[dilate(beyond_blur, 2) & ~beyond_blur]
    in_view = band[band > BELOW_AIR_HU]  # a round field of view's padding (-2048, -3024 HU) is not what it touches
    outside = float(np.median(in_view if in_view.size else band))
    logger.info(
        "bone surface at half-max %.0f HU (cortex %.0f HU, outside %.0f HU)", (cortex + outside) / 2, cortex, outside
    )
    return 0.5 * (cortex + outside)


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
