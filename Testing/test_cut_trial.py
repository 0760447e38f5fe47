"""The simulated osteotomy end to end (plan -> eq. 4 -> OpenIGTLink -> robot simulator -> the real blade ->
executed endpoints, and the tracked blade -> live guidance) against answers known by construction: with every
error off the executed cut is the planned one; a TCP told 0.5 mm off along the blade's normal moves the whole cut
0.5 mm along it (and the guidance sees it); a TCP error within the blade's plane leaves the cut where it was."""

import json

import numpy as np
import pytest

from RAMSICPRegistrationLib.commands import main
from RAMSICPRegistrationLib.experiments.cut_trial import ChainErrors, run_cut_trial

FAST = 400.0  # mm/s: the robot's motion runs in simulated time, so only the number of steps changes


def test_with_every_error_off_the_executed_cut_is_the_planned_one():
    result = run_cut_trial(speed_mm_s=FAST, errors=ChainErrors.none())
    assert result.distance_mm.max() < 1e-3  # float32 poses on the wire: 0.03 um at 500 mm
    assert result.tilt_deg < 1e-4 and result.registration_error_mm.max() < 1e-9
    assert result.guidance["tip_distance_max_mm"] < 1e-3 and result.guidance["on_plan_fraction"] == 1.0
    assert result.path["passes"] >= 4 and result.streaming["poses"] == result.path["poses"]


def test_a_tcp_told_half_a_millimetre_off_along_the_blades_normal_moves_the_cut_by_that():
    """The flange's y axis is the blade's normal (the path's poses): the robot, told its TCP is 0.5 mm further
    along +y than it is, puts the real blade 0.5 mm on the plan's -normal side, parallel to it."""
    result = run_cut_trial(speed_mm_s=FAST, errors=ChainErrors.none(tcp_error_mm=(0.0, 0.5, 0.0)))
    np.testing.assert_allclose(result.normal_mm, -0.5, atol=1e-3)
    assert result.tilt_deg < 1e-4
    assert result.guidance["tip_distance_mean_mm"] == pytest.approx(-0.5, abs=1e-3)  # the tracker sees the blade
    assert result.guidance["on_plan_fraction"] == 1.0  # 0.5 mm is within the 1 mm tolerance
    sideways = run_cut_trial(speed_mm_s=FAST, errors=ChainErrors.none(tcp_error_mm=(0.5, 0.0, 0.5)))
    assert sideways.distance_mm.max() < 1e-3  # an error within the blade's own plane does not move the cut


def test_the_measured_result_with_every_error_and_the_command_line(tmp_path, capsys):
    assert main(["cut-demo", "--out", str(tmp_path), "--speed", str(FAST)]) == 0
    document = json.loads((tmp_path / "cut_result.json").read_text())
    planned, executed = np.array(document["planned_endpoints"]), np.array(document["executed_endpoints"])
    distances = np.linalg.norm(executed - planned, axis=1)
    np.testing.assert_allclose(document["distance_mm"], distances)
    assert np.all(np.abs(document["along_normal_mm"]) <= distances + 1e-12)
    assert document["rms_mm"] == pytest.approx(np.sqrt(np.mean(distances**2)))
    assert 0.0 < document["rms_mm"] < max(document["registration_error_mm"]) + 0.2  # the chain's own errors
    for name in ("cut_result.png", "guidance.png"):
        assert (tmp_path / name).stat().st_size > 20_000
    printed = capsys.readouterr().out
    assert "E1 anterior" in printed and f"RMS {document['rms_mm']:.2f} mm" in printed
    assert main(["cut-demo", "--out", str(tmp_path / "cut_result.json")]) == 2
    assert "is a file; give a folder" in capsys.readouterr().err
