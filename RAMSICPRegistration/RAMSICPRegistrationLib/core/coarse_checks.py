"""What the coarse registration (CR, eq. 5) says about the inputs before the fine step uses them.

After the CR every probe point should lie on the bone's surface, within what the CR's own error explains (its
predicted TRE at the point, Fitzpatrick-West-Maurer, ``metrics.predicted_tre``) and the probe noise. Two ways out:

* **A few touches far from the bone** (a touch in the air between touches, on soft tissue, on the drape): each is
  left out of the fine step until the user includes it by hand (``far_touches``), and listed.
* **Most probe points far from the bone**: not outliers but a mistake in the inputs. When undoing one candidate
  mistake brings them onto the bone, they are refused before any fine step runs, naming it: a unit (the probe
  points in metres, centimetres or inches) or a frame (the probe points and the patient markers, or the image
  markers and the IPC, one in LPS and the other read as RAS). Otherwise the registration runs with an alarm naming
  the likely causes: tracker coordinates instead of the reference body's, another session's points, another
  scan's IPC (``diagnose_far_points``).

The CR's marker fit itself is checked against a given marker error (``marker_fit_alarm``): a fit worse than the
FLE explains means a centre misplaced or a marker bent since the CT.
"""

from dataclasses import dataclass

import numpy as np

from .metrics import predicted_tre
from .paired_point import rigid_procrustes
from .transforms import apply_transform

#: A probe point closer than this to the IPC after the CR (mm) is never counted far, whatever the CR's error: a
#: touch through 2-3 mm of periosteum and cartilage still counts as on the bone.
FAR_TOUCH_FLOOR_MM = 3.0
#: Significance at which a probe point is counted far after the CR: its distance over the CR's predicted error
#: and the probe noise there follows at worst chi-square(1) (all the error along the surface normal).
FAR_TOUCH_P = 1e-4
#: A CR whose FRE is above this (mm) pairs its markers wrongly or holds a misplaced one (``core.marker_geometry``'s
#: pairing tolerance).
MARKER_PAIRING_FRE_MM = 2.0
#: RAS from LPS (and back): the mirror a frame mistake applies, a 180-degree turn about the S axis.
_LPS = np.diag([-1.0, -1.0, 1.0])
#: Unit mistakes tried on the probe points: (factor to mm, the words).
_UNITS = ((1000.0, "in metres"), (10.0, "in centimetres"), (25.4, "in inches"))


@dataclass(frozen=True)
class FarTouches:
    """Probe points after the CR: ``distances_mm`` (N,) to the IPC, ``limits_mm`` (N,) beyond which each is far,
    ``far`` (N,) booleans."""

    distances_mm: np.ndarray
    limits_mm: np.ndarray

    @property
    def far(self):
        return self.distances_mm > self.limits_mm

    @property
    def indices(self):
        return tuple(int(i) for i in np.flatnonzero(self.far))

    def describe(self, indices):
        """'3 (7.4 mm, limit 3.0 mm), 9 (5.1 mm, ...)' for 0-based ``indices``, numbered from 1."""
        return ", ".join(
            f"{i + 1} ({self.distances_mm[i]:.1f} mm, limit {self.limits_mm[i]:.1f} mm)" for i in list(indices)[:10]
        ) + (f" and {len(indices) - 10} more" if len(indices) > 10 else "")


