"""Recorded poses from the three files they come in (io.pose_files, OpenIGTLinkBridgeLib.pose_recordings) and
``ramsicp pivot`` on them: scikit-surgery's real recording, a PLUS file, CSV tables; one line for every bad file."""

import json
from pathlib import Path

import numpy as np
import pytest

from OpenIGTLinkBridgeLib.plus_sequence import read_sequence
from OpenIGTLinkBridgeLib.pose_recordings import read_poses
from RAMSICPRegistrationLib.commands import main
from RAMSICPRegistrationLib.core.transforms import make_transform, rotation_about_axis
from RAMSICPRegistrationLib.io.pose_files import read_pose_folder, read_pose_table

DATA = Path(__file__).parent / "Data"
SKSURGERY = DATA / "sksurgerycore_pivot"
CALIBRATION = DATA / "ReferenceToRASCalibration.igs.mha"
TIP = np.array([1.5, -2.0, 160.0])
PIVOT = np.array([30.0, -40.0, 250.0])


def _pivoting(count=40):
    rotations = [
        rotation_about_axis((1, 0, 0), np.radians(20 * np.sin(k)))
        @ rotation_about_axis((0, 1, 0), np.radians(15 * np.cos(k)))
        for k in np.linspace(0, 6, count)
    ]
    return np.array([make_transform(rotation, PIVOT - rotation @ TIP) for rotation in rotations])


def test_scikit_surgerys_folder_is_read_in_time_order_with_its_times():
    recording = read_pose_folder(SKSURGERY)
    assert len(recording) == 1151 and recording.labels[0] == "1378476416922755200.txt"
    assert recording.times_s[0] == pytest.approx(1378476416.9227552) and np.all(np.diff(recording.times_s) > 0)
    assert recording.times_s[-1] - recording.times_s[0] == pytest.approx(53.82, abs=0.01)
    np.testing.assert_array_equal(recording.poses[0, 0], [0.2324886024, -0.9449805021, 0.2301324457, -425.5186462402])


@pytest.mark.parametrize(
    "with_time, header, separator", [(False, "", ","), (True, "time,m00,m01\\n", ";"), (True, "", " ")]
)
def test_csv_tables_of_matrices_with_or_without_times_and_headers(tmp_path, with_time, header, separator):
    poses = _pivoting()
    lines = [
        separator.join(_text(([0.05 * k] if with_time else []) + list(pose.ravel()))) for k, pose in enumerate(poses)
    ]
    path = tmp_path / "poses.csv"
    path.write_text(header.replace("\\n", "\n") + "# a comment\n" + "\n".join(lines) + "\n")
    recording = read_pose_table(path)
    np.testing.assert_array_equal(recording.poses, poses)
    if with_time:
        np.testing.assert_allclose(recording.times_s, 0.05 * np.arange(len(poses)))
    else:
        assert recording.times_s is None


def test_a_plus_file_gives_the_tool_in_the_reference_frame_with_its_time_stamps():
    recording = read_poses(CALIBRATION)
    plus = read_sequence(CALIBRATION)
    stylus, _ = plus.matrices("StylusToTracker")
    reference, _ = plus.matrices("ReferenceToTracker")
    np.testing.assert_allclose(recording.poses, np.linalg.inv(reference) @ stylus, atol=1e-9)
    np.testing.assert_array_equal(recording.times_s, plus.timestamps_s)
    assert recording.source.endswith("(StylusToTracker)") and recording.labels[5] == "frame 5"


def _text(values):
    return [repr(float(value)) for value in values]


def _write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


def _folder(tmp_path, matrices):
    folder = tmp_path / "poses"
    folder.mkdir()
    for number, matrix in enumerate(matrices):
        (folder / f"{1000 + number}.txt").write_text(matrix)
    return folder


GOOD = "1 0 0 10\n0 1 0 20\n0 0 1 30\n0 0 0 1\n"


