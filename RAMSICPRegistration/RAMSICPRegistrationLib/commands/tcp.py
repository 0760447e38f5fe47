"""``ramsicp tcp``: the robot's tool-centre point by the four-point method, from flange poses."""

from pathlib import Path

import numpy as np

from ..io.atomic_files import write_json_atomic
from ..io.file_checks import check_output_file
from ..io.matrix_files import read_poses
from ._console import decimals


def add_parser(commands):
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
    tcp.set_defaults(run=run)


def run(arguments):
    from ..core.robot import tcp_four_point

    check_output_file(arguments.json, "--json", (".json",), [arguments.flange_poses])
    poses = read_poses(arguments.flange_poses, "--flange-poses")
    result = tcp_four_point(poses)
    print(f"flange poses     {len(poses)} from {arguments.flange_poses}")
    print(f"TCP in flange    ({decimals(result.tcp_in_flange)}) mm, {np.linalg.norm(result.tcp_in_flange):.2f} mm out")
    print(f"fixed point      ({decimals(result.point_in_base)}) mm in the robot base")
    print(f"residuals        {decimals(result.residuals_mm)} mm; RMS {result.rms_mm:.3f} mm")
    print(f"least turn       {result.spread_deg:.1f} degrees about any axis")
    if arguments.json:
        write_json_atomic(arguments.json, result.to_dict())
    return 0
