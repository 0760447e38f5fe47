"""A new user's mistakes, drawn at random and applied to a correct session, run through ``ramsicp register``.

Each case writes a correct session of the shipped demo patient to disk (the IPC as Slicer writes models, the image
marker centres as ``ramsicp ipc`` writes them, the probe points and the patient marker centres as text files), then
applies one or two mistakes drawn from ``MISTAKES`` (units, frames, marker order and pairing, file formats, touches
in the air, another scan's IPC, ...), runs ``ramsicp register`` in this process and classifies the outcome:

* ``refused``: exit 2 with one line on stderr (before any work);
* ``alarmed``: exit 4 with one line on stderr (the result printed, led by its WARNING lines);
* ``correct``: exit 0 and ReferenceToImage within ``TOLERANCE_MM`` of the truth at the osteotomy targets;
* ``noise``: exit 0 and farther than that, but so is the same session without the mistakes (the simulated marker
  and probe noise alone, not the mistake, put it beyond the tolerance);
* ``wrong``: exit 0 and farther than that while the session without the mistakes is within it: the failure this
  benchmark exists to count (must be 0);
* ``traceback``: any exception, or an exit code or stderr other than the above (must be 0).

Some mistakes are harmless by design (markers in another order are re-paired, decimal commas and named columns are
read): their cases must come out correct. The tests (``Testing/test_user_mistakes.py``) run a sample of seeds.

Run: python benchmarks/user_mistakes.py [--cases 200] [--seed 0]
"""

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from RAMSICPRegistrationLib.commands import main
from RAMSICPRegistrationLib.core.transforms import (
    apply_transform,
    invert_transform,
    make_transform,
    rotation_about_axis,
)
from RAMSICPRegistrationLib.io.marker_files import write_markers
from RAMSICPRegistrationLib.io.surface_files import write_surface

#: A result farther than this from the truth at any osteotomy target (mm), with exit 0, is wrong.
TOLERANCE_MM = 1.0
#: IPC points written per case (a sample of the demo patient's dense IPC: registration stays fast).
IPC_POINTS = 30_000
_LPS = np.array([-1.0, -1.0, 1.0])
#: StylusTipToStylus of PlusLibData's fCal test configuration (mm): the stylus the recordings are made with.
STYLUS_TIP_MM = np.array([203.772, -12.283, 1.17469])
OUTCOMES = ("refused", "alarmed", "correct", "noise", "wrong", "traceback")


@dataclass
class Session:
    """A session's data in memory (RAS mm) and how each file is to be written; mistakes edit it."""

    ipc: np.ndarray
    ppc: np.ndarray
    markers_image: np.ndarray
    markers_patient: np.ndarray
    truth: np.ndarray  # ReferenceToImage (4, 4)
    targets_image: np.ndarray
    # how the files are written: "tagged" or the frame the untagged coordinates are in
    ipc_frame: str = "tagged"
    ppc_frame: str = "RAS"
    markers_image_frame: str = "tagged"
    markers_patient_frame: str = "RAS"
    ppc_text: dict = field(default_factory=dict)  # {"header": "z,y,x", "decimal_comma": True}
    image_numbers: list = None
    tip: np.ndarray = None  # collect --tip as the user types it: the probe points then come from a recording
    options: list = field(default_factory=list)  # extra command-line options
    notes: list = field(default_factory=list)  # the mistakes applied


def _patient(bone="right-tibia"):
    from RAMSICPRegistrationLib.simulation.package_data import shipped_patient

    if bone not in _patient.cache:
        _patient.cache[bone] = shipped_patient(bone)[0]
    return _patient.cache[bone]


_patient.cache = {}


def correct_session(rng, bone="right-tibia"):
    """A correct session: the paper's acquisition with a marker error drawn from 0.1-0.5 mm, probe noise 0.25 mm."""
    patient = _patient(bone)
    trial = patient.simulate_trial(rng, marker_fle_mm=float(rng.uniform(0.1, 0.5)))
    ipc = patient.ipc[rng.choice(len(patient.ipc), IPC_POINTS, replace=False)]
    return Session(
        ipc=ipc,
        ppc=trial.ppc,
        markers_image=trial.markers_image,
        markers_patient=trial.markers_patient,
        truth=patient.reference_to_image,
        targets_image=patient.targets_image,
        image_numbers=[1, 2, 3, 4],
    )


# -- the mistakes: each edits a Session (and may add options) --------------------------------------------------
def patient_markers_shuffled(session, rng):
    order = rng.permutation(len(session.markers_patient))
    while np.array_equal(order, np.arange(len(order))):
        order = rng.permutation(len(order))
    session.markers_patient = session.markers_patient[order]