@pytest.mark.parametrize(
    "make, expected",
    [
        (lambda p: _folder(p, []), "holds no pose files; give a folder of 4x4 matrices as text"),
        (lambda p: _folder(p, [GOOD, "1 0 0\n0 1 0\n"]), "1001.txt: 6 numbers, expected 16"),
        (lambda p: _folder(p, [GOOD.replace("1 0 0 10", "1.02 0 0 10")]), "not a rigid transform, its rotation is off"),
        (lambda p: _folder(p, [GOOD.replace("0 0 1 30", "0 0 -1 30")]), "its rotation is a reflection"),
        (lambda p: _folder(p, [GOOD.replace("0 0 0 1", "0 0 1 1")]), "last row is '0 0 1 1', expected '0 0 0 1'"),
        (lambda p: _folder(p, [GOOD.replace("10", "nan")]), "holds NaN or infinity"),
        (lambda p: _folder(p, [GOOD.replace("10", "ten")]), "'ten' is not a number"),
        (lambda p: _write(p, "poses.csv", "a,b\n"), "holds no poses; give one row-major 4x4 matrix"),
        (lambda p: _write(p, "poses.csv", "1,0,0,1\n"), "line 1: 4 numbers, expected 16"),
        (lambda p: p / "missing.csv", "missing.csv: no such file or folder"),
    ],
)
def test_bad_pose_files_give_one_line_naming_the_file(tmp_path, make, expected):
    path = make(tmp_path)
    with pytest.raises(ValueError, match=expected) as error:
        read_poses(path)
    assert "\n" not in str(error.value)


def test_too_few_poses_and_a_folder_where_a_table_is_expected_are_refused(tmp_path, capsys):
    folder = _folder(tmp_path, [GOOD] * 3)
    assert main(["pivot", "--poses", str(folder)]) == 2
    assert "3 poses recorded, at least 10 needed; keep pivoting" in capsys.readouterr().err
    with pytest.raises(ValueError, match="is a folder; give the CSV file itself"):
        read_pose_table(folder)


def test_the_pivot_command_on_scikit_surgerys_recording_lsq_and_robust(tmp_path, capsys):
    """``ramsicp pivot --method lsq`` equals the owner's expected values to 1e-3 mm; the robust default names the
    slips by time (s from the first pose) and residual; both in JSON under the documented keys."""
    report = tmp_path / "lsq.json"
    assert main(["pivot", "--poses", str(SKSURGERY), "--method", "lsq", "--json", str(report)]) == 0
    document = json.loads(report.read_text())
    np.testing.assert_allclose(document["tip_mm"], (-14.476, 395.143, -7.558), atol=1e-3)
    np.testing.assert_allclose(document["pivot_mm"], (-805.285, -85.448, -2112.066), atol=1e-3)
    assert document["residual_per_axis_mm"] == pytest.approx(1.838, abs=1e-3) and document["dropped"] == []
    assert document["rms_mm"] == pytest.approx(np.sqrt(3) * document["residual_per_axis_mm"])
    printed = capsys.readouterr().out
    assert "1151 of 1151 poses kept" in printed and "(-14.48 395.14 -7.56) mm in the probe's frame" in printed
    report = tmp_path / "robust.json"
    assert main(["pivot", "--poses", str(SKSURGERY), "--json", str(report)]) == 0
    document = json.loads(report.read_text())
    assert (
        document["method"] == "robust" and document["rms_mm"] < 3.184 and document["times"] == "s from the first pose"
    )
    longest = max(document["dropped"], key=lambda entry: entry["poses"])
    assert longest["start_s"] == pytest.approx(22.88, abs=0.01) and longest["end_s"] == pytest.approx(24.47, abs=0.01)
    assert longest["max_residual_mm"] > 10
    assert "poses   489-523     22.88-24.47   s (35 poses from 1378476439807064200.txt)" in capsys.readouterr().out


def test_the_pivot_command_on_a_plus_file_and_a_csv_table(tmp_path, capsys):
    """A pivot recorded as a PLUS file (the tool found, the reference's frame) and the same poses as CSV: the tip and
    the pivot we built them about."""
    from OpenIGTLinkBridgeLib.plus_sequence import TrackedFrame, write_sequence

    poses = _pivoting()
    reference = make_transform(rotation_about_axis((0, 0, 1), 0.4), (100.0, -50.0, -1500.0))
    frames = [
        TrackedFrame(10 + k / 20, {"ReferenceToTracker": reference, "PointerToTracker": reference @ pose})
        for k, pose in enumerate(poses)
    ]
    path = write_sequence(tmp_path / "pivot.igs.mha", frames)
    report = tmp_path / "plus.json"
    assert main(["pivot", "--poses", str(path), "--json", str(report)]) == 0
    document = json.loads(report.read_text())
    np.testing.assert_allclose(document["tip_mm"], TIP, atol=1e-6)
    np.testing.assert_allclose(document["pivot_mm"], PIVOT, atol=1e-6)
    assert "(PointerToTracker)" in capsys.readouterr().out
    table = tmp_path / "pivot.csv"
    table.write_text("\n".join(",".join(_text(pose.ravel())) for pose in poses))
    assert main(["pivot", "--poses", str(table), "--method", "lsq", "--json", str(report)]) == 0
    np.testing.assert_allclose(json.loads(report.read_text())["tip_mm"], TIP, atol=1e-6)
