"""``ramsicp pivot``: the pivot calibration of a probe (its tip in its own frame) from poses recorded while it
swivelled about its tip: plain least squares as PLUS and scikit-surgery compute it, or the robust default that names
the poses it leaves out."""

from pathlib import Path

from ..core.pivot import METHODS
from ..io.atomic_files import write_json_atomic
from ..io.file_checks import check_output_file
from ._console import decimals


def add_parser(commands):
    pivot = commands.add_parser(
        "pivot",
        help="the probe's tip from poses recorded while it swivelled about it (pivot calibration)",
        description="Solves R_i tip + t_i = pivot over the poses by least squares (lsq: every pose, as PLUS and "
        "scikit-surgery do; robust, the default: repeated without the poses whose tip lands more than 2.62 times the "
        "median residual from the pivot, named as time ranges). Prints the tip in the probe's frame, the pivot, the "
        "per-pose 3-D RMS, scikit-surgery's per-axis residual and the swivel.",
    )
    pivot.add_argument(
        "--poses",
        type=Path,
        required=True,
        help="a PLUS sequence file (.igs.mha, .seq.mha), a folder of 4 x 4 matrices as text (one per file, named by "
        "the time in ns, as scikit-surgery records them) or a CSV table (16 numbers a line, row by row, or a time "
        "in s and 16 numbers)",
    )
    pivot.add_argument(
        "--tool",
        help="with a PLUS file: the probe's transform (default: the one tool besides the reference that moves)",
    )
    pivot.add_argument(
        "--reference",
        default="ReferenceToTracker",
        help="with a PLUS file: the reference body's transform (default ReferenceToTracker; without it in the file, "
        "the tracker's frame)",
    )
    pivot.add_argument(
        "--method",
        choices=METHODS,
        default="robust",
        help="robust (default): leaves out the poses off the pivot and names them; lsq: every pose",
    )
    pivot.add_argument("--json", type=Path, help="write tip_mm, pivot_mm, rms_mm, dropped (ranges) and more as JSON")
    pivot.set_defaults(run=run)


def run(arguments):
    from OpenIGTLinkBridgeLib.pose_recordings import read_poses

    from ..core.pivot import pivot_calibration

    check_output_file(arguments.json, "--json", (".json",), [arguments.poses])
    recording = read_poses(arguments.poses, arguments.tool, arguments.reference)
    times = None if recording.times_s is None else recording.times_s - recording.times_s[0]
    result = pivot_calibration(recording.poses, arguments.method, times)
    kept = int(result.inliers.sum())
    span = f" over {times[-1]:.1f} s" if times is not None else ""
    print(f"poses            {len(recording)} from {recording.source}{span}")
    for warning in recording.warnings:
        print(f"WARNING          {warning}")
    print(f"method           {result.method}: {kept} of {len(recording)} poses kept")
    print(f"tip              ({decimals(result.tip_in_probe)}) mm in the probe's frame")
    print(f"pivot            ({decimals(result.pivot_in_reference)}) mm")
    print(
        f"residual         {result.rms_mm:.3f} mm RMS per pose (3-D); {result.residual_per_axis_mm:.3f} mm per axis "
        f"(scikit-surgery); {result.mean_residual_mm:.3f} mm mean (PLUS)"
    )
    print(f"swivel           {result.rotation_range_deg:.1f} degrees between the two poses farthest apart")
    if result.method == "robust":
        print(
            f"left out         the poses more than {result.threshold_mm:.2f} mm from the pivot, "
            f"{len(result.dropped)} ranges"
        )
        for entry in result.dropped:
            when = f"{entry.start_s:7.2f}-{entry.end_s:<7.2f} s " if times is not None else ""
            label = recording.labels[entry.first] if recording.labels else f"pose {entry.first}"
            print(
                f"    poses {entry.first:5d}-{entry.last:<5d} {when}({entry.count} poses from {label}): "
                f"{entry.max_residual_mm:.2f} mm max, {entry.rms_residual_mm:.2f} mm RMS"
            )
    if arguments.json:
        document = {
            "poses_from": recording.source,
            "warnings": list(recording.warnings),
            "times": "s from the first pose" if times is not None else None,
            **result.to_dict(),
        }
        write_json_atomic(arguments.json, document)
    return 0
