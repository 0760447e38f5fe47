"""The whole image side in one call: CT -> segmentation -> IPC, and the marker spheres in the tool's order.

The command line (``ramsicp ipc``), the demo and the Slicer logic all run this one function.
"""

import time
from dataclasses import dataclass, field

import numpy as np

from .ct_segmentation import DEFAULT_THRESHOLD_HU, bone_surface, segment_bone
from .marker_spheres import detect_marker_spheres, order_to_tool

#: A sphere set whose best pairing with the tool geometry leaves more than this FRE (mm) is not that tool.
TOOL_MISMATCH_FRE_MM = 1.0


@dataclass(frozen=True)
class ImageSideResult:
    """Segmentation, IPC surface, marker spheres (in the tool's order when all were found), warnings, timings (s)."""

    segmentation: object
    surface: object
    spheres: tuple
    warnings: tuple
    seconds: dict = field(default_factory=dict)

    @property
    def centres(self):
        """(K, 3) centres of all spheres found, in ``spheres`` order (RAS mm)."""
        return np.array([sphere.centre for sphere in self.spheres]).reshape(-1, 3)


def process_ct(volume, threshold_hu=DEFAULT_THRESHOLD_HU, fill_cavities=True, tool_markers=None, progress=None):
    """Run the image side on a CTVolume.

    Args:
        threshold_hu: bone threshold (HU) or 'auto'.
        fill_cavities: keep only the outer bone surface in the IPC.
        tool_markers: (K, 3) marker geometry of the reference body; when K spheres are found they are put in
            its order (and a warning is given if they do not fit it).
        progress: optional callable ``progress(step, done, total)``.
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
    detection = detect_marker_spheres(volume, segmentation)
    spheres, warnings = list(detection.spheres), list(detection.warnings)
    if tool_markers is not None and len(spheres) == len(tool_markers):
        order, fre = order_to_tool(np.array([sphere.centre for sphere in spheres]), tool_markers)
        spheres = [spheres[i] for i in order]
        if fre > TOOL_MISMATCH_FRE_MM:
            warnings.append(
                f"the sphere centres do not match the reference body's geometry (FRE {fre:.2f} mm); "
                "check which NDI tool is mounted"
            )
    seconds["marker_spheres"] = time.perf_counter() - clock
    report("marker spheres", 3, 3)
    return ImageSideResult(segmentation, surface, tuple(spheres), tuple(warnings), seconds)