def image_markers_unnumbered_and_shuffled(session, rng):
    order = rng.permutation(len(session.markers_image))
    session.markers_image, session.image_numbers = session.markers_image[order], None


def patient_markers_in_metres(session, rng):
    session.markers_patient = session.markers_patient / 1000.0


def patient_markers_in_cm(session, rng):
    session.markers_patient = session.markers_patient / 10.0


def probe_points_in_metres(session, rng):
    session.ppc = session.ppc / 1000.0


def probe_points_in_cm(session, rng):
    session.ppc = session.ppc / 10.0


def probe_points_in_inches(session, rng):
    session.ppc = session.ppc / 25.4


def probe_points_lps_untagged(session, rng):
    session.ppc_frame = "LPS"


def patient_markers_lps_untagged(session, rng):
    session.markers_patient_frame = "LPS"


def ipc_lps_without_tag(session, rng):
    session.ipc_frame = "LPS"


def image_markers_lps_untagged(session, rng):
    session.markers_image_frame = "LPS"
    session.image_numbers = None


def untagged_space_lps_for_everything(session, rng):
    session.options += ["--untagged-space", "LPS"]


def probe_points_in_tracker_coordinates(session, rng):
    session.ppc = apply_transform(_tracker_pose(rng), session.ppc)


def patient_markers_in_tracker_coordinates(session, rng):
    session.markers_patient = apply_transform(_tracker_pose(rng), session.markers_patient)


def both_patient_files_in_tracker_coordinates(session, rng):
    pose = _tracker_pose(rng)
    session.ppc, session.markers_patient = (
        apply_transform(pose, session.ppc),
        apply_transform(pose, session.markers_patient),
    )


def touches_in_the_air(session, rng):
    """2-4 points recorded between touches, 5-15 mm off the bone (auto-collect)."""
    count = int(rng.integers(2, 5))
    rows = rng.choice(len(session.ppc), count, replace=False)
    image_to_reference = invert_transform(session.truth)
    ipc_reference = apply_transform(image_to_reference, session.ipc)
    for row in rows:
        moves = np.vstack((np.eye(3), -np.eye(3))) * rng.uniform(5.0, 15.0)
        gaps = [np.linalg.norm(ipc_reference - (session.ppc[row] + move), axis=1).min() for move in moves]
        session.ppc[row] = session.ppc[row] + moves[int(np.argmax(gaps))]


def csv_header_z_y_x(session, rng):
    session.ppc_text["header"] = "z,y,x"


def csv_decimal_commas(session, rng):
    session.ppc_text["decimal_comma"] = True


def nan_probe_point(session, rng):
    session.ppc[int(rng.integers(len(session.ppc)))] = np.nan


def duplicated_patient_marker(session, rng):
    session.markers_patient = np.vstack((session.markers_patient[:3], session.markers_patient[2]))


def image_marker_misplaced(session, rng):
    """One image centre off by 3-8 mm (clicked on the sphere's rim, or on the wrong sphere's side)."""
    direction = rng.normal(size=3)
    row = int(rng.integers(len(session.markers_image)))
    session.markers_image[row] = session.markers_image[row] + rng.uniform(3.0, 8.0) * direction / np.linalg.norm(
        direction
    )


def another_scans_ipc(session, rng):
    """The IPC of another scan of the bone: moved 5-30 mm and turned up to 5 degrees."""
    direction = rng.normal(size=3)
    pose = make_transform(
        rotation_about_axis(rng.normal(size=3), np.radians(rng.uniform(0.0, 5.0))),
        rng.uniform(5.0, 30.0) * direction / np.linalg.norm(direction),
    )
    centre = session.ipc.mean(axis=0)
    session.ipc = apply_transform(pose, session.ipc - centre) + centre


def probe_points_of_another_session(session, rng):
    session.ppc = session.ppc + rng.uniform(20.0, 60.0) * np.array([0.0, 0.0, 1.0])


def tip_in_cm(session, rng):
    session.tip = STYLUS_TIP_MM / 10.0


def tip_in_metres(session, rng):
    session.tip = STYLUS_TIP_MM / 1000.0


def tip_with_a_wrong_sign(session, rng):
    """The tip's x typed without its sign (or another probe's calibration): 2 x 204 mm off along the stylus."""
    session.tip = STYLUS_TIP_MM * np.array([-1.0, 1.0, 1.0])


def tip_of_another_probe(session, rng):
    session.tip = np.array([0.0, 0.0, -110.0])  # the simulated Vega probe's, not this stylus's


