"""The scale-factor sweep of the paper ("Effect of the scale factor": L = 1 to 5, step 0.2) and how to pick L."""

from dataclasses import dataclass

import numpy as np

from .icp import DEFAULT_MAX_ITERATIONS, DEFAULT_MIN_RADIUS_MM, DEFAULT_TOLERANCE_MM, MAX_SCALE, MatchingRanges, ramsicp
from .metrics import target_registration_error
from .transforms import apply_transform

#: The paper's sweep: L = 1.0, 1.2, ..., 5.0 (21 values).
PAPER_SCALES = tuple(np.round(np.linspace(1.0, 5.0, 21), 6))
#: Most L values one sweep runs (one RAMSICP run each, about 1 ms; README, "Speed"): five times the paper's 21,
#: e.g. 1 to 5 step 0.04.
MAX_SCALES = 101


@dataclass(frozen=True)
class SweepEntry:
    """One L of a sweep: the RAMSICP result and, when targets were given, its TRE (eq. 11, mm)."""

    scale: float
    result: object  # FineResult
    tre_mm: float = None

    def to_dict(self):
        return {
            "scale": self.scale,
            "rms_mm": self.result.rms_mm,
            "tre_mm": self.tre_mm,
            "iterations": self.result.iterations,
            "converged": self.result.converged,
        }


def make_scales(start=1.0, stop=5.0, step=0.2):
    """The L values ``start, start + step, ..., stop`` (inclusive), rounded to 1e-6 to keep 1.2 exact.

    Raises ValueError unless ``1 <= start <= stop <= MAX_SCALE``, ``step > 0`` and the range holds at most
    ``MAX_SCALES`` values.
    """
    if not (np.isfinite([start, stop, step]).all() and step > 0 and MAX_SCALE >= stop >= start >= 1.0):
        raise ValueError(
            f"scale range {start:g} to {stop:g} step {step:g}: need 1 <= start <= stop <= {MAX_SCALE:g}, a step above "
            f"0 and at most {MAX_SCALES} values of L (the paper's sweep, 1 5 0.2, has 21)"
        )
    count = int(np.floor((stop - start) / step + 1e-9)) + 1
    if count > MAX_SCALES:
        raise ValueError(
            f"scale range {start:g} to {stop:g} step {step:g}: {count:,} values of L, but a sweep runs at most "
            f"{MAX_SCALES} (the paper's, 1 5 0.2, runs 21); give a larger step"
        )
    return tuple(np.round(start + step * np.arange(count), 6))


def sweep_scales(
    index,
    patient_points,
    coarse_transform,
    scales=PAPER_SCALES,
    targets_patient=None,
    targets_image=None,
    min_radius_mm=DEFAULT_MIN_RADIUS_MM,
    max_iterations=DEFAULT_MAX_ITERATIONS,
    tolerance_mm=DEFAULT_TOLERANCE_MM,
):
    """Run RAMSICP for every L in ``scales`` from one CR result, sharing the KD-tree and one ball query.

    Args:
        index: SurfaceIndex of the IPC.
        patient_points: (N, 3) PPC in reference coordinates (mm), validated.
        coarse_transform: (4, 4) CR ReferenceToImage.
        scales: the L values (each >= 1).
        targets_patient, targets_image: optional (T, 3) targets for the TRE of each L (eq. 11).

    Returns:
        tuple of SweepEntry, in the order of ``scales``.
    """
    cr_points = apply_transform(coarse_transform, patient_points)
    ranges = MatchingRanges(index, cr_points, max(scales), min_radius_mm)
    entries = []
    for scale in scales:
        result = ramsicp(
            index,
            patient_points,
            coarse_transform,
            scale,
            max_iterations=max_iterations,
            tolerance_mm=tolerance_mm,
            ranges=ranges,
        )
        tre = None
        if targets_patient is not None:
            tre = target_registration_error(result.transform, targets_patient, targets_image)
        entries.append(SweepEntry(scale=float(scale), result=result, tre_mm=tre))
    return tuple(entries)
