"""``ramsicp collect --recording``: the touches in a recorded session, known answers on synthetic and real files."""

import json
from pathlib import Path

import numpy as np
import pytest
from test_hold_still import _synthetic_session

from OpenIGTLinkBridgeLib.plus_sequence import TrackedFrame, read_sequence, write_sequence
from RAMSICPRegistrationLib.commands import main
from RAMSICPRegistrationLib.core.transforms import make_transform, rotation_about_axis
from RAMSICPRegistrationLib.io.point_files import read_points

from conftest import random_transform

DATA = Path(__file__).parent / "Data"
TIP = np.array([203.772, -12.283, 1.17469])  # StylusTipToStylus of PlusLibData's fCal test configuration


def _recording_of(tips_reference, times, rng, tip=TIP, invalid=()):
    """A PLUS recording whose stylus tip (``tip`` in the stylus frame) follows ``tips_reference`` (reference
    coordinates), the stylus turning slowly, the reference body fixed at a random pose."""
    reference_to_tracker = random_transform(rng, max_translation_mm=500.0)
    frames = []
    for index, (point, time_s) in enumerate(zip(tips_reference, times)):
        rotation = rotation_about_axis((0.3, 1.0, 0.2), 0.2 * np.sin(time_s))
        stylus_to_reference = make_transform(rotation, point - rotation @ tip)
        statuses = {"ReferenceToTracker": "OK", "StylusToTracker": "INVALID" if index in invalid else "OK"}
        frames.append(
            TrackedFrame(
                50.0 + time_s,
                {
                    "ReferenceToTracker": reference_to_tracker,
                    "StylusToTracker": reference_to_tracker @ stylus_to_reference,
                },
                statuses,
                {"FrameNumber": str(1000 + index)},
            )
        )
    return frames


def test_eight_touches_with_tremor_in_a_recording_are_the_eight_points(tmp_path, capsys):
    rng = np.random.default_rng(17)
    positions = rng.uniform(-60, 60, size=(8, 3))
    tips, times, holds = _synthetic_session(rng, positions)
    path = write_sequence(tmp_path / "session.igs.mha", _recording_of(tips, times, rng))
    out, report = tmp_path / "points.csv", tmp_path / "touches.json"
    code = main(
        ["collect", "--recording", str(path), "--tip", *map(str, TIP), "--out", str(out), "--json", str(report)]
    )
    assert code == 0
    points = read_points(out).points
    assert points.shape == (8, 3)
    assert np.linalg.norm(points - positions, axis=1).max() < 0.1
    document = json.loads(report.read_text())
    for touch, (first, last) in zip(document["touches"], holds):  # each inside its true hold, covering most of it
        assert first - 3 <= touch["first_frame"] and touch["last_frame"] <= last + 1
        assert touch["frames"] >= 0.9 * (last - first + 1)
    assert document["valid_frames"] == document["frames"] == len(times)
    assert "8 touches ->" in capsys.readouterr().out


def test_an_invalid_frame_ends_a_touch(tmp_path):
    """A touch of 1 s with the stylus lost for one frame in the middle: two touches of 0.5 s, not one."""
    times = np.arange(0.0, 1.02, 0.02)  # 51 frames
    tips = np.zeros((51, 3))
    path = write_sequence(tmp_path / "lost.igs.mha", _recording_of(tips, times, np.random.default_rng(0), invalid={25}))
    out = tmp_path / "points.txt"
    arguments = ["--recording", str(path), "--tip", *map(str, TIP), "--hold-still-s", "0.4", "--out", str(out)]
    assert main(["collect", *arguments]) == 0
    assert len(read_points(out).points) == 2


def test_the_real_water_tank_recording_holds_one_still_stylus(tmp_path):
    """PlusLibData's water-tank recording: the stylus lies still for all 801 frames; the touch is the mean tip,
    computed here directly (eq. 2 in numpy) as the known answer."""
    path = DATA / "WaterTankBottomTranslationTrackerBuffer-trimmed.igs.mha"
    out, report = tmp_path / "stylus.mrk.json", tmp_path / "touches.json"
    assert (
        main(["collect", "--recording", str(path), "--tip", *map(str, TIP), "--out", str(out), "--json", str(report)])
        == 0
    )
    recording = read_sequence(path)
    stylus, _ = recording.matrices("StylusToTracker")
    reference, _ = recording.matrices("ReferenceToTracker")
    tips = np.array([(np.linalg.inv(r) @ s @ np.append(TIP, 1.0))[:3] for r, s in zip(reference, stylus)])
    document = json.loads(report.read_text())
    (touch,) = document["touches"]
    assert (touch["first_frame"], touch["last_frame"], touch["frames"]) == (0, 800, 801)
    np.testing.assert_allclose(touch["position_mm"], tips.mean(axis=0), atol=1e-9)
    spread = np.sqrt(np.mean(np.sum((tips - tips.mean(axis=0)) ** 2, axis=1)))
    assert touch["spread_mm"] == pytest.approx(spread, rel=1e-9) and spread < 0.5
    np.testing.assert_allclose(read_points(out).points[0], tips.mean(axis=0), atol=1e-6)  # written in LPS, read back
    assert document["timing"]["frames"] == 801 and document["timing"]["duration_s"] == pytest.approx(20.705643)


@pytest.mark.parametrize(
    "arguments, expected",
    [
        (["--recording", "missing.igs.mha"], "missing.igs.mha: no such file"),
        (
            ["--tool", "NeedleToTracker"],
            "has no NeedleToTracker transform (it has ReferenceToTracker, StylusToTracker)",
        ),
        (["--reference", "RasToTracker"], "choose one with --reference"),
        (["--hold-still-mm", "0"], "hold-still radius 0.0 mm: give a finite number > 0"),
        (["--hold-still-s", "-1"], "hold-still time -1.0 s: give a finite number >= 0"),
        (["--out", "{folder}"], "is a folder; give a file name"),
        (["--out", "{folder}/no/points.csv"], "does not exist"),
        (["--out", "{folder}/points.vtk"], "give a file name ending in .mrk.json"),
        (["--hold-still-mm", "0.01"], "no touch found (the tip never stayed within 0.01 mm for 0.5 s)"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, arguments, expected):
    defaults = {"--recording": str(DATA / "ReferenceToRASCalibration.igs.mha"), "--out": str(tmp_path / "p.csv")}
    for option, value in zip(arguments[::2], arguments[1::2]):
        defaults[option] = value.format(folder=tmp_path)
    argv = ["collect", "--tip", "0", "0", "0"] + [item for pair in defaults.items() for item in pair]
    argv += [
        item
        for option, value in zip(arguments[::2], arguments[1::2])
        if option not in defaults
        for item in (option, value)
    ]
    assert main(argv) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and error.startswith("ramsicp collect: error: ") and expected in error
