"""The ramsicp command line end to end: its JSON equals the Python result; bad input is one line, exit 2."""

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from RAMSICPRegistrationLib.commands import main
from RAMSICPRegistrationLib.core.registration import register
from RAMSICPRegistrationLib.core.surface_index import SurfaceIndex
from RAMSICPRegistrationLib.experiments import demo
from RAMSICPRegistrationLib.io.marker_files import read_markers, write_markers
from RAMSICPRegistrationLib.io.point_files import write_points
from RAMSICPRegistrationLib.io.surface_files import write_surface

from conftest import PAPER_FIG8_MM, recorded_trials, register_every_way

#: The re-registration (see ``register_every_way``) that each row of the demo's table must equal, and the paper's
#: Fig. 8 row it is printed beside.
DEMO_ROWS = {
    "CR": ("CR", "CR"),
    "CR-ICP": ("CR-ICP", "CR-ICP"),
    "CR-ICP point-to-plane (Open3D's method)": ("cr-icp-plane", None),
    "CR-RAMSICP (L by min TRE, paper)": ("paper's L", "CR-RAMSICP"),
    "CR-RAMSICP (rms-plateau, target-free)": ("rms-plateau", None),
    "CR-RAMSICP (fixed L = 5)": ("fixed L = 5", None),
    "cr-fused (markers + surface, target-free)": ("cr-fused", None),
}


@pytest.fixture(scope="module")
def case_files(tmp_path_factory, tibia_patient):
    """A small case on disk: a 20,000-point IPC as .vtp, markers as markups JSON (LPS), probe points as csv."""
    folder = tmp_path_factory.mktemp("case")
    rng = np.random.default_rng(8)
    trial = tibia_patient.simulate_trial(rng, marker_fle_mm=1.0)
    ipc = tibia_patient.ipc[rng.choice(len(tibia_patient.ipc), 20_000, replace=False)]
    write_surface(folder / "ipc.vtp", ipc)
    write_points(folder / "ppc.csv", trial.ppc)
    write_points(folder / "markers_image.mrk.json", trial.markers_image)
    write_points(folder / "markers_patient.fcsv", trial.markers_patient)
    write_points(folder / "targets_image.mrk.json", trial.targets_image)
    write_points(folder / "targets_patient.npy", trial.targets_patient)
    return folder, ipc, trial


def _arguments(folder, *extra):
    return [
        "register",
        "--ipc",
        str(folder / "ipc.vtp"),
        "--ppc",
        str(folder / "ppc.csv"),
        "--markers-image",
        str(folder / "markers_image.mrk.json"),
        "--markers-patient",
        str(folder / "markers_patient.fcsv"),
        "--targets-image",
        str(folder / "targets_image.mrk.json"),
        "--targets-patient",
        str(folder / "targets_patient.npy"),
        *extra,
    ]


