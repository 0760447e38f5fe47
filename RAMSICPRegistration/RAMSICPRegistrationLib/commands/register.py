"""``ramsicp register``: probe points and marker centres registered to the image point cloud (CR, then the fine
step), with FRE, TRE and the per-point residuals; given the plan's targets in the image, cr-fused's predicted error
there, the next touch that lowers it most and, with a limit, whether it is enough (``core.touch_guidance``); exit 4
when the result fails a check."""

import sys
import time
from pathlib import Path

import numpy as np

from ..core.registration import DEFAULT_METHOD, METHODS, POLICIES
from ..core.sweep import MAX_SCALES
from ..io.atomic_files import write_json_atomic
from ..io.file_checks import check_output_file
from ..io.ndi_tools import DEFAULT_REFERENCE_TOOL
from ._arguments import COUNT, FINITE, POSITIVE_MM
from ._console import decimals
from .exit_codes import EXIT_ALARM

#: The inputs whose frame can be given one by one (``--<input>-space``).
SPACE_OPTIONS = ("ipc", "ppc", "markers-image", "markers-patient", "targets-image", "targets-patient")


def add_parser(commands):
    reg = commands.add_parser(
        "register",
        help="register probe points and markers to an image point cloud",
        description="The coarse registration (CR) on the marker-sphere centres, then the fine step of --method on "
        "the probe points (cr-fused by default: markers and probe points in one weighted fit), and ReferenceToImage "
        "with the FRE, the probe points' residuals and, given targets, the TRE (eq. 11). Coordinates: files that "
        "state their frame (markups JSON, fcsv, model headers) are honoured; others are taken as --untagged-space.",
    )
    reg.add_argument("--ipc", required=True, help="image point cloud: .vtk .vtp .stl .ply .obj or a point file")
    reg.add_argument(
        "--ppc", required=True, help="probe points in reference coordinates (.mrk.json .fcsv .csv .txt .npy)"
    )
    reg.add_argument(
        "--markers-image",
        required=True,
        help="marker-sphere centres in the image; labels 'M<n> <status>' (as ramsicp ipc writes them) pair "
        "marker n with the n-th patient marker and say whether its sphere was ok, partial or deformed",
    )
    reg.add_argument("--markers-patient", required=True, help="the same centres in reference coordinates")
    reg.add_argument(
        "--accept-flagged-markers",
        action="store_true",
        help="use marker centres that ramsicp ipc flagged partial or deformed (refused otherwise)",
    )
    reg.add_argument(
        "--tool",
        default=DEFAULT_REFERENCE_TOOL,
        help=f"NDI reference body (default {DEFAULT_REFERENCE_TOOL}): patient marker centres that are its markers "
        "must lie where its definition puts them (the reference frame is its frame)",
    )
    reg.add_argument(
        "--targets-image",
        help="target points in the image, e.g. the plan's endpoints: cr-fused's predicted error there and the next "
        "touch; with --targets-patient also the TRE",
    )
    reg.add_argument("--targets-patient", help="the same targets in reference coordinates (for the TRE)")
    reg.add_argument(
        "--reachable",
        help="points of the exposed bone surface in the image, where the probe can touch: the next touch is chosen "
        "among them (default: the whole IPC; needs --targets-image)",
    )
    reg.add_argument(
        "--target-tre",
        type=POSITIVE_MM,
        metavar="MM",
        help="the error the plan needs at every target: the JSON's 'enough' is true when cr-fused's predicted error "
        "at each target is below it with 95 %% confidence (needs --targets-image)",
    )
    reg.add_argument(
        "--method",
        choices=METHODS,
        help=f"default {DEFAULT_METHOD} (markers and probe points in one fit); cr-ramsicp with --scale or --sweep",
    )
    how = reg.add_mutually_exclusive_group()
    how.add_argument("--scale", type=FINITE, help="scale factor L for one RAMSICP run, 1 to 20 (default 5; cr-ramsicp)")
    how.add_argument("--sweep", action="store_true", help="run L = 1..5 step 0.2 and choose L by --policy (cr-ramsicp)")
    reg.add_argument(
        "--scales",
        nargs=3,
        type=FINITE,
        metavar=("START", "STOP", "STEP"),
        default=(1.0, 5.0, 0.2),
        help=f"the sweep's range (default 1 5 0.2; L from 1 to 20, at most {MAX_SCALES} values)",
    )
    reg.add_argument(
        "--policy",
        choices=POLICIES,
        help="how the sweep picks L (default: targets when targets are given, else rms-plateau)",
    )
    reg.add_argument(
        "--fle",
        type=POSITIVE_MM,
        help="marker localisation error (mm) for the predicted TRE and cr-fused's marker weights "
        "(default: estimated from the FRE)",
    )
    reg.add_argument(
        "--untagged-space",
        type=str.upper,
        choices=("RAS", "LPS"),
        help="frame of files that do not state one (default RAS); the options below set it for one input. When "
        "neither the IPC nor the image markers state a frame, give it (nothing else can tell a mirror)",
    )
    for option in SPACE_OPTIONS:
        reg.add_argument(
            f"--{option}-space",
            type=str.upper,
            choices=("RAS", "LPS"),
            help=f"frame of the --{option} file when it states none (default --untagged-space), e.g. LPS for a "
            "model exported without its SPACE tag",
        )
    reg.add_argument(
        "--include-far",
        type=COUNT,
        nargs="+",
        default=(),
        metavar="N",
        help="probe points (numbered from 1) to keep in the fit although they lie far from the bone after the "
        "coarse registration (left out otherwise, and listed)",
    )
    reg.add_argument(
        "--json",
        type=Path,
        help=f"write the full result as JSON (also when the result fails a check: exit code {EXIT_ALARM})",
    )
    reg.set_defaults(run=run)


