"""``ramsicp simulate-collection``: the patient side of a phantom's session, as the tracker would give it: the
reference body's marker centres, probe touches in 8 sub-areas and the 4 osteotomy targets, in reference
coordinates, with the targets and the cut plane in the image. With ``ramsicp phantom`` and ``ramsicp ipc`` it makes
every file ``ramsicp register`` and ``ramsicp plan`` need."""

import json
from pathlib import Path

import numpy as np

from ..io.file_checks import check_input_file, check_output_folder
from ._arguments import POSITIVE_MM, SEED

#: The files written, with their frame.
FILES = {
    "markers_patient": ("markers_patient.mrk.json", "reference (the tool's marker geometry, numbered M1-M4)"),
    "probe_points": ("probe_points.mrk.json", "reference (the probe's tip at each touch)"),
    "targets_patient": ("targets_patient.mrk.json", "reference (each the mean of 10 touches)"),
    "targets_image": ("targets_image.mrk.json", "image (RAS): the plan's endpoints on the CT's bone"),
    "cut_plane": ("cut_plane.txt", "image (RAS): a point of the cut plane and its normal, for ramsicp plan --plane"),
    "session": ("session.json", "what was simulated, with the true ReferenceToImage"),
}


def add_parser(commands):
    simulate = commands.add_parser(
        "simulate-collection",
        help="the patient side of a phantom's session: marker centres, probe touches and targets (tracker side)",
        description="Reads a folder written by ramsicp phantom and writes what the tracker side of its session "
        "would give: the reference body's marker centres (markers_patient.mrk.json), probe touches in the paper's "
        "8 sub-areas (probe_points.mrk.json) and the 4 osteotomy targets touched on the bone "
        "(targets_patient.mrk.json), all in reference coordinates, with the targets in the image "
        "(targets_image.mrk.json), the cut's plane (cut_plane.txt) and the session's truth (session.json).",
    )
    simulate.add_argument("--phantom", type=Path, required=True, help="folder written by ramsicp phantom")
    simulate.add_argument("--out", type=Path, required=True, help="folder for the session's files")
    simulate.add_argument(
        "--probe-noise", type=POSITIVE_MM, default=0.25, help="RMS error of a probe touch, mm (default 0.25)"
    )
    simulate.add_argument(
        "--points-per-area",
        type=int,
        choices=range(1, 11),
        default=5,
        metavar="N",
        help="touches in each of the 8 sub-areas, 1 to 10 (default 5: the paper's 40 points)",
    )
    simulate.add_argument("--seed", type=SEED, default=0, help="random seed of the touches (default 0)")
    simulate.set_defaults(run=run)


def run(arguments):
    from ..core.transforms import apply_transform, invert_transform
    from ..io.atomic_files import write_json_atomic, write_text_atomic
    from ..io.marker_files import write_markers
    from ..io.point_files import write_points
    from ..simulation.package_data import BONES, shipped_patient

    truth_path = arguments.phantom / "truth.json"
    check_input_file(truth_path, "--phantom's truth.json")
    check_output_folder(arguments.out, "--out")
    try:
        truth = json.loads(truth_path.read_text(encoding="utf-8"))
        bone, phantom_seed = truth["bone"], int(truth["seed"])
        reference_to_image = np.array(truth["reference_to_image"], dtype=np.float64)
    except (ValueError, KeyError, TypeError):
        raise ValueError(f"{truth_path}: not a truth.json of ramsicp phantom (run ramsicp phantom again)") from None
    if bone not in BONES:
        raise ValueError(f"{truth_path}: bone {bone!r} is not one of {', '.join(BONES)}")
    patient, _, _ = shipped_patient(bone, phantom_seed)
    if not np.allclose(patient.reference_to_image, reference_to_image, atol=1e-6):
        raise ValueError(f"{truth_path}: its ReferenceToImage is not the {bone}'s of seed {phantom_seed}")
    trial = patient.simulate_trial(
        np.random.default_rng(arguments.seed),
        marker_fle_mm=0.0,
        probe_noise_mm=arguments.probe_noise,
        points_per_area=arguments.points_per_area,
    )
    arguments.out.mkdir(parents=True, exist_ok=True)
    paths = {name: arguments.out / file for name, (file, _) in FILES.items()}
    count = len(trial.markers_patient)
    write_markers(paths["markers_patient"], trial.markers_patient, range(1, count + 1), ["ok"] * count)
    labels = [f"P{number + 1} SA{area}" for number, area in enumerate(trial.sub_area)]
    write_points(paths["probe_points"], trial.ppc, labels=labels)
    targets = [f"T{number + 1}" for number in range(len(trial.targets_image))]
    write_points(paths["targets_patient"], trial.targets_patient, labels=targets)
    write_points(paths["targets_image"], trial.targets_image, labels=targets)
    origin, normal = _plane_through(trial.targets_image)
    write_text_atomic(paths["cut_plane"], " ".join(f"{value:.6f}" for value in (*origin, *normal)) + "\n")
    session = {
        "phantom": str(arguments.phantom),
        "bone": bone,
        "seed": arguments.seed,
        "probe_noise_mm": arguments.probe_noise,
        "probe_points": len(trial.ppc),
        "reference_to_image": reference_to_image.tolist(),
        "targets_image_from_patient_mm": np.linalg.norm(
            apply_transform(invert_transform(reference_to_image), trial.targets_image) - trial.targets_patient, axis=1
        ).tolist(),
        "files": {name: {"file": file, "frame": frame} for name, (file, frame) in FILES.items()},
    }
    write_json_atomic(paths["session"], session)
    print(f"session of the {bone.replace('-', ' ')} phantom in {arguments.phantom}:")
    print(f"  {len(trial.ppc)} probe touches in 8 sub-areas ({arguments.probe_noise:g} mm RMS), 4 targets, 4 markers")
    for file, frame in FILES.values():
        print(f"  {arguments.out / file}  [{frame}]")
    return 0


def _plane_through(points):
    """The least-squares plane of (N, 3) points: (origin (3,), unit normal (3,))."""
    origin = points.mean(axis=0)
    normal = np.linalg.svd(points - origin)[2][-1]
    return origin, normal
