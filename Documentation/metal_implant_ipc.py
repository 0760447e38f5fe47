"""Draw Documentation/metal_implant_ipc.png: what the IPC does next to a metal implant in a real CT.

The CT is TotalSegmentator's example (Testing/Data/example_ct.nii.gz, Apache-2.0): 3 mm voxels, the patient's
left femur holding metal (by its shape a nail with a screw into the femoral head). Run from the repository's root:

    python Documentation/metal_implant_ipc.py
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from scipy import ndimage  # noqa: E402

from RAMSICPRegistrationLib.image.ct_segmentation import bone_surface, segment_bone  # noqa: E402
from RAMSICPRegistrationLib.image.metal import METAL_HU, STREAK_REACH_MM  # noqa: E402
from RAMSICPRegistrationLib.image.volume_io import load_volume  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CT = ROOT / "Testing" / "Data" / "example_ct.nii.gz"
OUT = ROOT / "Documentation" / "metal_implant_ipc.png"
WINDOW = (-250.0, 1250.0)  # bone window (HU)
X_RANGE, Y_RANGE, Z_RANGE = (-12.0, -176.0), (50.0, 215.0), (93.0, 200.0)  # RAS mm; x runs right to left


def main():
    volume = load_volume(CT)
    segmentation = segment_bone(volume)
    kept = bone_surface(volume, segmentation)
    everything = bone_surface(volume, segmentation, leave_out_metal=False)
    left_out = everything.points[kept.metal.contains(volume, everything.points)]
    metal = volume.voxels >= METAL_HU
    metal_slices = np.flatnonzero(metal.any(axis=(0, 1)))
    origin, step = volume.ijk_to_ras[:3, 3], volume.spacing  # the grid is RAS-aligned (+3 mm on each axis)

    figure, axes = plt.subplots(1, 3, figsize=(16.5, 6.2), gridspec_kw={"width_ratios": [1, 1, 1.05]})
    for axis, k, title in (
        (axes[0], 8, "axial, through the nail's head and the screw"),
        (axes[1], 14, "axial, through the femoral head"),
    ):
        z = origin[2] + k * step[2]
        extent = _extent(origin[0], step[0], volume.voxels.shape[0], origin[1], step[1], volume.voxels.shape[1])
        axis.imshow(
            volume.voxels[:, :, k].T, cmap="gray", vmin=WINDOW[0], vmax=WINDOW[1], origin="lower", extent=extent
        )
        near_metal = metal[:, :, max(k - 1, 0) : k + 2].any(axis=2)
        in_slice = ndimage.distance_transform_edt(~near_metal, sampling=step[:2])
        grid_x, grid_y = (
            origin[0] + step[0] * np.arange(metal.shape[0]),
            origin[1] + step[1] * np.arange(metal.shape[1]),
        )
        axis.contour(grid_x, grid_y, metal[:, :, k].T.astype(float), [0.5], colors="deepskyblue", linewidths=1.6)
        axis.contour(grid_x, grid_y, in_slice.T, [STREAK_REACH_MM], colors="gold", linewidths=1.3, linestyles="--")
        _points(axis, kept.points, left_out, 2, z, step[2])
        axis.set_title(f"{title} (z = {z:.0f} mm)", fontsize=11)
        _frame(axis, "R", "L", "A", "P", X_RANGE, Y_RANGE)

    j = int(round(np.argwhere(metal)[:, 1].mean()))
    y = origin[1] + j * step[1]
    extent = _extent(origin[0], step[0], volume.voxels.shape[0], origin[2], step[2], volume.voxels.shape[2])
    axes[2].imshow(volume.voxels[:, j, :].T, cmap="gray", vmin=WINDOW[0], vmax=WINDOW[1], origin="lower", extent=extent)
    grid_x, grid_z = origin[0] + step[0] * np.arange(metal.shape[0]), origin[2] + step[2] * np.arange(metal.shape[2])
    axes[2].contour(grid_x, grid_z, metal[:, j, :].T.astype(float), [0.5], colors="deepskyblue", linewidths=1.6)
    top = origin[2] + (metal_slices.max() + 1.5) * step[2]
    axes[2].axhline(top, color="gold", linestyle="--", linewidth=1.3)
    axes[2].text(-40.0, top + 3.0, "above the metal's slices: surface kept", color="gold", fontsize=9, ha="left")
    _points(axes[2], kept.points, left_out, 1, y, step[1])
    axes[2].set_title(f"coronal, through the metal (y = {y:.0f} mm)", fontsize=11)
    _frame(axes[2], "R", "L", "S", "I", X_RANGE, Z_RANGE)

    legend = [
        Line2D([], [], marker="o", color="w", markerfacecolor="limegreen", markersize=7, label="IPC kept"),
        Line2D([], [], marker="o", color="w", markerfacecolor="red", markersize=7, label="left out next to metal"),
        Line2D([], [], color="deepskyblue", linewidth=1.6, label=f"metal (> {METAL_HU:.0f} HU)"),
        Line2D(
            [], [], color="gold", linestyle="--", linewidth=1.3, label=f"{STREAK_REACH_MM:.0f} mm in the metal's slices"
        ),
    ]
    figure.legend(handles=legend, loc="lower center", ncol=4, fontsize=10, frameon=False)
    figure.suptitle(
        f"Real CT with metal in the left femur (TotalSegmentator example, 3 mm voxels): {kept.left_out:,} of "
        f"{len(everything.points):,} IPC points are left out; the bone surface resumes beyond the zone",
        fontsize=12,
    )
    figure.tight_layout(rect=(0, 0.06, 1, 0.95))
    figure.savefig(OUT, dpi=110)
    print(f"wrote {OUT}: {kept.left_out} of {len(everything.points)} IPC points left out")


def _extent(origin_u, step_u, count_u, origin_v, step_v, count_v):
    return (
        origin_u - step_u / 2,
        origin_u + step_u * (count_u - 0.5),
        origin_v - step_v / 2,
        origin_v + step_v * (count_v - 0.5),
    )


def _points(axis, kept, left_out, across, level, thickness):
    """Plot IPC points within half a voxel of the plane at ``level`` along axis ``across`` (x, y on the others)."""
    u, v = [a for a in range(3) if a != across]
    for points, colour in ((kept, "limegreen"), (left_out, "red")):
        near = np.abs(points[:, across] - level) <= thickness / 2
        axis.plot(points[near, u], points[near, v], ".", color=colour, markersize=3.5)


def _frame(axis, left, right, up, down, range_u, range_v):
    """Radiological view: the patient's right on the viewer's left; labels on the sides, a 20 mm scale bar."""
    axis.set_xlim(*range_u)
    axis.set_ylim(*range_v)
    axis.set_xticks([])
    axis.set_yticks([])
    style = {"color": "white", "fontsize": 12, "fontweight": "bold", "ha": "center", "va": "center"}
    u0, u1, v0, v1 = range_u[0], range_u[1], range_v[0], range_v[1]
    axis.text(u0 + 0.04 * (u1 - u0), (v0 + v1) / 2, left, **style)
    axis.text(u1 - 0.04 * (u1 - u0), (v0 + v1) / 2, right, **style)
    axis.text((u0 + u1) / 2, v1 - 0.04 * (v1 - v0), up, **style)
    axis.text((u0 + u1) / 2, v0 + 0.04 * (v1 - v0), down, **style)
    bar_start = u1 - 0.08 * (u1 - u0) - np.sign(u1 - u0) * 20.0
    bar_v = v0 + 0.1 * (v1 - v0)
    axis.plot([bar_start, bar_start + np.sign(u1 - u0) * 20.0], [bar_v, bar_v], color="white", linewidth=3)
    axis.text(bar_start + np.sign(u1 - u0) * 10.0, bar_v + 0.035 * (v1 - v0), "20 mm", color="white", ha="center")


if __name__ == "__main__":
    main()
