"""The ``ramsicp`` command line: ``register`` files, ``plan`` a cut, run the ``demo``, serve the browser view
(``web``). It owns the console.

Only what the argument parser needs is imported here (numpy and light constants), so that ``--help`` and a mistyped
argument answer at once; each command imports its own machinery (scipy, VTK, the image side) when it runs.
"""

import argparse
import json
import logging
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from . import __version__
from .core.hold_still import DEFAULT_STILL_MM, DEFAULT_STILL_S
from .core.registration import DEFAULT_METHOD, METHODS, POLICIES
from .core.sweep import MAX_SCALES
from .core.tool_path import DEFAULT_FAR_MARGIN_MM, DEFAULT_TOOL_WIDTH_MM, TOOLS
from .core.validation import as_transform
from .experiments.design import DEFAULT_SUBJECTS, EXPERIMENTS, SUBJECT_BONES
from .image.hounsfield import DEFAULT_THRESHOLD_HU
from .io.command_line import EXIT_BAD_INPUT, OneLineParser
from .io.file_checks import check_input_file, check_output_file, check_output_folder
from .io.ndi_tools import DEFAULT_REFERENCE_TOOL
from .io.point_files import POINT_SUFFIXES
from .simulation.ct_painting import BODY_MATERIALS
from .simulation.package_data import BONES

#: ``ramsicp ipc --markers``: every file was written, but fewer marker centres are usable than the tool has.
EXIT_TOO_FEW_MARKERS = 3
#: ``ramsicp register``: the result is printed and written, but it failed a check (``RegistrationResult.alarms``).
EXIT_ALARM = 4


def main(argv=None):
    """Entry point of the console script; returns the process exit code."""
    try:
        arguments = _parser().parse_args(argv)
    except SystemExit as stop:  # --help, --version, or an argument error already said in one line
        return stop.code
    logging.basicConfig(
        level=logging.DEBUG if arguments.verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s"
    )
    sys.stdout = _ReaderMayLeave(sys.stdout)
    try:
        code = arguments.run(arguments)
        sys.stdout.flush()
        return code
    except (ValueError, OSError) as error:
        message = " ".join(str(error).split())
        print(f"ramsicp {arguments.command}: error: {message}", file=sys.stderr)
        return EXIT_BAD_INPUT
    finally:
        sys.stdout = sys.stdout.stream


class _ReaderMayLeave:
    """Standard output for a reader that may stop reading (``ramsicp register ... | head``).

    When the pipe breaks, the rest of the output goes to ``os.devnull``, as Python's documentation recommends for
    SIGPIPE, and the command goes on: its files are still written and its exit code is its own, with no traceback
    and no "Broken pipe" message.
    """

    def __init__(self, stream):
        self.stream = stream

    def write(self, text):
        try:
            return self.stream.write(text)
        except BrokenPipeError:
            self._to_devnull()
            return len(text)

    def flush(self):
        try:
            self.stream.flush()
        except BrokenPipeError:
            self._to_devnull()

    def _to_devnull(self):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, self.stream.fileno())
        os.close(devnull)

    def __getattr__(self, name):
        return getattr(self.stream, name)


def _number(kind, test, requirement):
    """An argparse type: ``kind(text)`` that passes ``test``, else one line saying what to give."""

    def convert(text):
        try:
            value = kind(text)
        except ValueError:
            value = None
        if value is None or (kind is float and not math.isfinite(value)) or not test(value):
            raise argparse.ArgumentTypeError(f"{text!r}: {requirement}")
        return value

    return convert


_POSITIVE_MM = _number(float, lambda value: value > 0, "give a positive number of mm")
_FINITE = _number(float, lambda value: True, "give a finite number")
_COUNT = _number(int, lambda value: value >= 1, "give a whole number, 1 or more")
_SEED = _number(int, lambda value: value >= 0, "give a whole number, 0 or more")
_SPEED = _number(float, lambda value: value > 0, "give a speed above 0 mm/s")


def _threshold(text):
    """``ramsicp ipc --threshold``: a number of HU, or 'auto' (Otsu)."""
    return text if text == "auto" else _number(float, lambda value: True, "give a number of HU or 'auto'")(text)


