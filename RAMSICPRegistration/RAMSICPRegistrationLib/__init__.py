"""RAMSICP Navigator's Qt-free library: the CR-RAMSICP patient-to-image registration of Zhang et al.

Plain Python, the Slicer Python console and the ``ramsicp`` command line all use this package::

    from RAMSICPRegistrationLib import SurfaceIndex, read_points, read_surface_points, register
    ipc = read_surface_points("bone.vtp")            # (M, 3) image points, RAS mm
    ppc = read_points("probe_points.mrk.json").points  # (N, 3) probe points in reference coordinates
    result = register(SurfaceIndex(ipc), ppc, markers_image, markers_patient, method="cr-ramsicp", sweep=True)
    result.reference_to_image  # (4, 4) ReferenceToImage, the paper's eq. 10

    volume = load_volume("ct.nrrd")  # or a vtkMRMLScalarVolumeNode inside Slicer
    segmentation = segment_bone(volume)
    ipc = bone_surface(volume, segmentation).points
    spheres = detect_marker_spheres(volume, segmentation)

Points are (N, 3) float arrays in mm, transforms (4, 4) arrays; ``AToB`` maps frame A to frame B.

The sub-packages are the layers of DESIGN.md, each importing only those before it:

=============== ==========================================================================================
``core``        the registration itself (numpy/scipy only): paired points, ICP, RAMSICP, sweep, metrics,
                hold-still detection of probe touches; the robot's calibrations, the osteotomy plan, its tool
                path and the live guidance of the cut
``io``          point and surface files, VTK array conversion, the shipped NDI tool geometries
``image``       CT volumes to the IPC and the marker-sphere centres
``simulation``  the virtual patient, CT phantoms and the shipped bone meshes
``navigation``  the surgeon's workflow on an MRML scene, scene rendering
``experiments`` the demo, the trials and the paper's experiments
``web``         the browser navigation view (trame-slicer), a second shell over the navigation controller
``commands``    the ``ramsicp`` command line, one module per command
=============== ==========================================================================================

The names below are imported on first use, so ``import RAMSICPRegistrationLib`` stays cheap and the registration
core can be used without VTK.
"""

import importlib

__version__ = "0.1.0"

#: Public name -> the module (relative to this package) that defines it.
_EXPORTS = {
    # core: the registration (eqs. 5-11)
    "fit_rigid_transform": "core.paired_point",
    "PairedPointFit": "core.paired_point",
    "FineResult": "core.icp",
    "MatchingRanges": "core.icp",
    "icp": "core.icp",
    "ramsicp": "core.icp",
    "icp_point_to_plane": "core.plane_icp",
    "fle_from_fre": "core.metrics",
    "predicted_tre": "core.metrics",
    "target_registration_error": "core.metrics",
    "DEFAULT_METHOD": "core.registration",
    "DEFAULT_SCALE": "core.registration",
    "METHODS": "core.registration",
    "POLICIES": "core.registration",
    "RegistrationResult": "core.registration",
    "register": "core.registration",
    "select_scale": "core.registration",
    "SurfaceIndex": "core.surface_index",
    "FusedWeights": "core.fused",
    "fused_fit": "core.fused",
    "marker_fle": "core.fused",
    "surface_sigma": "core.fused",
    "PoseUncertainty": "core.error_prediction",
    "PredictedErrors": "core.error_prediction",
    "TouchGuidance": "core.touch_guidance",
    "TouchSuggestion": "core.touch_guidance",
    "touch_guidance": "core.touch_guidance",
    "PAPER_SCALES": "core.sweep",
    "SweepEntry": "core.sweep",
    "make_scales": "core.sweep",
    "sweep_scales": "core.sweep",
    "apply_transform": "core.transforms",
    "invert_transform": "core.transforms",
    "make_transform": "core.transforms",
    "probe_to_reference": "core.transforms",
    "pivot_calibration": "core.pivot",
    # core: the robot (eqs. 3-4, the four-point TCP), the osteotomy plan, its tool path and live guidance
    "robot_base_to_tracker": "core.robot",
    "image_to_robot_base": "core.robot",
    "tcp_four_point": "core.robot",
    "TcpCalibration": "core.robot",
    "CutPlan": "core.osteotomy",
    "plan_cut": "core.osteotomy",
    "wedge_plane": "core.osteotomy",
    "ToolPath": "core.tool_path",
    "plan_tool_path": "core.tool_path",
    "plan_osteotomy": "core.tool_path",
    "plan_document": "core.tool_path",
    "CutGuidance": "core.guidance",
    "cut_guidance": "core.guidance",
    # core: touches (the tip held at one point, still or swivelled) and the fixed point of a swivel
    "HoldStillDetector": "core.hold_still",
    "Touch": "core.touch",
    "find_touches": "core.hold_still",
    "find_pose_touches": "core.hold_still",
    "fixed_point_fit": "core.fixed_point",
    # io: files
    "PointFileError": "io.point_files",
    "read_points": "io.point_files",
    "write_points": "io.point_files",
    "write_points_atomic": "io.point_files",
    "read_surface_points": "io.surface_files",
    "read_surface_mesh": "io.surface_files",
    "write_surface": "io.surface_files",
    "tool_marker_geometry": "io.ndi_tools",
    "MarkerSet": "io.marker_files",
    "read_markers": "io.marker_files",
    "write_markers": "io.marker_files",
    "pair_markers": "io.marker_files",
    # image side
    "CTVolume": "image.volume_io",
    "load_volume": "image.volume_io",
    "segment_bone": "image.ct_segmentation",
    "bone_surface": "image.ct_segmentation",
    "detect_marker_spheres": "image.marker_spheres",
    "pair_by_geometry": "core.marker_geometry",
    "find_metal_zone": "image.metal",
    "process_ct": "image.ct_pipeline",
    "NoBoneSurface": "image.ct_pipeline",
    # simulation
    "make_ct_phantom": "simulation.ct_phantom",
    "make_reference_body_phantom": "simulation.reference_body_phantom",
    "make_family_ct": "simulation.reference_ct_family",
    "ReferenceBodyModel": "simulation.ct_painting",
    "MetalRod": "simulation.ct_painting",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
