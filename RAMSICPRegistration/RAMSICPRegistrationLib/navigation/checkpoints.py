"""Checkpoints: points on the bone (a divot, a landmark) touched after the registration and touched again later, to
find out whether the reference body still sits where it sat when the patient was registered.

A checkpoint is stored in reference coordinates, the frame the registration maps to the image: if the reference
body slips on its bracket or on the bone, every bone point moves in that frame, by up to the slip's size, and the
registration no longer holds. Touching a checkpoint again measures that move directly.

Each touch is the **held tip**: the mean tip position (reference coordinates) over the frames of the last
``HOLD_S`` seconds, which must all lie within the hold-still radius of their mean (the tip held in the divot, not
sliding); its standard error is the frames' RMS scatter over the square root of their number. A check compares
the held tip with the nearest stored checkpoint: a move beyond the limit (``checkpointLimitMm``, 0.6 mm by default)
is an alarm. A check whose own noise, three standard errors of the move, reaches the limit is refused (hold the
tip still for longer): the limit then always lies above the noise, so noise alone never raises the alarm, and a
1 mm slip is caught.

The stored checkpoints are the ``Checkpoints`` markups fiducial, drawn under ReferenceToImage (so they sit on the
bone in the CT); each check relabels its point with the move measured.
"""

from collections import deque
from dataclasses import dataclass

import numpy as np

from .mrml_nodes import fiducial_positions, glyph_fiducial_node

#: Seconds of tip frames a held tip averages (the tip rests in the checkpoint while the button is pressed).
HOLD_S = 0.5
#: Fewest frames a held tip needs.
MIN_FRAMES = 5
#: Tip frames kept (s): enough for any hold.
BUFFER_S = 3.0
#: A check farther than this (mm) from every stored checkpoint is not a touch of one.
SEARCH_MM = 10.0
NODE_NAME = "Checkpoints"
COLOUR = (0.2, 0.6, 1.0)
ALARM_COLOUR = (0.9, 0.1, 0.1)


@dataclass(frozen=True)
class HeldTip:
    """The tip held still: ``position`` (3,) mean tip in reference coordinates (mm), ``standard_error_mm`` (3-D RMS
    of the mean's error), ``frames`` averaged, ``spread_mm`` the farthest frame from the mean."""

    position: np.ndarray
    standard_error_mm: float
    frames: int
    spread_mm: float


@dataclass(frozen=True)
class CheckResult:
    """A checkpoint touched again: its ``label``, the move ``distance_mm`` from where it was stored, the move's own
    noise ``sigma_mm`` (one standard error), the ``limit_mm`` and whether it is an ``alarm``."""

    label: str
    distance_mm: float
    sigma_mm: float
    limit_mm: float
    alarm: bool
    held: HeldTip

    @property
    def text(self):
        if self.alarm:
            return (
                f"ALARM: checkpoint {self.label} moved {self.distance_mm:.2f} mm since it was stored (limit "
                f"{self.limit_mm:.2f} mm): the reference body may have slipped and the registration no longer holds. "
                "Check its fixation, collect the probe points again and register again; then store the checkpoints "
                "again"
            )
        return (
            f"checkpoint {self.label}: {self.distance_mm:.2f} mm from where it was stored (limit {self.limit_mm:.2f} "
            f"mm, noise {3 * self.sigma_mm:.2f} mm at 3 sigma): the reference body has not moved"
        )