def _parser():
    parser = OneLineParser(
        prog="ramsicp",
        description="CR-RAMSICP patient-to-image registration for robot-assisted long-bone osteotomy.",
        epilog=f"Exit codes: 0 done; {EXIT_BAD_INPUT} bad input (one line, before any work); "
        f"{EXIT_TOO_FEW_MARKERS} ipc --markers: fewer usable marker centres than the tool has (files written); "
        f"{EXIT_ALARM} register: the result failed a check (printed and written, led by WARNING lines).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log what happens")
    commands = parser.add_subparsers(dest="command", required=True)

    reg = commands.add_parser(
        "register",
        help="register probe points and markers to an image point cloud",
        description="Coordinates: files that state their frame (markups JSON, fcsv, model "
        "headers) are honoured; others are taken as --untagged-space.",
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
    reg.add_argument("--targets-image", help="target points in the image (for the TRE)")
    reg.add_argument("--targets-patient", help="the same targets in reference coordinates")
    reg.add_argument(
        "--method",
        choices=METHODS,
        help=f"default {DEFAULT_METHOD} (markers and probe points in one fit); cr-ramsicp with --scale or --sweep",
    )
    how = reg.add_mutually_exclusive_group()
    how.add_argument(
        "--scale", type=_FINITE, help="scale factor L for one RAMSICP run, 1 to 20 (default 5; cr-ramsicp)"
    )
    how.add_argument("--sweep", action="store_true", help="run L = 1..5 step 0.2 and choose L by --policy (cr-ramsicp)")
    reg.add_argument(
        "--scales",
        nargs=3,
        type=_FINITE,
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
        type=_POSITIVE_MM,
        help="marker localisation error (mm) for the predicted TRE and cr-fused's marker weights "
        "(default: estimated from the FRE)",
    )
    reg.add_argument(
        "--untagged-space",
        type=str.upper,
        choices=("RAS", "LPS"),
        default="RAS",
        help="frame of files that do not state one (default RAS)",
    )
    reg.add_argument(
        "--json",
        type=Path,
        help=f"write the full result as JSON (also when the result fails a check: exit code {EXIT_ALARM})",
    )
    reg.set_defaults(run=_run_register)

    demo = commands.add_parser(
        "demo", help="CR, CR-ICP, CR-RAMSICP and cr-fused on a virtual patient from a real bone (tibia or ilium)"
    )
    demo.add_argument("--trials", type=_COUNT, default=50, help="number of simulated registrations (default 50)")
    demo.add_argument("--seed", type=_SEED, default=0, help="random seed (default 0)")
    demo.add_argument("--bone", choices=tuple(BONES), default="right-tibia")
    demo.add_argument(
        "--image-source",
        choices=("ct", "mesh"),
        default="ct",
        help="ct: IPC and marker centres from a CT phantom (default); mesh: IPC sampled on the mesh",
    )
    demo.add_argument("--json", type=Path, help="write every trial's TRE as JSON")
    demo.add_argument("--screenshot", type=Path, help="write a PNG of the last trial's registration (3-D view)")
    demo.add_argument(
        "--live",
        action="store_true",
        help="play one trial through the whole tracking chain: Vega simulator -> NDI driver -> "
        "OpenIGTLink server -> receiver (MRML) -> point collection -> cr-fused; needs the package's [live] extra "
        "(slicer-core, Python >= 3.10)",
    )
    demo.add_argument(
        "--record",
        type=Path,
        metavar="FILE",
        help="with --live: record the tracker feed to a PLUS sequence file (.igs.mha), for "
        "ramsicp-tracker-server --replay and ramsicp collect --recording",
    )
    demo.set_defaults(run=_run_demo)

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
        "--tip", type=_FINITE, nargs=3, required=True, metavar=("X", "Y", "Z"), help="the tip in the tool's frame (mm)"
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
    collect.set_defaults(run=_run_collect)

    ipc = commands.add_parser("ipc", help="CT -> image point cloud (IPC) and marker-sphere centres")
    ipc.add_argument("ct", help="CT volume: .nrrd, .nhdr, .nii, .nii.gz or a DICOM series folder")
    ipc.add_argument(
        "--threshold",
        type=_threshold,
        default=DEFAULT_THRESHOLD_HU,
        help=f"bone threshold in HU, or 'auto' (Otsu); default {DEFAULT_THRESHOLD_HU:g}",
    )
    ipc.add_argument("--spacing", type=_POSITIVE_MM, help="thin the IPC to about one point per this many mm")
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
    ipc.set_defaults(run=_run_ipc)

    # The phantom's numbers are checked by ReferenceBodyModel, rotated_direction and make_ct_phantom before any work.
    phantom = commands.add_parser(
        "phantom",
        help="write a CT phantom (NRRD) of a shipped bone with its ground truth",
        description="Writes ct.nrrd (LPS), truth.json (RAS, stated in the file), bone_surface.vtp (the true "
        "surface cut to the CT's field of view, LPS-tagged) and marker_centres.mrk.json. Markers are numbered 1 "
        "to 4 in the reference body's (NDI tool's) order.",
    )
    phantom.add_argument("--out", type=Path, required=True, help="folder for the phantom's files")
    phantom.add_argument("--bone", choices=tuple(BONES), default="right-tibia")
    phantom.add_argument("--seed", type=_SEED, default=0)
    phantom.add_argument("--noise", type=float, default=25.0, help="image noise, HU (default 25; low dose: 40-60)")
    marker = {"type": int, "choices": range(1, 5), "metavar": "N"}
    phantom.add_argument("--partial", **marker, help="make marker N (1-4) partial: a cap missing")
    phantom.add_argument("--deformed", **marker, help="make marker N (1-4) deformed: stretched by 20 %%")
    phantom.add_argument("--cut-marker", **marker, help="let the edge of the field of view cut marker N's sphere")
    for part, default_diameter in (("post", 3.0), ("frame", 6.0)):
        phantom.add_argument(
            f"--{part}-material",
            choices=BODY_MATERIALS,
            default="plastic",
            help=f"the reference body's {part}s: plastic (150 HU, below the bone threshold; default), "
            "dense-polymer (1000 HU) or aluminium (2500 HU): then spheres, posts and frame are one bright object",
        )
        phantom.add_argument(
            f"--{part}-diameter", type=float, default=default_diameter, help=f"mm (default {default_diameter:g})"
        )
    phantom.add_argument(
        "--post-length", type=float, default=12.0, help="from the sphere's centre to the frame, mm (default 12)"
    )
    phantom.add_argument(
        "--metal",
        choices=("none", "pin"),
        default="none",
        help="pin: a 5 mm steel pin through the shaft where the bracket is clamped, with streak artefacts",
    )
    phantom.add_argument(
        "--oblique",
        type=float,
        default=0.0,
        metavar="DEG",
        help="turn the scanner grid by DEG about an oblique axis (a non-identity direction matrix)",
    )
    phantom.set_defaults(run=_run_phantom)

    plan = commands.add_parser(
        "plan",
        help="plan an osteotomy cut on the IPC: its four endpoints and the tool path (image, or robot base)",
        description="Writes the cut's plane, its four endpoints on the bone (plane x bone) and the tool path (TCP "
        "poses, 4 x 4) as JSON, in image (RAS) mm, and in robot-base coordinates with --image-to-robot-base. The "
        "bone's section is exact when the IPC is a surface with triangles (as ramsicp ipc writes it).",
    )
    plan.add_argument("--ipc", required=True, help="image point cloud: .vtk .vtp .stl .ply .obj or a point file")
    plan.add_argument(
        "--plane",
        type=float,
        nargs=6,
        required=True,
        metavar=("X", "Y", "Z", "NX", "NY", "NZ"),
        help="a point of the cut plane (its middle) and its normal, RAS mm",
    )
    plan.add_argument(
        "--depth",
        type=float,
        nargs=3,
        metavar=("DX", "DY", "DZ"),
        help="the direction the blade advances, from its entry side (default: across the bone's narrowest width)",
    )
    plan.add_argument("--extent", type=float, metavar="MM", help="the cut's width across the bone (default: all)")
    plan.add_argument(
        "--wedge", type=_FINITE, default=0.0, metavar="DEG", help="a closing wedge: the second cut's angle"
    )
    plan.add_argument("--tool", choices=TOOLS, default="saw")
    plan.add_argument(
        "--tool-width",
        type=float,
        metavar="MM",
        help=f"blade width or burr diameter (default {DEFAULT_TOOL_WIDTH_MM['saw']:g} mm saw, "
        f"{DEFAULT_TOOL_WIDTH_MM['burr']:g} mm burr)",
    )
    plan.add_argument(
        "--far-margin",
        type=float,
        default=DEFAULT_FAR_MARGIN_MM,
        metavar="MM",
        help=f"stop this far before the far cortex (default {DEFAULT_FAR_MARGIN_MM:g} mm)",
    )
    plan.add_argument(
        "--image-to-robot-base",
        type=Path,
        metavar="MATRIX_FILE",
        help="ImageToRobotBase (eq. 4): 4 rows of 4 numbers (.txt/.csv), or JSON (a 4 x 4 list, or an object with "
        "'image_to_robot_base')",
    )
    plan.add_argument("--untagged-space", choices=("RAS", "LPS"), default="RAS", help="frame of an untagged IPC file")
    plan.add_argument("--out", type=Path, required=True, help="the plan, JSON")
    plan.set_defaults(run=_run_plan)

    tcp = commands.add_parser(
        "tcp",
        help="the robot's tool-centre point by the four-point method, from flange poses",
        description="Each flange pose (FlangeToRobotBase from the robot's kinematics) is taken with the TCP held on "
        "one fixed point, the flange turned differently each time (4 or more poses, turns about two axes).",
    )
    tcp.add_argument(
        "--flange-poses",
        type=Path,
        required=True,
        help="JSON list of 4 x 4 matrices, or text with one pose a line (16 numbers, row by row), mm",
    )
    tcp.add_argument("--json", type=Path, help="write the TCP, the fixed point and the residuals as JSON")
    tcp.set_defaults(run=_run_tcp)

    cut = commands.add_parser(
        "cut-demo",
        help="a simulated osteotomy through the whole chain: planned vs executed endpoints (Fig. 6b), guidance",
        description="Registers one demo trial (cr-fused), calibrates the robot (eq. 3, the four-point TCP), sends the "
        "planned tool path over OpenIGTLink to the robot simulator, follows the tracked blade with the live "
        "guidance, and compares the executed cut's endpoints with the planned ones. Writes cut_result.json, "
        "cut_result.png (the cut in its plane, the endpoint errors) and guidance.png (what the surgeon sees).",
    )
    cut.add_argument("--bone", choices=tuple(name for name, bone in BONES.items() if bone["anatomy"] == "long-bone"),
                     default="right-tibia")  # fmt: skip
    cut.add_argument("--seed", type=_SEED, default=0)
    cut.add_argument("--speed", type=_SPEED, default=20.0, help="the robot's TCP speed, mm/s (default 20)")
    cut.add_argument("--out", type=Path, default=Path("cut"), help="folder for the results (default ./cut)")
    cut.set_defaults(run=_run_cut_demo)

    reproduce = commands.add_parser(
        "reproduce", help="the paper's experiments (Figs. 7-10) on CT phantoms of four bones, with cr-fused"
    )
    reproduce.add_argument("--experiment", choices=(*EXPERIMENTS, "all"), default="all")
    reproduce.add_argument("--trials", type=_COUNT, help="repetitions per condition (default: the paper's)")
    reproduce.add_argument(
        "--subjects",
        type=_COUNT,
        default=DEFAULT_SUBJECTS,
        help=f"virtual patients, the bones {', '.join(SUBJECT_BONES)} in turn (default {DEFAULT_SUBJECTS})",
    )
    reproduce.add_argument("--seed", type=_SEED, default=0)
    reproduce.add_argument("--image-source", choices=("ct", "mesh"), default="ct")
    reproduce.add_argument(
        "--out", type=Path, default=Path("reproduction"), help="folder for report.md, results.json, PNGs"
    )
    reproduce.set_defaults(run=_run_reproduce)

    web = commands.add_parser(
        "web",
        help="the navigation view in a web browser (trame-slicer): tracker, pivot, points, registration, verification",
        description="Serve the surgeon's navigation view to a browser on this machine (a second screen or a tablet). "
        "The page opens no file: the scene comes from --scene or --demo, and saves go into --output.",
    )
    source = web.add_mutually_exclusive_group()
    source.add_argument(
        "--demo",
        action="store_true",
        help="the demo patient's CT phantom and, without --tracker, a simulated tracker (pivot, then 40 touches)",
    )
    source.add_argument("--scene", type=Path, help="a Slicer scene to navigate on (.mrb, or .mrml with its files)")
    web.add_argument(
        "--tracker", metavar="HOST:PORT", help="OpenIGTLink server of the tracker (PLUS or ramsicp-tracker-server)"
    )
    web.add_argument(
        "--host", default="127.0.0.1", help="address to serve the page on (default 127.0.0.1: this machine only)"
    )
    web.add_argument(
        "--port", type=int, default=8080, help="port to serve the page on (default 8080; 0: any free port)"
    )
    web.add_argument(
        "--output",
        type=Path,
        default=Path("ramsicp-web"),
        help="folder for the autosaved points and the saved scenes (default ./ramsicp-web)",
    )
    web.set_defaults(run=_run_web)
    return parser


def _run_register(arguments):
    from .core.registration import register
    from .core.surface_index import SurfaceIndex
    from .core.sweep import make_scales
    from .io.point_files import read_points
    from .io.surface_files import read_surface_points

    space = arguments.untagged_space
    if (arguments.targets_image is None) != (arguments.targets_patient is None):
        raise ValueError("give --targets-image and --targets-patient together")
    scales = make_scales(*arguments.scales)
    inputs = (arguments.ipc, arguments.ppc, arguments.markers_image, arguments.markers_patient)
    inputs += (arguments.targets_image, arguments.targets_patient)
    check_output_file(arguments.json, "--json", (".json",), inputs)
    clock = time.perf_counter()
    ipc = read_surface_points(arguments.ipc, space)
    ppc = read_points(arguments.ppc, space).points
    markers_image, markers_patient, marker_warnings = _read_markers_pair(arguments, space)
    targets_image = targets_patient = None
    if arguments.targets_image:
        targets_image = read_points(arguments.targets_image, space).points
        targets_patient = read_points(arguments.targets_patient, space).points
    result = register(
        SurfaceIndex(ipc),
        ppc,
        markers_image,
        markers_patient,
        targets_image,
        targets_patient,
        method=arguments.method or (DEFAULT_METHOD if _default_method_fits(arguments) else "cr-ramsicp"),
        scale=arguments.scale,
        sweep=arguments.sweep,
        scales=scales,
        policy=arguments.policy,
        fle_mm=arguments.fle,
    )
    seconds = time.perf_counter() - clock
    if arguments.json:  # written before anything is printed: a reader that leaves early loses nothing
        document = result.to_dict()
        document["warnings"] = marker_warnings + document["warnings"]
        document["seconds"] = seconds
        arguments.json.write_text(json.dumps(document, indent=2), encoding="utf-8")
    loud = marker_warnings + list(result.alarms)
    print("".join(f"WARNING: {warning}\n" for warning in loud) + _format_result(result, len(ipc), seconds))
    if result.alarms:
        print(
            f"ramsicp register: the result failed {len(result.alarms)} check(s) (WARNING above); it is printed"
            + (f" and written to {arguments.json}" if arguments.json else "")
            + f", and the exit code is {EXIT_ALARM}",
            file=sys.stderr,
        )
        return EXIT_ALARM
    return 0


def _read_markers_pair(arguments, space):
    """Image and patient marker centres, paired by marker number; flagged ones refused unless accepted.

    Returns (markers_image (K, 3), markers_patient (K, 3), warnings): a warning for each flagged marker used.
    """
    from .io.marker_files import flagged_message, pair_markers, read_markers

    image = read_markers(arguments.markers_image, space)
    patient = read_markers(arguments.markers_patient, space)
    markers_image, markers_patient, _ = pair_markers(image, patient)
    if not image.flagged():
        return markers_image, markers_patient, []
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
        [
            f"{flagged} in {arguments.markers_image} (flagged by ramsicp ipc), used as you asked: the coarse "
            "registration may be off by that sphere's error"
        ],
    )


