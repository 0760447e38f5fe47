"""The measured result of a simulated cut as a picture (the paper's Fig. 6b: planned and actual endpoints): the cut
seen in its own plane, with the tool path and both sets of endpoints, and the endpoint errors beside it."""

import numpy as np

from ..io.atomic_files import atomic_path
from .experiment_plots import _pyplot

PLANNED_COLOUR = "#d62728"  # red, as the paper marks the image-space points
EXECUTED_COLOUR = "#1f77b4"  # blue, the points of the actual cut
#: The error arrows in the plane are drawn this many times longer than they are.
ARROW_SCALE = 20.0


def plot_cut_result(result, path):
    """Write ``result`` (``cut_trial.CutResult``) as a PNG of two panels."""
    plt = _pyplot()
    figure, (section_axes, error_axes) = plt.subplots(
        1, 2, figsize=(12.0, 6.6), dpi=110, gridspec_kw={"width_ratios": (1.0, 1.0)}
    )
    _section_panel(section_axes, result)
    _error_panel(error_axes, result)
    figure.suptitle(
        f"Simulated osteotomy of the {result.bone.replace('-', ' ')}: planned vs executed endpoints "
        f"(RMS {result.rms_mm:.2f} mm, executed plane tilted {result.tilt_deg:.2f} deg)",
        fontsize=11,
    )
    figure.text(
        0.5,
        0.015,
        "Executed: the real blade's plane met with the bone (registration, robot calibration, TCP and robot errors "
        "all in); each executed endpoint is the point of the executed cut's edge nearest to the planned one.",
        ha="center",
        fontsize=8,
    )
    figure.tight_layout(rect=(0, 0.04, 1, 0.95))
    with atomic_path(path) as temporary:  # whole or not at all
        figure.savefig(temporary)
    plt.close(figure)


def _section_panel(axes, result):
    plan = result.plan
    for index, section in enumerate((plan.section, result.executed_plan.section)):
        uv = plan.plane.to_plane(section.points)[:, :2]
        segments = uv.reshape(-1, 2, 2)
        colour = "#555555" if index == 0 else EXECUTED_COLOUR
        label = "bone's section in the planned plane" if index == 0 else "executed cut's edge on the bone"
        for number, (first, second) in enumerate(segments):
            axes.plot(*np.transpose((first, second)), color=colour, lw=1.0 if index == 0 else 0.8,
                      ls="-" if index == 0 else "--", label=label if number == 0 else None)  # fmt: skip
    path_uv = plan.plane.to_plane(result.path_positions)[:, :2]
    for number in np.unique(result.pass_index):
        on_pass = path_uv[result.pass_index == number]
        axes.plot(on_pass[:, 0], on_pass[:, 1], color="#e0b000", lw=1.0, alpha=0.8,
                  label="tool path: a pass in and out" if number == 0 else None)  # fmt: skip
    planned = plan.plane.to_plane(result.planned)[:, :2]
    executed = plan.plane.to_plane(result.executed)[:, :2]
    axes.scatter(*planned.T, s=46, color=PLANNED_COLOUR, zorder=5, label="planned endpoints (image)")
    arrows = planned + ARROW_SCALE * (executed - planned)
    axes.scatter(*arrows.T, s=30, color=EXECUTED_COLOUR, marker="D", zorder=5,
                 label=f"executed endpoints (their in-plane offset x{ARROW_SCALE:g})")  # fmt: skip
    for start, end in zip(planned, arrows):
        axes.annotate("", end, start, arrowprops={"arrowstyle": "->", "color": EXECUTED_COLOUR, "lw": 1.0})
    for number, (point, word) in enumerate(zip(planned, result.directions)):
        axes.annotate(f"E{number + 1} {word}", point, textcoords="offset points", xytext=(6, 6), fontsize=8)
    axes.set_aspect("equal")
    # the directions of the +across and the far ends (a whole-bone cut's), in the bone's own words
    across, far = result.directions[0], result.directions[2]
    axes.set_xlabel(f"across the cut (mm), + {across}")
    axes.set_ylabel(f"depth (mm): the blade advances upwards, {far}")
    axes.set_title("The cut in its planned plane", fontsize=9)
    axes.grid(alpha=0.3)
    axes.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2)


def _error_panel(axes, result):
    numbers = np.arange(len(result.labels))
    axes.bar(
        numbers - 0.2,
        result.distance_mm,
        0.36,
        color=EXECUTED_COLOUR,
        label="executed cut's edge from the planned endpoint",
    )
    axes.bar(numbers + 0.2, np.abs(result.normal_mm), 0.36, color="#9ecae1",
             label="its part along the planned normal (the cut's height)")  # fmt: skip
    axes.scatter(numbers, result.registration_error_mm, marker="_", s=500, color="k", zorder=5,
                 label="registration error there (true, 3-D)")  # fmt: skip
    axes.scatter(numbers, result.predicted_error_mm, marker="x", s=40, color=PLANNED_COLOUR, zorder=5,
                 label="cr-fused's predicted registration error")  # fmt: skip
    for number, value in zip(numbers, result.distance_mm):
        axes.annotate(f"{value:.2f}", (number - 0.2, value), textcoords="offset points", xytext=(0, 3),
                      ha="center", fontsize=8)  # fmt: skip
    words = result.directions
    axes.set_xticks(numbers, [f"E{n + 1} {label}\n{words[n]}" for n, label in enumerate(result.labels)], fontsize=8)
    axes.set_ylabel("mm")
    axes.set_ylim(bottom=0.0, top=max(0.5, 1.35 * max(result.registration_error_mm.max(), result.distance_mm.max())))
    axes.set_title("Endpoint errors", fontsize=9)
    axes.grid(alpha=0.3, axis="y")
    axes.legend(fontsize=7, loc="upper left")
