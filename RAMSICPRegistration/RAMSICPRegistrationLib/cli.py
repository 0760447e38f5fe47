"""The ``ramsicp`` command line: ``register`` files, or run the ``demo``. It owns the console."""

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np

from . import __version__
from .demo import PAPER_ROWS, PAPER_TRE_MM, run_demo
from .package_data import BONES
from .point_files import read_points
from .registration import METHODS, POLICIES, register
from .surface_files import read_surface_points
from .surface_index import SurfaceIndex
from .sweep import make_scales

EXIT_BAD_INPUT = 2


def main(argv=None):
    """Entry point of the console script; returns the process exit code."""
    parser = _parser()
    arguments = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if arguments.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return arguments.run(arguments)
    except (ValueError, OSError) as error:
        message = " ".join(str(error).split())
        print(f"ramsicp {arguments.command}: error: {message}", file=sys.stderr)
        return EXIT_BAD_INPUT


def _parser():
    parser = argparse.ArgumentParser(prog="ramsicp", description="CR-RAMSICP patient-to-image registration "
                                     "for robot-assisted long-bone osteotomy.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log what happens")
    commands = parser.add_subparsers(dest="command", required=True)

    reg = commands.add_parser("register", help="register probe points and markers to an image point cloud",
                              description="Coordinates: files that state their frame (markups JSON, fcsv, model "
                              "headers) are honoured; others are taken as --untagged-space.")
    reg.add_argument("--ipc", required=True, help="image point cloud: .vtk .vtp .stl .ply .obj or a point file")
    reg.add_argument("--ppc", required=True, help="probe points in reference coordinates (.mrk.json .fcsv .csv .txt .npy)")
    reg.add_argument("--markers-image", required=True, help="marker-sphere centres in the image")
    reg.add_argument("--markers-patient", required=True, help="the same centres in reference coordinates")
    reg.add_argument("--targets-image", help="target points in the image (for the TRE)")
    reg.add_argument("--targets-patient", help="the same targets in reference coordinates")
    reg.add_argument("--method", choices=METHODS, default="cr-ramsicp")
    how = reg.add_mutually_exclusive_group()
    how.add_argument("--scale", type=float, help="scale factor L for one RAMSICP run (default 5)")
    how.add_argument("--sweep", action="store_true", help="run L = 1..5 step 0.2 and choose L by --policy")
    reg.add_argument("--scales", nargs=3, type=float, metavar=("START", "STOP", "STEP"), default=(1.0, 5.0, 0.2),
                     help="the sweep's range (default 1 5 0.2)")
    reg.add_argument("--policy", choices=POLICIES,
                     help="how the sweep picks L (default: targets when targets are given, else rms-plateau)")
    reg.add_argument("--fle", type=float, help="marker localisation error (mm) for the predicted TRE "
                     "(default: estimated from the FRE)")
    reg.add_argument("--untagged-space", choices=("RAS", "LPS"), default="RAS",
                     help="frame of files that do not state one (default RAS)")
    reg.add_argument("--json", type=Path, help="write the full result as JSON")
    reg.set_defaults(run=_run_register)

    demo = commands.add_parser("demo", help="CR, CR-ICP and CR-RAMSICP on a virtual patient from a real tibia")
    demo.add_argument("--trials", type=int, default=50, help="number of simulated registrations (default 50)")
    demo.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    demo.add_argument("--bone", choices=tuple(BONES), default="right-tibia")
    demo.add_argument("--json", type=Path, help="write every trial's TRE as JSON")
    demo.set_defaults(run=_run_demo)
    return parser