@pytest.mark.parametrize(
    "extra, options",
    [
        (["--method", "cr"], {"method": "cr"}),
        (["--method", "cr-icp"], {"method": "cr-icp"}),
        (["--method", "cr-icp-plane"], {"method": "cr-icp-plane"}),
        (["--scale", "2.4"], {"method": "cr-ramsicp", "scale": 2.4}),
        (["--sweep", "--policy", "rms-plateau"], {"method": "cr-ramsicp", "sweep": True, "policy": "rms-plateau"}),
        ([], {}),  # the default method: cr-fused
    ],
)
def test_register_json_matches_python_result(case_files, tmp_path, capsys, extra, options):
    folder, ipc, trial = case_files
    output = tmp_path / "result.json"
    assert main(_arguments(folder, *extra, "--json", str(output))) == 0
    printed = capsys.readouterr().out
    document = json.loads(output.read_text())
    expected = register(
        SurfaceIndex(ipc),
        trial.ppc,
        trial.markers_image,
        trial.markers_patient,
        trial.targets_image,
        trial.targets_patient,
        **options,
    )
    np.testing.assert_allclose(document["reference_to_image"], expected.reference_to_image, atol=1e-9)
    assert document["tre_mm"] == pytest.approx(expected.tre_mm, abs=1e-9)
    assert document["fre_mm"] == pytest.approx(expected.fre_mm, abs=1e-9)
    assert document["ppc_rms_mm"] == pytest.approx(expected.ppc_rms_mm, abs=1e-9)
    np.testing.assert_allclose(document["residuals_mm"], expected.residuals_mm, atol=1e-9)
    assert document["scale"] == expected.scale and document["iterations"] == expected.iterations
    assert len(document["sweep"]) == (21 if options.get("sweep") else 0)
    assert document["warnings"] == list(expected.warnings)
    assert f"TRE (eq. 11)      {expected.tre_mm:.2f} mm" in printed
    if expected.method == "cr-fused":
        assert document["method"] == "cr-fused"
        weights = expected.fused_weights
        assert document["fused_weights"]["marker_fle_mm"] == pytest.approx(weights.marker_fle_mm)
        assert document["fused_weights"]["surface_sigma_mm"] == pytest.approx(weights.surface_sigma_mm)
        np.testing.assert_allclose(document["predicted_tre_mm"], expected.predicted_tre_mm)
        assert f"predicted TRE     {expected.predicted_tre_rms_mm:.2f} mm" in printed
        assert f"FLE {weights.marker_fle_mm:.2f} mm" in printed


@pytest.mark.parametrize(
    "mutate, message",
    [
        (
            lambda folder: (folder / "ppc.csv").write_text("1,2,3\n4,5\n"),
            "ppc.csv: line 2: expected 3 numbers x y z, got 2",
        ),
        (lambda folder: (folder / "markers_image.mrk.json").write_text("{"), "markers_image.mrk.json: not valid JSON"),
        (lambda folder: (folder / "ipc.vtp").write_text("<xml"), "ipc.vtp: cannot read as VTP surface"),
        (lambda folder: (folder / "ppc.csv").write_text("1,2,3\n1,2,3\n"), "PPC (probe points): 2 point(s) given"),
    ],
)
def test_bad_input_exits_2_with_one_line(case_files, tmp_path, capsys, mutate, message):
    source, _, _ = case_files
    folder = tmp_path / "copy"
    folder.mkdir()
    for path in source.iterdir():
        (folder / path.name).write_bytes(path.read_bytes())
    mutate(folder)
    assert main(_arguments(folder)) == 2
    error = capsys.readouterr().err.strip()
    assert message in error and "\n" not in error and error.startswith("ramsicp register: error:")


def test_register_rejects_half_given_targets_and_missing_files(case_files, capsys):
    folder, _, _ = case_files
    arguments = _arguments(folder)
    at = arguments.index("--targets-image")
    assert main(arguments[:at] + arguments[at + 2 :]) == 2  # patient targets without the image's
    assert "--targets-patient needs the same targets in the image" in capsys.readouterr().err
    assert (
        main(["register", "--ipc", "nothing.vtp", "--ppc", "a", "--markers-image", "b", "--markers-patient", "c"]) == 2
    )
    assert "nothing.vtp: no such file" in capsys.readouterr().err


