"""The whole image side in one call: CT -> segmentation -> marker spheres -> the bone -> IPC.

The command line (``ramsicp ipc``), the demo and the Slicer logic all run this one function. The order matters: the
marker spheres are found first (anywhere in the CT, paired with the tool by its geometry), because the bone is
recognised as the object that holds none of them (``bone_recognition``).
"""

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from .bone_recognition import FINE_MAX_CELLS, MAX_CELLS, finer_grids_possible
from .ct_segmentation import DEFAULT_THRESHOLD_HU, bone_surface, reference_body_spheres, threshold_ct, with_bone
from .ipc_self_check import describe as describe_spheres_in_surface
from .ipc_self_check import (
    describe_unfound,
    solid_body_taken_for_bone,
    solid_under_surface,
    spheres_in_surface,
    unfound_spheres_in_surface,
)
from .marker_spheres import detect_marker_spheres, label_sphere_voxels, usable_spheres
from .solid_patches import without_solid_patches

logger = logging.getLogger(__name__)


class NoBoneSurface(ValueError):
    """The CT gives no IPC: no object in it is plausibly bone, or all of the bone's surface lies next to metal. The
    marker spheres were found all the same: ``detection`` (a ``marker_spheres.MarkerDetection``), ``usable`` the
    ones the coarse registration may use (status 'ok', paired with a tool marker)."""

    def __init__(self, message, detection):
        super().__init__(message)
        self.detection = detection

    @property
    def usable(self):
        return usable_spheres(self.detection.spheres)

    def spheres_found(self, tool_markers):
        """What the refusal still gives, for its message: "the 4 marker spheres found (3 of 4 usable)"."""
        spheres = self.detection.spheres
        return f"the {len(spheres)} marker spheres found ({len(self.usable)} of {tool_markers} usable)"


@dataclass(frozen=True)
class ImageSideResult:
    """Segmentation, IPC surface, marker spheres, warnings, timings (s).

    ``spheres`` are in the order of the tool's markers when a tool was given: each has its tool marker
    ``number`` (1-based; 0 when it could not be paired), and unpaired ones come last. ``missing`` holds a
    ``marker_spheres.MissingMarker`` (number, expected centre, in the field of view or not) for each tool marker
    no sphere was found for; ``pairing`` the ``core.marker_geometry.GeometricPairing`` (None without a tool, or
    when fewer than 3 spheres fit it).
    """

    segmentation: object
    surface: object
    spheres: tuple
    warnings: tuple
    seconds: dict = field(default_factory=dict)
    missing: tuple = ()
    pairing: object = None

    @property
    def centres(self):
        """(K, 3) centres of all spheres found, in ``spheres`` order (RAS mm)."""
        return np.array([sphere.centre for sphere in self.spheres]).reshape(-1, 3)

    @property
    def usable(self):
        """The spheres the coarse registration may use: status 'ok' and paired with a tool marker."""
        return usable_spheres(self.spheres)


def process_ct(volume, threshold_hu=DEFAULT_THRESHOLD_HU, fill_cavities=True, tool_markers=None, progress=None):
    """Run the image side on a CTVolume.

    Args:
        threshold_hu: bone threshold (HU) or 'auto'.
        fill_cavities: keep only the outer bone surface in the IPC.
        tool_markers: (K, 3) marker geometry of the reference body; its markers are chosen among the spheres
            found by their distances, and a missing one is located.
        progress: optional callable ``progress(step, done, total)``.

    The segmentation's labels give each sphere's own voxels a label of their own (``sphere.label``), split from
    the posts and frame they touch, so a labelmap of the spheres shows the spheres only.

    Raises:
        ValueError: a bad threshold, or no voxel above it.
        NoBoneSurface: no object in the CT that is plausibly bone, none of its surface away from metal, a bone
            without a cortex that is solid beside marker spheres (or, with none found, dimmer on its rim than
            inside), a bone with a cortex whose surface left for the IPC has none under it (a bar joined to it:
            ``ipc_self_check.solid_under_surface``), or a surface that holds the reference body's marker spheres
            (those found, or, with none paired or tied, two balls of their size at the tool's distances:
            ``ipc_self_check``; the message says what was found); it holds the marker spheres found.
    """
    report = progress or (lambda step, done, total: None)
    seconds = {}
    clock = time.perf_counter()
    report("segmentation", 0, 3)
    segmentation = threshold_ct(volume, threshold_hu)
    seconds["segmentation"] = time.perf_counter() - clock
    report("marker spheres", 1, 3)
    clock = time.perf_counter()
    expected = 4 if tool_markers is None else len(tool_markers)
    detection = detect_marker_spheres(volume, segmentation, expected=expected, tool_markers=tool_markers)
    seconds["marker_spheres"] = time.perf_counter() - clock
    report("bone surface", 2, 3)
    clock = time.perf_counter()
    try:
        segmentation, surface = _bone_and_surface(volume, segmentation, detection, tool_markers, fill_cavities)
    except NoBoneSurface as error:
        if not finer_grids_possible(volume, segmentation):
            raise
        # Coarse cells can leave no opening between a bracket's width and a thin bone's thickness.
        logger.info("no bone surface with the objects measured on coarse grids: once more on finer ones")
        try:
            segmentation, surface = _bone_and_surface(
                volume, segmentation, detection, tool_markers, fill_cavities, FINE_MAX_CELLS
            )
        except NoBoneSurface:
            raise error from None
    seconds["surface"] = time.perf_counter() - clock
    spheres = label_sphere_voxels(volume, segmentation, detection.spheres)
    report("bone surface", 3, 3)
    warnings = list(detection.warnings) + list(segmentation.recognition.warnings)
    if surface.left_out:
        centre = ", ".join(f"{value:.0f}" for value in surface.metal.centre)
        warnings.append(
            f"metal in the CT ({surface.metal.metal_mm3:.0f} mm^3 brighter than any bone, around ({centre}) mm): "
            f"{surface.left_out:,} bone-surface points within {surface.metal.margin_mm:.0f} mm of it, and within "
            f"{surface.metal.reach_mm:.0f} mm of it in its slices (streaks), are left out of the IPC; collect "
            "probe points away from it"
        )
    return ImageSideResult(
        segmentation, surface, tuple(spheres), tuple(warnings), seconds, detection.missing, detection.pairing
    )