def _default_method_fits(arguments):
    """--scale, --sweep and --policy are RAMSICP's: without --method they ask for cr-ramsicp."""
    return arguments.scale is None and not arguments.sweep and arguments.policy is None


def _format_result(result, ipc_count, seconds):
    lines = []
    method = result.method.upper()
    if result.method == "cr-ramsicp":
        method += f" (L = {result.scale:g}, chosen by '{result.scale_policy}')"
    if result.iterations is not None:
        method += f", {result.iterations} iterations" + ("" if result.converged else " (not converged)")
    lines.append(f"method            {method}")
    lines.append(f"point clouds      {ipc_count} IPC points, {len(result.residuals_mm)} probe points; {seconds:.2f} s")
    lines.append(f"FRE (markers)     {result.fre_mm:.2f} mm  [{_numbers(result.marker_residuals_mm)}]")
    worst = int(np.argmax(result.residuals_mm))
    lines.append(
        f"probe points RMS  {result.ppc_rms_mm:.2f} mm to the surface "
        f"(worst: point {worst}, {result.residuals_mm[worst]:.2f} mm)"
    )
    weights = result.fused_weights
    if weights is not None:
        lines.append(f"weights           {weights.describe()}")
    if result.tre_mm is not None:
        lines.append(f"TRE (eq. 11)      {result.tre_mm:.2f} mm  [{_numbers(result.target_errors_mm)}]")
        if result.predicted_tre_mm is not None:
            lines.append(
                f"predicted TRE     {result.predicted_tre_rms_mm:.2f} mm  [{_numbers(result.predicted_tre_mm)}] "
                "from the fused fit's covariance"
            )
        lines.append(f"predicted CR TRE  [{_numbers(result.predicted_cr_tre_mm)}] mm for FLE {result.fle_mm:.2f} mm")
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