def test_register_with_the_plans_targets_alone_gives_the_next_touch_and_enough(case_files, tmp_path, capsys):
    """--targets-image alone: the predicted error at the plan's targets (no TRE), the next touch among the
    reachable points and 'enough' for --target-tre, all equal to the library's (``core.touch_guidance``)."""
    from RAMSICPRegistrationLib.core.touch_guidance import touch_guidance

    folder, ipc, trial = case_files
    reachable = ipc[np.linalg.norm(ipc - trial.targets_image.mean(axis=0), axis=1) < 30.0]
    write_points(tmp_path / "reachable.csv", reachable)
    index = SurfaceIndex(ipc)
    expected = register(index, trial.ppc, trial.markers_image, trial.markers_patient, trial.targets_image)
    limit = float(expected.predicted_tre_95_mm.max()) + 0.01  # just above every target's 95 % bound: enough
    guidance = touch_guidance(expected, index, reachable=reachable, target_tre_mm=limit)
    arguments = _arguments(folder)
    at = arguments.index("--targets-patient")
    output = tmp_path / "result.json"
    extra = ["--reachable", str(tmp_path / "reachable.csv"), "--target-tre", f"{limit!r}", "--json", str(output)]
    assert main(arguments[:at] + arguments[at + 2 :] + extra) == 0
    printed = capsys.readouterr().out
    document = json.loads(output.read_text())
    assert document["tre_mm"] is None and document["target_errors_mm"] is None
    np.testing.assert_allclose(document["predicted_tre_mm"], expected.predicted_tre_mm, rtol=1e-9)
    np.testing.assert_allclose(document["predicted_tre_95_mm"], expected.predicted_tre_95_mm, rtol=1e-6)
    touch = document["next_touch"]
    np.testing.assert_allclose(touch["position_image"], guidance.next_touch.position_image, atol=1e-6)
    assert touch["predicted_tre_rms_mm"] == pytest.approx(guidance.next_touch.predicted_tre_rms_mm, rel=1e-6)
    assert touch["predicted_tre_rms_mm"] < document["predicted_tre_rms_mm"]
    assert np.linalg.norm(reachable - touch["position_image"], axis=1).min() < 1e-4  # one of the reachable points
    assert document["enough"] is True and document["target_tre_mm"] == pytest.approx(limit)
    assert "next touch        (" in printed and f"enough            yes: every target below {limit:g} mm" in printed
    # Just below the largest bound: not enough.
    extra[3] = f"{limit - 0.02!r}"
    assert main(arguments[:at] + arguments[at + 2 :] + extra) == 0
    assert json.loads(output.read_text())["enough"] is False and "enough            no" in capsys.readouterr().out


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--target-tre", "0.5", "--method", "cr-icp"], "need cr-fused's predicted error, not cr-icp's"),
        (["--reachable", "REACHABLE"], "mm from the IPC"),
    ],
)
def test_register_guidance_mistakes_are_one_line(case_files, tmp_path, capsys, extra, message):
    folder, _, _ = case_files
    write_points(tmp_path / "far.csv", np.full((3, 3), 1e4))
    extra = [str(tmp_path / "far.csv") if value == "REACHABLE" else value for value in extra]
    assert main(_arguments(folder, *extra)) == 2
    error = capsys.readouterr().err.strip()
    assert message in error and "\n" not in error
    arguments = _arguments(folder)
    at = arguments.index("--targets-image")
    assert main(arguments[:at] + arguments[at + 4 :] + ["--target-tre", "0.5"]) == 2
    assert "give --targets-image too" in capsys.readouterr().err


def _check_demo_document(document, trials, registered):
    """Every TRE of the demo's JSON equals its trial registered again, every summary its trials' mean and SD."""
    modes = list(document["tre_mm"])
    assert len(registered) == trials * len(modes)  # trial by trial, each marker mode in turn
    for number, (index, data, markers) in enumerate(registered):
        mode, trial = modes[number % len(modes)], number // len(modes)
        assert (markers is None) == (mode == "manual")  # by hand: the trial's own markers
        again = register_every_way(index, data, markers)
        for label, values in document["tre_mm"][mode].items():
            assert values[trial] == pytest.approx(again[DEMO_ROWS[label][0]], abs=1e-9), (mode, trial, label)
        chosen = document["chosen_scales"][mode]
        assert chosen["fixed"][trial] == 5.0 and chosen["targets"][trial] == again["paper's L value"]
        assert chosen["rms-plateau"][trial] == again["rms-plateau L"]
    for mode, rows in document["tre_mm"].items():
        for label, values in rows.items():
            assert len(values) == trials
            assert document["summary_mm"][mode][label]["mean"] == pytest.approx(np.mean(values))
            assert document["summary_mm"][mode][label]["sd"] == pytest.approx(np.std(values, ddof=1))


