"""The whole image side in one call: CT -> segmentation -> IPC, and the marker spheres paired with the tool.

The command line (``ramsicp ipc``), the demo and the Slicer logic all run this one function.
"""

import time
from dataclasses import dataclass, field, replace

import numpy as np

from .ct_segmentation import DEFAULT_THRESHOLD_HU, bone_surface, segment_bone
from .marker_spheres import detect_marker_spheres, label_sphere_voxels, match_to_tool, sphere_warning

#: A sphere set whose best pairing with the tool geometry leaves more than this FRE (mm) is not that tool.
TOOL_MISMATCH_FRE_MM = 1.0


@dataclass(frozen=True)
class ImageSideResult:
    """Segmentation, IPC surface, marker spheres, warnings, timings (s).

    ``spheres`` are in the order of the tool's markers when a tool was given: each has its tool marker
    ``number`` (1-based; 0 when it could not be paired), and unpaired ones come last.
    """

    segmentation: object
    surface: object
    spheres: tuple
    warnings: tuple
    seconds: dict = field(default_factory=dict)

    @property
    def centres(self):
        """(K, 3) centres of all spheres found, in ``spheres`` order (RAS mm)."""
        return np.array([sphere.centre for sphere in self.spheres]).reshape(-1, 3)

    @property
    def usable(self):
        """The spheres the coarse registration may use: status 'ok' and paired with a tool marker."""
        return tuple(sphere for sphere in self.spheres if sphere.status == "ok" and sphere.number > 0)


def process_ct(volume, threshold_hu=DEFAULT_THRESHOLD_HU, fill_cavities=True, tool_markers=None, progress=None):
    """Run the image side on a CTVolume.

    Args:
        threshold_hu: bone threshold (HU) or 'auto'.
        fill_cavities: keep only the outer bone surface in the IPC.
        tool_markers: (K, 3) marker geometry of the reference body; the spheres found are paired with its
            markers by their distances (a warning is given if they do not fit it).
        progress: optional callable ``progress(step, done, total)``.

    The segmentation's labels give each sphere's own voxels a label of their own (``sphere.label``), split from
    the posts and frame they touch, so a labelmap of the spheres shows the spheres only.
    """
    report = progress or (lambda step, done, total: None)
    seconds = {}
    clock = time.perf_counter()
    report("segmentation", 0, 3)
    segmentation = segment_bone(volume, threshold_hu)
    seconds["segmentation"] = time.perf_counter() - clock
    report("bone surface", 1, 3)
    clock = time.perf_counter()
    surface = bone_surface(volume, segmentation, fill_cavities=fill_cavities)
    seconds["surface"] = time.perf_counter() - clock
    report("marker spheres", 2, 3)
    clock = time.perf_counter()
    detection = detect_marker_spheres(volume, segmentation, expected=4 if tool_markers is None else len(tool_markers))
    spheres = list(label_sphere_voxels(volume, segmentation, detection.spheres))
    warnings = list(detection.warnings)
    if tool_markers is not None and spheres:
        spheres, warning = _pair_with_tool(spheres, tool_markers)
        # Name the flagged spheres by their marker numbers now that they have them.
        unnamed = {sphere_warning(sphere) for sphere in detection.spheres}
        named = [sphere_warning(sphere) for sphere in spheres if sphere.status != "ok"]
        warnings = named + [w for w in warnings if w not in unnamed] + ([warning] if warning else [])
    seconds["marker_spheres"] = time.perf_counter() - clock
    report("marker spheres", 3, 3)
    if surface.left_out:
        centre = ", ".join(f"{value:.0f}" for value in surface.metal.centre)
        warnings.append(
            f"metal in the CT ({surface.metal.metal_mm3:.0f} mm^3 brighter than any bone, around ({centre}) mm): "
            f"{surface.left_out:,} bone-surface points within {surface.metal.margin_mm:.0f} mm of it, and within "
            f"{surface.metal.reach_mm:.0f} mm of it in its slices (streaks), are left out of the IPC; collect "
            "probe points away from it"
        )
    return ImageSideResult(segmentation, surface, tuple(spheres), tuple(warnings), seconds)


def _pair_with_tool(spheres, tool_markers):
    """Number the spheres by the tool's markers and sort them so; a warning when they do not fit the tool."""
    centres = np.array([sphere.centre for sphere in spheres])
    usable = np.array([sphere.status == "ok" for sphere in spheres])
    numbers, fre = match_to_tool(centres, tool_markers, usable)
    spheres = [replace(sphere, number=int(number)) for sphere, number in zip(spheres, numbers)]
    spheres.sort(key=lambda sphere: sphere.number if sphere.number > 0 else len(tool_markers) + 1)
    if fre is None:
        return spheres, (
            f"{len(spheres)} sphere(s) cannot be paired with the reference body's {len(tool_markers)} markers "
            "(at least 3 are needed); place the centres by hand"
        )
    if fre > TOOL_MISMATCH_FRE_MM:
        return spheres, (
            f"the sphere centres do not match the reference body's geometry (FRE {fre:.2f} mm); "
            "check which NDI tool is mounted"
        )
    return spheres, None
