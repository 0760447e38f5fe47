"""RAMSICP Navigator's Qt-free library: the CR-RAMSICP patient-to-image registration of Zhang et al.

Plain Python, the Slicer Python console and the ``ramsicp`` command line all use this package::

    from RAMSICPRegistrationLib import SurfaceIndex, register
    result = register(SurfaceIndex(ipc), ppc, markers_image, markers_patient, method="cr-ramsicp", sweep=True)
    result.reference_to_image  # (4, 4) ReferenceToImage, the paper's eq. 10

    volume = load_volume("ct.nrrd")  # or a vtkMRMLScalarVolumeNode inside Slicer
    segmentation = segment_bone(volume)
    ipc = bone_surface(volume, segmentation).points
    spheres = detect_marker_spheres(volume, segmentation)

Points are (N, 3) float arrays in mm, transforms (4, 4) arrays; ``AToB`` maps frame A to frame B.
"""

from .ct_phantom import make_ct_phantom
from .ct_segmentation import bone_surface, segment_bone
from .icp import FineResult, MatchingRanges, icp, ramsicp
from .marker_spheres import detect_marker_spheres, order_to_tool
from .metrics import fle_from_fre, predicted_tre, target_registration_error
from .paired_point import PairedPointFit, fit_rigid_transform
from .registration import DEFAULT_SCALE, METHODS, POLICIES, RegistrationResult, register, select_scale
from .surface_index import SurfaceIndex
from .sweep import PAPER_SCALES, SweepEntry, make_scales, sweep_scales
from .transforms import apply_transform, invert_transform, make_transform, probe_to_reference
from .volume_io import CTVolume, load_volume

__version__ = "0.1.0"

__all__ = [
    "CTVolume",
    "DEFAULT_SCALE",
    "METHODS",
    "PAPER_SCALES",
    "POLICIES",
    "FineResult",
    "MatchingRanges",
    "PairedPointFit",
    "RegistrationResult",
    "SurfaceIndex",
    "SweepEntry",
    "apply_transform",
    "fit_rigid_transform",
    "fle_from_fre",
    "icp",
    "invert_transform",
    "make_scales",
    "make_transform",
    "predicted_tre",
    "probe_to_reference",
    "ramsicp",
    "register",
    "select_scale",
    "sweep_scales",
    "target_registration_error",
    "load_volume",
    "segment_bone",
    "bone_surface",
    "detect_marker_spheres",
    "order_to_tool",
    "make_ct_phantom",
]