class TipFrames:
    """The last ``BUFFER_S`` seconds of tip positions (reference coordinates, mm) with their times (s)."""

    def __init__(self):
        self._frames = deque()

    def add(self, time_s, tip):
        self._frames.append((float(time_s), np.asarray(tip, dtype=np.float64)))
        while self._frames and self._frames[0][0] < time_s - BUFFER_S:
            self._frames.popleft()

    def clear(self):
        self._frames.clear()

    @property
    def latest_s(self):
        """Time (s) of the newest frame, or None."""
        return self._frames[-1][0] if self._frames else None

    def held(self, now_s, still_mm, hold_s=HOLD_S):
        """The HeldTip over the frames of the last ``hold_s`` seconds before ``now_s``; ValueError saying what to do
        when there are too few or they spread beyond ``still_mm`` from their mean."""
        tips = np.array([tip for time_s, tip in self._frames if now_s is not None and time_s >= now_s - hold_s])
        tips = tips.reshape(-1, 3)
        if len(tips) < MIN_FRAMES:
            raise ValueError(
                f"only {len(tips)} tip frames in the last {hold_s:g} s (at least {MIN_FRAMES} needed): hold the tip in "
                "the checkpoint while the tracker sees the probe, then press again"
            )
        mean = tips.mean(axis=0)
        spread = float(np.linalg.norm(tips - mean, axis=1).max())
        if spread > still_mm:
            raise ValueError(
                f"the tip moved {spread:.1f} mm in the last {hold_s:g} s (hold-still radius {still_mm:g} mm): hold it "
                "still in the checkpoint, then press again"
            )
        scatter = np.sqrt(np.sum(np.var(tips, axis=0, ddof=1)))
        return HeldTip(mean, float(scatter / np.sqrt(len(tips))), len(tips), spread)


def check(stored_positions, stored_errors, labels, held, limit_mm):
    """CheckResult of a held tip against the nearest of the stored checkpoints ((K, 3) reference mm, their standard
    errors (K,) and labels); ValueError when none lies within ``SEARCH_MM`` or the check is too noisy to tell."""
    distances = np.linalg.norm(np.asarray(stored_positions) - held.position, axis=1)
    nearest = int(np.argmin(distances))
    if distances[nearest] > SEARCH_MM:
        raise ValueError(
            f"the tip is {distances[nearest]:.1f} mm from the nearest checkpoint, {labels[nearest]}: touch a stored "
            "checkpoint (they are drawn on the bone), or store a new one"
        )
    sigma = float(np.hypot(stored_errors[nearest], held.standard_error_mm))
    if 3.0 * sigma >= limit_mm:
        raise ValueError(
            f"checkpoint {labels[nearest]}: the touch is too noisy to tell a move of {limit_mm:.2f} mm (3 sigma "
            f"{3 * sigma:.2f} mm): hold the tip still for longer, then press again"
        )
    distance = float(distances[nearest])
    return CheckResult(labels[nearest], distance, sigma, float(limit_mm), distance > limit_mm, held)


def checkpoint_node(scene, parameters, reference_to_image):
    """The ``Checkpoints`` fiducial (created once, recorded as ``checkpoints``), under ``reference_to_image`` so that
    its points, in reference coordinates, are drawn on the bone in the CT."""
    node = parameters.checkpoints
    if node is None:
        node = glyph_fiducial_node(scene, NODE_NAME, "Diamond3D", 4.0, COLOUR)
        parameters.checkpoints = node
    if reference_to_image is not None and node.GetTransformNodeID() != reference_to_image.GetID():
        node.SetAndObserveTransformNodeID(reference_to_image.GetID())
    node.SetLocked(True)
    return node


def stored(node):
    """(positions (K, 3) reference mm, labels) of the stored checkpoints; the label is the point's name before ':'."""
    if node is None:
        return np.zeros((0, 3)), []
    labels = [node.GetNthControlPointLabel(i).split(":")[0] for i in range(node.GetNumberOfControlPoints())]
    return fiducial_positions(node), labels


def show_check(node, result, alarming):
    """Relabel the checked point with its move (``C1: 1.02 mm MOVED``; ``result`` None relabels nothing) and draw the
    checkpoints red while one of them ``alarming``."""
    if result is not None:
        _, labels = stored(node)
        moved = " MOVED" if result.alarm else ""
        node.SetNthControlPointLabel(labels.index(result.label), f"{result.label}: {result.distance_mm:.2f} mm{moved}")
    node.GetDisplayNode().SetSelectedColor(*(ALARM_COLOUR if alarming else COLOUR))
