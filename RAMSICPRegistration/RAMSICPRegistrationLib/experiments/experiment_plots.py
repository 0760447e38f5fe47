"""The reproduction's figures (Figs. 7-10 and the guided touches), one PNG each, a panel per bone, every mark explained
on the figure.

Each figure says what its bars or bands are (mean +- 1 sd over the trials, with their number), draws the paper's
own numbers where the paper gives them, and offsets series that share an x so none hides another.
"""

import numpy as np

from ..io.atomic_files import atomic_path
from .experiments import FUSED, PAPER, PLANE, TARGET_FREE

RAMSICP_PAPER = "CR-RAMSICP (paper's L)"
RAMSICP_FREE = f"CR-RAMSICP ({TARGET_FREE})"
#: Every method in the order and colour the figures use.
COLOURS = {
    "CR": "#7f7f7f",
    "CR-ICP": "#1f77b4",
    PLANE: "#9467bd",
    RAMSICP_PAPER: "#ff7f0e",
    RAMSICP_FREE: "#2ca02c",
    FUSED: "#d62728",
}
SHORT = {
    "CR": "CR",
    "CR-ICP": "CR-ICP",
    PLANE: "CR-ICP\npoint to plane",
    RAMSICP_PAPER: "CR-RAMSICP\n(paper's L)",
    RAMSICP_FREE: f"CR-RAMSICP\n({TARGET_FREE})",
    FUSED: FUSED,
}
BONE_COLOURS = ("#4c72b0", "#dd8452", "#55a868", "#8172b3")
PAPER_COLOUR = "#bbbbbb"
PAPER_SPAN = "#e8f0e8"
SD_NOTE = "Error bars: mean +- 1 standard deviation over the trials (n given per panel)."


def plot_fig7(data, path):
    """TRE against L for the three sub-area combinations, a panel per bone; cr-fused and the paper's levels drawn."""
    plt, figure, panels = _panels(data["bones"])
    symbols = ("o", "s", "^")
    paper_icp, paper_ramsicp = PAPER["fig8"]["CR-ICP"][0], PAPER["fig8"]["CR-RAMSICP"][0]
    for axes, (bone, bone_data) in zip(panels, data["bones"].items()):
        count = None
        for number, (name, curve) in enumerate(bone_data["combinations"].items()):
            scales, mean, sd = (np.array(curve[key]) for key in ("scales", "mean_tre_mm", "sd_tre_mm"))
            count = len(curve["trials_tre_mm"])
            colour = BONE_COLOURS[number]
            axes.plot(scales, mean, "-", color=colour, marker=symbols[number], markersize=3, label=f"{name}")
            shown = np.isin(np.round(scales, 6), (1.0, 2.0, 3.0, 4.0, 5.0))
            offset = (number - 1) * 0.06
            axes.errorbar(scales[shown] + offset, mean[shown], yerr=sd[shown], fmt="none", ecolor=colour, capsize=2)
            axes.axhline(curve["fused"]["mean"], color=colour, linestyle=(0, (1, 3)), linewidth=1.2)
        axes.axhline(paper_ramsicp, color="black", linestyle="--", linewidth=0.8)
        axes.axhline(paper_icp, color="black", linestyle="-.", linewidth=0.8)
        _label(axes, f"{_bone(bone)} (n = {count} trials per combination)", "scale factor L")
    handles, labels = panels[0].get_legend_handles_labels()
    handles += [
        plt.Line2D([], [], color="grey", linestyle=(0, (1, 3)), linewidth=1.2),
        plt.Line2D([], [], color="black", linestyle="--", linewidth=0.8),
        plt.Line2D([], [], color="black", linestyle="-.", linewidth=0.8),
    ]
    labels += [
        f"{FUSED} on the same trials (no L), in the combination's colour",
        f"paper, Fig. 8: CR-RAMSICP {paper_ramsicp:.2f} mm (40 points)",
        f"paper, Fig. 8: CR-ICP {paper_icp:.2f} mm",
    ]
    _finish(
        plt,
        figure,
        path,
        "Fig. 7: CR-RAMSICP's TRE against the scale factor L, three sub-area combinations",
        handles,
        labels,
        "Error bars at L = 1, 2, 3, 4, 5: +- 1 sd over the trials. The paper's Fig. 7 curves are not given in "
        "numbers; its Fig. 8 levels are drawn for scale.",
    )