def run(arguments):
    from ..core.coarse_checks import check_reference_frame
    from ..core.registration import register
    from ..core.surface_index import SurfaceIndex
    from ..core.sweep import make_scales
    from ..core.touch_guidance import touch_guidance
    from ..io.ndi_tools import tool_marker_geometry
    from ..io.point_files import read_points
    from ..io.surface_files import read_surface_points

    space = {
        option: getattr(arguments, option.replace("-", "_") + "_space") or arguments.untagged_space or "RAS"
        for option in SPACE_OPTIONS
    }
    if arguments.targets_patient is not None and arguments.targets_image is None:
        raise ValueError("--targets-patient needs the same targets in the image: give --targets-image too")
    guided = arguments.reachable is not None or arguments.target_tre is not None
    if guided and arguments.targets_image is None:
        raise ValueError("--reachable and --target-tre are about the plan's targets: give --targets-image too")
    method = arguments.method or (DEFAULT_METHOD if _default_method_fits(arguments) else "cr-ramsicp")
    if guided and method != "cr-fused":
        raise ValueError(f"--reachable and --target-tre need cr-fused's predicted error, not {method}'s")
    scales = make_scales(*arguments.scales)
    inputs = (arguments.ipc, arguments.ppc, arguments.markers_image, arguments.markers_patient)
    inputs += (arguments.targets_image, arguments.targets_patient, arguments.reachable)
    check_output_file(arguments.json, "--json", (".json",), inputs)
    clock = time.perf_counter()
    ipc, ipc_stated = read_surface_points(arguments.ipc, space["ipc"], with_space=True)
    ppc = read_points(arguments.ppc, space["ppc"]).points
    markers_image, markers_patient, marker_warnings = _read_markers_pair(arguments, space, ipc_stated)
    targets_image = targets_patient = reachable = None
    if arguments.targets_image:
        targets_image = read_points(arguments.targets_image, space["targets-image"]).points
    if arguments.targets_patient:
        targets_patient = read_points(arguments.targets_patient, space["targets-patient"]).points
    if arguments.reachable:
        reachable = read_points(arguments.reachable, space["targets-image"]).points
    check_reference_frame(ppc, f"--ppc {arguments.ppc}")
    check_reference_frame(
        markers_patient,
        f"--markers-patient {arguments.markers_patient}",
        tool_marker_geometry(arguments.tool),
        f"NDI tool {arguments.tool}",
    )
    far_kept = [number - 1 for number in arguments.include_far]
    if any(number > len(ppc) for number in arguments.include_far):
        raise ValueError(f"--include-far {max(arguments.include_far)}: {arguments.ppc} has {len(ppc)} probe points")
    index = SurfaceIndex(ipc)
    result = register(
        index,
        ppc,
        markers_image,
        markers_patient,
        targets_image,
        targets_patient,
        method=method,
        scale=arguments.scale,
        sweep=arguments.sweep,
        scales=scales,
        policy=arguments.policy,
        fle_mm=arguments.fle,
        include_far=far_kept,
    )
    guidance = None
    if result.uncertainty is not None and targets_image is not None:
        guidance = touch_guidance(result, index, reachable=reachable, target_tre_mm=arguments.target_tre)
    seconds = time.perf_counter() - clock
    if arguments.json:  # written before anything is printed: a reader that leaves early loses nothing
        document = result.to_dict()
        document["warnings"] = marker_warnings + document["warnings"]
        if guidance is not None:
            document.update(guidance_fields(guidance))
        document["seconds"] = seconds
        write_json_atomic(arguments.json, document)
    loud = marker_warnings + list(result.alarms)
    summary = _format_result(result, len(ipc), seconds, guidance)
    print("".join(f"WARNING: {warning}\n" for warning in loud) + summary)
    if result.alarms:
        print(
            f"ramsicp register: the result failed {len(result.alarms)} check(s) (WARNING above); it is printed"
            + (f" and written to {arguments.json}" if arguments.json else "")
            + f", and the exit code is {EXIT_ALARM}",
            file=sys.stderr,
        )
        return EXIT_ALARM
    return 0


