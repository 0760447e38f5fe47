"""``ramsicp collect --recording``: the touches in a recorded session, known answers on synthetic and real files,
the tool found in the file, the rests reported apart."""

import json
from pathlib import Path

import numpy as np
import pytest

from OpenIGTLinkBridgeLib.landmark_sessions import random_landmark_session
from OpenIGTLinkBridgeLib.plus_sequence import TrackedFrame, read_sequence, write_sequence
from OpenIGTLinkBridgeLib.recorded_touches import choose_tool, find_recorded_touches
from RAMSICPRegistrationLib.commands import main
from RAMSICPRegistrationLib.core.transforms import make_transform, rotation_about_axis
from RAMSICPRegistrationLib.io.point_files import read_points

from conftest import random_transform

DATA = Path(__file__).parent / "Data"
CALIBRATION = DATA / "ReferenceToRASCalibration.igs.mha"
WATER_TANK = DATA / "WaterTankBottomTranslationTrackerBuffer-trimmed.igs.mha"
TIP = np.array([203.772, -12.283, 1.17469])  # StylusTipToStylus of PlusLibData's fCal test configuration


def synthetic_session(rng, positions, rate_hz=60.0):
    """Tip samples (N, 3), times (N,) and the true hold intervals: each touch held 0.7-1.4 s with hand tremor
    (8-12 Hz, 0.15 mm) and tracker noise (0.1 mm RMS), reached by a lifted, decelerating move; one brief pause
    (0.25 s) mid-move and one slow slide (10 mm/s for 1.5 s); lifted off at the end."""
    tips, times, holds = [], [], []
    clock = 0.0
    current = positions[0] + np.array([0.0, 0.0, 30.0])

    def sample(point):
        nonlocal clock
        tips.append(point + rng.normal(scale=0.1 / np.sqrt(3), size=3))
        times.append(clock)
        clock += (1.0 + rng.uniform(-0.1, 0.1)) / rate_hz  # timing jitter

    for number, target in enumerate(positions):
        move_s = rng.uniform(0.4, 0.8)
        start, steps = current.copy(), int(move_s * rate_hz)
        for step in range(1, steps + 1):
            fraction = step / steps
            eased = 1 - (1 - fraction) ** 3  # decelerates onto the bone
            point = start + (target - start) * eased + np.array([0, 0, 15.0]) * np.sin(np.pi * fraction)
            sample(point)
            if number == 3 and step == steps // 2:  # a brief pause in the air
                for _ in range(int(0.25 * rate_hz)):
                    sample(point)
        hold_s = rng.uniform(0.7, 1.4)
        frequency, phase = rng.uniform(8, 12), rng.uniform(0, 2 * np.pi)
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        begin = len(times)
        hold_start = clock
        while clock - hold_start < hold_s:
            sample(target + 0.15 * np.sin(2 * np.pi * frequency * (clock - hold_start) + phase) * direction)
        holds.append((begin, len(times) - 1))
        if number == 5:  # a slow slide across the bone
            slide_start = clock
            while clock - slide_start < 1.5:
                sample(target + np.array([10.0 * (clock - slide_start) + 3.0, 0.0, 0.0]))
        current = target + np.array([0.0, 0.0, 0.0])
    for step in range(1, int(0.3 * rate_hz) + 1):  # lifted off the last point
        sample(current + (0.0, 0.0, 20.0 * step / (0.3 * rate_hz)))
    return np.array(tips), np.array(times), holds


def _recording_of(tips_reference, times, rng, tip=TIP, invalid=(), tool="StylusToTracker"):
    """A PLUS recording whose stylus tip (``tip`` in the stylus frame) follows ``tips_reference`` (reference
    coordinates), the stylus turning slowly, the reference body fixed at a random pose."""
    reference_to_tracker = random_transform(rng, max_translation_mm=500.0)
    frames = []
    for index, (point, time_s) in enumerate(zip(tips_reference, times)):
        rotation = rotation_about_axis((0.3, 1.0, 0.2), 0.2 * np.sin(time_s))
        stylus_to_reference = make_transform(rotation, point - rotation @ tip)
        statuses = {"ReferenceToTracker": "OK", tool: "INVALID" if index in invalid else "OK"}
        frames.append(
            TrackedFrame(
                50.0 + time_s,
                {"ReferenceToTracker": reference_to_tracker, tool: reference_to_tracker @ stylus_to_reference},
                statuses,
                {"FrameNumber": str(1000 + index)},
            )
        )
    return frames