def plot_fig8(data, path):
    """Mean TRE per method, markers by hand and automatic, a bar per bone beside the paper's."""
    plt = _pyplot()
    figure, panels = plt.subplots(1, 2, figsize=(12.0, 4.8), dpi=110, sharey=False)
    bones = list(data["bones"])
    methods = list(COLOURS)
    for axes, mode, title in zip(
        panels, ("manual_markers", "automatic_markers"), ("markers placed by hand", "markers found in the CT")
    ):
        groups = len(bones) + (1 if mode == "manual_markers" else 0)
        width = 0.8 / groups
        positions = np.arange(len(methods))
        slot = 0
        if mode == "manual_markers":
            paper = [PAPER["fig8"].get({RAMSICP_PAPER: "CR-RAMSICP"}.get(m, m), (np.nan, np.nan)) for m in methods]
            axes.bar(
                positions + (slot - (groups - 1) / 2) * width,
                [p[0] for p in paper],
                width,
                yerr=[p[1] for p in paper],
                capsize=2,
                color=PAPER_COLOUR,
                label="paper (porcine iliums, n = 15)",
            )
            slot += 1
        for number, bone in enumerate(bones):
            rows = data["bones"][bone][mode]
            axes.bar(
                positions + (slot - (groups - 1) / 2) * width,
                [rows[m]["mean"] for m in methods],
                width,
                yerr=[rows[m]["sd"] for m in methods],
                capsize=2,
                color=BONE_COLOURS[number],
                label=f"{_bone(bone)} (n = {rows['CR']['n']})",
            )
            slot += 1
        axes.set_xticks(positions)
        axes.set_xticklabels([SHORT[m] for m in methods], fontsize=8)
        axes.set_title(title, fontsize=10)
        axes.set_ylabel("TRE (mm)")
        axes.grid(alpha=0.3, axis="y")
        axes.legend(fontsize=7)
    figure.suptitle("Fig. 8: TRE by method", fontsize=11)
    figure.text(0.5, 0.01, SD_NOTE, ha="center", fontsize=8)
    figure.tight_layout(rect=(0, 0.04, 1, 0.95))
    with atomic_path(path) as temporary:  # whole or not at all
        figure.savefig(temporary)
    plt.close(figure)


def plot_fig9(data, path):
    """TRE against the CR error, a panel per bone, the series side by side, the 1 mm goal labelled."""
    plt, figure, panels = _panels(data["bones"])
    methods = ("CR-ICP", PLANE, RAMSICP_PAPER, RAMSICP_FREE, FUSED)
    goal = PAPER["fig9_below_1_mm_up_to"]
    for axes, (bone, bone_data) in zip(panels, data["bones"].items()):
        levels = np.array([float(level) for level in bone_data["levels"]])
        rows = list(bone_data["levels"].values())
        axes.plot(levels, levels, color=COLOURS["CR"], linewidth=0.8, label="CR (its TRE is the x value)")
        _side_by_side(axes, levels, rows, methods, spacing=0.07)
        axes.axhline(1.0, color="black", linestyle="--", linewidth=0.8)
        axes.axvspan(levels[0] - 0.35, goal + 0.25, color=PAPER_SPAN, zorder=0)
        counts = sorted({row["CR-ICP"]["n"] for row in rows})
        title = f"{_bone(bone)} (n = {', '.join(map(str, counts))} trials per point)"
        _label(axes, title, "CR error (TRE of the coarse registration, mm)")
        axes.set_xlim(levels[0] - 0.35, levels[-1] + 0.35)
        axes.set_ylim(0.0, max(levels[-1] + 0.5, axes.get_ylim()[1]))
    from matplotlib.patches import Patch

    handles, labels = panels[0].get_legend_handles_labels()
    handles += [plt.Line2D([], [], color="black", linestyle="--", linewidth=0.8), Patch(color=PAPER_SPAN)]
    labels += ["1 mm: the paper's accuracy goal", f"paper: CR-RAMSICP under 1 mm up to a CR error of {goal:g} mm"]
    _finish(plt, figure, path, "Fig. 9: robustness to the CR error", handles, labels, SD_NOTE)