def _read_markers_pair(arguments, space, ipc_stated=None):
    """Image and patient marker centres, paired by marker number or row and checked by their distances
    (``pair_marker_sets``: another order is re-paired and said); flagged ones refused unless accepted.

    Returns (markers_image (K, 3), markers_patient (K, 3), warnings): the re-pairing, and each flagged marker used.
    """
    from ..io.marker_files import flagged_message, pair_marker_sets, read_markers

    image = read_markers(arguments.markers_image, space["markers-image"])
    _check_image_frame_given(arguments, ipc_stated, image.stated_space)
    patient = read_markers(arguments.markers_patient, space["markers-patient"])
    pairing = pair_marker_sets(image, patient)
    markers_image, markers_patient = pairing.image, pairing.patient
    if not image.flagged():
        return markers_image, markers_patient, list(pairing.warnings)
    flagged = flagged_message(image)
    if not arguments.accept_flagged_markers:
        raise ValueError(
            f"{arguments.markers_image}: {flagged} (flagged by ramsicp ipc: the centre may be off); check it in "
            "the CT, then delete it from the file (3 markers are enough) or correct it and relabel it 'ok', "
            "or pass --accept-flagged-markers to use it anyway"
        )
    return (
        markers_image,
        markers_patient,
        list(pairing.warnings)
        + [
            f"{flagged} in {arguments.markers_image} (flagged by ramsicp ipc), used as you asked: the coarse "
            "registration may be off by that sphere's error"
        ],
    )


def _check_image_frame_given(arguments, ipc_stated, markers_stated):
    """Refuse when neither image-side file states its frame and none was given: both LPS read as RAS is a mirror
    about S, which is a rotation, so the two agree, every check passes and the result is in the wrong frame."""
    given = arguments.untagged_space or arguments.ipc_space or arguments.markers_image_space
    if ipc_stated is None and markers_stated is None and not given:
        raise ValueError(
            f"neither {arguments.ipc} nor {arguments.markers_image} states its coordinate frame, and if both are LPS "
            "read as RAS no check can see it (the mirror turns both alike): give their frame, --untagged-space RAS "
            "or LPS (or --ipc-space and --markers-image-space); ramsicp ipc and Slicer write both tagged"
        )