def _bone_and_surface(volume, segmentation, detection, tool_markers, fill_cavities, max_cells=MAX_CELLS):
    """(segmentation with its bone, BoneSurface): the bone recognised on grids of at most ``max_cells`` cells, its
    surface, and the IPC's checks against the reference body (``ipc_self_check``); raises NoBoneSurface. Patches over
    a solid part dimmer than the cortex (a rod resting on the bone) are left out last (``solid_patches``)."""
    body_spheres = reference_body_spheres(detection)
    try:
        segmentation = _with_bone(volume, segmentation, detection, body_spheres, max_cells)
        surface = bone_surface(volume, segmentation, fill_cavities=fill_cavities)
    except ValueError as error:  # the spheres found are the user's all the same
        raise NoBoneSurface(str(error), detection) from error
    solid = solid_body_taken_for_bone(volume, segmentation, detection.spheres) or solid_under_surface(
        volume, segmentation, surface.points
    )
    if solid:
        raise NoBoneSurface(solid, detection)
    on_spheres = spheres_in_surface(surface.points, body_spheres)
    if on_spheres:  # the last word: an IPC that is the reference body's never leaves
        raise NoBoneSurface(describe_spheres_in_surface(on_spheres), detection)
    if tool_markers is not None and detection.pairing is None and not detection.tied:
        unfound = unfound_spheres_in_surface(surface.points, surface.triangles, tool_markers)
        if unfound:  # ... nor one that holds spheres no look at the CT found (sunk into a brighter plate)
            raise NoBoneSurface(describe_unfound(unfound), detection)
    return segmentation, without_solid_patches(volume, segmentation, surface)


def _with_bone(volume, segmentation, detection, body_spheres, max_cells=MAX_CELLS):
    """``with_bone``, and once more as if no sphere were seen when the body's spheres are only tied by the tool's
    distances (``MarkerDetection.tied``: none numbered) and no bone is found with them as the body's. Two sphere-like
    spots of the body can lie at one of the tool's distances by chance (family seed 19089: a 10.8 mm bracket's end,
    7.5 mm from the bone, and a 10.9 mm frame's, 62.8 mm apart against the tool's 64.3 mm), and such a spot holds
    the bone's core to the body. Such a spot can also lie in the bone itself (27033: a bracket's round end in a
    tibia's marrow): with tied spheres, no cut may leave a piece with a cortex round its inside on the body's side
    larger than the bone it keeps (``recognise_bone``'s ``spheres_sure``), so that the first look finds no bone
    rather than a piece of the frame. The IPC must still hold none of them (``spheres_in_surface``, in
    ``process_ct``); when the second look finds no bone either, the first's message is the one raised."""
    try:  # (spheres are tied only when none could be paired: ``detect_marker_spheres``)
        return with_bone(volume, segmentation, body_spheres, not detection.tied, max_cells)
    except ValueError as error:
        if not detection.tied:
            raise
        logger.info("no bone with the spheres tied by the tool's distances as the body's: once more without them")
        try:
            return with_bone(volume, segmentation, [], max_cells=max_cells)
        except ValueError:
            raise error from None
