"""The paper's experiments, reduced: files and fields, statistics recomputed from the stored trials, bone by bone."""

import json

import numpy as np
import pytest
from scipy import stats

from RAMSICPRegistrationLib.cli import main
from RAMSICPRegistrationLib.experiments.experiments import FIG9_LEVELS_MM, run_experiments


@pytest.fixture(scope="module")
def reproduction(tmp_path_factory):
    folder = tmp_path_factory.mktemp("reproduction")
    # Two subjects: the first two bones in turn, a right tibia (a long bone) and a right ilium (a flat bone).
    arguments = ["reproduce", "--subjects", "2", "--trials", "2", "--image-source", "mesh", "--out", str(folder)]
    assert main(arguments) == 0
    return folder, json.loads((folder / "results.json").read_text())


def test_all_files_are_written(reproduction):
    folder, results = reproduction
    for name in ("report.md", "results.json", "fig7.png", "fig8.png", "fig9.png", "fig10a.png", "fig10b.png"):
        assert (folder / name).stat().st_size > 1000
    assert set(results["experiments"]) == {"fig7", "fig8", "fig9", "fig10a", "fig10b"}
    report = (folder / "report.md").read_text()
    for heading in (
        "## Error model",
        "## Fig. 7",
        "## Fig. 8",
        "## Fig. 9",
        "## Fig. 10a",
        "## Fig. 10b",
        "## cr-fused against the targets set for it",
        "## Why our figures differ",
    ):
        assert heading in report
    assert "1.33 ± 0.27" in report and "0.25 mm RMS" in report
    assert results["settings"]["bones"] == ["right-tibia", "right-ilium"]
    for name, data in results["experiments"].items():
        assert list(data["bones"]) == ["right-tibia", "right-ilium"], name
    assert "| right-ilium | cr-fused |" in report


def _summaries(node):
    """Every {'mean', 'sd', 'n', 'trials_mm'} summary in the results, wherever it is."""
    if isinstance(node, dict):
        if "trials_mm" in node:
            yield node
        for value in node.values():
            yield from _summaries(value)


def test_every_summary_is_computed_from_its_trials(reproduction):
    _, results = reproduction
    summaries = list(_summaries(results["experiments"]))
    assert len(summaries) > 50
    for summary in summaries:
        trials = np.array(summary["trials_mm"])
        assert summary["n"] == len(trials)
        assert summary["mean"] == pytest.approx(trials.mean())
        assert summary["sd"] == pytest.approx(trials.std(ddof=1))


def test_fig8_paired_tests_match_scipy_on_the_stored_trials(reproduction):
    _, results = reproduction
    fig8 = results["experiments"]["fig8"]["bones"]["right-ilium"]
    icp = np.array(fig8["manual_markers"]["CR-ICP"]["trials_mm"])
    ramsicp = np.array(fig8["manual_markers"]["cr-fused"]["trials_mm"])
    assert len(icp) == 1 * 2  # 1 ilium subject x 2 trials
    test = fig8["paired_tests"]["CR-ICP vs cr-fused"]
    assert test["mean_difference_mm"] == pytest.approx(np.mean(icp - ramsicp))
    if test["paired_t_p"] is not None:
        assert test["paired_t_p"] == pytest.approx(stats.ttest_rel(icp, ramsicp).pvalue)
        assert test["wilcoxon_p"] == pytest.approx(stats.wilcoxon(icp, ramsicp).pvalue)


def test_fig9_sets_the_cr_error_to_each_level(reproduction):
    _, results = reproduction
    for bone in ("right-tibia", "right-ilium"):
        levels = results["experiments"]["fig9"]["bones"][bone]["levels"]
        assert [float(level) for level in levels] == list(FIG9_LEVELS_MM)
        for level, row in levels.items():
            np.testing.assert_allclose(row["CR"]["trials_mm"], float(level), rtol=0.01)  # the CR's own TRE


def test_fig7_sweeps_l_1_to_5_and_fig10_counts(reproduction):
    _, results = reproduction
    for bone in ("right-tibia", "right-ilium"):
        for curve in results["experiments"]["fig7"]["bones"][bone]["combinations"].values():
            assert curve["scales"] == pytest.approx(np.arange(1.0, 5.01, 0.2))
            assert curve["mean_tre_mm"] == pytest.approx(np.mean(curve["trials_tre_mm"], axis=0))
        assert list(results["experiments"]["fig10a"]["bones"][bone]["sub_areas"]) == [f"SA{i}" for i in range(1, 9)]
        assert list(results["experiments"]["fig10b"]["bones"][bone]["point_counts"]) == ["8", "16", "24", "32"]


def test_fused_checks_and_calibration_follow_from_the_stored_trials(reproduction):
    from RAMSICPRegistrationLib.experiments.experiment_report import fused_checks

    _, results = reproduction
    fig8 = results["experiments"]["fig8"]["bones"]["right-tibia"]
    measured = np.array(fig8["manual_markers"]["cr-fused"]["trials_mm"])
    predicted = np.array(fig8["fused_prediction"]["manual_markers"]["predicted"]["trials_mm"])
    target_noise = 0.25 / np.sqrt(10)  # each target is the mean of 10 touches of 0.25 mm RMS
    calibration = np.sqrt(np.mean(measured**2)) / np.sqrt(np.mean(predicted**2) + target_noise**2)
    assert fig8["fused_prediction"]["manual_markers"]["calibration"] == pytest.approx(calibration)
    checks = {what: (met, figures) for what, met, figures in fused_checks(results["experiments"])}
    ratio_check = checks["Fig. 8, right-tibia, markers by hand: cr-fused <= 0.75 x CR-ICP"]
    icp = np.mean(fig8["manual_markers"]["CR-ICP"]["trials_mm"])
    assert ratio_check[0] == (measured.mean() <= 0.75 * icp)
    assert any(what.startswith("Fig. 9, right-ilium: cr-fused never more than 0.05 mm worse") for what in checks)


def test_fig8_on_ct_phantoms_uses_the_automatic_centres():
    results = run_experiments(["fig8"], trials=2, subjects=1, image_source="ct")
    subject = results["settings"]["subjects"][0]
    assert subject["automatic_marker_error_max_mm"] < 0.1 and abs(subject["ipc_offset_mm"]) < 0.05
    automatic = results["experiments"]["fig8"]["bones"]["right-tibia"]["automatic_markers"]["CR"]
    assert automatic["mean"] < 0.3  # CR on centres found in the CT, far below the manual 1 mm placement error


def test_unknown_experiment_is_refused():
    with pytest.raises(ValueError, match="experiment\\(s\\) fig11: use fig7"):
        run_experiments(["fig11"], subjects=1)


@pytest.mark.parametrize(
    "curve, words",
    [
        ([1.0, 0.8, 0.7, 0.9, 1.1], "falls, then rises"),
        ([1.0, 0.8, 0.7, 0.7, 0.7], "falls, then stays flat"),
        ([0.7, 0.7, 0.8, 0.9, 1.0], "lowest at small L"),
        ([0.7, 0.705, 0.7, 0.702, 0.7], "flat"),
        ([1.86, 2.05, 1.95, 1.86, 1.86], "rises, then falls back"),
    ],
)
def test_fig7_curve_shapes_in_words(curve, words):
    from RAMSICPRegistrationLib.experiments.experiment_report import _curve_shape

    assert _curve_shape(np.array(curve)).startswith(words)