def _collect(path, *options, tip=TIP):
    return main(["collect", "--recording", str(path), "--tip", *map(str, tip), *map(str, options)])


def test_eight_touches_with_tremor_in_a_recording_are_the_eight_points(tmp_path, capsys):
    """Held 0.7-1.4 s each: with 1 mm and 0.5 s, the eight points and nothing else. With the defaults (1.5 mm,
    0.2 s) the 0.25 s pause in the air is a hold too (a ninth touch, where the pause was), the slide still not."""
    rng = np.random.default_rng(17)
    positions = rng.uniform(-60, 60, size=(8, 3))
    tips, times, holds = synthetic_session(rng, positions)
    path = write_sequence(tmp_path / "session.igs.mha", _recording_of(tips, times, rng, tool="PointerToTracker"))
    out, report = tmp_path / "points.csv", tmp_path / "touches.json"
    code = _collect(path, "--hold-still-mm", 1, "--hold-still-s", 0.5, "--out", out, "--json", report)
    assert code == 0
    points = read_points(out).points
    assert points.shape == (8, 3)
    assert np.linalg.norm(points - positions, axis=1).max() < 0.1
    document = json.loads(report.read_text())
    assert document["tool"] == "PointerToTracker"  # found in the file
    for touch, (first, last) in zip(document["touches"], holds):  # each inside its true hold, covering most of it
        assert first - 3 <= touch["first_frame"] and touch["last_frame"] <= last + 1
        assert touch["frames"] >= 0.9 * (last - first + 1)
        assert touch["kind"] == "hold" and touch["method"] == "mean tip"
    assert document["valid_frames"] == document["frames"] == len(times)
    assert "8 touches ->" in capsys.readouterr().out
    assert _collect(path, "--out", out) == 0
    points = read_points(out).points
    assert len(points) == 9
    assert np.linalg.norm(points[[0, 1, 2, 4, 5, 6, 7, 8]] - positions, axis=1).max() < 0.1
    assert np.linalg.norm(points[3] - positions[3]) > 10  # the pause, in the air on the way to point 4


def test_a_run_of_invalid_frames_inside_a_touch_does_not_split_it(tmp_path):
    """A touch of 1 s with the stylus lost for 0.2 s in the middle: one touch over the whole second."""
    times = np.arange(0.0, 1.02, 0.02)  # 51 frames
    tips = np.zeros((51, 3))
    tips[:5] += (0.0, 0.0, 40.0)  # in the air first
    path = write_sequence(
        tmp_path / "lost.igs.mha", _recording_of(tips, times, np.random.default_rng(0), invalid=range(25, 35))
    )
    found = find_recorded_touches(read_sequence(path), tip_mm=TIP)
    (touch,) = found.touches
    assert (touch.first_frame, touch.last_frame, touch.frames, touch.kind) == (5, 50, 36, "rest")  # lying at the end
    np.testing.assert_allclose(touch.position, 0.0, atol=1e-9)


def test_the_tool_is_the_one_that_moves_and_a_choice_it_cannot_make_lists_the_names(tmp_path, capsys):
    recording = read_sequence(WATER_TANK)
    assert choose_tool(recording) == "ProbeToTracker"  # the ultrasound probe moves 25 mm; the stylus lies still
    assert choose_tool(read_sequence(CALIBRATION)) == "StylusToTracker"  # the only tool
    rng = np.random.default_rng(4)
    tips = rng.uniform(-50, 50, size=(30, 3))
    frames = _recording_of(tips, np.arange(30) / 15.0, rng, tool="ProbeToTracker")
    for frame, point in zip(frames, tips):  # a second tool, moving as well
        frame.transforms["NeedleToTracker"] = make_transform(translation=point * 2)
    path = write_sequence(tmp_path / "two.igs.mha", frames)
    assert _collect(path, "--out", tmp_path / "p.csv") == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith(f"ramsicp collect: error: {path}: which tool? several of them move: ProbeToTracker (moved")
    assert "NeedleToTracker (moved" in error and error.endswith("choose one with --tool")