def tip_right_through_collect(session, rng):
    """Not a mistake: the probe points come from a recording through ramsicp collect with the right tip."""
    session.tip = STYLUS_TIP_MM.copy()


def fle_given_too_small(session, rng):
    """--fle 0.05 for hand-placed centres: the marker fit is beyond it (an alarm), or harmless."""
    session.options += ["--fle", "0.05"]


def _tracker_pose(rng):
    """A ReferenceToTracker pose as a Polaris sees a reference body: 1-2 m away, any orientation."""
    direction = rng.normal(size=3)
    return make_transform(
        rotation_about_axis(rng.normal(size=3), rng.uniform(0.0, np.pi)),
        rng.uniform(1000.0, 2000.0) * direction / np.linalg.norm(direction),
    )


MISTAKES = {
    function.__name__: function
    for function in (
        patient_markers_shuffled,
        image_markers_unnumbered_and_shuffled,
        patient_markers_in_metres,
        patient_markers_in_cm,
        probe_points_in_metres,
        probe_points_in_cm,
        probe_points_in_inches,
        probe_points_lps_untagged,
        patient_markers_lps_untagged,
        ipc_lps_without_tag,
        image_markers_lps_untagged,
        untagged_space_lps_for_everything,
        probe_points_in_tracker_coordinates,
        patient_markers_in_tracker_coordinates,
        both_patient_files_in_tracker_coordinates,
        touches_in_the_air,
        csv_header_z_y_x,
        csv_decimal_commas,
        nan_probe_point,
        duplicated_patient_marker,
        image_marker_misplaced,
        another_scans_ipc,
        probe_points_of_another_session,
        fle_given_too_small,
        tip_in_cm,
        tip_in_metres,
        tip_with_a_wrong_sign,
        tip_of_another_probe,
        tip_right_through_collect,
    )
}


# -- writing and running ----------------------------------------------------------------------------------------
def write_recording(path, points, rng):
    """A PLUS recording of a stylus (tip ``STYLUS_TIP_MM``) held still 1 s on each of the (N, 3) reference points,
    each touch at its own tilt, at 20 Hz; the reference body 1-2 m from the tracker."""
    from OpenIGTLinkBridgeLib.plus_sequence import TrackedFrame, write_sequence

    reference_to_tracker = _tracker_pose(rng)
    frames, time_s = [], 0.0
    finite = points[np.isfinite(points).all(axis=1)]
    travel = np.linspace(finite[0] + (0.0, 0.0, 200.0), finite[0] + (0.0, 0.0, 30.0), 20)
    for tip in travel:  # brought in from the table: the first touch is a touch, not a rest where it starts
        stylus = reference_to_tracker @ make_transform(np.eye(3), tip - STYLUS_TIP_MM)
        frames.append(TrackedFrame(time_s, {"ReferenceToTracker": reference_to_tracker, "StylusToTracker": stylus}))
        time_s += 0.05
    for index, point in enumerate(finite):
        rotation = rotation_about_axis(rng.normal(size=3), np.radians(rng.uniform(10.0, 40.0)))
        for _ in range(20):  # held still
            tip = point + rng.normal(scale=0.03, size=3)
            stylus = reference_to_tracker @ make_transform(rotation, tip - rotation @ STYLUS_TIP_MM)
            frames.append(TrackedFrame(time_s, {"ReferenceToTracker": reference_to_tracker, "StylusToTracker": stylus}))
            time_s += 0.05
        following = finite[min(index + 1, len(finite) - 1)]
        for tip in np.linspace(point + (0.0, 0.0, 10.0), following + (0.0, 0.0, 60.0), 8):  # lifted, moving on
            stylus = reference_to_tracker @ make_transform(rotation, tip - rotation @ STYLUS_TIP_MM)
            frames.append(TrackedFrame(time_s, {"ReferenceToTracker": reference_to_tracker, "StylusToTracker": stylus}))
            time_s += 0.05
    write_sequence(path, frames)


