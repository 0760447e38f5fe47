"""``ramsicp phantom``: a CT phantom (NRRD) of a shipped bone with its reference body, and its ground truth."""

import dataclasses
import time
from pathlib import Path

from ..io.file_checks import check_output_folder
from ..simulation.ct_painting import BODY_MATERIALS
from ..simulation.package_data import BONES
from ._arguments import SEED
from ._console import Progress


def add_parser(commands):
    # The phantom's numbers are checked by ReferenceBodyModel, rotated_direction and make_ct_phantom before any work.
    phantom = commands.add_parser(
        "phantom",
        help="write a CT phantom (NRRD) of a shipped bone with its ground truth",
        description="Writes ct.nrrd (LPS), truth.json (RAS, stated in the file), bone_surface.vtp (the true "
        "surface cut to the CT's field of view, LPS-tagged) and marker_centres.mrk.json. Markers are numbered 1 "
        "to 4 in the reference body's (NDI tool's) order.",
    )
    phantom.add_argument("--out", type=Path, required=True, help="folder for the phantom's files")
    phantom.add_argument(
        "--bone", choices=tuple(BONES), default="right-tibia", help="the shipped bone (default right-tibia)"
    )
    phantom.add_argument("--seed", type=SEED, default=0, help="random seed of the pose and the noise (default 0)")
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
    phantom.set_defaults(run=run)


def run(arguments):
    from ..simulation.ct_painting import ReferenceBodyModel, rotated_direction
    from ..simulation.ct_phantom import FILE_FRAMES, make_ct_phantom, write_phantom
    from ..simulation.package_data import shipped_patient

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
        progress=Progress(),
    )
    # The bone's name lets ramsicp simulate-collection rebuild the same virtual patient from the folder.
    truth = dataclasses.replace(truth, settings={**truth.settings, "bone": arguments.bone})
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
