"""Marker-sphere candidates: distance-transform peaks (ours) against a matched filter, on every reference body.

Both candidate generators feed the same fit (``marker_spheres._fit_candidate``), so the table compares what the
candidates decide: which spheres are found, how many candidates are tried, and the time. The matched filter
correlates the thresholded object with a zero-mean template (+1 in a ball of the sphere's radius, a negative shell
1.5 mm thick around it, summing to 0) by FFT and keeps peaks above half the response of an isolated sphere.
The old detector (isolated components whose size and shape fit a sphere) is the third row.

Run: python benchmarks/bench_marker_candidates.py
"""

import time

import numpy as np
from scipy import ndimage, signal

from RAMSICPRegistrationLib.image import marker_spheres
from RAMSICPRegistrationLib.image.ct_segmentation import segment_bone
from RAMSICPRegistrationLib.io.ndi_tools import MARKER_DIAMETER_MM
from RAMSICPRegistrationLib.simulation.ct_painting import MetalRod, ReferenceBodyModel, rotated_direction
from RAMSICPRegistrationLib.simulation.reference_body_phantom import body_pose, make_reference_body_phantom

RADIUS = MARKER_DIAMETER_MM / 2.0
DENSE = ReferenceBodyModel("dense-polymer", "dense-polymer")
ALUMINIUM = ReferenceBodyModel("aluminium", "aluminium")


def _rod_across_marker_2():
    from RAMSICPRegistrationLib.core.transforms import apply_transform
    from RAMSICPRegistrationLib.io.ndi_tools import tool_marker_geometry

    centre = apply_transform(body_pose(tool_marker_geometry()), tool_marker_geometry())[1]
    return MetalRod(start=(20.0, -10.0, centre[2]), end=(20.0, 25.0, centre[2]), streak_towards=tuple(centre))


VARIANTS = {
    "plastic posts and frame (isolated spheres)": {},
    "post as bright as the sphere": {"body": ReferenceBodyModel(post_material="marker")},
    "dense polymer, 1000 HU": {"body": DENSE},
    "aluminium, 2500 HU": {"body": ALUMINIUM},
    "aluminium, oblique grid": {"body": ALUMINIUM, "direction": rotated_direction(25.0)},
    "aluminium, low dose 60 HU": {"body": ALUMINIUM, "noise_hu": 60.0},
    "dense polymer, streaks across sphere 2": {"body": DENSE, "metal": _rod_across_marker_2()},
    "aluminium, sphere 3 cut by the field of view": {"body": ALUMINIUM, "cut_marker": 3},
}


def matched_filter_candidates(volume, segmentation, radius):
    spacing = volume.spacing
    half = np.ceil((radius + 1.5) / spacing).astype(int)
    grid = np.stack(np.meshgrid(*[np.arange(-h, h + 1) for h in half], indexing="ij"), axis=-1) * spacing
    distance = np.linalg.norm(grid, axis=-1)
    ball, shell = distance <= radius, (distance > radius) & (distance <= radius + 1.5)
    template = ball.astype(np.float32) - shell * (ball.sum() / shell.sum())
    isolated = float(ball.sum())
    slices = ndimage.find_objects(segmentation.labels)
    found = []
    for label in segmentation.object_labels:
        region = slices[label - 1]
        low = np.array([max(s.start - h, 0) for s, h in zip(region, half)])
        high = np.array([min(s.stop + h, n) for s, h, n in zip(region, half, segmentation.labels.shape)])
        mask = (segmentation.labels[tuple(slice(a, b) for a, b in zip(low, high))] == label).astype(np.float32)
        response = signal.fftconvolve(mask, template[::-1, ::-1, ::-1], mode="same")
        peaks = (response == ndimage.maximum_filter(response, size=5)) & (response >= 0.5 * isolated)
        order = np.argsort(-response[peaks])
        kept = []
        for index in np.argwhere(peaks)[order]:
            centre = volume.ijk_to_ras_points((index + low)[None])[0]
            if all(np.linalg.norm(centre - other) > radius for other in kept):
                kept.append(centre)
        found.extend((centre, label, True) for centre in kept)
    return found


def component_candidates(volume, segmentation, radius):
    """The old detector: isolated components of sphere size (0.3-2 x) and shape (elongation <= 1.8)."""
    nominal = 4.0 / 3.0 * np.pi * radius**3
    found = []
    slices = ndimage.find_objects(segmentation.labels)
    for label in segmentation.object_labels:
        mask = segmentation.labels[slices[label - 1]] == label
        coordinates = np.argwhere(mask) * volume.spacing
        eigenvalues = np.linalg.eigvalsh(np.cov(coordinates.T))
        size = mask.sum() * float(np.prod(volume.spacing))
        if 0.3 * nominal <= size <= 2.0 * nominal and np.sqrt(eigenvalues[-1] / max(eigenvalues[0], 1e-9)) <= 1.8:
            centre = np.argwhere(mask).mean(axis=0) + [s.start for s in slices[label - 1]]
            found.append((volume.ijk_to_ras_points(centre[None])[0], label, True))
    return found


GENERATORS = {
    "ours: distance-transform peaks": marker_spheres._candidates,
    "matched filter (FFT)": matched_filter_candidates,
    "old: isolated components": component_candidates,
}


def run(volume, truth, generator):
    segmentation = segment_bone(volume)
    original = marker_spheres._candidates
    marker_spheres._candidates = generator
    try:
        start = time.perf_counter()
        detection = marker_spheres.detect_marker_spheres(volume, segmentation)
        seconds = time.perf_counter() - start
    finally:
        marker_spheres._candidates = original
    errors = [
        np.linalg.norm(truth.marker_centres - s.centre, axis=1).min() for s in detection.spheres if s.status == "ok"
    ]
    tried = len(detection.spheres) + detection.rejected
    mean, worst = (np.mean(errors), np.max(errors)) if errors else (float("nan"), float("nan"))
    return sum(error < 0.1 for error in errors), len(detection.spheres), tried, mean, worst, seconds


def main():
    print("centre errors of the spheres found 'ok', against the generator's true centres (mm)")
    print(f"{'variant':<46} {'candidates':<32} {'ok':>3} {'found':>5} {'tried':>5} {'mean':>7} {'max':>7} {'s':>6}")
    totals = {name: 0.0 for name in GENERATORS}
    for variant, options in VARIANTS.items():
        volume, truth = make_reference_body_phantom(**options)
        for name, generator in GENERATORS.items():
            ok, found, tried, mean, worst, seconds = run(volume, truth, generator)
            totals[name] += seconds
            print(f"{variant:<46} {name:<32} {ok:>3} {found:>5} {tried:>5} {mean:7.4f} {worst:7.4f} {seconds:6.2f}")
    baseline = totals["ours: distance-transform peaks"]
    print("\ntotal detection time, ratio to ours:")
    for name, seconds in totals.items():
        print(f"  {name:<32} {seconds:6.2f} s  {seconds / baseline:5.2f}")


if __name__ == "__main__":
    main()