def write_session(session, folder, rng=None):
    """The session's files as a user has them; returns the commands to run (collect first when the probe points come
    from a recording), the last one ``register``."""
    folder = Path(folder)
    paths = {
        "ipc": folder / ("ipc.vtp" if session.ipc_frame == "tagged" else "ipc.ply"),
        "ppc": folder / "ppc.csv",
        "markers_image": folder / ("markers_image.mrk.json" if session.markers_image_frame == "tagged" else "mi.csv"),
        "markers_patient": folder / "markers_patient.csv",
    }
    if session.ipc_frame == "tagged":
        write_surface(paths["ipc"], session.ipc)
    else:  # exported without its SPACE tag: coordinates in LPS, nothing says so
        _write_untagged_ply(paths["ipc"], session.ipc * _LPS)
    if session.markers_image_frame == "tagged":
        numbers = session.image_numbers or [0] * len(session.markers_image)
        write_markers(paths["markers_image"], session.markers_image, numbers, ["ok"] * len(session.markers_image))
    else:
        _write_text(paths["markers_image"], session.markers_image * _LPS, {})
    frames = {"RAS": 1.0, "LPS": _LPS}
    commands = []
    if session.tip is None:
        _write_text(paths["ppc"], session.ppc * frames[session.ppc_frame], session.ppc_text)
    else:
        write_recording(folder / "session.igs.mha", session.ppc, rng)
        tip = [f"{value:g}" for value in session.tip]
        commands.append(
            ["collect", "--recording", str(folder / "session.igs.mha"), "--tip", *tip, "--out", str(paths["ppc"])]
        )
    _write_text(paths["markers_patient"], session.markers_patient * frames[session.markers_patient_frame], {})
    return commands + [
        [
            "register",
            "--ipc",
            str(paths["ipc"]),
            "--ppc",
            str(paths["ppc"]),
            "--markers-image",
            str(paths["markers_image"]),
            "--markers-patient",
            str(paths["markers_patient"]),
            "--json",
            str(folder / "result.json"),
            *session.options,
        ]
    ]


def _write_text(path, points, style):
    """Untagged text points, as a spreadsheet or a script writes them (no SPACE line)."""
    lines = []
    order = [0, 1, 2]
    if style.get("header"):
        names = style["header"].split(",")
        order = ["xyz".index(name) for name in names]
        lines.append(style["header"])
    for point in points:
        values = [f"{point[axis]:.6f}" for axis in order]
        if style.get("decimal_comma"):
            lines.append(";".join(value.replace(".", ",") for value in values))
        else:
            lines.append(",".join(values))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def _write_untagged_ply(path, vertices):
    lines = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}", "property float x", "property float y"]
    lines += ["property float z", "end_header"] + [f"{x:.4f} {y:.4f} {z:.4f}" for x, y, z in vertices]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def target_error_mm(session, reference_to_image):
    """Largest distance (mm) between where the result and the truth put the osteotomy targets."""
    targets_patient = apply_transform(invert_transform(session.truth), session.targets_image)
    return float(
        np.linalg.norm(apply_transform(reference_to_image, targets_patient) - session.targets_image, axis=1).max()
    )


def run_case(seed, folder, mistakes=None, options=()):
    """One case: (outcome, the mistakes applied, detail). ``mistakes`` names them; else 1 or 2 drawn at random.
    ``options`` are added to register's command line (the fix a message asked for)."""
    rng = np.random.default_rng(seed)
    session = correct_session(rng)
    if mistakes is None:
        names = list(MISTAKES)
        mistakes = list(rng.choice(names, size=int(rng.integers(1, 3)), replace=False))
    for name in mistakes:
        MISTAKES[name](session, rng)
    session.options += list(options)
    for arguments in write_session(session, folder, rng):
        out, err = io.StringIO(), io.StringIO()
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                code = main(arguments)
        except BaseException as error:  # noqa: BLE001 (a traceback is what this counts)
            return "traceback", mistakes, f"{arguments[0]}: {type(error).__name__}: {error}"
        if code != 0:
            break
    lines = err.getvalue().strip().splitlines()
    if code in (2, 4):
        if len(lines) != 1 or "Traceback" in err.getvalue():
            return "traceback", mistakes, f"exit {code} with {len(lines)} stderr lines: {err.getvalue()[:300]}"
        return ("refused" if code == 2 else "alarmed"), mistakes, lines[0]
    if code != 0:
        return "traceback", mistakes, f"exit {code}: {err.getvalue()[:300]}"
    document = json.loads((Path(folder) / "result.json").read_text())
    error_mm = target_error_mm(session, np.array(document["reference_to_image"]))
    if error_mm <= TOLERANCE_MM:
        return "correct", mistakes, f"target error {error_mm:.2f} mm"
    if mistakes:  # the same session without the mistakes: is the simulation's own noise beyond the tolerance?
        baseline = Path(folder) / "baseline"
        baseline.mkdir(exist_ok=True)
        outcome, _, detail = run_case(seed, baseline, [])
        if outcome != "correct":
            return "noise", mistakes, f"target error {error_mm:.2f} mm; without the mistakes: {detail}"
    return "wrong", mistakes, f"target error {error_mm:.2f} mm"


