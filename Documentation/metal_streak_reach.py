"""Measure how far the metal's streaks reach in the TotalSegmentator CT (the basis of metal.STREAK_REACH_MM).

In each slice, the soft tissue (away from bone and metal, inside the body) is compared with its own local median
(7 x 7 voxels in the slice): streaks are thin lines, so they show as spread around that median. The robust spread
(1.4826 x the median absolute deviation, HU) is printed per band of in-slice distance from the metal, in slices
through the metal and, for comparison, in slices without metal. Run from the repository's root:

    python Documentation/metal_streak_reach.py
"""

from pathlib import Path

import numpy as np
from scipy import ndimage

from RAMSICPRegistrationLib.image.metal import METAL_HU
from RAMSICPRegistrationLib.image.volume_io import load_volume

CT = Path(__file__).resolve().parents[1] / "Testing" / "Data" / "example_ct.nii.gz"
BANDS_MM = ((0, 10), (10, 20), (20, 30), (30, 45), (45, 70), (70, 120))


def main():
    volume = load_volume(CT)
    voxels = volume.voxels.astype(np.float32)
    metal = voxels >= METAL_HU
    bone = ndimage.binary_dilation(voxels >= 200.0, iterations=2)
    tissue = (voxels > -300.0) & ~bone & ~ndimage.binary_dilation(metal, iterations=2)
    tissue &= ndimage.binary_erosion(voxels > -500.0, iterations=3)  # inside the body
    deviation = voxels - ndimage.median_filter(voxels, size=(7, 7, 1))
    metal_anywhere = metal.any(axis=2)
    print("slice  metal   " + "  ".join(f"{low:>3}-{high:<3} mm" for low, high in BANDS_MM))
    for k in list(range(2, 18, 2)) + [25, 40, 60]:
        here = metal[:, :, k] if metal[:, :, k].any() else metal_anywhere
        distance = ndimage.distance_transform_edt(~here, sampling=volume.spacing[:2])
        cells = []
        for low, high in BANDS_MM:
            band = tissue[:, :, k] & (distance >= low) & (distance < high)
            spread = 1.4826 * np.median(np.abs(deviation[:, :, k][band])) if band.sum() > 20 else np.nan
            cells.append(f"{spread:10.1f}")
        print(f"{k:5d}  {'yes' if metal[:, :, k].any() else 'no ':5s} " + "  ".join(cells))


if __name__ == "__main__":
    main()