def plot_fig10a(data, path):
    """TRE with the 5 points of one sub-area, a panel per bone, CR beside the surface methods."""
    _grouped_bars(data, "sub_areas", path, "Fig. 10a: the 5 probe points of one sub-area at a time", "sub-area")


def plot_fig10b(data, path):
    """TRE against the number of probe points, a panel per bone, the series side by side."""
    plt, figure, panels = _panels(data["bones"])
    for axes, (bone, bone_data) in zip(panels, data["bones"].items()):
        counts = np.array([int(count) for count in bone_data["point_counts"]])
        rows = list(bone_data["point_counts"].values())
        _side_by_side(axes, counts, rows, list(COLOURS), spacing=0.8)
        axes.set_xticks(counts)
        title = f"{_bone(bone)} (n = {rows[0]['CR']['n']} trials per point)"
        _label(axes, title, "probe points (1 to 4 in each of the 8 sub-areas)")
    handles, labels = panels[0].get_legend_handles_labels()
    _finish(
        plt,
        figure,
        path,
        "Fig. 10b: number of probe points",
        handles,
        labels,
        SD_NOTE + " Each count is a new set of random trials: differences within about 2 sd/sqrt(n) are noise.",
    )


#: The guided experiment's arms, in the order and colour its figure uses.
ARM_STYLES = {
    "guided": ("#d62728", "guided by the predicted TRE (cr-fused)"),
    "free": ("#1f77b4", "free: anywhere on the exposed bone"),
    "paper": ("#7f7f7f", "the paper's 8 sub-areas, one each in turn"),
}


def plot_guided(data, path):
    """TRE against the number of touches, a panel per bone: guided, free and the paper's sub-areas, +- 1 sd bands,
    the guided touches' own predicted TRE, and the check: 12 guided touches against 40 free ones + 0.05 mm."""
    plt, figure, panels = _panels(data["bones"])
    for axes, (bone, bone_data) in zip(panels, data["bones"].items()):
        counts = np.array(bone_data["counts"])
        check = bone_data["check"]
        for arm, (colour, label) in ARM_STYLES.items():
            mean, sd = (np.array(bone_data["arms"][arm][key]) for key in ("mean_tre_mm", "sd_tre_mm"))
            axes.plot(counts, mean, color=colour, linewidth=1.5, label=label)
            axes.fill_between(counts, mean - sd, mean + sd, color=colour, alpha=0.12, linewidth=0)
        axes.plot(counts, bone_data["guided_predicted_mm"], color=ARM_STYLES["guided"][0], linestyle=":",
                  linewidth=1.2, label="guided: its predicted TRE (RMS)")  # fmt: skip
        level = check["free_mm"] + check["tolerance_mm"]
        axes.axhline(level, color="black", linestyle="--", linewidth=0.8)
        axes.axvline(check["guided_touches"], color="black", linestyle=(0, (1, 3)), linewidth=0.8)
        axes.plot([check["guided_touches"]], [check["guided_mm"]], "o", color=ARM_STYLES["guided"][0], markersize=5)
        verdict = "met" if check["met"] else "not met"
        _label(axes, f"{_bone(bone)} (n = {check['trials']} trials; 12 guided {check['guided_mm']:.2f} mm vs "
                     f"40 free {check['free_mm']:.2f} mm: {verdict})", "touches (probe points)")  # fmt: skip
        axes.set_xlim(counts[0] - 0.5, counts[-1] + 0.5)
        top = max(np.max(np.array(bone_data["arms"][arm]["mean_tre_mm"])[counts >= 5]) for arm in ARM_STYLES)
        axes.set_ylim(0.0, 1.3 * top)
    handles, labels = panels[0].get_legend_handles_labels()
    handles += [plt.Line2D([], [], color="black", linestyle="--", linewidth=0.8),
                plt.Line2D([], [], color="black", linestyle=(0, (1, 3)), linewidth=0.8)]  # fmt: skip
    labels += ["40 free touches' mean TRE + 0.05 mm (the target)", "12 touches"]
    _finish(
        plt,
        figure,
        path,
        "Guided touches: TRE at the plan's targets against the number of touches (cr-fused, markers placed by hand)",
        handles,
        labels,
        "Lines: mean over the trials; bands: +- 1 sd. The same markers and targets in every arm; the guided and free "
        "touches start from the same 3 free ones. TRE: eq. 11 at the 4 measured targets.",
    )