def test_the_real_water_tank_recording_holds_no_touch_and_its_lying_stylus_is_one_rest(tmp_path, capsys):
    """PlusLibData's water-tank recording: the tool that moves is the ultrasound probe, swept up and down without
    pause (no touch); the stylus lies still all 801 frames: a rest, the mean tip (eq. 2 in numpy, the known answer),
    reported and not written."""
    out = tmp_path / "stylus.mrk.json"
    assert _collect(WATER_TANK, "--out", out) == 2
    error = capsys.readouterr().err
    assert "ramsicp collect: error: " in error and "no touch found (the tip never stayed" in error
    assert not out.exists()
    assert _collect(WATER_TANK, "--tool", "StylusToTracker", "--out", out) == 2
    assert "no touch found, only 1 rest (the probe lying still at the start or end)" in capsys.readouterr().err
    recording = read_sequence(WATER_TANK)
    (rest,) = find_recorded_touches(recording, "StylusToTracker", tip_mm=TIP).touches
    stylus, _ = recording.matrices("StylusToTracker")
    reference, _ = recording.matrices("ReferenceToTracker")
    tips = np.array([(np.linalg.inv(r) @ s @ np.append(TIP, 1.0))[:3] for r, s in zip(reference, stylus)])
    assert (rest.kind, rest.first_frame, rest.last_frame, rest.frames) == ("rest", 0, 800, 801)
    np.testing.assert_allclose(rest.position, tips.mean(axis=0), atol=1e-9)
    spread = np.sqrt(np.mean(np.sum((tips - tips.mean(axis=0)) ** 2, axis=1)))
    assert rest.spread_mm == pytest.approx(spread, rel=1e-9) and spread < 0.5


def test_the_real_calibration_recording_holds_one_quarter_second_touch(tmp_path):
    """PlusLibData's ReferenceToRAS calibration recording (15 Hz, the stylus moving about for 6 s, what it touched
    unknown): with the defaults the tip stays at one point once, frames 47-51 (0.25 s within 1.5 mm, drifting
    0.5 mm); every other slow moment drifts 1.3-2.7 mm in a quarter second (the hand moving at 5-15 mm/s). The point
    is the mean of those five tips (eq. 2 in numpy)."""
    out, report = tmp_path / "points.csv", tmp_path / "touches.json"
    assert _collect(CALIBRATION, "--out", out, "--json", report) == 0
    (touch,) = json.loads(report.read_text())["touches"]
    assert (touch["kind"], touch["first_frame"], touch["last_frame"], touch["method"]) == ("hold", 47, 51, "mean tip")
    recording = read_sequence(CALIBRATION)
    stylus, _ = recording.matrices("StylusToTracker")
    reference, _ = recording.matrices("ReferenceToTracker")
    tips = [(np.linalg.inv(reference[k]) @ stylus[k] @ np.append(TIP, 1.0))[:3] for k in range(47, 52)]
    np.testing.assert_allclose(touch["position_mm"], np.mean(tips, axis=0), atol=1e-9)
    np.testing.assert_allclose(read_points(out).points[0], np.mean(tips, axis=0), atol=1e-6)