def _run_register(arguments):
    space = arguments.untagged_space
    if (arguments.targets_image is None) != (arguments.targets_patient is None):
        raise ValueError("give --targets-image and --targets-patient together")
    clock = time.perf_counter()
    ipc = read_surface_points(arguments.ipc, space)
    ppc = read_points(arguments.ppc, space).points
    markers_image = read_points(arguments.markers_image, space).points
    markers_patient = read_points(arguments.markers_patient, space).points
    targets_image = targets_patient = None
    if arguments.targets_image:
        targets_image = read_points(arguments.targets_image, space).points
        targets_patient = read_points(arguments.targets_patient, space).points
    result = register(SurfaceIndex(ipc), ppc, markers_image, markers_patient, targets_image, targets_patient,
                      method=arguments.method, scale=arguments.scale, sweep=arguments.sweep,
                      scales=make_scales(*arguments.scales), policy=arguments.policy, fle_mm=arguments.fle)
    seconds = time.perf_counter() - clock
    print(_format_result(result, len(ipc), seconds))
    if arguments.json:
        document = result.to_dict()
        document["seconds"] = seconds
        arguments.json.write_text(json.dumps(document, indent=2), encoding="utf-8")
    return 0


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
    lines.append(f"probe points RMS  {result.ppc_rms_mm:.2f} mm to the surface "
                 f"(worst: point {worst}, {result.residuals_mm[worst]:.2f} mm)")
    if result.tre_mm is not None:
        lines.append(f"TRE (eq. 11)      {result.tre_mm:.2f} mm  [{_numbers(result.target_errors_mm)}]")
        lines.append(f"predicted CR TRE  [{_numbers(result.predicted_cr_tre_mm)}] mm for FLE {result.fle_mm:.2f} mm")
    lines.append("ReferenceToImage")
    lines.extend("  " + "  ".join(f"{value:11.5f}" for value in row) for row in result.reference_to_image)
    if result.sweep:
        lines.append("sweep     L   RMS (mm)   TRE (mm)   iterations")
        for entry in result.sweep:
            tre = "-" if entry.tre_mm is None else f"{entry.tre_mm:.3f}"
            mark = "  <- chosen" if entry.scale == result.scale else ""
            lines.append(f"      {entry.scale:5.1f}   {entry.result.rms_mm:8.3f}   {tre:>8}   {entry.result.iterations:10d}{mark}")
    for warning in result.warnings:
        lines.append(f"warning: {warning}")
    return "\n".join(lines)


def _numbers(values):
    return " ".join(f"{value:.2f}" for value in values)


def _run_demo(arguments):
    def progress(done, total):
        if sys.stderr.isatty():
            filled = int(30 * done / total)
            print(f"\r  trials [{'#' * filled}{'.' * (30 - filled)}] {done}/{total}", end="", file=sys.stderr,
                  flush=True)
            if done == total:
                print(file=sys.stderr)

    clock = time.perf_counter()
    report = run_demo(trials=arguments.trials, seed=arguments.seed, bone=arguments.bone, progress=progress)
    total = time.perf_counter() - clock
    print(_format_demo(report, total))
    if arguments.json:
        document = report.to_dict()
        document["seconds"]["total"] = total
        arguments.json.write_text(json.dumps(document, indent=2), encoding="utf-8")
    return 0


def _format_demo(report, total_seconds):
    bone = report.bone.replace("-", " ")
    lines = [
        f"RAMSICP Navigator demo: virtual patient from the Visible Human Female {bone} (CC BY 4.0)",
        f"  IPC {report.ipc_points:,} surface points; PPC {report.probe_points} probe points in 8 sub-areas x 5 "
        f"on the medial shaft; probe noise {report.probe_noise_mm:.2f} mm RMS",
        f"  reference body NDI 8700339 (4 spheres, 11.5 mm); marker placement error {report.marker_fle_mm:.2f} mm "
        "RMS (set for the paper's CR TRE)",
        f"  4 targets on a high tibial osteotomy cut; {report.trials} trials, seed {report.seed}",
        "",
        f"  {'method':<42} {'TRE mean +- sd (mm)':>20}   {'paper (mm)':>12}",
    ]
    for label, (mean, sd) in report.summary().items():
        paper = PAPER_TRE_MM.get(PAPER_ROWS.get(label))
        paper_text = f"{paper[0]:.2f} +- {paper[1]:.2f}" if paper else ""
        lines.append(f"  {label:<42} {mean:>9.2f} +- {sd:<8.2f}   {paper_text:>12}")
    seconds = report.seconds
    lines += [
        "",
        "  mean L chosen by policy: " + ", ".join(f"{policy} {np.mean(values):.1f}"
                                                  for policy, values in report.chosen_scales.items()),
        f"  time: {total_seconds:.1f} s in all (set-up {seconds['setup']:.1f} s, KD-tree "
        f"{1000 * seconds['kd_tree_build']:.0f} ms once, {1000 * seconds['per_trial_mean']:.0f} ms per trial "
        "for CR + CR-ICP + a 21-value RAMSICP sweep)",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
