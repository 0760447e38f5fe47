"""A new user's mistakes applied to a correct session, run through ``ramsicp collect`` and ``ramsicp register``
(``benchmarks/user_mistakes.py`` runs 200 and more): every case is refused (exit 2, one line), alarmed (exit 4, one
line) or correct (exit 0, within 1 mm of the truth at the osteotomy targets); never wrong with exit 0, never a
traceback. Each mistake once, then random pairs of them."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import user_mistakes  # noqa: E402

#: Mistakes that cannot give a right result as written: never correct with exit 0 (the checks must catch them).
CANNOT_BE_RIGHT = {
    "patient_markers_in_metres",
    "patient_markers_in_cm",
    "probe_points_in_metres",
    "probe_points_in_cm",
    "probe_points_in_inches",
    "probe_points_lps_untagged",
    "patient_markers_lps_untagged",
    "ipc_lps_without_tag",
    "image_markers_lps_untagged",
    "probe_points_in_tracker_coordinates",
    "patient_markers_in_tracker_coordinates",
    "both_patient_files_in_tracker_coordinates",
    "nan_probe_point",
    "duplicated_patient_marker",
    "tip_in_cm",
    "tip_in_metres",
    "tip_with_a_wrong_sign",
    "tip_of_another_probe",
}
#: Mistakes the program must absorb: the result is right (re-paired, read by name, left out, ...).
ABSORBED = {
    "patient_markers_shuffled",
    "image_markers_unnumbered_and_shuffled",
    "touches_in_the_air",
    "csv_header_z_y_x",
    "csv_decimal_commas",
    "tip_right_through_collect",
}

#: What the one line must name for a mistake refused before any work: the likely cause.
NAMED_CAUSE = {
    "patient_markers_in_metres": "look to be in metres",
    "patient_markers_in_cm": "look to be in centimetres",
    "probe_points_in_metres": "look to be in metres",
    "probe_points_in_cm": "look to be in centimetres",
    "probe_points_in_inches": "look to be in inches",
    "probe_points_lps_untagged": "one file LPS read as RAS",
    "patient_markers_lps_untagged": "LPS read as RAS",
    "ipc_lps_without_tag": "one file LPS read as RAS",
    "image_markers_lps_untagged": "one file LPS read as RAS",
    "probe_points_in_tracker_coordinates": "tracker coordinates",
    "patient_markers_in_tracker_coordinates": "tracker coordinates",
    "both_patient_files_in_tracker_coordinates": "tracker coordinates",
    "nan_probe_point": "contain NaN",
    "duplicated_patient_marker": "the same sphere twice",
    "tip_in_cm": "in centimetres",
    "tip_in_metres": "in metres",
}


def test_both_image_files_untagged_need_their_frame_given(tmp_path):
    """The IPC and the image markers both LPS without a tag: they agree with each other (a mirror about S is a
    rotation), so no check could see it; neither stating its frame, the frame must be given."""
    mistakes = ["ipc_lps_without_tag", "image_markers_lps_untagged"]
    outcome, _, detail = user_mistakes.run_case(2, tmp_path, mistakes)
    assert outcome == "refused" and "states its coordinate frame" in detail and "--untagged-space RAS or LPS" in detail
    outcome, _, detail = user_mistakes.run_case(
        2, tmp_path, mistakes, ["--ipc-space", "LPS", "--markers-image-space", "LPS"]
    )
    assert outcome == "correct", detail


@pytest.mark.parametrize("mistake", list(user_mistakes.MISTAKES))
def test_each_mistake_alone_is_refused_alarmed_or_right(tmp_path, mistake):
    outcome, _, detail = user_mistakes.run_case(7, tmp_path, [mistake])
    assert outcome in ("refused", "alarmed", "correct"), f"{mistake}: {outcome}: {detail}"
    if mistake in CANNOT_BE_RIGHT:
        assert outcome in ("refused", "alarmed"), f"{mistake}: {outcome}: {detail}"
    if mistake in ABSORBED:
        assert outcome == "correct", f"{mistake}: {outcome}: {detail}"
    if mistake in NAMED_CAUSE:
        assert outcome == "refused" and NAMED_CAUSE[mistake] in detail, f"{mistake}: {outcome}: {detail}"


@pytest.mark.parametrize("seed", range(12))
def test_random_mistakes_are_never_wrong_with_exit_0(tmp_path, seed):
    outcome, mistakes, detail = user_mistakes.run_case(10_000 + seed, tmp_path)
    assert outcome in ("refused", "alarmed", "correct"), f"{' + '.join(mistakes)}: {outcome}: {detail}"
