"""Touches from recordings like the real ones (``landmark_sessions``: a stylus swivelled about each landmark, rests at
the start and the end, hand tremor, tracker noise, a tip calibration off, 10-60 Hz, INVALID runs, other tool names),
written as PLUS files and read back: every landmark exactly one touch, the touches within 0.3 mm RMS of the
landmarks after a rigid fit (the held-out recordings' criterion). A sample of seeds here;
``benchmarks/bench_touches.py`` runs hundreds."""

import numpy as np
import pytest

from OpenIGTLinkBridgeLib.landmark_sessions import TOOL_NAMES, random_landmark_session
from OpenIGTLinkBridgeLib.plus_sequence import read_sequence
from OpenIGTLinkBridgeLib.recorded_touches import find_recorded_touches
from RAMSICPRegistrationLib.core.paired_point import fit_rigid_transform


def touch_outcome(session, path):
    """(landmark touches in the order found, rests, fit RMS (mm) to the landmarks or None, each landmark's count of
    touches within 3 mm, the times of the frames with the tool tracked) of ``session`` written at ``path`` and read
    back, with collect's defaults."""
    session.write(path)
    recording = read_sequence(path)
    found = find_recorded_touches(recording, tip_mm=session.tip_calibrated)
    tracked = recording.timestamps_s[recording.matrices(session.tool)[1]]
    touches = found.landmarks
    positions = np.array([touch.position for touch in touches]).reshape(-1, 3)
    counts = [int((np.linalg.norm(positions - landmark, axis=1) < 3.0).sum()) for landmark in session.landmarks]
    fit_rms = None
    if len(touches) == len(session.landmarks):
        fit = fit_rigid_transform(positions, session.landmarks)
        fit_rms = float(np.sqrt(np.mean(fit.residuals_mm**2)))
    rests = [touch for touch in found.touches if touch.rest]
    return touches, rests, fit_rms, counts, tracked


@pytest.mark.parametrize(
    "seed, settings",
    [
        (0, {}),
        (2, {"rate_hz": 10.0, "invalid_runs": 3}),  # the slowest tracker, markers hidden three times
        (3, {"rate_hz": 60.0, "noise_mm": 0.25, "tip_error_mm": 2.5}),
        (4, {"rate_hz": 15.0, "landmarks": 8, "swivel_deg": (34.0, 36.0), "swivel_s": (2.0, 2.5)}),
        (5, {"landmarks": 12, "tremor_mm": 0.3, "tool": "PointerToTracker"}),
    ],
)
def test_every_landmark_is_one_touch_within_three_tenths_of_a_millimetre(tmp_path, seed, settings):
    session = random_landmark_session(seed, **settings)
    touches, rests, fit_rms, counts, tracked = touch_outcome(session, tmp_path / "session.igs.mha")
    assert counts == [1] * len(session.landmarks), counts
    assert len(touches) == len(session.landmarks)
    assert fit_rms <= 0.3, fit_rms
    errors = np.linalg.norm(np.array([touch.position for touch in touches]) - session.landmarks, axis=1)
    assert errors.max() < 0.3  # in the reference frame, without the fit
    for touch, (start, end) in zip(touches, session.contacts):  # each over its landmark's contact
        assert touch.kind == "swivel" and start - 0.3 <= touch.start_s and touch.end_s <= end + 0.3  # landing, lift
        contact = tracked[(tracked >= start) & (tracked <= end)]
        assert np.mean((contact >= touch.start_s) & (contact <= touch.end_s)) >= 0.9  # nearly all its frames
    assert len(rests) == 2
    for rest, place in zip(rests, session.rests):
        assert np.linalg.norm(rest.position - place) < 5.0  # the calibrated tip, 1-2.5 mm off, lying there


def test_a_session_is_drawn_from_its_seed_and_holds_what_it_says(tmp_path):
    """The same seed gives the same file; the truth matches the frames: the true tip sits on each landmark during
    its contact, the tool and the rate are the drawn ones."""
    one = random_landmark_session(7, rate_hz=20.0, invalid_runs=0)
    other = random_landmark_session(7, rate_hz=20.0, invalid_runs=0)
    assert one.write(tmp_path / "a.igs.mha").read_bytes() == other.write(tmp_path / "b.igs.mha").read_bytes()
    recording = read_sequence(tmp_path / "a.igs.mha")
    assert one.tool in TOOL_NAMES and recording.transform_names == [one.tool, "ReferenceToTracker"]
    times = recording.timestamps_s
    assert np.median(np.diff(times)) == pytest.approx(1 / 20.0, rel=0.05)
    tools, _ = recording.matrices(one.tool)
    references, _ = recording.matrices("ReferenceToTracker")
    for landmark, (start, end) in zip(one.landmarks, one.contacts):
        inside = (times > start + 0.05) & (times < end - 0.05)
        poses = np.linalg.solve(references[inside], tools[inside])
        tips = poses[:, :3, :3] @ one.tip_true + poses[:, :3, 3]
        assert np.sqrt(np.mean(np.sum((tips - landmark) ** 2, axis=1))) < 0.5  # tracker noise, no bias
    assert np.linalg.norm(one.tip_calibrated - one.tip_true) == pytest.approx(one.settings["tip_error_mm"])
    with pytest.raises(ValueError, match="unknown session settings"):
        random_landmark_session(0, rate=15)