def _numbers(values):
    return " ".join(f"{value:.2f}" for value in values)


class _ProgressBar:
    """A one-line progress bar on stderr, drawn only when stderr is a terminal."""

    def __init__(self, stream=sys.stderr, width=30):
        self.stream, self.width, self.step = stream, width, None

    def __call__(self, step, done, total):
        if not self.stream.isatty():
            return
        filled = int(self.width * done / max(total, 1))
        print(
            f"\r  {step:<22} [{'#' * filled}{'.' * (self.width - filled)}] {done}/{total}",
            end="",
            file=self.stream,
            flush=True,
        )
        if done >= total:
            print(file=self.stream)


def _run_demo(arguments):
    if arguments.record is not None and not arguments.live:
        raise ValueError("--record records the tracker feed: use it with --live")
    if arguments.live and (arguments.json or arguments.screenshot):
        raise ValueError("--json and --screenshot report the simulated trials; the live demo (--live) writes neither")
    check_output_file(arguments.record, "--record", (".mha",))
    check_output_file(arguments.json, "--json", (".json",))
    check_output_file(arguments.screenshot, "--screenshot", (".png",))
    if arguments.live:
        return _run_live_demo(arguments)
    from .experiments.demo import run_demo

    clock = time.perf_counter()
    report = run_demo(
        trials=arguments.trials,
        seed=arguments.seed,
        bone=arguments.bone,
        image_source=arguments.image_source,
        progress=_ProgressBar(),
        screenshot=arguments.screenshot,
    )
    total = time.perf_counter() - clock
    if arguments.json:  # written before anything is printed: a reader that leaves early loses nothing
        document = report.to_dict()
        document["seconds"]["total"] = total
        arguments.json.write_text(json.dumps(document, indent=2), encoding="utf-8")
    print(_format_demo(report, total))
    return 0