def far_touches(index, ppc, coarse_transform, markers_image, fle_mm, probe_noise_mm):
    """Distances of the (N, 3) probe points (reference mm) to the IPC after the CR, and each one's limit.

    The limit at a point is ``FAR_TOUCH_FLOOR_MM`` or ``k sqrt(e^2 + s^2)`` if larger, where ``e`` is the CR's
    predicted RMS error there for ``fle_mm`` (eq. 46 of Fitzpatrick-West-Maurer), ``s`` the probe noise and ``k``
    the chi-square(1) quantile at ``FAR_TOUCH_P`` (3.9).
    """
    from scipy import stats  # here: the command line's --help must not wait for scipy.stats

    at_cr = apply_transform(coarse_transform, ppc)
    distances, _ = index.nearest(at_cr)
    expected = predicted_tre(markers_image, at_cr, fle_mm)
    ratio = float(np.sqrt(stats.chi2.ppf(1.0 - FAR_TOUCH_P, 1)))
    limits = np.maximum(FAR_TOUCH_FLOOR_MM, ratio * np.sqrt(expected**2 + probe_noise_mm**2))
    return FarTouches(np.asarray(distances, dtype=np.float64), limits)


def mostly_far(touches):
    """True when half the probe points or more are far after the CR: a mistake in the inputs, not outliers."""
    return touches.far.sum() * 2 >= len(touches.far)


def diagnose_far_points(index, ppc, markers_patient, markers_image, touches, fre_mm=0.0):
    """(The message refusing probe points that mostly lie far from the IPC after the CR, naming the likely cause;
    whether a tried fix explained it).

    Each candidate mistake is undone on the data (the probe points scaled to mm, mirrored LPS/RAS, the image markers
    mirrored, which is also the IPC mirrored) and the CR applied again; one under which most points come within
    their limits is named. Otherwise tracker coordinates (or another session's points) are named as the likely causes.
    """
    median = float(np.median(touches.distances_mm))
    share = f"{int(touches.far.sum())} of {len(ppc)} probe points lie far from the bone after the coarse " + (
        f"registration on the markers (median {median:.1f} mm from the IPC)"
    )
    for (points, markers), cause in _candidate_fixes(ppc, markers_image):
        distances, _ = index.nearest(apply_transform(rigid_procrustes(markers_patient, markers), points))
        if (distances <= touches.limits_mm).mean() > 0.5:
            return f"{share}: {cause}", True
    if fre_mm > MARKER_PAIRING_FRE_MM:
        return (
            f"{share}, and the marker fit is poor (FRE {fre_mm:.1f} mm): the image and patient marker centres are "
            "paired in the wrong order, or some are misplaced; check them (ramsicp register pairs them by their "
            "distances)"
        ), False
    spread = float(np.sqrt(np.mean(np.sum((ppc - ppc.mean(axis=0)) ** 2, axis=1))))
    where = float(np.linalg.norm(ppc.mean(axis=0)))
    return (
        f"{share}, and no unit or LPS/RAS mistake explains it (the points spread {spread:.0f} mm RMS around a centre "
        f"{where:.0f} mm from the reference's origin). Likely: the probe points (or the patient marker centres) are "
        "in tracker coordinates, not the reference body's (ProbeToReference = inv(ReferenceToTracker) "
        "ProbeToTracker); or the probe points are another session's, the probe's tip was not calibrated, or the IPC "
        "or the image markers are another scan's. Do not use this result before checking them"
    ), False


def _candidate_fixes(ppc, markers_image):
    """((probe points, image markers) with one mistake undone, what to tell the user) for each candidate."""
    for factor, words in _UNITS:
        yield (
            (ppc * factor, markers_image),
            (f"multiplied by {factor:g} they fit the bone, so the probe points look to be {words}; give them in mm"),
        )
    yield (
        (ppc @ _LPS, markers_image),
        (
            "mirrored from LPS to RAS they fit the bone, so the probe points and the patient marker centres are in "
            "different frames (one file LPS read as RAS); give the untagged one's frame (--ppc-space or "
            "--markers-patient-space LPS)"
        ),
    )
    # Mirroring the image markers or the IPC is one test: either puts the two back in one frame.
    yield (
        (ppc, markers_image @ _LPS),
        (
            "with the image marker centres mirrored from LPS to RAS they fit the bone, so the image markers and the "
            "IPC are in different frames (one file LPS read as RAS, e.g. a model exported without its SPACE tag); "
            "give the untagged one's frame (--ipc-space LPS or --markers-image-space LPS)"
        ),
    )


