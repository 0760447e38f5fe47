"""``ramsicp ipc``: a CT volume to the image point cloud (the bone's surface) and the marker-sphere centres."""

import sys
import time
from pathlib import Path

from ..image.hounsfield import DEFAULT_THRESHOLD_HU, check_hounsfield_units
from ..io.atomic_files import write_json_atomic
from ..io.file_checks import check_output_file
from ..io.ndi_tools import DEFAULT_REFERENCE_TOOL
from ..io.point_files import POINT_SUFFIXES
from ._arguments import POSITIVE_MM, threshold
from ._console import Progress
from .exit_codes import EXIT_TOO_FEW_MARKERS


def add_parser(commands):
    ipc = commands.add_parser(
        "ipc",
        help="CT -> image point cloud (IPC) and marker-sphere centres",
        description="Finds the reference body's marker spheres (11.5 mm) anywhere in the CT and numbers them in the "
        "tool's order by its inter-marker distances (a missing one is located); segments the CT by a threshold, "
        "recognises the bone as the object holding no sphere, with a cortex (cut off a bracket that joins it to the "
        "reference body; no plausible bone: exit 2 with what was found, the marker centres written all the same with "
        "--markers), and writes its outer surface as the IPC (in the CT's RAS coordinates).",
    )
    ipc.add_argument("ct", help="CT volume: .nrrd, .nhdr, .nii, .nii.gz or a DICOM series folder")
    ipc.add_argument(
        "--threshold",
        type=threshold,
        default=DEFAULT_THRESHOLD_HU,
        help=f"bone threshold in HU, or 'auto' (Otsu); default {DEFAULT_THRESHOLD_HU:g}",
    )
    ipc.add_argument("--spacing", type=POSITIVE_MM, help="thin the IPC to about one point per this many mm")
    ipc.add_argument(
        "--keep-cavities",
        action="store_true",
        help="keep the inner (marrow) surface of the cortex in the IPC, as the paper's IPC does",
    )
    ipc.add_argument("--out", type=Path, required=True, help="IPC file: .vtp .vtk .ply .stl .obj or a point file")
    ipc.add_argument(
        "--markers",
        type=Path,
        help="write the marker-sphere centres (.mrk.json or .fcsv), labelled 'M<n> <status>' (n: the tool's "
        f"marker number; status ok, partial or deformed); exit code {EXIT_TOO_FEW_MARKERS} when fewer than the "
        "tool's markers are usable (the file is written all the same)",
    )
    ipc.add_argument(
        "--accept-fewer",
        action="store_true",
        help="exit 0 even when fewer marker centres than the tool's markers are usable",
    )
    ipc.add_argument(
        "--labelmap", type=Path, help="write the segmentation as a .nrrd labelmap (1 bone, 1 + n marker n's sphere)"
    )
    ipc.add_argument(
        "--tool",
        default=DEFAULT_REFERENCE_TOOL,
        help=f"NDI tool whose marker order the centres follow (default {DEFAULT_REFERENCE_TOOL})",
    )
    ipc.add_argument("--json", type=Path, help="write counts, thresholds, spheres and timings as JSON")
    ipc.set_defaults(run=run)