def _format_demo(report, total_seconds):
    from .experiments.demo import FUSED_LABEL, MARKER_MODES, PAPER_ROWS, PAPER_TRE_MM
    from .simulation.virtual_patient import LAYOUT_WORDS

    bone = BONES[report.bone]
    words = LAYOUT_WORDS[bone["anatomy"]]
    side = report.image_side
    lines = [f"RAMSICP Navigator demo: virtual patient from the {report.bone.replace('-', ' ')} of {bone['source']}"]
    if report.image_source == "ct":
        errors = side.marker_errors_mm
        lines.append(
            f"  image side from a CT phantom (0.5 x 0.5 x 0.625 mm): IPC {report.ipc_points:,} points "
            f"(median {side.ipc_offset_mm:+.2f} mm from the true surface); automatic marker centres "
            f"off by {errors.mean():.3f} mm mean, {errors.max():.3f} mm max"
        )
    else:
        lines.append(f"  IPC {report.ipc_points:,} points sampled on the bone mesh")
    lines += [
        f"  PPC {report.probe_points} probe points in 8 sub-areas x 5 on {words['probe']}; probe noise "
        f"{report.probe_noise_mm:.2f} mm RMS; reference body NDI 8700339 (4 spheres, 11.5 mm)",
        f"  manual marker placement error {report.marker_fle_mm:.2f} mm RMS (set for the paper's CR TRE); "
        f"4 targets at {words['targets']}, each the mean of 10 touches ({report.target_noise_mm:.2f} mm RMS); "
        f"{report.trials} trials, seed {report.seed}",
    ]
    for mode, rows in report.summary().items():
        lines += [
            "",
            f"  {MARKER_MODES[mode]}",
            f"  {'method':<42} {'TRE mean +- sd (mm)':>20}   {'paper (mm)':>12}   {'predicted (mm)':>14}",
        ]
        for label, (mean, sd) in rows.items():
            paper = PAPER_TRE_MM.get(PAPER_ROWS.get(label)) if mode == "manual" else None
            paper_text = f"{paper[0]:.2f} +- {paper[1]:.2f}" if paper else ""
            predicted = report.predicted_tre_mm[mode] if label == FUSED_LABEL else None
            predicted_text = f"{np.mean(predicted):.2f}" if predicted is not None else ""
            lines.append(f"  {label:<42} {mean:>9.2f} +- {sd:<8.2f}   {paper_text:>12}   {predicted_text:>14}")
        lines.append(
            "  mean L chosen by policy: "
            + ", ".join(f"{policy} {np.mean(values):.1f}" for policy, values in report.chosen_scales[mode].items())
        )
        lines.append(
            f"  cr-fused: measured / predicted RMS TRE {report.calibration(mode):.2f} (1 = calibrated; the targets' "
            f"own {report.target_noise_mm:.2f} mm counted); it warned in {report.fused_warnings[mode]} of "
            f"{report.trials} trials"
        )
    seconds = report.seconds
    image_seconds = ", ".join(f"{name.replace('_', ' ')} {value:.1f} s" for name, value in side.seconds.items())
    lines += [
        "",
        f"  time: {total_seconds:.1f} s in all"
        + (f" ({image_seconds})" if image_seconds else "")
        + f"; KD-tree {1000 * seconds['kd_tree_build']:.0f} ms once; "
        f"{1000 * seconds['per_trial_and_mode']:.0f} ms per trial for CR + CR-ICP + a 21-value RAMSICP sweep "
        "+ cr-fused",
    ]
    return "\n".join(lines)