def marker_fit_alarm(fre_mm, marker_count, fle_mm, p_value):
    """An alarm (words) when the CR's FRE exceeds what a given marker error explains at ``p_value``, else None.

    ``K FRE^2 / (FLE^2 / 3)`` follows chi-square(3K - 6) for isotropic FLE (RMS 3-D ``fle_mm``) and K markers.
    """
    from scipy import stats

    freedom = 3 * marker_count - 6
    if freedom < 1 or fle_mm is None:
        return None
    limit = float(np.sqrt(stats.chi2.ppf(1.0 - p_value, freedom) * fle_mm**2 / (3.0 * marker_count)))
    if fre_mm <= limit:
        return None
    return (
        f"The marker fit (FRE {fre_mm:.2f} mm) is worse than the marker error FLE {fle_mm:.2f} mm explains (limit "
        f"{limit:.2f} mm, p < {p_value:g}): a marker centre is misplaced, or the reference body bent or moved on the "
        "bone since the CT. Check the marker centres before using this result."
    )


#: No bone point lies farther than this (mm) from a reference body fixed to that bone; tracker coordinates do (a
#: Polaris measures from 950 mm on).
MAX_REFERENCE_DISTANCE_MM = 700.0
#: Patient marker centres that are a tool's markers must lie where the tool's definition puts them, within this
#: (mm, and degrees): the reference frame is the tool's own frame.
TOOL_FRAME_TOLERANCE = (10.0, 10.0)


def check_reference_frame(points, name, tool_markers=None, tool_name="the reference body"):
    """Raise ValueError when (N, 3) points said to be in the reference body's frame cannot be.

    Two tests: no point lies farther than ``MAX_REFERENCE_DISTANCE_MM`` from the reference's origin; and when
    ``tool_markers`` (K, 3) is given and the points are that tool's markers (they pair by their distances,
    ``core.marker_geometry``), they lie where the tool's definition puts them (the reference frame is the tool's
    frame), within ``TOOL_FRAME_TOLERANCE``. The message names tracker coordinates, or LPS read as RAS when the
    markers are turned 180 degrees about S.
    """
    from .marker_geometry import pair_by_geometry

    points = np.asarray(points, dtype=np.float64)
    farthest = float(np.linalg.norm(points, axis=1).max())
    if farthest > MAX_REFERENCE_DISTANCE_MM:
        raise ValueError(
            f"{name}: a point lies {farthest:.0f} mm from the reference body's origin, farther than any bone it is "
            f"fixed to ({MAX_REFERENCE_DISTANCE_MM:g} mm): they look to be in tracker coordinates; give them in the "
            "reference body's frame (ProbeToReference = inv(ReferenceToTracker) ProbeToTracker)"
        )
    if tool_markers is None or len(points) < 3:
        return
    try:
        pairing = pair_by_geometry(points, tool_markers, reference_name=tool_name)
    except ValueError:
        return  # not this tool's markers: another reference body, nothing to compare with
    if pairing.ambiguous:
        return
    rotation, shift = pairing.transform[:3, :3], float(np.linalg.norm(pairing.transform[:3, 3]))
    angle = float(np.degrees(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0))))
    if shift <= TOOL_FRAME_TOLERANCE[0] and angle <= TOOL_FRAME_TOLERANCE[1]:
        return
    if np.abs(rotation - _LPS).max() < 0.05 and shift <= TOOL_FRAME_TOLERANCE[0]:
        cause = "they look to be LPS read as RAS (or the other way): give the file's frame"
    else:
        cause = "they look to be in tracker coordinates: give them in the reference body's frame"
    raise ValueError(
        f"{name}: these are the markers of {tool_name}, but they lie {shift:.0f} mm and {angle:.0f} degrees from "
        f"where its definition puts them in its own frame, the reference frame; {cause}"
    )
