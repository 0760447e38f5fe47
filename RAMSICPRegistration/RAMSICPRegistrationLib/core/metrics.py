"""Error measures: TRE (paper eq. 11), surface residuals, and the Fitzpatrick-West-Maurer TRE prediction."""

import numpy as np

from .transforms import apply_transform


def target_registration_error(reference_to_image, targets_patient, targets_image):
    """Paper eq. 11: RMS distance (mm) between image targets ``Y_n`` and registered patient targets ``T X_n``.

    Args:
        reference_to_image: (4, 4) registration.
        targets_patient: (T, 3) targets ``X_n`` in reference coordinates (mm).
        targets_image: (T, 3) the same targets ``Y_n`` in image coordinates (mm).
    """
    errors = target_errors(reference_to_image, targets_patient, targets_image)
    return float(np.sqrt(np.mean(errors**2)))


def target_errors(reference_to_image, targets_patient, targets_image):
    """Distance (mm) of each registered target from its image position, (T,)."""
    return np.linalg.norm(apply_transform(reference_to_image, targets_patient) - targets_image, axis=1)


def surface_residuals(index, reference_to_image, patient_points):
    """Distance (mm) of each registered patient point to its closest IPC point, (N,)."""
    return index.nearest(apply_transform(reference_to_image, patient_points))[0]


def rms(values):
    """Root mean square of an array of distances (mm)."""
    values = np.asarray(values, dtype=np.float64)
    return float(np.sqrt(np.mean(values**2)))


def fle_from_fre(fre_mm, marker_count):
    """Estimate the fiducial localisation error (RMS, mm) from an observed FRE.

    Uses the expectation ``<FRE^2> = (1 - 2/N) <FLE^2>`` for a rigid fit in 3-D (Fitzpatrick, West and
    Maurer 1998). With 4 markers the estimate is itself uncertain by about +-40 %.
    """
    if marker_count <= 2:
        raise ValueError(f"marker_count = {marker_count}: at least 3 markers are needed to estimate FLE")
    return float(fre_mm / np.sqrt(1.0 - 2.0 / marker_count))


def predicted_tre(fiducials, targets, fle_mm):
    """Expected RMS TRE (mm) at each target for isotropic FLE (Fitzpatrick, West and Maurer 1998, eq. 46).

    ``TRE^2(r) = FLE^2 / N * (1 + 1/3 * sum_k d_k^2 / f_k^2)``, where ``d_k`` is the distance of the target
    from principal axis k of the fiducial configuration and ``f_k`` the RMS distance of the fiducials from
    that axis.

    Args:
        fiducials: (N, 3) marker centres in any frame (mm), N >= 3, not collinear.
        targets: (T, 3) targets in the same frame (mm).
        fle_mm: RMS fiducial localisation error (mm).

    Returns:
        (T,) predicted RMS TRE in mm.
    """
    centre = fiducials.mean(axis=0)
    centred = fiducials - centre
    offsets = np.asarray(targets, dtype=np.float64) - centre
    _, _, principal_axes = np.linalg.svd(centred)
    ratio_sum = np.zeros(len(offsets))
    for axis in principal_axes:
        fiducial_squared = np.mean(np.sum(centred**2, axis=1) - (centred @ axis) ** 2)  # f_k^2
        target_squared = np.sum(offsets**2, axis=1) - (offsets @ axis) ** 2  # d_k^2
        ratio_sum += target_squared / fiducial_squared
    return fle_mm / np.sqrt(len(fiducials)) * np.sqrt(1.0 + ratio_sum / 3.0)