def _printed_rows(printed):
    """The demo's table as printed: label -> (mean, sd, paper mean, paper sd), numbers as text, None if blank (the
    predicted column of cr-fused's row is left out)."""
    pattern = re.compile(
        r"^\s+(\S.*?)\s+(\d+\.\d\d) \+- (\d+\.\d\d)(?:\s+(\d+\.\d\d) \+- (\d+\.\d\d))?(?:\s+\d+\.\d\d)?\s*$"
    )
    return {match[1]: match.groups()[1:5] for match in map(pattern.match, printed.splitlines()) if match}


def test_demo_on_the_mesh_reports_trials_and_summary(tmp_path, capsys):
    output = tmp_path / "demo.json"
    with recorded_trials(demo) as registered:
        assert main(["demo", "--image-source", "mesh", "--trials", "3", "--seed", "2", "--json", str(output)]) == 0
    printed = capsys.readouterr().out
    document = json.loads(output.read_text())
    assert document["trials"] == 3 and document["ipc_points"] == 200_000 and document["probe_points"] == 40
    assert list(document["tre_mm"]) == ["manual"]
    _check_demo_document(document, 3, registered)
    rows = document["tre_mm"]["manual"]
    # The minimum-TRE L is not L = 5 in some trial, so the paper's row and the fixed row cannot be swapped unseen.
    assert any(
        paper < fixed - 1e-3
        for paper, fixed in zip(rows["CR-RAMSICP (L by min TRE, paper)"], rows["CR-RAMSICP (fixed L = 5)"])
    )
    table = _printed_rows(printed)
    assert set(table) == set(DEMO_ROWS)
    for label, values in rows.items():
        paper = PAPER_FIG8_MM.get(DEMO_ROWS[label][1])
        assert table[label] == (
            f"{np.mean(values):.2f}",
            f"{np.std(values, ddof=1):.2f}",
            *((f"{paper[0]:.2f}", f"{paper[1]:.2f}") if paper else (None, None)),
        )


def test_demo_on_the_ilium(capsys):
    assert main(["demo", "--bone", "right-ilium", "--image-source", "mesh", "--trials", "2"]) == 0
    printed = capsys.readouterr().out
    assert "right ilium of TotalSegmentator's example CT" in printed
    assert "lateral face of the wing" in printed and "corners of a 40 mm cut" in printed
    assert "cr-fused (markers + surface, target-free)" in printed and "measured / predicted RMS TRE" in printed


def test_demo_on_the_ct_phantom_runs_the_image_side(tmp_path, capsys):
    output = tmp_path / "demo.json"
    with recorded_trials(demo) as registered:
        assert main(["demo", "--trials", "2", "--json", str(output)]) == 0
    document = json.loads(output.read_text())
    side = document["image_side"]
    assert max(side["automatic_marker_errors_mm"]) < 0.1  # the target for automatic centres
    assert 50_000 < side["ipc_points"] < 300_000 and abs(side["ipc_offset_mm"]) < 0.1
    assert list(document["tre_mm"]) == ["manual", "automatic"]
    _check_demo_document(document, 2, registered)
    # Automatic centres are a hundred times better than the paper's manual placement: the CR shows it.
    assert max(document["tre_mm"]["automatic"]["CR"]) < 0.3
    assert "marker centres found automatically in the CT" in capsys.readouterr().out