def _run_live_demo(arguments):
    try:
        import slicer
    except ImportError:
        raise ValueError(
            "the live demo writes real MRML transform nodes: pip install 'ramsicp-navigator[live]' "
            "(slicer-core, Python >= 3.10)"
        ) from None
    from OpenIGTLinkBridgeLib.live_demo import run_live_demo

    from .core.surface_index import SurfaceIndex
    from .experiments.demo import PAPER_TRE_MM, PROBE_NOISE_MM, ct_image_side
    from .simulation.package_data import shipped_patient

    clock = time.perf_counter()
    patient, vertices, triangles = shipped_patient(arguments.bone, arguments.seed)
    ipc = patient.ipc
    if arguments.image_source == "ct":
        ipc = ct_image_side(patient, vertices, triangles, arguments.seed, _ProgressBar()).ipc
    fle = patient.marker_fle_for_cr_tre(PAPER_TRE_MM["CR"][0], seed=arguments.seed)
    trial = patient.simulate_trial(np.random.default_rng(arguments.seed + 1), fle, probe_noise_mm=0.0)
    result = run_live_demo(
        slicer.vtkMRMLScene(),
        patient,
        SurfaceIndex(ipc),
        trial,
        PROBE_NOISE_MM,
        progress=_ProgressBar(),
        record=arguments.record,
    )
    error = result.collection_error_mm
    print(
        f"live: {len(result.collected)} of {len(result.touched)} points collected from {result.frames} probe frames "
        f"in {result.seconds:.1f} s (Vega simulator -> NDI driver -> OpenIGTLink -> MRML receiver)"
    )
    print(f"  collected points vs the true touches: {np.sqrt(np.mean(error**2)):.2f} mm RMS, {error.max():.2f} mm max")
    for label, registered in (("live points", result.live), ("exact touches", result.reference)):
        print(
            f"  {registered.method.upper()} on the {label:<14} TRE {registered.tre_mm:.2f} mm "
            f"(predicted {registered.predicted_tre_rms_mm:.2f}), probe points {registered.ppc_rms_mm:.2f} mm RMS"
        )
    spreads = [touch.spread_mm for touch in result.touches]
    print(
        f"  touches held {np.mean([touch.duration_s for touch in result.touches]):.2f} s on average, "
        f"tip spread {np.median(spreads):.2f} mm RMS (median), {max(spreads):.2f} mm max"
    )
    if result.recording is not None:
        print(f"  recorded to {result.recording} (replay: ramsicp-tracker-server --replay {result.recording})")
    print(f"  total {time.perf_counter() - clock:.1f} s")
    return 0


def _run_collect(arguments):
    from OpenIGTLinkBridgeLib.plus_sequence import read_sequence
    from OpenIGTLinkBridgeLib.recorded_touches import find_recorded_touches, frame_timing

    from .core.hold_still import HoldStillDetector
    from .io.point_files import write_points

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


def _run_ipc(arguments):
    from .image.ct_pipeline import process_ct
    from .image.ct_segmentation import resample_points
    from .image.marker_spheres import sphere_labelmap
    from .image.volume_io import CTVolume, load_volume, save_nrrd
    from .io.marker_files import check_markers_path, write_markers
    from .io.ndi_tools import tool_marker_geometry
    from .io.point_files import _suffix, write_points
    from .io.surface_files import SURFACE_SUFFIXES, write_surface

    threshold = arguments.threshold
    check_output_file(arguments.out, "--out", SURFACE_SUFFIXES + POINT_SUFFIXES, [arguments.ct])
    check_output_file(arguments.markers, "--markers", inputs=[arguments.ct])
    if arguments.markers is not None:
        check_markers_path(arguments.markers)  # a file that keeps each marker's number and status
    check_output_file(arguments.labelmap, "--labelmap", (".nrrd",), [arguments.ct])
    check_output_file(arguments.json, "--json", (".json",), [arguments.ct])
    clock = time.perf_counter()
    volume = load_volume(arguments.ct)
    load_seconds = time.perf_counter() - clock
    tool = tool_marker_geometry(arguments.tool)
    image = process_ct(
        volume,
        threshold,
        fill_cavities=not arguments.keep_cavities,
        tool_markers=tool,
        progress=_ProgressBar(),
    )
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
        write_markers(arguments.markers, image.centres, [s.number for s in spheres], [s.status for s in spheres])
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
            "ipc_points_left_out_near_metal": image.surface.left_out,
            "warnings": warnings,
            "seconds": seconds,
        }
        arguments.json.write_text(json.dumps(document, indent=2), encoding="utf-8")
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


def _run_phantom(arguments):
    from .simulation.ct_painting import ReferenceBodyModel, rotated_direction
    from .simulation.ct_phantom import FILE_FRAMES, make_ct_phantom, write_phantom
    from .simulation.package_data import shipped_patient

    check_output_folder(arguments.out, "--out")
    defects = {}
    if arguments.partial is not None:
        defects[arguments.partial] = "partial"
    if arguments.deformed is not None:
        if arguments.deformed in defects:
            raise ValueError("--partial and --deformed name the same marker; pick two different ones")
        defects[arguments.deformed] = "deformed"
    direction = rotated_direction(arguments.oblique)
    body = ReferenceBodyModel(
        post_material=arguments.post_material,
        frame_material=arguments.frame_material,
        post_diameter_mm=arguments.post_diameter,
        post_length_mm=arguments.post_length,
        frame_diameter_mm=arguments.frame_diameter,
    )
    patient, vertices, triangles = shipped_patient(arguments.bone, arguments.seed)
    clock = time.perf_counter()
    volume, truth = make_ct_phantom(
        patient,
        vertices,
        triangles,
        seed=arguments.seed,
        noise_hu=arguments.noise,
        defects=defects,
        body=body,
        metal=None if arguments.metal == "none" else arguments.metal,
        direction=direction,
        cut_marker=arguments.cut_marker,
    )
    paths = write_phantom(arguments.out, volume, truth)
    shape = "x".join(str(n) for n in volume.voxels.shape)
    print(
        f"CT phantom of the {arguments.bone}: {shape} voxels of 0.5 x 0.5 x 0.625 mm, "
        f"{time.perf_counter() - clock:.1f} s"
    )
    for name, path in paths.items():
        print(f"  {name:<15} {path}  [{FILE_FRAMES[name]}]")
    print("  bone_surface.vtp is cut to the CT's field of view; markers are numbered 1-4 in the tool's order")
    return 0


