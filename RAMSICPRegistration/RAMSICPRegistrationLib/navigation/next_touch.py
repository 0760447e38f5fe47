"""Where to touch next and when to stop, for every shell: ``core.touch_guidance`` on the workflow's nodes.

After a registration by cr-fused is applied (or accepted), the controller asks here for the next touch: the
reachable bone point where one more probe touch lowers the predicted error at the plan's targets most (the
planned cut's endpoints once a cut is planned, else the selected image targets), with the predicted error now and
after that touch. 'Enough' is the targets' 95 % bounds (``core.error_prediction``, E2) all below the parameter
node's ``targetTreMm``; it is judged when the status is read, so a new limit needs no new computation.

The suggestion is drawn on the bone in every view as the ``NextTouch`` markups fiducial (image coordinates,
labelled ``next: 0.21 mm``, the predicted error after the touch), which is all a shell needs to show it.
"""

from dataclasses import dataclass

import numpy as np

from ..core.touch_guidance import touch_guidance
from .mrml_nodes import glyph_fiducial_node
from .navigation import points_of

#: A touch within this distance (mm) of the suggestion is taken by guided collection (the prediction hardly changes
#: over a few mm of bone; a hand finds a drawn point to 2-3 mm).
GUIDED_RADIUS_MM = 5.0
#: How the suggestion is drawn: its colour (RGB), glyph size (mm) and name.
NODE_NAME = "NextTouch"
COLOUR = (1.0, 0.55, 0.0)
GLYPH_MM = 4.0


@dataclass(frozen=True)
class NextTouch:
    """What the shells show about the next touch. Distances in mm.

    Attributes:
        position_image: (3,) the suggested point on the bone, image RAS.
        predicted_tre_mm: the predicted RMS error over the targets now; ``predicted_tre_after_mm`` after the touch.
        bound_95_mm: the largest target's 95 % bound now; enough when it is below ``target_tre_mm``.
        targets: what the targets are, in words ('the planned cut's endpoints' or 'the targets').
        tip_distance_mm: the tracked tip's distance to the suggestion (image), or None when not tracked.
    """

    position_image: tuple
    predicted_tre_mm: float
    predicted_tre_after_mm: float
    bound_95_mm: float
    target_tre_mm: float
    enough: bool
    targets: str
    tip_distance_mm: float = None

    @property
    def text(self):
        """One line for the surgeon."""
        figures = (
            f"predicted error at {self.targets} {self.predicted_tre_mm:.2f} mm (95 % bound {self.bound_95_mm:.2f} mm, "
            f"limit {self.target_tre_mm:.2f} mm)"
        )
        after = f"{self.predicted_tre_after_mm:.2f} mm"
        if self.enough:
            return f"ENOUGH touches: {figures}; one more at the drawn point would give {after}"
        where = "" if self.tip_distance_mm is None else f", the tip is {self.tip_distance_mm:.1f} mm from it"
        return f"next touch: the point drawn on the bone{where}; it brings {after}; {figures}"


def guidance_targets(planned_cut, targets_node):
    """(targets (T, 3) image RAS, their name) for the next touch: the planned cut's endpoints, else the selected
    image targets; ValueError saying what to do when there are neither."""
    if planned_cut is not None:
        return planned_cut.endpoints, "the planned cut's endpoints"
    if targets_node is not None and targets_node.GetNumberOfControlPoints():
        return points_of(targets_node, "targets (image)"), "the targets"
    raise ValueError("the next touch needs the plan's targets: plan the cut, or select targets in the image")


def compute(result, index, targets_image, reachable_node=None):
    """TouchGuidance (one touch) of a registration at the targets, the reachable bone from ``reachable_node`` (a
    model or markups in image coordinates) or the whole IPC; ValueError with what to do otherwise."""
    if result.uncertainty is None:
        raise ValueError(f"it needs cr-fused's predicted error, which {result.method} does not give: choose cr-fused")
    reachable = None if reachable_node is None else points_of(reachable_node, "reachable surface")
    return touch_guidance(result, index, targets_image=targets_image, reachable=reachable)


def status_of(guidance, targets_name, target_tre_mm, tip_image=None):
    """The NextTouch of a TouchGuidance against the limit ``target_tre_mm``, with the tip (3,) image RAS if tracked."""
    touch = guidance.next_touch
    bound = float(np.max(guidance.predicted_tre_95_mm))
    distance = None if tip_image is None else float(np.linalg.norm(np.asarray(tip_image) - touch.position_image))
    return NextTouch(
        position_image=tuple(float(value) for value in touch.position_image),
        predicted_tre_mm=guidance.predicted_tre_rms_mm,
        predicted_tre_after_mm=touch.predicted_tre_rms_mm,
        bound_95_mm=bound,
        target_tre_mm=float(target_tre_mm),
        enough=bool(bound < target_tre_mm),
        targets=targets_name,
        tip_distance_mm=distance,
    )


def draw(scene, parameters, guidance):
    """Show the suggestion as the ``NextTouch`` fiducial (created once, recorded as ``nextTouch``), or remove its
    point when there is none (``guidance`` None)."""
    node = parameters.nextTouch
    if node is None:
        if guidance is None:
            return None
        node = glyph_fiducial_node(scene, NODE_NAME, "Sphere3D", GLYPH_MM, COLOUR)
        parameters.nextTouch = node
    node.RemoveAllControlPoints()
    if guidance is not None:
        touch = guidance.next_touch
        node.AddControlPoint(touch.position_image.tolist(), f"next: {touch.predicted_tre_rms_mm:.2f} mm")
    node.SetLocked(True)
    return node