def test_console_script_module_runs():
    completed = subprocess.run(
        [sys.executable, "-m", "RAMSICPRegistrationLib.commands", "--version"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert completed.stdout.startswith("ramsicp 0.1.0")


def _markers_with_status(folder, trial, statuses, numbers=(1, 2, 3, 4)):
    """The image-side markers as ``ramsicp ipc`` writes them: labels 'M<n> <status>'."""
    path = folder / "markers_ct.mrk.json"
    write_markers(path, trial.markers_image[[n - 1 for n in numbers]], numbers, statuses)
    return path


def test_register_refuses_markers_flagged_by_ipc(case_files, tmp_path, capsys):
    """Issue 14, item 4: a partial or deformed centre from ``ramsicp ipc`` is not used without a word."""
    folder, _, trial = case_files
    flagged = _markers_with_status(tmp_path, trial, ["ok", "partial", "ok", "deformed"])
    arguments = _arguments(folder)
    arguments[arguments.index("--markers-image") + 1] = str(flagged)
    assert main(arguments) == 2
    error = capsys.readouterr().err.strip()
    assert "\n" not in error and "Traceback" not in error
    assert "marker 2 is partial and marker 4 is deformed" in error and "--accept-flagged-markers" in error
    output = tmp_path / "result.json"
    assert main(arguments + ["--accept-flagged-markers", "--json", str(output)]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("WARNING: marker 2 is partial and marker 4 is deformed")
    warnings = json.loads(output.read_text())["warnings"]
    assert warnings[0].startswith("marker 2 is partial and marker 4 is deformed") and "used as you asked" in warnings[0]


def test_register_pairs_markers_by_number_when_one_is_left_out(case_files, tmp_path, capsys):
    """Delete a flagged marker from the file: the other three keep their partners in the tool geometry."""
    folder, ipc, trial = case_files
    three = _markers_with_status(tmp_path, trial, ["ok", "ok", "ok"], numbers=(1, 2, 4))
    arguments = _arguments(folder, "--method", "cr", "--json", str(tmp_path / "result.json"))
    arguments[arguments.index("--markers-image") + 1] = str(three)
    assert main(arguments) == 0
    document = json.loads((tmp_path / "result.json").read_text())
    expected = register(
        SurfaceIndex(ipc),
        trial.ppc,
        trial.markers_image[[0, 1, 3]],
        trial.markers_patient[[0, 1, 3]],
        trial.targets_image,
        trial.targets_patient,
        method="cr",
    )
    np.testing.assert_allclose(document["reference_to_image"], expected.reference_to_image, atol=1e-9)
    assert document["fre_mm"] == pytest.approx(expected.fre_mm, abs=1e-9)
    capsys.readouterr()
    wrong = tmp_path / "wrong.mrk.json"
    write_markers(wrong, trial.markers_image[[0, 1, 3]], [1, 2, 5], ["ok", "ok", "ok"])
    arguments[arguments.index("--markers-image") + 1] = str(wrong)
    assert main(arguments) == 0  # marker 5 has no partner: the markers' distances pair it with the tool's 4th
    assert "paired by the markers' distances instead (image M1 = row 1, image M2 = row 2, image M5 = row 4" in (
        capsys.readouterr().out
    )
    document = json.loads((tmp_path / "result.json").read_text())
    np.testing.assert_allclose(document["reference_to_image"], expected.reference_to_image, atol=1e-9)


def test_marker_files_round_trip_numbers_and_statuses(tmp_path):
    centres = np.arange(12.0).reshape(4, 3)
    for name in ("m.mrk.json", "m.fcsv"):
        write_markers(tmp_path / name, centres, [3, 1, 0, 2], ["ok", "partial", "deformed", "ok"])
        markers = read_markers(tmp_path / name)
        np.testing.assert_allclose(markers.points, centres, atol=1e-12)
        assert markers.numbers == (3, 1, None, 2) and markers.statuses == ("ok", "partial", "deformed", "ok")
        assert markers.flagged() == [(1, "partial"), (3, "deformed")]
    write_points(tmp_path / "plain.csv", centres)  # no labels: no numbers, no status, pairs row by row
    plain = read_markers(tmp_path / "plain.csv")
    assert plain.numbers == (None,) * 4 and plain.statuses == (None,) * 4 and plain.flagged() == []


def test_register_refuses_an_ipc_that_is_not_a_surface(case_files, tmp_path, capsys):
    """Issue 14, item 1: a 3-point IPC gave a pose about 850 mm from the CR and exit 0; now every method refuses it."""
    folder, ipc, _ = case_files
    write_points(tmp_path / "three.txt", ipc[:3])
    for method in ("cr-fused", "cr", "cr-icp", "cr-ramsicp"):
        arguments = _arguments(folder, "--method", method, "--json", str(tmp_path / "result.json"))
        arguments[arguments.index("--ipc") + 1] = str(tmp_path / "three.txt")
        assert main(arguments) == 2
        error = capsys.readouterr().err.strip()
        assert error.startswith("ramsicp register: error: IPC: 3 points") and "\n" not in error
        assert "cannot be the surface under the 40 probe points" in error and "at least 16" in error
    assert not (tmp_path / "result.json").exists()


@pytest.mark.parametrize("method, shift_mm", [("cr-icp", 20.0), ("cr-ramsicp", 20.0), ("cr-fused", 20.0), ("cr", 60.0)])
def test_a_result_that_fails_its_checks_leads_with_warnings_and_exits_4(case_files, tmp_path, capsys, method, shift_mm):
    """Issue 14, item 1: an IPC 20 mm from where the markers put the bone (another scan's, say). ICP and RAMSICP
    slide the probe points onto it, far from the CR; cr-fused stays with the markers and the probe points stay off
    the surface. Each is printed and written, led by its WARNINGs, with exit code 4. The CR alone is allowed its
    own predicted error, which 4 markers know poorly (up to 9 times it here), so its IPC is 60 mm away."""
    folder, ipc, trial = case_files
    write_surface(tmp_path / "moved.vtp", ipc + (0.0, shift_mm, 0.0))
    arguments = _arguments(folder, "--method", method, "--json", str(tmp_path / "result.json"))
    arguments[arguments.index("--ipc") + 1] = str(tmp_path / "moved.vtp")
    assert main(arguments) == 4
    captured = capsys.readouterr()
    document = json.loads((tmp_path / "result.json").read_text())
    alarms = document["alarms"]
    assert alarms and document["warnings"][: len(alarms)] == alarms
    expected = "moved probe point" if method in ("cr-icp", "cr-ramsicp") else "half the probe points lie more than"
    assert any(alarm.startswith(f"{method} moved") or expected in alarm for alarm in alarms)
    if method in ("cr-icp", "cr-ramsicp"):
        assert document["fine_shift_mm"] > 10.0  # it slid onto the moved IPC
    assert captured.out.startswith("WARNING: ") and captured.out.count("WARNING: ") == len(alarms)
    assert "exit code is 4" in captured.err and "Traceback" not in captured.err
    assert main(_arguments(folder, "--method", method)) == 0  # the right IPC: no alarm
    assert "WARNING" not in capsys.readouterr().out


def test_a_reader_that_leaves_early_costs_nothing(case_files, tmp_path):
    """Issue 14, item 8: ``ramsicp register ... | head`` said ``Broken pipe`` and exited 2. The pipe is closed before
    the command writes a line: it still writes its JSON, exits 0 and says nothing."""
    folder, _, _ = case_files
    output = tmp_path / "result.json"
    arguments = _arguments(folder, "--sweep", "--json", str(output))
    process = subprocess.Popen(
        [sys.executable, "-m", "RAMSICPRegistrationLib.commands", *arguments],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    process.stdout.close()
    error = process.stderr.read().decode()
    assert process.wait() == 0 and error == ""
    assert len(json.loads(output.read_text())["sweep"]) == 21


def test_every_command_and_argument_says_what_it_is_for():
    import argparse

    from RAMSICPRegistrationLib.commands import COMMANDS, build_parser

    parser = build_parser()
    commands = next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction))
    assert list(commands.choices) == [name.replace("_", "-") for name in COMMANDS]
    for name, command in commands.choices.items():
        assert command.description and len(command.description) > 60, name
        silent = [a.dest for a in command._actions if not a.help and not isinstance(a, argparse._HelpAction)]
        assert silent == [], (name, silent)


def test_the_documented_command_reference_is_the_parsers_own():
    from RAMSICPRegistrationLib.commands.reference import BEGIN, END, command_reference, replace_in

    document = (Path(__file__).resolve().parents[1] / "Documentation" / "command-line.md").read_text(encoding="utf-8")
    assert replace_in(document, command_reference()) == document, (
        "Documentation/command-line.md is out of date: python -m RAMSICPRegistrationLib.commands.reference "
        "Documentation/command-line.md"
    )
    assert document.count(BEGIN) == document.count(END) == 1
    assert "### `ramsicp register`" in document and "| `--markers-patient` |  | the same centres" in document


def test_progress_is_drawn_by_tqdm_on_a_terminal_only():
    import io

    from RAMSICPRegistrationLib.commands._console import Progress

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    terminal, pipe = Terminal(), io.StringIO()
    for stream in (terminal, pipe):
        progress = Progress(stream)
        for done in range(4):
            progress("phantom", done, 3)
        progress("registration", 1, 2)
        progress.close()
    assert pipe.getvalue() == ""
    drawn = terminal.getvalue()
    assert "phantom: 100%" in drawn and "3/3" in drawn and "registration:  50%" in drawn and "1/2" in drawn


def test_simulate_collection_writes_the_patient_side_of_a_phantoms_session(
    tmp_path, tibia_patient, tibia_index, capsys
):
    """Only the phantom's truth.json is read: the same virtual patient is rebuilt from its bone and seed, and its
    touches land on that patient's bone, mapped there by the true ReferenceToImage."""
    from RAMSICPRegistrationLib.core.transforms import apply_transform
    from RAMSICPRegistrationLib.io.marker_files import read_markers
    from RAMSICPRegistrationLib.io.point_files import read_points

    phantom = tmp_path / "phantom"
    phantom.mkdir()
    truth = {"bone": "right-tibia", "seed": 0, "reference_to_image": tibia_patient.reference_to_image.tolist()}
    (phantom / "truth.json").write_text(json.dumps(truth))
    out = tmp_path / "session"
    assert main(["simulate-collection", "--phantom", str(phantom), "--out", str(out), "--probe-noise", "0.1"]) == 0
    markers = read_markers(out / "markers_patient.mrk.json")
    np.testing.assert_allclose(markers.points, tibia_patient.markers_reference)
    assert markers.numbers == (1, 2, 3, 4) and markers.statuses == ("ok",) * 4
    probe = read_points(out / "probe_points.mrk.json").points
    on_bone = apply_transform(tibia_patient.reference_to_image, probe)
    distances = tibia_index.nearest(on_bone)[0]
    assert len(probe) == 40 and np.sqrt(np.mean(distances**2)) < 0.3  # 0.1 mm noise and the IPC's own spacing
    targets_image = read_points(out / "targets_image.mrk.json").points
    np.testing.assert_allclose(targets_image, tibia_patient.targets_image)
    targets_patient = read_points(out / "targets_patient.mrk.json").points
    assert np.abs(apply_transform(tibia_patient.reference_to_image, targets_patient) - targets_image).max() < 0.2
    plane = np.array((out / "cut_plane.txt").read_text().split(), dtype=float)
    assert np.abs((targets_image - plane[:3]) @ plane[3:]).max() < 0.5 and abs(np.linalg.norm(plane[3:]) - 1) < 1e-5
    capsys.readouterr()
    (phantom / "truth.json").write_text(json.dumps({**truth, "seed": 3}))
    assert main(["simulate-collection", "--phantom", str(phantom), "--out", str(out)]) == 2
    assert "is not the right-tibia's of seed 3" in capsys.readouterr().err