def _run_reproduce(arguments):
    from .experiments.experiment_report import write_outputs
    from .experiments.experiments import run_experiments

    check_output_folder(arguments.out, "--out")
    clock = time.perf_counter()
    experiments = EXPERIMENTS if arguments.experiment == "all" else (arguments.experiment,)
    results = run_experiments(
        experiments,
        trials=arguments.trials,
        seed=arguments.seed,
        subjects=arguments.subjects,
        image_source=arguments.image_source,
        progress=_ProgressBar(),
    )
    results["settings"]["seconds"] = time.perf_counter() - clock
    paths = write_outputs(results, arguments.out)
    print(
        f"{len(experiments)} experiment(s) on {arguments.subjects} subject(s) in {results['settings']['seconds']:.0f} s"
    )
    for name, path in paths.items():
        print(f"  {name:<8} {path}")
    return 0


def _run_web(arguments):
    try:
        import trame_slicer  # noqa: F401
    except ImportError:
        raise ValueError(
            "the browser view needs trame-slicer: pip install 'ramsicp-navigator[web]' (Python >= 3.10)"
        ) from None
    from .web.app import (
        NavigationWebApp,
        check_output_directory,
        check_port_free,
        check_scene_path,
        parse_tracker_address,
    )

    tracker = None if arguments.tracker is None else parse_tracker_address(arguments.tracker)
    if arguments.scene is not None:
        check_scene_path(arguments.scene)
    check_output_directory(arguments.output)
    if not 0 <= arguments.port <= 65535:
        raise ValueError(f"--port {arguments.port}: give a port from 1 to 65535 (0: any free port)")
    check_port_free(arguments.host, arguments.port)  # before the slow set-up, so a busy port fails at once
    if arguments.host not in ("127.0.0.1", "localhost", "::1"):
        print(
            f"ramsicp web: warning: serving on {arguments.host}: anyone who can reach this address can drive the "
            "navigation; use a closed network, or the default 127.0.0.1",
            file=sys.stderr,
        )
    app = NavigationWebApp(arguments.output)
    if arguments.scene is not None:
        app.load_scene(arguments.scene)
    app.start_workflow()
    if arguments.demo:
        print("ramsicp web: building the demo patient's CT phantom and its IPC (about 30 s) ...", flush=True)
        app.add_demo_patient()
    if tracker is not None:
        app.connect_tracker(*tracker)
    elif arguments.demo:
        app.start_simulator()

    def ready(url):
        print(f"RAMSICP Navigator web view: {url}  (Ctrl+C to stop)", flush=True)

    app.serve(arguments.host, arguments.port, on_ready=ready)
    return 0


def _run_plan(arguments):
    from .core.tool_path import plan_document, plan_osteotomy
    from .io.point_files import _suffix, read_points
    from .io.surface_files import SURFACE_SUFFIXES, read_surface_mesh

    check_output_file(arguments.out, "--out", (".json",), [arguments.ipc, arguments.image_to_robot_base])
    image_to_base = None
    if arguments.image_to_robot_base is not None:
        image_to_base = _read_matrix(arguments.image_to_robot_base, "--image-to-robot-base")
    clock = time.perf_counter()
    triangles = None
    if _suffix(Path(arguments.ipc)) in SURFACE_SUFFIXES:
        points, triangles = read_surface_mesh(arguments.ipc, arguments.untagged_space)
    else:
        points = read_points(arguments.ipc, arguments.untagged_space).points
    plans, path = plan_osteotomy(
        points,
        arguments.plane[:3],
        arguments.plane[3:],
        depth=arguments.depth,
        extent_mm=arguments.extent,
        wedge_deg=arguments.wedge,
        triangles=triangles,
        tool=arguments.tool,
        width_mm=arguments.tool_width,
        far_margin_mm=arguments.far_margin,
    )
    document = plan_document(plans, path, image_to_base)
    arguments.out.write_text(json.dumps(document, indent=2), encoding="utf-8")
    section = "exact (mesh)" if plans[0].section.exact else "from the IPC points within 0.3 mm"
    print(f"IPC              {arguments.ipc}: {len(points):,} points; section {section}")
    for number, plan in enumerate(plans):
        plane = plan.plane
        name = "cut" if len(plans) == 1 else f"cut {number + 1}"
        width = "the whole bone" if plan.extent_mm is None else f"{plan.extent_mm:g} mm"
        print(
            f"{name:<17}origin ({_numbers(plane.origin)}) normal ({_numbers(plane.normal)}) depth "
            f"({_numbers(plane.depth)}); across {width}"
        )
        for label, word, point in zip(plan.endpoint_labels, plan.endpoint_directions, plan.endpoints):
            print(f"  {label:<15}({_numbers(point)})  {word}")
    print(
        f"tool path        {path.tool} {path.width_mm:g} mm: {len(path.poses)} poses in {path.passes} passes, "
        f"{path.length_mm:.0f} mm, stopping {path.far_margin_mm:g} mm before the far cortex"
    )
    frames = "image and robot base" if image_to_base is not None else "image"
    print(f"written          {arguments.out} ({frames} coordinates); {time.perf_counter() - clock:.2f} s")
    return 0


