"""Beyond the paper: TRE against the number of touches, touched where the guidance says, freely, or as the paper does.

Each trial of a subject places the marker centres by hand (the error model's FLE) and measures the 4 targets, then
registers by cr-fused after every touch, 3 to ``MAX_TOUCHES``, three ways on the same markers and targets:

* **guided**: from the ``START_TOUCHES`` first free touches, each next touch where ``core.touch_guidance`` says it
  lowers the predicted TRE at the plan's targets most, among the IPC's points on the exposed bone
  (``VirtualPatient.exposed_points``: the surface within 15 mm of the paper's sub-areas, facing their way);
* **free**: touches drawn uniformly over the same exposed bone;
* **paper**: the paper's 8 sub-areas x 5 points, taken one per sub-area in turn (8 points: one in each).

Every touch lands on the true surface with the probe's noise. The TRE is eq. 11 at the measured targets, as in
the other experiments. The check: 12 guided touches as good as 40 free ones, within ``MATCH_TOLERANCE_MM``.
"""

import numpy as np

from ..core.registration import register
from ..core.touch_guidance import best_touch

ARMS = ("guided", "free", "paper")
START_TOUCHES = 3
MAX_TOUCHES = 40
#: Guided touches that should do as well as ``MAX_TOUCHES`` free ones, and by how much they may fall short (mm).
GUIDED_TOUCHES = 12
MATCH_TOLERANCE_MM = 0.05
#: The IPC's points within this distance (mm) of the exposed true surface are the touches the guidance may choose.
REACHABLE_MM = 0.5


def run_guided(subjects, trials, rng, progress, acquire, probe_noise_mm):
    """The guided experiment on one bone's subjects: ``trials`` trials, the subjects in turn.

    Args:
        subjects: ``experiments.Subject`` of one bone.
        acquire: ``acquire(subject, rng)`` -> TrialData with the markers placed by hand and 8 x 5 sub-area points.
        probe_noise_mm: RMS 3-D error of one touch.

    Returns:
        ``{"counts", "arms": {arm: {"mean_tre_mm", "sd_tre_mm", "trials_tre_mm"}}, "guided_predicted_mm",
        "trials": [per trial: "subject", "markers_image", "targets_patient", "touches_patient" {arm: (40, 3)},
        "suggested_image" (37, 3)], "check"}``: TREs in mm per count of touches, every touch as registered.
    """
    counts = list(range(START_TOUCHES, MAX_TOUCHES + 1))
    tre = {arm: np.empty((trials, len(counts))) for arm in ARMS}
    predicted = np.empty((trials, len(counts)))
    reachable = {}
    records = []
    for trial in range(trials):
        subject = subjects[trial % len(subjects)]
        if subject.name not in reachable:
            reachable[subject.name] = reachable_points(subject)
        data = acquire(subject, rng)
        case = (data.markers_image, data.markers_patient, data.targets_image, data.targets_patient)
        free = subject.patient.random_touches(rng, MAX_TOUCHES, probe_noise_mm)
        paper = data.ppc[_round_robin(data.sub_area)]
        for column, count in enumerate(counts):
            tre["free"][trial, column] = register(subject.index, free[:count], *case).tre_mm
            tre["paper"][trial, column] = register(subject.index, paper[:count], *case).tre_mm
        guided, touched = free[:START_TOUCHES], []
        for column, count in enumerate(counts):
            result = register(subject.index, guided, *case)
            tre["guided"][trial, column], predicted[trial, column] = result.tre_mm, result.predicted_tre_rms_mm
            if count == MAX_TOUCHES:
                break
            # touch_guidance's next touch, without the 95 % bounds it also computes (not needed here).
            suggestion = best_touch(result.uncertainty, data.targets_image, subject.index, reachable[subject.name])
            touched.append(suggestion.position_image)
            guided = np.vstack((guided, subject.patient.touch(rng, suggestion.position_image, probe_noise_mm)))
        records.append(
            {
                "subject": subject.name,
                "markers_image": data.markers_image.tolist(),
                "targets_patient": data.targets_patient.tolist(),
                "touches_patient": {"guided": guided.tolist(), "free": free.tolist(), "paper": paper.tolist()},
                "suggested_image": np.array(touched).tolist(),
            }
        )
        if progress is not None:
            progress("guided", trial + 1, trials)
    return _summary(counts, tre, predicted, records)


def reachable_points(subject):
    """(R, 3) the subject's IPC points within ``REACHABLE_MM`` of its exposed true surface (image coordinates)."""
    from scipy.spatial import cKDTree

    distances, _ = cKDTree(subject.patient.exposed_points).query(
        subject.index.points, distance_upper_bound=REACHABLE_MM
    )
    return subject.index.points[np.isfinite(distances)]


def _round_robin(sub_area):
    """Indices of the probe points one per sub-area in turn: the first of each sub-area, then the second, ..."""
    rank = np.zeros(len(sub_area), dtype=int)
    for area in np.unique(sub_area):
        members = np.flatnonzero(sub_area == area)
        rank[members] = np.arange(len(members))
    return np.lexsort((sub_area, rank))


def _summary(counts, tre, predicted, records):
    arms = {
        arm: {
            "mean_tre_mm": values.mean(axis=0).tolist(),
            "sd_tre_mm": (values.std(axis=0, ddof=1) if len(values) > 1 else np.zeros(len(counts))).tolist(),
            "trials_tre_mm": values.tolist(),
        }
        for arm, values in tre.items()
    }
    guided = tre["guided"].mean(axis=0)
    free_all = float(tre["free"][:, -1].mean())
    within = np.flatnonzero(guided <= free_all + MATCH_TOLERANCE_MM)
    at = counts.index(GUIDED_TOUCHES)
    return {
        "counts": counts,
        "arms": arms,
        "guided_predicted_mm": predicted.mean(axis=0).tolist(),
        "trials": records,
        "check": {
            "guided_touches": GUIDED_TOUCHES,
            "guided_mm": float(guided[at]),
            "free_touches": MAX_TOUCHES,
            "free_mm": free_all,
            "paper_mm": float(tre["paper"][:, -1].mean()),
            "tolerance_mm": MATCH_TOLERANCE_MM,
            "met": bool(guided[at] <= free_all + MATCH_TOLERANCE_MM),
            "guided_touches_to_match": int(counts[within[0]]) if within.size else None,
            "trials": int(len(tre["guided"])),
        },
    }
