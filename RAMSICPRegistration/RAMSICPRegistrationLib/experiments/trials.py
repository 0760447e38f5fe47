"""One simulated acquisition registered every way: the paper's CR, CR-ICP and CR-RAMSICP for every L, the point-to-plane
ICP (cr-icp-plane) and cr-fused."""

from dataclasses import dataclass

import numpy as np

from ..core.registration import FUSED_WARNINGS, POLICIES, register, select_scale


@dataclass(frozen=True)
class TrialResult:
    """TRE (mm, eq. 11) of one trial: CR, CR-ICP, the RAMSICP sweep, the L each policy picks, cr-icp-plane and cr-fused.

    Attributes:
        cr_mm, icp_mm: TRE of CR and CR-ICP (the paper's point-to-point ICP).
        scales: (S,) the sweep's L values; sweep_tre_mm: (S,) RAMSICP's TRE at each.
        chosen: policy -> (L, TRE) for each of ``POLICIES``.
        fused_mm: TRE of cr-fused; fused_predicted_mm: the RMS over the targets of its predicted TRE.
        fused_warned: cr-fused gave an alarm (``RegistrationResult.alarms``) or a warning of its own (markers and
            surface disagree, noisy surface, no settling).
        icp_plane_mm: TRE of cr-icp-plane (point-to-plane ICP from the CR, ``core.plane_icp``).
    """

    cr_mm: float
    icp_mm: float
    scales: np.ndarray
    sweep_tre_mm: np.ndarray
    chosen: dict
    fused_mm: float
    fused_predicted_mm: float
    fused_warned: bool
    icp_plane_mm: float

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
    icp_plane = register(method="cr-icp-plane", **common).tre_mm
    sweep = register(method="cr-ramsicp", sweep=True, policy="targets", **common).sweep
    fused = register(method="cr-fused", **common)
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
        fused_mm=fused.tre_mm,
        fused_predicted_mm=fused.predicted_tre_rms_mm,
        fused_warned=bool(fused.alarms) or any(warning.startswith(FUSED_WARNINGS) for warning in fused.warnings),
        icp_plane_mm=icp_plane,
    )
