"""Inputs a new user gives in ways the program must read right or refuse by name (issue 23): CSV headers in any
column order and Slicer's control points table, decimal commas, points counted from 1, one frame per input file;
and outputs written whole or not at all when a write is interrupted."""

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from RAMSICPRegistrationLib.commands import main
from RAMSICPRegistrationLib.io.atomic_files import PARTIAL, write_json_atomic
from RAMSICPRegistrationLib.io.file_checks import PointFileError
from RAMSICPRegistrationLib.io.point_files import read_points, write_points
from RAMSICPRegistrationLib.io.surface_files import read_surface_mesh, write_surface

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import user_mistakes  # noqa: E402

POINTS = np.array([[1.5, -2.25, 3.0], [10.0, 20.0, -30.5], [-7.125, 0.5, 12.0]])


def _read(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return read_points(path)


def test_a_header_picks_the_columns_by_name_in_any_order(tmp_path):
    rows = "\n".join(f"{z},{y},{x}" for x, y, z in POINTS)
    np.testing.assert_array_equal(_read(tmp_path, "zyx.csv", "z,y,x\n" + rows).points, POINTS)
    rows = "\n".join(f"p{i} {x} {z} 7 {y}" for i, (x, y, z) in enumerate(POINTS))
    read = _read(tmp_path, "named.txt", "label X Z extra Y\n" + rows)
    np.testing.assert_array_equal(read.points, POINTS)
    assert read.labels == ("p0", "p1", "p2")


def test_slicers_control_points_table_is_read_in_its_frame(tmp_path):
    """Slicer's markups control points table (Docs/developer_guide/modules/markups.md): 'l,p,s' columns are LPS,
    'r,a,s' RAS; a point whose 'defined' is 0 has no position and is skipped."""
    header = "label,l,p,s,defined,selected,visible,locked,description\n"
    rows = "".join(f"F-{i + 1},{-x},{-y},{z},1,1,1,0,\n" for i, (x, y, z) in enumerate(POINTS))
    read = _read(tmp_path, "lps.csv", header + rows + "F-4,0,0,0,0,1,1,0,template\n")
    np.testing.assert_allclose(read.points, POINTS)  # converted to RAS
    assert read.labels == ("F-1", "F-2", "F-3")
    rows = "".join(f"F-{i + 1},{x},{y},{z},1,1,1,0,\n" for i, (x, y, z) in enumerate(POINTS))
    ras = _read(tmp_path, "ras.csv", header.replace("l,p,s", "r,a,s") + rows)
    np.testing.assert_allclose(ras.points, POINTS)


@pytest.mark.parametrize("separator", [";", "\t", " "])
def test_decimal_commas_are_read_when_the_columns_are_separated_otherwise(tmp_path, separator):
    rows = "\n".join(separator.join(f"{value:g}".replace(".", ",") for value in point) for point in POINTS)
    np.testing.assert_array_equal(_read(tmp_path, "comma.csv", rows).points, POINTS)


def test_decimal_commas_between_commas_are_refused_by_name(tmp_path):
    with pytest.raises(PointFileError, match=r"line 1: expected 3 numbers x y z, got 6 \(decimal commas\?"):
        _read(tmp_path, "six.csv", "1,5,2,25,3,0\n")


def test_a_header_without_coordinates_and_nan_points_are_refused_counting_from_1(tmp_path):
    with pytest.raises(PointFileError, match="the header 'a,b,c' names no coordinate columns"):
        _read(tmp_path, "abc.csv", "a,b,c\n1,2,3\n")
    with pytest.raises(PointFileError, match=r"point\(s\) 3 \(counted from 1\) contain NaN"):
        _read(tmp_path, "nan.csv", "1,2,3\n4,5,6\nnan,1,2\n")


def test_one_untagged_input_in_another_frame_is_given_by_its_own_option(tmp_path):
    """A model exported without its LPS tag: refused naming the frame; --ipc-space LPS reads it right, the other
    untagged files still as --untagged-space (RAS)."""
    outcome, _, detail = user_mistakes.run_case(3, tmp_path, ["ipc_lps_without_tag"])
    assert outcome == "refused" and "--ipc-space LPS" in detail
    outcome, _, detail = user_mistakes.run_case(3, tmp_path, ["ipc_lps_without_tag"], ["--ipc-space", "LPS"])
    assert outcome == "correct", detail
    outcome, _, detail = user_mistakes.run_case(3, tmp_path, ["probe_points_lps_untagged"], ["--ppc-space", "LPS"])
    assert outcome == "correct", detail


# -- outputs written whole or not at all --------------------------------------------------------------------------
WRITERS = {
    "points.csv": lambda path: write_points(path, POINTS),
    "points.mrk.json": lambda path: write_points(path, POINTS),
    "points.npy": lambda path: write_points(path, POINTS),
    "surface.vtp": lambda path: write_surface(path, POINTS),
    "surface.stl": lambda path: write_surface(path, POINTS, np.array([[0, 1, 2]])),
    "surface.obj": lambda path: write_surface(path, POINTS, np.array([[0, 1, 2]])),
    "result.json": lambda path: write_json_atomic(path, {"points": POINTS.tolist()}),
}


@pytest.mark.parametrize("name", list(WRITERS))
def test_a_write_interrupted_at_the_last_moment_leaves_the_old_file_and_no_part(tmp_path, monkeypatch, name):
    """Ctrl-C as the new file is complete but not yet in place: the old file is untouched, no temporary is left."""
    path = tmp_path / name
    path.write_bytes(b"the previous result")

    def interrupted(source, target):
        assert Path(source).stat().st_size > 0 and PARTIAL in Path(source).name  # written beside, in full
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        WRITERS[name](path)
    assert path.read_bytes() == b"the previous result"
    assert sorted(item.name for item in tmp_path.iterdir()) == [name]


@pytest.mark.parametrize("name", list(WRITERS))
def test_a_write_completes_in_place(tmp_path, name):
    path = tmp_path / name
    WRITERS[name](path)
    assert sorted(item.name for item in tmp_path.iterdir()) == [name]
    if name.startswith("points"):
        np.testing.assert_allclose(read_points(path).points, POINTS)
    elif name.startswith("surface"):
        np.testing.assert_allclose(read_surface_mesh(path)[0], POINTS, atol=1e-5)
    else:
        assert json.loads(path.read_text())["points"] == POINTS.tolist()


def test_ctrl_c_while_register_writes_its_json_is_one_line_exit_130_and_no_file(tmp_path, monkeypatch, capsys):
    user_mistakes.run_case(4, tmp_path, [])  # writes the session's files (and a first result.json)
    (tmp_path / "result.json").unlink()
    arguments = user_mistakes.write_session(user_mistakes.correct_session(np.random.default_rng(4)), tmp_path)[-1]
    real_write_text = Path.write_text

    def half_then_ctrl_c(self, text, *args, **kwargs):
        if self.name.endswith(".json") and PARTIAL in self.name:
            real_write_text(self, text[: len(text) // 2], *args, **kwargs)
            raise KeyboardInterrupt
        return real_write_text(self, text, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", half_then_ctrl_c)
    capsys.readouterr()
    assert main(arguments) == 130
    assert capsys.readouterr().err == "ramsicp register: stopped by Ctrl-C\n"
    assert not (tmp_path / "result.json").exists() and not list(tmp_path.glob(f"*{PARTIAL}*"))


# -- numbers that cannot be right, refused before any work ------------------------------------------------------
@pytest.mark.parametrize(
    "threshold, words",
    [
        ("0.2", "threshold 0.2 HU looks like a fraction"),
        ("50", "threshold 50 HU is below bone: soft tissue"),
        ("-100", "is below bone"),
        ("3000", "threshold 3000 HU is above most cortical bone"),
    ],
)
def test_an_ipc_threshold_outside_bone_is_refused_naming_why(tmp_path, capsys, threshold, words):
    """Refused by the parser, before the CT is even opened (it does not exist here)."""
    arguments = ["ipc", str(tmp_path / "ct.nrrd"), "--threshold", threshold, "--out", str(tmp_path / "ipc.vtp")]
    assert main(arguments) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and words in error and not list(tmp_path.iterdir())


def test_a_ct_without_air_is_not_taken_for_hounsfield_units():
    from RAMSICPRegistrationLib.image.hounsfield import check_hounsfield_units

    raw = np.full((4, 4, 4), 1024.0)  # water as stored without the rescale intercept (-1024)
    raw[0, 0, 0], raw[1, 1, 1] = 0.0, 2200.0  # air, bone
    with pytest.raises(ValueError, match="the lowest is 0 .* Stored without its rescale slope and intercept"):
        check_hounsfield_units(raw, 200.0)
    check_hounsfield_units(raw - 1024.0, 200.0)  # the same CT in HU: air at -1024
    check_hounsfield_units(raw, "auto")  # Otsu decides on the values it sees
    check_hounsfield_units(np.zeros((4, 4, 4)), 200.0)  # nothing above the threshold: segmentation says so


@pytest.mark.parametrize(
    "tip, words",
    [
        (["20.38", "-1.23", "0.12"], "it looks to be in centimetres"),
        (["0.204", "-0.012", "0.001"], "it looks to be in metres"),
        (["2", "0", "0"], "check the probe's calibration"),
        (["900", "0", "0"], "check the probe's calibration"),
    ],
)
def test_a_tip_no_probe_has_is_refused_before_the_recording_is_read(tmp_path, capsys, tip, words):
    arguments = [
        "collect",
        "--recording",
        str(tmp_path / "none.igs.mha"),
        "--tip",
        *tip,
        "--out",
        str(tmp_path / "p.csv"),
    ]
    assert main(arguments) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "where no probe's tip lies (30 to 500 mm" in error and words in error


def test_a_marker_fit_beyond_the_given_marker_error_is_an_alarm(tibia_patient):
    """Markers placed with 1 mm error (FRE about 0.7 mm) registered with --fle 0.1: the FRE is beyond what 0.1 mm
    explains (chi-square(6) at 1e-4: 0.14 mm for 4 markers), an alarm; given 1 mm, none."""
    from RAMSICPRegistrationLib.core.registration import register

    trial = tibia_patient.simulate_trial(np.random.default_rng(5), marker_fle_mm=1.0)
    arguments = (tibia_patient.ipc, trial.ppc, trial.markers_image, trial.markers_patient)
    tight = register(*arguments, method="cr", fle_mm=0.1)
    assert tight.fre_mm > 0.3 and any(alarm.startswith("The marker fit (FRE") for alarm in tight.alarms)
    assert not any("marker fit (FRE" in alarm for alarm in register(*arguments, method="cr", fle_mm=1.0).alarms)


def test_an_image_marker_off_its_sphere_is_refused_naming_it(tmp_path):
    """One image centre 6 mm off (clicked on the sphere's rim): no pairing of all four within 2 mm; the message names
    the marker that fits none, and deleting it lets the other three register."""
    from RAMSICPRegistrationLib.io.marker_files import MarkerSet, pair_marker_sets
    from RAMSICPRegistrationLib.io.ndi_tools import tool_marker_geometry

    tool = tool_marker_geometry()
    image = tool + np.array([100.0, 50.0, 20.0])
    image[2] += (0.0, 6.0, 0.0)  # in the plane of the markers (out of it, a tilt absorbs much of it)
    image_set = MarkerSet(image, (1, 2, 3, 4), ("ok",) * 4, "image.mrk.json")
    patient_set = MarkerSet(tool, (None,) * 4, (None,) * 4, "patient.csv")
    with pytest.raises(ValueError, match="only 3 of the markers pair within 2 mm .* image M3 fits none"):
        pair_marker_sets(image_set, patient_set)
    three = MarkerSet(image[[0, 1, 3]], (1, 2, 4), ("ok",) * 3, "image.mrk.json")
    pairing = pair_marker_sets(three, patient_set)
    np.testing.assert_allclose(pairing.patient, tool[[0, 1, 3]])


def test_a_report_folder_interrupted_keeps_its_old_files_and_gets_no_new_one(tmp_path):
    from RAMSICPRegistrationLib.io.atomic_files import atomic_folder

    report = tmp_path / "report"
    report.mkdir()
    (report / "report.md").write_text("the previous report")
    with pytest.raises(KeyboardInterrupt), atomic_folder(report) as folder:
        (folder / "results.json").write_text("{}")
        raise KeyboardInterrupt  # Ctrl-C while the figures are drawn
    assert sorted(item.name for item in tmp_path.iterdir()) == ["report"]
    assert [item.name for item in report.iterdir()] == ["report.md"]
    with atomic_folder(report) as folder:
        (folder / "results.json").write_text("{}")
        (folder / "report.md").write_text("the new report")
    assert sorted(item.name for item in report.iterdir()) == ["report.md", "results.json"]
    assert (report / "report.md").read_text() == "the new report"


@pytest.mark.parametrize(
    "point, words",
    [
        ((-1.0, -1.0, 1.0), "it looks to be LPS: give it in RAS"),
        ((1e-3, 1e-3, 1e-3), "it looks to be in metres"),
        ((0.1, 0.1, 0.1), "it looks to be in centimetres"),
    ],
)
def test_a_cut_plane_point_off_the_bone_is_refused_naming_the_frame_or_unit(
    tmp_path, capsys, tibia_patient, point, words
):
    """The plan's point is the cut's middle, on the bone: given in LPS, metres or centimetres it lies hundreds of mm
    off (a plane facing S would still cross the bone and the plan would go ahead)."""
    middle = tibia_patient.targets_image.mean(axis=0)
    write_surface(tmp_path / "bone.vtp", tibia_patient.ipc[::10])
    given = [f"{value:g}" for value in middle * np.array(point)]
    arguments = ["plan", "--ipc", str(tmp_path / "bone.vtp"), "--plane", *given, "0", "0", "1"]
    assert main(arguments + ["--out", str(tmp_path / "plan.json")]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "is the cut's middle but lies" in error and words in error
    assert not (tmp_path / "plan.json").exists()
