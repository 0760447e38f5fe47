"""One simulated acquisition registered every way the paper compares: CR, CR-ICP, and CR-RAMSICP for every L."""

from dataclasses import dataclass

import numpy as np

from ..core.registration import POLICIES, register, select_scale


@dataclass(frozen=True)
class TrialResult:
    """TRE (mm, eq. 11) of one trial: CR, CR-ICP, the RAMSICP sweep, and the L each policy picks.

    Attributes:
        cr_mm, icp_mm: TRE of CR and CR-ICP.
        scales: (S,) the sweep's L values; sweep_tre_mm: (S,) RAMSICP's TRE at each.
        chosen: policy -> (L, TRE) for each of ``POLICIES``.
    """

    cr_mm: float
    icp_mm: float
    scales: np.ndarray
    sweep_tre_mm: np.ndarray
    chosen: dict

    def ramsicp_mm(self, policy):
        return self.chosen[policy][1]


def evaluate_trial(index, data, markers_image=None):
    """Register one TrialData (``markers_image`` replaces its image marker centres when given)."""
    common = dict(
        ipc=index,
        ppc=data.ppc,
        markers_image=data.markers_image if markers_image is None else markers_image,
        markers_patient=data.markers_patient,
        targets_image=data.targets_image,
        targets_patient=data.targets_patient,
    )
    cr = register(method="cr", **common).tre_mm
    icp = register(method="cr-icp", **common).tre_mm
    sweep = register(method="cr-ramsicp", sweep=True, policy="targets", **common).sweep
    chosen = {}
    for policy in POLICIES:
        entry = sweep[select_scale(sweep, policy)]
        chosen[policy] = (entry.scale, entry.tre_mm)
    return TrialResult(
        cr_mm=cr,
        icp_mm=icp,
        scales=np.array([entry.scale for entry in sweep]),
        sweep_tre_mm=np.array([entry.tre_mm for entry in sweep]),
        chosen=chosen,
    )