#: ``ramsicp ipc`` mistakes on the demo's CT phantom: (what the user gives, --threshold, the CT's values shifted by).
IPC_CASES = (
    ("the default threshold (no mistake)", "200", 0.0),
    ("'auto' (no mistake)", "auto", 0.0),
    ("a higher bone threshold (no mistake)", "400", 0.0),
    ("a fraction: 0.2", "0.2", 0.0),
    ("a fraction: 0.5", "0.5", 0.0),
    ("soft tissue: 50 HU", "50", 0.0),
    ("fat: -100 HU", "-100", 0.0),
    ("metal only: 3000 HU", "3000", 0.0),
    ("a CT stored without its rescale (air at 24)", "200", 1024.0),
)


def run_ipc_cases(folder):
    """Each of ``IPC_CASES`` through ``ramsicp ipc`` on one CT phantom: [(case, outcome, detail)]. Correct: exit 0 and
    the IPC's median distance to the phantom's true bone surface within ``TOLERANCE_MM``."""
    from RAMSICPRegistrationLib.core.surface_index import SurfaceIndex
    from RAMSICPRegistrationLib.image.volume_io import CTVolume, load_volume, save_nrrd
    from RAMSICPRegistrationLib.io.surface_files import read_surface_mesh

    folder = Path(folder)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        main(["phantom", "--out", str(folder / "phantom")])
    truth = SurfaceIndex(read_surface_mesh(folder / "phantom" / "bone_surface.vtp")[0])
    volume = load_volume(folder / "phantom" / "ct.nrrd")
    outcomes = []
    for number, (case, threshold, shift) in enumerate(IPC_CASES):
        ct = folder / "phantom" / "ct.nrrd"
        if shift:
            ct = folder / f"shifted{number}.nrrd"
            save_nrrd(ct, CTVolume(voxels=volume.voxels + shift, ijk_to_ras=volume.ijk_to_ras))
        out, err = io.StringIO(), io.StringIO()
        arguments = ["ipc", str(ct), "--threshold", threshold, "--out", str(folder / f"ipc{number}.vtp")]
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                code = main(arguments)
        except BaseException as error:  # noqa: BLE001
            outcomes.append((case, "traceback", f"{type(error).__name__}: {error}"))
            continue
        lines = err.getvalue().strip().splitlines()
        if code in (2, 3, 4):
            outcome = "traceback" if len(lines) != 1 else ("alarmed" if code in (3, 4) else "refused")
            outcomes.append((case, outcome, lines[0] if lines else ""))
            continue
        distances, _ = truth.nearest(read_surface_mesh(folder / f"ipc{number}.vtp")[0])
        median = float(np.median(distances))
        outcomes.append((case, "correct" if median <= TOLERANCE_MM else "wrong", f"IPC median {median:.2f} mm off"))
    return outcomes


def main_benchmark():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--show", choices=OUTCOMES, nargs="*", default=["wrong", "traceback"])
    parser.add_argument("--ipc", action="store_true", help="also run ramsicp ipc's mistakes on a CT phantom")
    arguments = parser.parse_args()
    counts, by_mistake = Counter(), {}
    clock = time.perf_counter()
    for case in range(arguments.cases):
        with tempfile.TemporaryDirectory() as folder:
            outcome, mistakes, detail = run_case(arguments.seed * 100_000 + case, folder)
        counts[outcome] += 1
        for name in mistakes:
            by_mistake.setdefault(name, Counter())[outcome] += 1
        if outcome in arguments.show:
            print(f"case {case}: {outcome}: {' + '.join(mistakes)}: {detail}", file=sys.stderr)
    print(f"{arguments.cases} cases, seed {arguments.seed}, {time.perf_counter() - clock:.0f} s")
    print("mistake                                      " + "  ".join(f"{name:>9}" for name in OUTCOMES))
    for name in MISTAKES:
        row = by_mistake.get(name, Counter())
        print(f"{name:<45}" + "  ".join(f"{row[outcome]:9d}" for outcome in OUTCOMES))
    print(f"{'all cases':<45}" + "  ".join(f"{counts[outcome]:9d}" for outcome in OUTCOMES))
    if arguments.ipc:
        with tempfile.TemporaryDirectory() as folder:
            for case, outcome, detail in run_ipc_cases(folder):
                counts[outcome] += 1
                print(f"ipc: {case:<45} {outcome:<9} {detail[:150]}")
    return 1 if counts["wrong"] or counts["traceback"] else 0


if __name__ == "__main__":
    sys.exit(main_benchmark())