def test_a_landmark_session_gives_one_point_per_landmark_and_reports_the_rests(tmp_path, capsys):
    """A drawn session (``landmark_sessions``: 8 landmarks swivelled about, 15 Hz, the tip 2.5 mm off, a tool name
    that is not StylusToTracker): 8 points written in the order touched, on the landmarks; the rests at the start
    and the end reported, not written; the recording's own tip within 0.1 mm of the true one."""
    session = random_landmark_session(3, landmarks=8, rate_hz=15.0, tip_error_mm=2.5, tool="StylusTipToTracker")
    path = session.write(tmp_path / "landmarks.igs.mha")
    out, report = tmp_path / "points.csv", tmp_path / "touches.json"
    assert _collect(path, "--out", out, "--json", report, tip=session.tip_calibrated) == 0
    points = read_points(out).points
    assert points.shape == (8, 3)
    assert np.sqrt(np.mean(np.sum((points - session.landmarks) ** 2, axis=1))) < 0.3
    document = json.loads(report.read_text())
    assert [touch["kind"] for touch in document["touches"]] == ["rest"] + ["swivel"] * 8 + ["rest"]
    assert np.linalg.norm(np.array(document["recording_tip_mm"]) - session.tip_true) < 0.1
    printed = capsys.readouterr().out
    assert "StylusTipToTracker (the tool that moves)" in printed and "8 touches ->" in printed
    assert "2 rests not written" in printed


def test_a_recording_cut_off_in_the_middle_gives_the_touches_before_the_cut_with_a_warning(tmp_path, capsys):
    """The landmark session cut in the middle of a frame after its fourth landmark: the frames before the cut are
    used (the rest at the start and the four landmarks, where the whole file puts them) and the warning says so."""
    session = random_landmark_session(3, landmarks=8, rate_hz=15.0, tip_error_mm=2.5, invalid_runs=0)
    whole = session.write(tmp_path / "whole.igs.mha")
    text = whole.read_text()
    fifth = int(np.searchsorted(read_sequence(whole).timestamps_s, session.contacts[4, 0]))
    cut = tmp_path / "cut.igs.mha"
    cut.write_text(text[: text.index(f"Seq_Frame{fifth:04d}_Timestamp") + 20])
    out, report = tmp_path / "points.csv", tmp_path / "touches.json"
    assert _collect(cut, "--out", out, "--json", report, tip=session.tip_calibrated) == 0
    printed = capsys.readouterr().out
    assert f"WARNING          {cut}: the file was cut short (no 'ElementDataFile = LOCAL' line): {fifth} complete" in (
        printed
    )
    document = json.loads(report.read_text())
    assert len(document["warnings"]) == 1 and document["frames"] == fifth
    assert [touch["kind"] for touch in document["touches"]] == ["rest"] + ["swivel"] * 4
    np.testing.assert_allclose(read_points(out).points, session.landmarks[:4], atol=0.3)


@pytest.mark.parametrize(
    "arguments, expected",
    [
        (["--recording", "missing.igs.mha"], "missing.igs.mha: no such file"),
        (
            ["--tool", "NeedleToTracker"],
            "has no NeedleToTracker transform (it has ReferenceToTracker, StylusToTracker)",
        ),
        (["--reference", "RasToTracker"], "has no RasToTracker transform (it has ReferenceToTracker, StylusToTracker)"),
        (["--hold-still-mm", "0"], "hold-still radius 0.0 mm: give a finite number > 0"),
        (["--hold-still-s", "-1"], "hold-still time -1.0 s: give a finite number >= 0"),
        (["--tip-error-mm", "-1"], "tip calibration error -1.0 mm: give a finite number >= 0"),
        (["--out", "{folder}"], "is a folder; give a file name"),
        (["--out", "{folder}/no/points.csv"], "does not exist"),
        (["--out", "{folder}/points.vtk"], "give a file name ending in .mrk.json"),
        (
            ["--hold-still-mm", "0.01"],
            "no touch found (the tip never stayed within 0.01 mm for 0.2 s without drifting)",
        ),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, arguments, expected):
    defaults = {"--recording": str(CALIBRATION), "--out": str(tmp_path / "p.csv")}
    for option, value in zip(arguments[::2], arguments[1::2]):
        defaults[option] = value.format(folder=tmp_path)
    argv = ["collect", "--tip", *map(str, TIP)] + [item for pair in defaults.items() for item in pair]
    assert main(argv) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and error.startswith("ramsicp collect: error: ") and expected in error
