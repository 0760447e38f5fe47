"""``ramsicp cut-demo``: a simulated osteotomy through the whole chain (registration, robot calibration, the tool
path over OpenIGTLink, live guidance), planned against executed endpoints (the paper's Fig. 6b)."""

from pathlib import Path

from ..io.atomic_files import write_json_atomic
from ..io.file_checks import check_output_folder
from ..simulation.package_data import BONES
from ._arguments import SEED, SPEED
from ._console import Progress, decimals


def add_parser(commands):
    cut = commands.add_parser(
        "cut-demo",
        help="a simulated osteotomy through the whole chain: planned vs executed endpoints (Fig. 6b), guidance",
        description="Registers one demo trial (cr-fused), calibrates the robot (eq. 3, the four-point TCP), sends the "
        "planned tool path over OpenIGTLink to the robot simulator, follows the tracked blade with the live "
        "guidance, and compares the executed cut's endpoints with the planned ones. Writes cut_result.json, "
        "cut_result.png (the cut in its plane, the endpoint errors) and guidance.png (what the surgeon sees).",
    )
    long_bones = tuple(name for name, bone in BONES.items() if bone["anatomy"] == "long-bone")
    cut.add_argument("--bone", choices=long_bones, default="right-tibia", help="a long bone (default right-tibia)")
    cut.add_argument("--seed", type=SEED, default=0, help="random seed of the registration trial (default 0)")
    cut.add_argument("--speed", type=SPEED, default=20.0, help="the robot's TCP speed, mm/s (default 20)")
    cut.add_argument("--out", type=Path, default=Path("cut"), help="folder for the results (default ./cut)")
    cut.set_defaults(run=run)


def run(arguments):
    from ..experiments.cut_plots import plot_cut_result
    from ..experiments.cut_trial import run_cut_trial
    from ..navigation.cut_render import render_guidance

    check_output_folder(arguments.out, "--out")
    arguments.out.mkdir(parents=True, exist_ok=True)
    result = run_cut_trial(arguments.bone, arguments.seed, arguments.speed, progress=Progress())
    document = result.to_dict()
    write_json_atomic(arguments.out / "cut_result.json", document)
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
            f"  E{number + 1} {word:<13} {'(' + decimals(result.planned[number]) + ')':<24} "
            f"{'(' + decimals(result.executed[number]) + ')':<24} {result.distance_mm[number]:8.2f} "
            f"{result.normal_mm[number]:+13.2f}  {result.registration_error_mm[number]:.2f} "
            f"({result.predicted_error_mm[number]:.2f})"
        )
    print(f"  RMS {result.rms_mm:.2f} mm; the executed plane is tilted {result.tilt_deg:.2f} deg from the planned one")
    print(f"  written to {arguments.out}: cut_result.json, cut_result.png, guidance.png; {result.seconds:.1f} s")
    return 0