def _default_method_fits(arguments):
    """--scale, --sweep and --policy are RAMSICP's: without --method they ask for cr-ramsicp."""
    return arguments.scale is None and not arguments.sweep and arguments.policy is None


def guidance_fields(guidance):
    """The JSON's touch-guidance fields: ``next_touch`` (``position_image``, ``normal_image``, and the
    ``predicted_tre_rms_mm`` and per-target ``predicted_tre_mm`` once touched) and, with a limit, ``target_tre_mm``
    and ``enough``; the predicted error now is the result's own ``predicted_tre_mm`` and ``predicted_tre_95_mm``."""
    document = guidance.to_dict()
    return {key: document[key] for key in ("next_touch", "target_tre_mm", "enough") if key in document}


def _format_result(result, ipc_count, seconds, guidance=None):
    lines = []
    method = result.method.upper()
    if result.method == "cr-ramsicp":
        method += f" (L = {result.scale:g}, chosen by '{result.scale_policy}')"
    if result.iterations is not None:
        method += f", {result.iterations} iterations" + ("" if result.converged else " (not converged)")
    lines.append(f"method            {method}")
    lines.append(f"point clouds      {ipc_count} IPC points, {len(result.residuals_mm)} probe points; {seconds:.2f} s")
    lines.append(f"FRE (markers)     {result.fre_mm:.2f} mm  [{decimals(result.marker_residuals_mm)}]")
    worst = int(np.argmax(result.residuals_mm))
    lines.append(
        f"probe points RMS  {result.ppc_rms_mm:.2f} mm to the surface "
        f"(worst: point {worst}, {result.residuals_mm[worst]:.2f} mm)"
    )
    weights = result.fused_weights
    if weights is not None:
        lines.append(f"weights           {weights.describe()}")
    if result.tre_mm is not None:
        lines.append(f"TRE (eq. 11)      {result.tre_mm:.2f} mm  [{decimals(result.target_errors_mm)}]")
    if result.predicted_tre_mm is not None:
        lines.append(
            f"predicted TRE     {result.predicted_tre_rms_mm:.2f} mm  [{decimals(result.predicted_tre_mm)}] "
            "from the fused fit's covariance"
        )
        lines.append(f"95 % bound        [{decimals(result.predicted_tre_95_mm)}] mm at each target")
    if result.predicted_cr_tre_mm is not None:
        lines.append(f"predicted CR TRE  [{decimals(result.predicted_cr_tre_mm)}] mm for FLE {result.fle_mm:.2f} mm")
    if guidance is not None:
        touch = guidance.next_touch
        position = " ".join(f"{value:.1f}" for value in touch.position_image)
        lines.append(
            f"next touch        ({position}) mm in the image: the predicted TRE would fall to "
            f"{touch.predicted_tre_rms_mm:.2f} mm"
        )
        if guidance.enough is not None:
            verdict = "yes" if guidance.enough else "no"
            lines.append(
                f"enough            {verdict}: every target below {guidance.target_tre_mm:g} mm with 95 % confidence"
                if guidance.enough
                else f"enough            {verdict}: not every target is below {guidance.target_tre_mm:g} mm with 95 % "
                "confidence; touch more"
            )
    lines.append("ReferenceToImage")
    lines.extend("  " + "  ".join(f"{value:11.5f}" for value in row) for row in result.reference_to_image)
    if result.sweep:
        lines.append("sweep     L   RMS (mm)   TRE (mm)   iterations")
        for entry in result.sweep:
            tre = "-" if entry.tre_mm is None else f"{entry.tre_mm:.3f}"
            mark = "  <- chosen" if entry.scale == result.scale else ""
            result_text = f"{entry.result.rms_mm:8.3f}   {tre:>8}   {entry.result.iterations:10d}"
            lines.append(f"      {entry.scale:5.1f}   {result_text}{mark}")
    for warning in result.warnings:
        if warning not in result.alarms:  # the alarms lead the summary, in capitals
            lines.append(f"warning: {warning}")
    return "\n".join(lines)