def _run_tcp(arguments):
    from .core.robot import tcp_four_point

    check_output_file(arguments.json, "--json", (".json",), [arguments.flange_poses])
    poses = _read_poses(arguments.flange_poses)
    result = tcp_four_point(poses)
    print(f"flange poses     {len(poses)} from {arguments.flange_poses}")
    print(f"TCP in flange    ({_numbers(result.tcp_in_flange)}) mm, {np.linalg.norm(result.tcp_in_flange):.2f} mm out")
    print(f"fixed point      ({_numbers(result.point_in_base)}) mm in the robot base")
    print(f"residuals        {_numbers(result.residuals_mm)} mm; RMS {result.rms_mm:.3f} mm")
    print(f"least turn       {result.spread_deg:.1f} degrees about any axis")
    if arguments.json:
        arguments.json.write_text(json.dumps(result.to_dict(), indent=2), encoding="utf-8")
    return 0


def _run_cut_demo(arguments):
    from .experiments.cut_plots import plot_cut_result
    from .experiments.cut_trial import run_cut_trial
    from .navigation.cut_render import render_guidance

    check_output_folder(arguments.out, "--out")
    arguments.out.mkdir(parents=True, exist_ok=True)
    result = run_cut_trial(arguments.bone, arguments.seed, arguments.speed, progress=_ProgressBar())
    document = result.to_dict()
    (arguments.out / "cut_result.json").write_text(json.dumps(document, indent=2), encoding="utf-8")
    plot_cut_result(result, arguments.out / "cut_result.png")
    render_guidance(
        arguments.out / "guidance.png",
        *result.mesh,
        [result.plan],
        result.blade_pose,
        result.blade_guidance,
        result.path["width_mm"],
        path_positions=result.path_positions,
    )
    path, streaming, calibration, guidance = result.path, result.streaming, result.calibration, result.guidance
    print(f"simulated osteotomy of the {arguments.bone.replace('-', ' ')} (seed {arguments.seed})")
    print(
        f"  tool path        {path['poses']} poses in {path['passes']} passes, {path['length_mm']:.0f} mm; sent as "
        f"{streaming['bytes']:,} bytes of OpenIGTLink and accepted in {1000 * streaming['sent_and_accepted_s']:.1f} ms "
        f"({streaming['poses_per_s']:,.0f} poses/s)"
    )
    print(
        f"  robot            {path['robot_steps']} steps at {arguments.speed:g} mm/s ({path['simulated_s']:.1f} s of "
        f"simulated time); eq. 3 off by {calibration['eq3_error_at_cut_mm']:.3f} mm at the cut, TCP off by "
        f"{calibration['tcp_error_mm']:.3f} mm (four-point RMS {calibration['tcp_rms_mm']:.3f} mm)"
    )
    print(
        f"  guidance         {guidance['frames']} tracked frames in the bone: tip "
        f"{guidance['tip_distance_mean_mm']:+.2f} mm on average (at most {guidance['tip_distance_max_mm']:.2f}), angle "
        f"at most {guidance['angle_max_deg']:.2f} deg, on plan {100 * guidance['on_plan_fraction']:.0f} % of the time"
    )
    print(
        f"  {'endpoint':<16} {'planned (x y z) mm':<24} {'executed (x y z) mm':<24} {'distance':>8} "
        f"{'along normal':>13}  registration error (predicted)"
    )
    for number, word in enumerate(result.directions):
        print(
            f"  E{number + 1} {word:<13} {'(' + _numbers(result.planned[number]) + ')':<24} "
            f"{'(' + _numbers(result.executed[number]) + ')':<24} {result.distance_mm[number]:8.2f} "
            f"{result.normal_mm[number]:+13.2f}  {result.registration_error_mm[number]:.2f} "
            f"({result.predicted_error_mm[number]:.2f})"
        )
    print(f"  RMS {result.rms_mm:.2f} mm; the executed plane is tilted {result.tilt_deg:.2f} deg from the planned one")
    print(f"  written to {arguments.out}: cut_result.json, cut_result.png, guidance.png; {result.seconds:.1f} s")
    return 0


def _read_matrix(path, option):
    """A (4, 4) matrix from a text file (4 rows of 4 numbers) or JSON; ValueError in one line."""
    values = _read_numbers(path, option)
    if isinstance(values, dict):
        values = values.get("image_to_robot_base", values.get("robot_base", {}).get("image_to_robot_base"))
    try:
        matrix = np.array(values, dtype=np.float64)
    except (TypeError, ValueError):
        matrix = np.zeros(0)
    if matrix.shape != (4, 4):
        raise ValueError(f"{option} {path}: expected a 4 x 4 matrix (4 rows of 4 numbers), got shape {matrix.shape}")
    return as_transform(matrix, f"{option} {path}")


def _read_poses(path):
    """(N, 4, 4) poses from JSON (a list of 4 x 4) or text (16 numbers a line, row by row)."""
    values = _read_numbers(path, "--flange-poses")
    try:
        poses = np.array(values, dtype=np.float64)
    except (TypeError, ValueError):
        poses = np.zeros(0)
    if poses.ndim == 2 and poses.shape[1] == 16:
        poses = poses.reshape(-1, 4, 4)
    if poses.ndim == 1 and poses.size == 16:
        poses = poses.reshape(1, 4, 4)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ValueError(f"--flange-poses {path}: expected 4 x 4 poses (16 numbers a line), got shape {poses.shape}")
    return poses


def _read_numbers(path, option):
    check_input_file(path, f"{option} file")
    text = path.read_text(encoding="utf-8", errors="replace")
    if path.suffix.lower() == ".json":
        try:
            return json.loads(text)
        except json.JSONDecodeError as error:
            raise ValueError(f"{option} {path}: not valid JSON ({error.msg}, line {error.lineno})") from None
    rows = [line.replace(",", " ").split() for line in text.splitlines() if line.strip() and not line.startswith("#")]
    try:
        return [[float(value) for value in row] for row in rows]
    except ValueError as error:
        raise ValueError(f"{option} {path}: {error}; give numbers only") from None


if __name__ == "__main__":
    sys.exit(main())
