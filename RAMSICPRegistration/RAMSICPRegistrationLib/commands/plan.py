"""``ramsicp plan``: an osteotomy cut planned on the image point cloud: its plane, its four endpoints on the bone
and the tool path, in image coordinates and, given ImageToRobotBase (eq. 4), the robot's."""

import time
from pathlib import Path

from ..core.tool_path import DEFAULT_FAR_MARGIN_MM, DEFAULT_TOOL_WIDTH_MM, TOOLS
from ..io.atomic_files import write_json_atomic
from ..io.file_checks import check_output_file
from ..io.matrix_files import read_matrix
from ._arguments import FINITE
from ._console import decimals


def add_parser(commands):
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
        help="a point of the cut plane (its middle, on the bone) and its normal, RAS mm",
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
        "--wedge", type=FINITE, default=0.0, metavar="DEG", help="a closing wedge: the second cut's angle"
    )
    plan.add_argument("--tool", choices=TOOLS, default="saw", help="the cutting tool (default saw)")
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
    plan.set_defaults(run=run)


#: The plane's point is the cut's middle: farther than this (mm) from every IPC point, it is not on this bone.
PLANE_POINT_LIMIT_MM = 50.0


def _check_plane_point_on_bone(point, ipc, explained_only=False):
    """Refuse a plane point (3,) farther than ``PLANE_POINT_LIMIT_MM`` from the (M, 3) IPC, naming LPS or metres when
    undoing that brings it onto the bone (with ``explained_only``, only then)."""
    import numpy as np

    point = np.asarray(point, dtype=np.float64)

    def gap(candidate):
        return float(np.sqrt(np.min(np.sum((ipc - candidate) ** 2, axis=1))))

    distance = gap(point)
    if distance <= PLANE_POINT_LIMIT_MM:
        return
    causes = (
        (point * (-1.0, -1.0, 1.0), "it looks to be LPS: give it in RAS (x and y negated)"),
        (point * 1000.0, "it looks to be in metres: give it in mm"),
        (point * 10.0, "it looks to be in centimetres: give it in mm"),
    )
    cause = next((words for candidate, words in causes if gap(candidate) <= PLANE_POINT_LIMIT_MM), None)
    if cause is None and explained_only:
        return
    raise ValueError(
        f"--plane: the point ({', '.join(f'{value:g}' for value in point)}) is the cut's middle but lies "
        f"{distance:.0f} mm from the bone; "
        + (cause or "give a point on the bone, in the IPC's coordinates (image RAS, mm)")
    )


def run(arguments):
    from ..core.tool_path import plan_document, plan_osteotomy
    from ..io.point_files import _suffix, read_points
    from ..io.surface_files import SURFACE_SUFFIXES, read_surface_mesh

    check_output_file(arguments.out, "--out", (".json",), [arguments.ipc, arguments.image_to_robot_base])
    image_to_base = None
    if arguments.image_to_robot_base is not None:
        image_to_base = read_matrix(arguments.image_to_robot_base, "--image-to-robot-base")
    clock = time.perf_counter()
    triangles = None
    if _suffix(Path(arguments.ipc)) in SURFACE_SUFFIXES:
        points, triangles = read_surface_mesh(arguments.ipc, arguments.untagged_space)
    else:
        points = read_points(arguments.ipc, arguments.untagged_space).points
    try:
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
    except ValueError:
        _check_plane_point_on_bone(arguments.plane[:3], points, explained_only=True)  # a unit or frame says why
        raise
    _check_plane_point_on_bone(arguments.plane[:3], points)  # a plane that crosses the bone, but far from the point
    document = plan_document(plans, path, image_to_base)
    write_json_atomic(arguments.out, document)
    section = "exact (mesh)" if plans[0].section.exact else "from the IPC points within 0.3 mm"
    print(f"IPC              {arguments.ipc}: {len(points):,} points; section {section}")
    for number, plan in enumerate(plans):
        plane = plan.plane
        name = "cut" if len(plans) == 1 else f"cut {number + 1}"
        width = "the whole bone" if plan.extent_mm is None else f"{plan.extent_mm:g} mm"
        print(
            f"{name:<17}origin ({decimals(plane.origin)}) normal ({decimals(plane.normal)}) depth "
            f"({decimals(plane.depth)}); across {width}"
        )
        for label, word, point in zip(plan.endpoint_labels, plan.endpoint_directions, plan.endpoints):
            print(f"  {label:<15}({decimals(point)})  {word}")
    print(
        f"tool path        {path.tool} {path.width_mm:g} mm: {len(path.poses)} poses in {path.passes} passes, "
        f"{path.length_mm:.0f} mm, stopping {path.far_margin_mm:g} mm before the far cortex"
    )
    frames = "image and robot base" if image_to_base is not None else "image"
    print(f"written          {arguments.out} ({frames} coordinates); {time.perf_counter() - clock:.2f} s")
    return 0
