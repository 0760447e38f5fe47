"""The ramsicp command line end to end: its JSON equals the Python result; bad input is one line, exit 2."""

import json
import subprocess
import sys

import numpy as np
import pytest

from RAMSICPRegistrationLib.cli import main
from RAMSICPRegistrationLib.core.registration import register
from RAMSICPRegistrationLib.core.surface_index import SurfaceIndex
from RAMSICPRegistrationLib.io.point_files import write_points
from RAMSICPRegistrationLib.io.surface_files import write_surface


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
    arguments = _arguments(folder)[:-2]
    assert main(arguments) == 2
    assert "give --targets-image and --targets-patient together" in capsys.readouterr().err
    assert (
        main(["register", "--ipc", "nothing.vtp", "--ppc", "a", "--markers-image", "b", "--markers-patient", "c"]) == 2
    )
    assert "nothing.vtp: no such file" in capsys.readouterr().err


def _check_demo_document(document, trials):
    for mode, rows in document["tre_mm"].items():
        for label, values in rows.items():
            assert len(values) == trials
            assert document["summary_mm"][mode][label]["mean"] == pytest.approx(np.mean(values))
            assert document["summary_mm"][mode][label]["sd"] == pytest.approx(np.std(values, ddof=1))
        # The paper's policy takes the minimum TRE over the sweep: never worse than the fixed L.
        assert np.all(
            np.array(rows["CR-RAMSICP (L by min TRE, paper)"]) <= np.array(rows["CR-RAMSICP (fixed L = 5)"]) + 1e-12
        )


def test_demo_on_the_mesh_reports_trials_and_summary(tmp_path, capsys):
    output = tmp_path / "demo.json"
    assert main(["demo", "--image-source", "mesh", "--trials", "3", "--seed", "2", "--json", str(output)]) == 0
    printed = capsys.readouterr().out
    document = json.loads(output.read_text())
    assert document["trials"] == 3 and document["ipc_points"] == 200_000 and document["probe_points"] == 40
    assert list(document["tre_mm"]) == ["manual"]
    _check_demo_document(document, 3)
    assert "1.33 +- 0.27" in printed and "CR-RAMSICP (L by min TRE, paper)" in printed


def test_demo_on_the_ilium(capsys):
    assert main(["demo", "--bone", "right-ilium", "--image-source", "mesh", "--trials", "2"]) == 0
    printed = capsys.readouterr().out
    assert "right ilium of TotalSegmentator's example CT" in printed
    assert "lateral face of the wing" in printed and "corners of a 40 mm cut" in printed
    assert "cr-fused (markers + surface, target-free)" in printed and "measured / predicted RMS TRE" in printed


def test_demo_on_the_ct_phantom_runs_the_image_side(tmp_path, capsys):
    output = tmp_path / "demo.json"
    assert main(["demo", "--trials", "2", "--json", str(output)]) == 0
    document = json.loads(output.read_text())
    side = document["image_side"]
    assert max(side["automatic_marker_errors_mm"]) < 0.1  # the target for automatic centres
    assert 50_000 < side["ipc_points"] < 300_000 and abs(side["ipc_offset_mm"]) < 0.1
    assert list(document["tre_mm"]) == ["manual", "automatic"]
    _check_demo_document(document, 2)
    # Automatic centres are a hundred times better than the paper's manual placement: the CR shows it.
    assert max(document["tre_mm"]["automatic"]["CR"]) < 0.3
    assert "marker centres found automatically in the CT" in capsys.readouterr().out


def test_console_script_module_runs():
    completed = subprocess.run(
        [sys.executable, "-m", "RAMSICPRegistrationLib.cli", "--version"], capture_output=True, text=True, check=True
    )
    assert completed.stdout.startswith("ramsicp 0.1.0")