PLOTS = {
    "fig7": plot_fig7,
    "fig8": plot_fig8,
    "fig9": plot_fig9,
    "fig10a": plot_fig10a,
    "fig10b": plot_fig10b,
    "guided": plot_guided,
}


def _side_by_side(axes, x, rows, methods, spacing):
    """Mean +- sd of each method over ``rows`` against ``x``, each series shifted by ``spacing`` to stay visible."""
    for number, method in enumerate(methods):
        mean = np.array([row[method]["mean"] for row in rows])
        sd = np.array([row[method]["sd"] for row in rows])
        offset = (number - (len(methods) - 1) / 2) * spacing
        axes.errorbar(
            x + offset, mean, yerr=sd, marker="o", markersize=3, capsize=2, linewidth=1, color=COLOURS[method],
            label=method,
        )  # fmt: skip


def _grouped_bars(data, key, path, title, xlabel):
    plt, figure, panels = _panels(data["bones"])
    methods = list(COLOURS)
    width = 0.8 / len(methods)
    for axes, (bone, bone_data) in zip(panels, data["bones"].items()):
        groups = bone_data[key]
        positions = np.arange(len(groups))
        for number, method in enumerate(methods):
            axes.bar(
                positions + (number - (len(methods) - 1) / 2) * width,
                [groups[g][method]["mean"] for g in groups],
                width,
                yerr=[groups[g][method]["sd"] for g in groups],
                capsize=1.5,
                color=COLOURS[method],
                label=method,
                error_kw={"linewidth": 0.7},
            )
        axes.set_xticks(positions)
        axes.set_xticklabels(list(groups), fontsize=8)
        first = next(iter(groups.values()))
        _label(axes, f"{_bone(bone)} (n = {first['CR']['n']} trials per sub-area)", xlabel, grid_axis="y")
    handles, labels = panels[0].get_legend_handles_labels()
    _finish(plt, figure, path, title, handles, labels, SD_NOTE)


def _label(axes, title, xlabel, grid_axis="both"):
    """A panel's title, axis labels (TRE in mm from 0) and grid."""
    axes.set_title(title, fontsize=9)
    axes.set_xlabel(xlabel)
    axes.set_ylabel("TRE (mm)")
    axes.set_ylim(bottom=0.0)
    axes.grid(alpha=0.3, axis=grid_axis)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _panels(bones):
    """A figure with one panel per bone (2 x 2 for four), and the panels in the bones' order."""
    plt = _pyplot()
    count = len(bones)
    columns = 2 if count > 1 else 1
    rows = int(np.ceil(count / columns))
    figure, panels = plt.subplots(rows, columns, figsize=(12.0, 3.6 * rows + 1.2), dpi=110, squeeze=False)
    panels = panels.ravel()
    for extra in panels[count:]:
        extra.set_visible(False)
    return plt, figure, list(panels[:count])


def _finish(plt, figure, path, title, handles, labels, note):
    figure.suptitle(title, fontsize=11)
    height = figure.get_size_inches()[1]
    line = 0.22 / height  # one line of 8-point text, as a fraction of the figure's height
    rows = int(np.ceil(len(labels) / 3))
    figure.text(0.5, 0.4 * line, note, ha="center", fontsize=8)
    figure.legend(
        handles, labels, loc="lower center", bbox_to_anchor=(0.5, 1.4 * line), ncol=min(len(labels), 3),
        fontsize=8, frameon=False,
    )  # fmt: skip
    figure.tight_layout(rect=(0, (1.8 + 1.1 * rows) * line, 1, 0.96))
    with atomic_path(path) as temporary:  # whole or not at all
        figure.savefig(temporary)
    plt.close(figure)


def _bone(bone):
    return bone.replace("-", " ")
