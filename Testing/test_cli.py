"""The ramsicp command line end to end: its JSON equals the Python result; bad input is one line, exit 2."""

import json
import subprocess
import sys

import numpy as np
import pytest

from RAMSICPRegistrationLib.cli import main
from RAMSICPRegistrationLib.point_files import write_points
from RAMSICPRegistrationLib.registration import register
from RAMSICPRegistrationLib.surface_files import write_surface
from RAMSICPRegistrationLib.surface_index import SurfaceIndex


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
    return ["register", "--ipc", str(folder / "ipc.vtp"), "--ppc", str(folder / "ppc.csv"),
            "--markers-image", str(folder / "markers_image.mrk.json"),
            "--markers-patient", str(folder / "markers_patient.fcsv"),
            "--targets-image", str(folder / "targets_image.mrk.json"),
            "--targets-patient", str(folder / "targets_patient.npy"), *extra]


@pytest.mark.parametrize("extra, options", [
    (["--method", "cr"], {"method": "cr"}),
    (["--method", "cr-icp"], {"method": "cr-icp"}),
    (["--scale", "2.4"], {"method": "cr-ramsicp", "scale": 2.4}),
    (["--sweep", "--policy", "rms-plateau"], {"method": "cr-ramsicp", "sweep": True, "policy": "rms-plateau"}),
])
def test_register_json_matches_python_result(case_files, tmp_path, capsys, extra, options):
    folder, ipc, trial = case_files
    output = tmp_path / "result.json"
    assert main(_arguments(folder, *extra, "--json", str(output))) == 0
    printed = capsys.readouterr().out
    document = json.loads(output.read_text())
    expected = register(SurfaceIndex(ipc), trial.ppc, trial.markers_image, trial.markers_patient,
                        trial.targets_image, trial.targets_patient, **options)
    np.testing.assert_allclose(document["reference_to_image"], expected.reference_to_image, atol=1e-9)
    assert document["tre_mm"] == pytest.approx(expected.tre_mm, abs=1e-9)
    assert document["fre_mm"] == pytest.approx(expected.fre_mm, abs=1e-9)
    assert document["ppc_rms_mm"] == pytest.approx(expected.ppc_rms_mm, abs=1e-9)
    np.testing.assert_allclose(document["residuals_mm"], expected.residuals_mm, atol=1e-9)
    assert document["scale"] == expected.scale and document["iterations"] == expected.iterations
    assert len(document["sweep"]) == (21 if options.get("sweep") else 0)
    assert document["warnings"] == list(expected.warnings)
    assert f"TRE (eq. 11)      {expected.tre_mm:.2f} mm" in printed


@pytest.mark.parametrize("mutate, message", [
    (lambda folder: (folder / "ppc.csv").write_text("1,2,3\n4,5\n"), "ppc.csv: line 2: expected 3 numbers x y z, got 2"),
    (lambda folder: (folder / "markers_image.mrk.json").write_text("{"), "markers_image.mrk.json: not valid JSON"),
    (lambda folder: (folder / "ipc.vtp").write_text("<xml"), "ipc.vtp: cannot read as VTP surface"),
    (lambda folder: (folder / "ppc.csv").write_text("1,2,3\n1,2,3\n"), "PPC (probe points): 2 point(s) given"),
])
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
    arguments = _arguments(folder)[:-2]
    assert main(arguments) == 2
    assert "give --targets-image and --targets-patient together" in capsys.readouterr().err
    assert main(["register", "--ipc", "nothing.vtp", "--ppc", "a", "--markers-image", "b", "--markers-patient", "c"]) == 2
    assert "nothing.vtp: no such file" in capsys.readouterr().err


def test_demo_reports_trials_and_summary(tmp_path, capsys):
    output = tmp_path / "demo.json"
    assert main(["demo", "--trials", "3", "--seed", "2", "--json", str(output)]) == 0
    printed = capsys.readouterr().out
    document = json.loads(output.read_text())
    assert document["trials"] == 3 and document["ipc_points"] == 200_000 and document["probe_points"] == 40
    for label, values in document["tre_mm"].items():
        assert len(values) == 3
        assert document["summary_mm"][label]["mean"] == pytest.approx(np.mean(values))
        assert document["summary_mm"][label]["sd"] == pytest.approx(np.std(values, ddof=1))
    assert "1.33 +- 0.27" in printed and "CR-RAMSICP (L by min TRE, paper)" in printed
    # The paper's policy takes the minimum TRE over the sweep, so it can never be worse than the fixed L.
    paper = np.array(document["tre_mm"]["CR-RAMSICP (L by min TRE, paper)"])
    fixed = np.array(document["tre_mm"]["CR-RAMSICP (fixed L = 5)"])
    assert np.all(paper <= fixed + 1e-12)


def test_console_script_module_runs():
    completed = subprocess.run([sys.executable, "-m", "RAMSICPRegistrationLib.cli", "--version"],
                               capture_output=True, text=True, check=True)
    assert completed.stdout.startswith("ramsicp 0.1.0")
