"""``ramsicp collect``: the touches of a probe in a recorded tracking session (a PLUS sequence file), written as
probe points in reference coordinates: each touch the tip held still or swivelled about one point, the rests at the
start and the end reported apart."""

from pathlib import Path

import numpy as np

from ..core.hold_still import DEFAULT_STILL_MM, DEFAULT_STILL_S, DEFAULT_TIP_ERROR_MM, MAX_DRIFT_MM
from ..io.atomic_files import write_json_atomic
from ..io.file_checks import check_output_file
from ..io.point_files import POINT_SUFFIXES
from ._arguments import FINITE
from ._console import decimals


def add_parser(commands):
    collect = commands.add_parser(
        "collect",
        help="the touches of a probe in a recorded session (held still or swivelled about a point), as probe points",
        description="Finds where the probe tip stayed at one point in a PLUS sequence file: held still, or swivelled "
        "about it as for PLUS's landmark detection (then the swivel's fixed point, which a tip calibration a few mm "
        f"off does not move). A touch: every frame within --hold-still-mm of the point for --hold-still-s, its tip "
        f"drifting at most {MAX_DRIFT_MM:g} mm. The probe lying still when the recording starts or ends is a rest: "
        "reported, not written. Writes each touch's point in reference coordinates.",
    )
    collect.add_argument("--recording", type=Path, required=True, help="PLUS sequence file (.igs.mha, .seq.mha)")
    collect.add_argument(
        "--tool", help="the probe's transform (default: the one tool in the file besides the reference that moves)"
    )
    collect.add_argument(
        "--reference", default="ReferenceToTracker", help="the reference body's transform (default ReferenceToTracker)"
    )
    collect.add_argument(
        "--tip",
        type=FINITE,
        nargs=3,
        required=True,
        metavar=("X", "Y", "Z"),
        help="the tip in the tool's frame (mm): 30 to 500 mm from its origin, or 0 0 0 when --tool is the tip's own "
        "transform",
    )
    collect.add_argument(  # HoldStillDetector checks the settings before any work
        "--hold-still-mm",
        type=float,
        default=DEFAULT_STILL_MM,
        help=f"radius the tip stays within during a touch (default {DEFAULT_STILL_MM:g} mm, PLUS's)",
    )
    collect.add_argument(
        "--hold-still-s",
        type=float,
        default=DEFAULT_STILL_S,
        help=f"shortest touch (default {DEFAULT_STILL_S:g} s)",
    )
    collect.add_argument(
        "--tip-error-mm",
        type=float,
        default=DEFAULT_TIP_ERROR_MM,
        help=f"how far the swivel's fixed point may lie from --tip (default {DEFAULT_TIP_ERROR_MM:g} mm)",
    )
    collect.add_argument(
        "--out", type=Path, required=True, help="points file for register --ppc (.csv .txt .fcsv .mrk.json .npy)"
    )
    collect.add_argument("--json", type=Path, help="write every touch and rest (frames, times, method) and the timing")
    collect.set_defaults(run=run)


def run(arguments):
    from OpenIGTLinkBridgeLib.plus_sequence import read_sequence
    from OpenIGTLinkBridgeLib.recorded_touches import find_recorded_touches, frame_timing

    from ..core.hold_still import HoldStillDetector
    from ..core.pivot import check_tip_offset
    from ..io.point_files import write_points

    HoldStillDetector(arguments.hold_still_mm, arguments.hold_still_s, arguments.tip_error_mm)  # bad settings: now
    check_tip_offset(arguments.tip)  # a tip in cm or m, before any work
    check_output_file(arguments.out, "--out", POINT_SUFFIXES, [arguments.recording])
    check_output_file(arguments.json, "--json", (".json",), [arguments.recording])
    recording = read_sequence(arguments.recording)
    found = find_recorded_touches(
        recording,
        arguments.tool,
        arguments.reference,
        arguments.tip,
        arguments.hold_still_mm,
        arguments.hold_still_s,
        arguments.tip_error_mm,
    )
    timing = frame_timing(recording)
    print(
        f"recording        {arguments.recording}: {timing['frames']} frames over {timing['duration_s']:.1f} s"
        + (
            f" ({timing['rate_hz']:.1f} Hz; interval median {timing['interval_median_ms']:.1f} ms, "
            f"SD {timing['interval_sd_ms']:.1f} ms, {timing['interval_min_ms']:.1f}-{timing['interval_max_ms']:.1f} ms)"
            if "rate_hz" in timing
            else ""
        )
    )
    for warning in recording.warnings:
        print(f"WARNING          {warning}")
    chosen = "" if arguments.tool else " (the tool that moves)"
    print(f"tool             {found.tool}{chosen} in {found.reference}: valid in {len(found.frames)} frames")
    if found.recording_tip is not None:
        offset = np.linalg.norm(found.recording_tip - np.asarray(arguments.tip))
        print(
            f"tip              ({decimals(found.recording_tip)}) mm from the recording's swivels, {offset:.2f} mm "
            "from --tip: it places every touch"
        )
    landmarks = found.landmarks
    if not landmarks:
        rests = len(found.touches) - len(landmarks)
        raise ValueError(
            f"{arguments.recording}: no touch found"
            + (f", only {rests} rest{'s' * (rests > 1)} (the probe lying still at the start or end)" if rests else "")
            + f" (the tip never stayed within {arguments.hold_still_mm:g} mm for {arguments.hold_still_s:g} s without "
            "drifting); try a larger --hold-still-mm or a shorter --hold-still-s"
        )
    start = recording.timestamps_s[0]
    print(
        "touch   kind    x (mm)     y (mm)     z (mm)    frames       time (s from start)  spread (mm)  swivel  point"
    )
    labels, number = [], 0
    for touch in found.touches:
        x, y, z = touch.position
        if touch.rest:
            name = "   -"
        else:
            number += 1
            name = f"{number:4d}"
            labels.append(
                f"touch {number}: {touch.kind}, frames {touch.first_frame}-{touch.last_frame}, "
                f"spread {touch.spread_mm:.3f} mm"
            )
        print(
            f"{name}  {touch.kind:6s} {x:9.2f}  {y:9.2f}  {z:9.2f}  {touch.first_frame:5d}-{touch.last_frame:<5d}  "
            f"{touch.start_s - start:8.2f}-{touch.end_s - start:<8.2f}  {touch.spread_mm:9.3f}  "
            f"{touch.swivel_deg:4.0f} deg  {_point(touch)}"
        )
    write_points(arguments.out, np.array([touch.position for touch in landmarks]), labels=labels)
    rests = len(found.touches) - len(landmarks)
    print(f"{len(landmarks)} touches -> {arguments.out} (reference coordinates); {rests} rests not written")
    if arguments.json:
        document = {
            "recording": str(arguments.recording),
            "warnings": list(recording.warnings),
            "tip_mm": list(arguments.tip),
            "hold_still_mm": arguments.hold_still_mm,
            "hold_still_s": arguments.hold_still_s,
            "tip_error_mm": arguments.tip_error_mm,
            "timing": timing,
            **found.to_dict(),
        }
        write_json_atomic(arguments.json, document)
    return 0


def _point(touch):
    """How the touch's point was found, in a few words."""
    tip = {"pivot": "its own pivot", "calibration": "--tip", "recording": "the recording's tip"}[touch.tip_from]
    own = {"pivot": "swivel", "partial pivot": "partial swivel", "mean tip": "mean"}[touch.method]
    return f"{own}, {tip}"