def run(arguments):
    from ..image.ct_pipeline import NoBoneSurface, process_ct
    from ..image.ct_segmentation import resample_points
    from ..image.marker_spheres import sphere_labelmap
    from ..image.volume_io import CTVolume, load_volume, save_nrrd
    from ..io.marker_files import check_markers_path
    from ..io.ndi_tools import tool_marker_geometry
    from ..io.point_files import _suffix, write_points
    from ..io.surface_files import SURFACE_SUFFIXES, write_surface

    threshold = arguments.threshold
    check_output_file(arguments.out, "--out", SURFACE_SUFFIXES + POINT_SUFFIXES, [arguments.ct])
    check_output_file(arguments.markers, "--markers", inputs=[arguments.ct])
    if arguments.markers is not None:
        check_markers_path(arguments.markers)  # a file that keeps each marker's number and status
    check_output_file(arguments.labelmap, "--labelmap", (".nrrd",), [arguments.ct])
    check_output_file(arguments.json, "--json", (".json",), [arguments.ct])
    clock = time.perf_counter()
    volume = load_volume(arguments.ct)
    check_hounsfield_units(volume.voxels, threshold)
    load_seconds = time.perf_counter() - clock
    tool = tool_marker_geometry(arguments.tool)
    try:
        image = process_ct(
            volume,
            threshold,
            fill_cavities=not arguments.keep_cavities,
            tool_markers=tool,
            progress=Progress(),
        )
    except NoBoneSurface as error:
        if arguments.markers is None:
            raise
        # No IPC, but the marker centres found are the user's: written before the error, as a whole file.
        _write_spheres(arguments.markers, error.detection.spheres)
        raise ValueError(f"{error}; {error.spheres_found(len(tool))} are in {arguments.markers}") from error
    seconds = {"load": load_seconds, **image.seconds}
    segmentation, spheres, warnings = image.segmentation, list(image.spheres), list(image.warnings)
    points, triangles = image.surface.points, image.surface.triangles
    if arguments.spacing is not None:
        points, triangles = resample_points(points, arguments.spacing), None
    if _suffix(arguments.out) in POINT_SUFFIXES:
        write_points(arguments.out, points)
    else:
        write_surface(arguments.out, points, triangles)
    if arguments.labelmap is not None:
        save_nrrd(
            arguments.labelmap, CTVolume(voxels=sphere_labelmap(segmentation, spheres), ijk_to_ras=volume.ijk_to_ras)
        )
    if arguments.markers is not None:
        _write_spheres(arguments.markers, spheres)
    voxels = "x".join(str(n) for n in volume.voxels.shape)
    print(f"CT               {arguments.ct}: {voxels} voxels of {' x '.join(f'{s:g}' for s in volume.spacing)} mm")
    print(f"threshold        {segmentation.threshold_hu:.0f} HU")
    print(f"IPC              {len(points):,} points -> {arguments.out}")
    for sphere in spheres:
        centre = ", ".join(f"{value:.2f}" for value in sphere.centre)
        name = f"marker {sphere.number}" if sphere.number else "marker ?"
        print(
            f"{name:<17}({centre}) radius {sphere.radius_mm:.2f} mm, residual {sphere.residual_mm:.3f} mm, "
            f"{sphere.status}" + (f" ({sphere.note})" if sphere.note else "")
        )
    for missing in image.missing:
        centre = ", ".join(f"{value:.2f}" for value in missing.expected)
        where = "inside the CT" if missing.in_field_of_view else "outside the CT"
        if missing.cut_by_field_of_view:
            where += ", but a sphere there is cut by its edge"
        print(f"{f'marker {missing.number}':<17}not found; the other markers put it at ({centre}), {where}")
    recognition = segmentation.recognition
    bone = recognition.verdict
    print(
        f"bone             {bone.describe()}"
        + (
            f"; cut off the reference body, {image.surface.left_out_body:,} IPC points next to it left out"
            if segmentation.body is not None
            else ""
        )
        + (
            f"; {image.surface.left_out_base:,} IPC points round the base of a wire or stub cut off it left out"
            if image.surface.left_out_base
            else ""
        )
    )
    if arguments.markers is not None:
        print(f"marker centres   {len(image.usable)} of {len(tool)} usable -> {arguments.markers}")
    print("time             " + ", ".join(f"{name.replace('_', ' ')} {value:.2f} s" for name, value in seconds.items()))
    for warning in warnings:
        print(f"warning: {warning}")
    if arguments.json:
        document = {
            "ct": str(arguments.ct),
            "shape": list(volume.voxels.shape),
            "spacing_mm": volume.spacing.tolist(),
            "threshold_hu": segmentation.threshold_hu,
            "ipc_points": len(points),
            "spheres": [sphere.to_dict() for sphere in spheres],
            "usable_markers": [sphere.number for sphere in image.usable],
            "missing_markers": [missing.to_dict() for missing in image.missing],
            "pairing": None if image.pairing is None else image.pairing.to_dict(),
            "bone": {
                "objects": [verdict.to_dict() for verdict in recognition.objects],
                "label": recognition.label,
                "reference_body_cut_off": segmentation.body is not None,
                "ipc_points_left_out_next_to_the_reference_body": image.surface.left_out_body,
                "ipc_points_left_out_round_the_base_of_parts_cut_off": image.surface.left_out_base,
            },
            "ipc_points_left_out_near_metal": image.surface.left_out,
            "warnings": warnings,
            "seconds": seconds,
        }
        write_json_atomic(arguments.json, document)
    if arguments.markers is not None and len(image.usable) < len(tool) and not arguments.accept_fewer:
        missing = [n for n in range(1, len(tool) + 1) if n not in {s.number for s in image.usable}]
        print(
            f"ramsicp ipc: error: only {len(image.usable)} of {len(tool)} marker centres are usable (not usable: "
            f"marker {', '.join(map(str, missing))}); {arguments.markers} holds every sphere found with its status. "
            "Check the reference body in the CT or place the missing centres by hand; --accept-fewer exits 0",
            file=sys.stderr,
        )
        return EXIT_TOO_FEW_MARKERS
    return 0


def _write_spheres(path, spheres):
    """The spheres' centres, labelled with their marker numbers and statuses (``M<n> <status>``)."""
    from ..io.marker_files import write_markers

    write_markers(path, [s.centre for s in spheres], [s.number for s in spheres], [s.status for s in spheres])
