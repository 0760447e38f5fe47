"""``ramsicp demo``: CR, CR-ICP, CR-RAMSICP and cr-fused on a virtual patient made from a real bone, against the
paper's figures; ``--live`` plays one trial through the whole tracking chain."""

import time
from pathlib import Path

import numpy as np

from ..io.atomic_files import write_json_atomic
from ..io.file_checks import check_output_file
from ..simulation.package_data import BONES
from ._arguments import COUNT, SEED
from ._console import Progress


def add_parser(commands):
    demo = commands.add_parser(
        "demo",
        help="CR, CR-ICP, CR-RAMSICP and cr-fused on a virtual patient from a real bone (tibia or ilium)",
        description="Builds a virtual patient from a shipped bone (a CT phantom with a reference body, its IPC "
        "and marker centres found automatically), simulates --trials registrations with the paper's marker "
        "error and 40 probe points in 8 sub-areas, and prints each method's TRE (eq. 11) beside the paper's, "
        "with markers placed by hand and found automatically.",
    )
    demo.add_argument("--trials", type=COUNT, default=50, help="number of simulated registrations (default 50)")
    demo.add_argument("--seed", type=SEED, default=0, help="random seed (default 0)")
    demo.add_argument(
        "--bone", choices=tuple(BONES), default="right-tibia", help="the shipped bone (default right-tibia)"
    )
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
    demo.set_defaults(run=run)


def run(arguments):
    if arguments.record is not None and not arguments.live:
        raise ValueError("--record records the tracker feed: use it with --live")
    if arguments.live and (arguments.json or arguments.screenshot):
        raise ValueError("--json and --screenshot report the simulated trials; the live demo (--live) writes neither")
    check_output_file(arguments.record, "--record", (".mha",))
    check_output_file(arguments.json, "--json", (".json",))
    check_output_file(arguments.screenshot, "--screenshot", (".png",))
    if arguments.live:
        return _run_live_demo(arguments)
    from ..experiments.demo import run_demo

    clock = time.perf_counter()
    report = run_demo(
        trials=arguments.trials,
        seed=arguments.seed,
        bone=arguments.bone,
        image_source=arguments.image_source,
        progress=Progress(),
        screenshot=arguments.screenshot,
    )
    total = time.perf_counter() - clock
    if arguments.json:  # written before anything is printed: a reader that leaves early loses nothing
        document = report.to_dict()
        document["seconds"]["total"] = total
        write_json_atomic(arguments.json, document)
    print(_format_demo(report, total))
    return 0


def _format_demo(report, total_seconds):
    from ..experiments.demo import FUSED_LABEL, MARKER_MODES, PAPER_ROWS, PAPER_TRE_MM
    from ..simulation.virtual_patient import LAYOUT_WORDS

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
        f"{1000 * seconds['per_trial_and_mode']:.0f} ms per trial for CR + CR-ICP (point to point and to plane) + a "
        "21-value RAMSICP sweep "
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

    from ..core.surface_index import SurfaceIndex
    from ..experiments.demo import PAPER_TRE_MM, PROBE_NOISE_MM, ct_image_side
    from ..simulation.package_data import shipped_patient

    clock = time.perf_counter()
    patient, vertices, triangles = shipped_patient(arguments.bone, arguments.seed)
    ipc = patient.ipc
    if arguments.image_source == "ct":
        ipc = ct_image_side(patient, vertices, triangles, arguments.seed, Progress()).ipc
    fle = patient.marker_fle_for_cr_tre(PAPER_TRE_MM["CR"][0], seed=arguments.seed)
    trial = patient.simulate_trial(np.random.default_rng(arguments.seed + 1), fle, probe_noise_mm=0.0)
    result = run_live_demo(
        slicer.vtkMRMLScene(),
        patient,
        SurfaceIndex(ipc),
        trial,
        PROBE_NOISE_MM,
        progress=Progress(),
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
