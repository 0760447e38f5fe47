"""What the browser panel shows, as plain JSON values for trame's state, read from the two controllers.

Nothing here keeps workflow state: every value is computed from ``NavigationController.status()``,
``availability()``, ``last_result`` and its parameter node, and from ``BridgeController.status()``. Figures are
formatted here, once, at the precision the surgeon reads (mm to 2 decimals), so the page and the tests agree.
"""

from ..core.registration import METHODS, POLICIES
from ..navigation.controller import ACTIONS
from ..navigation.navigation import matrix_of
from .scene_display import residual_points
from .sweep_plot import result_sweep_svg

#: Colour of a tracking state's chip (Vuetify colour names).
STATE_COLOURS = {
    "valid": "success",
    "missing": "warning",
    "stale": "warning",
    "waiting": "grey",
    "never seen": "grey",
    "not selected": "grey",
    "disconnected": "error",
}


def millimetres(value, digits=2):
    """'1.23' for a number, '' for None: how every distance is shown (never '-0.00')."""
    if value is None:
        return ""
    text = f"{value:.{digits}f}"
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text


def tool_rows(bridge_status, navigation_status):
    """Chips for the tracker's devices (as the receiver sees them) and the workflow's ProbeToReference (eq. 2)."""
    rows = [{"name": device, "state": state} for device, state in bridge_status.tools]
    probe = navigation_status.tool("ProbeToReference")
    rows.append({"name": probe.label, "state": probe.state})
    for row in rows:
        row["colour"] = STATE_COLOURS.get(row["state"], "grey")
    return rows


def residual_rows(table_node):
    """One row per probe point of the residual table: index (0-based), label, residual (mm text), include, and the
    note of a point flagged by the registration (far from the bone after the CR), '' for the others."""
    if table_node is None or table_node.GetTable() is None:
        return []
    _, residuals, included = residual_points(table_node)
    labels = table_node.GetTable().GetColumnByName("point")
    notes = table_node.GetTable().GetColumnByName("note")
    return [
        {
            "index": row,
            "label": labels.GetValue(row),
            "residual": "" if residual != residual else millimetres(residual),  # NaN: left out of the last run
            "include": bool(include),
            "note": "" if notes is None or row >= notes.GetNumberOfValues() else str(notes.GetValue(row)),
        }
        for row, (residual, include) in enumerate(zip(residuals, included))
    ]


def guidance_state(status):
    """The plan and the live guidance of the cutting tool (issue 15), as the page shows them: the big numbers
    (tip distance to the plan in mm, angle in degrees) and whether the tool is on plan (green) or off (red)."""
    guidance = status.guidance
    return {
        "cut": status.cut,
        "robot": status.robot,
        "robot_progress": [] if status.robot_progress is None else list(status.robot_progress),
        "guidance": None
        if guidance is None
        else {
            "distance": f"{round(guidance.distance_mm, 1) + 0.0:+.1f}",
            "angle": f"{guidance.angle_deg:.1f}",
            "on_plan": bool(guidance.on_plan),
            "text": guidance.text,
        },
    }


def next_touch_state(status, parameters):
    """The next touch (issue 26) as the page shows it: the line for the surgeon, the predicted error now and after
    the touch (mm), whether the touches are enough, the limit, and whether guided collection follows it."""
    touch = status.next_touch
    return {
        "next_touch_text": status.next_touch_text,
        "next_touch": None
        if touch is None
        else {
            "now": millimetres(touch.predicted_tre_mm),
            "after": millimetres(touch.predicted_tre_after_mm),
            "bound": millimetres(touch.bound_95_mm),
            "enough": bool(touch.enough),
            "tip_distance": millimetres(touch.tip_distance_mm, 1),
        },
        "target_tre": parameters.targetTreMm,
        "guided_collect": status.guided_collect,
        "hold_still_collect": status.hold_still_collect,
    }


def checkpoint_state(status):
    """Checkpoints (issue 26): how many are stored, the last store or check in words, and the alarm of one that
    moved (the reference body slipped: navigation and the robot path withheld until a new registration)."""
    return {
        "checkpoint_count": status.checkpoint_count,
        "checkpoint_text": status.checkpoint_text,
        "checkpoint_alarm": status.checkpoint_alarm,
    }


def plane_state(status):
    """The osteotomy plane's placement in the bone's frame (level below the top in mm, tilts and entry in degrees),
    as texts, or None when no plane is placed."""
    placement = status.plane_placement
    if placement is None:
        return {"plane": None}
    return {
        "plane": {
            "level": millimetres(placement.level_mm, 1),
            "tilt_anterior": millimetres(placement.tilt_anterior_deg, 1),
            "tilt_side": millimetres(placement.tilt_side_deg, 1),
            "entry": f"{round(placement.entry_deg) % 360:d}",
        }
    }


def panel_state(controller, bridge_status):
    """The whole panel as a dict of JSON values (trame sends only the keys whose value changed)."""
    status = controller.status()
    parameters = controller.parameters
    result = controller.last_result
    tip_node = parameters.probeTipToProbe
    tip_offset = None if tip_node is None else matrix_of(tip_node, "ProbeTipToProbe")[:3, 3]
    reasons = controller.availability()
    return {
        "connection": bridge_status.connection,
        "tools": tool_rows(bridge_status, status),
        "pivot_recording": status.pivot_recording,
        "pivot_poses": status.pivot_poses,
        "tip_offset": [] if tip_offset is None else [millimetres(value) for value in tip_offset],
        "tip_reference": [] if status.tip_reference_mm is None else [millimetres(v) for v in status.tip_reference_mm],
        "auto_collect": status.auto_collect,
        "auto_collect_mm": parameters.autoCollectDistanceMm,
        "probe_points": status.probe_points,
        "marker_points": status.marker_points,
        "method": parameters.method,
        "policy": parameters.policy,
        "methods": list(METHODS),
        "policies": list(POLICIES),
        "registered": result is not None,
        "fre": "" if result is None else millimetres(result.fre_mm),
        "tre": "" if result is None else millimetres(result.tre_mm),
        "ppc_rms": "" if result is None else millimetres(result.ppc_rms_mm),
        "scale": "" if result is None or result.scale is None else f"{result.scale:g}",
        "residuals": residual_rows(parameters.residualTable),
        "alarms": list(status.alarms),  # a registration not applied until accepted: shown in red, with its button
        "warnings": list(status.warnings),
        "sweep_svg": "" if result is None else result_sweep_svg(result),
        "tip_to_surface": millimetres(status.tip_to_surface_mm, 1),
        **guidance_state(status),
        **next_touch_state(status, parameters),
        **checkpoint_state(status),
        **plane_state(status),
        "message": status.message,
        "message_is_error": status.message_is_error,
        "blocked": {action: reasons.get(action) or "" for action in ACTIONS},
    }
