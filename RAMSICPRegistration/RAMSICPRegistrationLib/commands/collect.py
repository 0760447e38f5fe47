"""``ramsicp collect``: the touches of a probe in a recorded tracking session (a PLUS sequence file), written as
probe points in reference coordinates."""

import json
from pathlib import Path

import numpy as np

from ..core.hold_still import DEFAULT_STILL_MM, DEFAULT_STILL_S
from ..io.file_checks import check_output_file
from ..io.point_files import POINT_SUFFIXES
from ._arguments import FINITE


def add_parser(commands):
    collect = commands.add_parser(
        "collect",
        help="the touches (hold-still periods) of a probe in a recorded session, as probe points",
        description="Finds where the probe tip was held still (within --hold-still-mm for --hold-still-s) in a "
        "PLUS sequence file and writes each touch's mean tip position in reference coordinates.",
    )
    collect.add_argument("--recording", type=Path, required=True, help="PLUS sequence file (.igs.mha, .seq.mha)")
    collect.add_argument("--tool", default="StylusToTracker", help="the probe's transform (default StylusToTracker)")
    collect.add_argument(
        "--reference", default="ReferenceToTracker", help="the reference body's transform (default ReferenceToTracker)"
    )
    collect.add_argument(
        "--tip", type=FINITE, nargs=3, required=True, metavar=("X", "Y", "Z"), help="the tip in the tool's frame (mm)"
    )
    collect.add_argument(  # HoldStillDetector checks both settings before any work
        "--hold-still-mm",
        type=float,
        default=DEFAULT_STILL_MM,
        help=f"radius the tip stays within during a touch (default {DEFAULT_STILL_MM:g} mm)",
    )
    collect.add_argument(
        "--hold-still-s",
        type=float,
        default=DEFAULT_STILL_S,
        help=f"shortest touch (default {DEFAULT_STILL_S:g} s)",
    )
    collect.add_argument(
        "--out", type=Path, required=True, help="points file for register --ppc (.csv .txt .fcsv .mrk.json .npy)"
    )
    collect.add_argument("--json", type=Path, help="write every touch (frames, times, spread) and the frame timing")
    collect.set_defaults(run=run)


def run(arguments):
    from OpenIGTLinkBridgeLib.plus_sequence import read_sequence
    from OpenIGTLinkBridgeLib.recorded_touches import find_recorded_touches, frame_timing

    from ..core.hold_still import HoldStillDetector
    from ..io.point_files import write_points

    HoldStillDetector(arguments.hold_still_mm, arguments.hold_still_s)  # refuses bad settings before any work
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
    print(f"tool             {arguments.tool} in {arguments.reference}: valid in {len(found.frames)} frames")
    if not found.touches:
        raise ValueError(
            f"{arguments.recording}: no touch found (the tip never stayed within {arguments.hold_still_mm:g} mm for "
            f"{arguments.hold_still_s:g} s); try a larger --hold-still-mm or a shorter --hold-still-s"
        )
    start = recording.timestamps_s[0]
    print("touch   x (mm)     y (mm)     z (mm)     frames        time (s from start)  spread (mm RMS)")
    labels = []
    for number, touch in enumerate(found.touches, start=1):
        x, y, z = touch.position
        print(
            f"{number:5d} {x:9.2f}  {y:9.2f}  {z:9.2f}   {touch.first_frame:5d}-{touch.last_frame:<5d}  "
            f"{touch.start_s - start:8.2f}-{touch.end_s - start:<8.2f}  {touch.spread_mm:.3f}"
        )
        labels.append(f"touch {number}: frames {touch.first_frame}-{touch.last_frame}, spread {touch.spread_mm:.3f} mm")
    write_points(arguments.out, np.array([touch.position for touch in found.touches]), labels=labels)
    print(f"{len(found.touches)} touches -> {arguments.out} (reference coordinates)")
    if arguments.json:
        document = {
            "recording": str(arguments.recording),
            "tool": arguments.tool,
            "reference": arguments.reference,
            "tip_mm": list(arguments.tip),
            "hold_still_mm": arguments.hold_still_mm,
            "hold_still_s": arguments.hold_still_s,
            "timing": timing,
            **found.to_dict(),
        }
        arguments.json.write_text(json.dumps(document, indent=2), encoding="utf-8")
    return 0
