"""Speed of the image side: a 512 x 512 x 400 CT at 0.5 mm -> IPC plus marker-sphere centres.

The tibia CT phantom is placed in a 512 x 512 x 400 volume of noisy air, the size of a C-arm CT at the paper's
resolution. Its reference body is the hard case for the marker detector (issue 12): aluminium posts and frame,
so spheres, posts and frame are one bright object, and a steel pin with streaks through the shaft, so the IPC
leaves out a metal zone. Each step is timed (median of the repeats) and shown as a share of the whole; beside
it, in the same run, one pass of VTK's vtkMarchingCubes over the whole uncropped volume, the baseline of issue 27's
targets: the whole image side at most 1.3 times that pass, the marker step at most 15 % of the whole.

Run: python benchmarks/bench_image_side.py [--repeats N]
"""

import argparse
import os
import statistics
import time

import numpy as np
from vtkmodules.vtkFiltersCore import vtkMarchingCubes

from RAMSICPRegistrationLib.image.ct_segmentation import (
    bone_surface,
    reference_body_spheres,
    threshold_ct,
    with_bone,
)
from RAMSICPRegistrationLib.image.marker_spheres import detect_marker_spheres
from RAMSICPRegistrationLib.image.volume_io import CTVolume
from RAMSICPRegistrationLib.io.vtk_arrays import image_data
from RAMSICPRegistrationLib.simulation.ct_painting import ReferenceBodyModel
from RAMSICPRegistrationLib.simulation.ct_phantom import HU, make_ct_phantom
from RAMSICPRegistrationLib.simulation.package_data import shipped_patient

#: Issue 27: the whole image side within this many vtkMarchingCubes passes, the marker step within this share.
TARGET_RATIO = 1.3
TARGET_MARKER_SHARE = 0.15
SHAPE = (512, 512, 400)
MARKERS = "marker spheres (anywhere, paired by the tool's distances)"


def big_ct():
    patient, vertices, triangles = shipped_patient("right-tibia")
    body = ReferenceBodyModel(post_material="aluminium", frame_material="aluminium")
    phantom, truth = make_ct_phantom(patient, vertices, triangles, body=body, metal="pin")
    rng = np.random.default_rng(0)
    voxels = (HU["air"] + rng.normal(scale=25.0, size=SHAPE)).astype(np.int16)
    offset = (np.array(SHAPE) - phantom.voxels.shape) // 2
    voxels[tuple(slice(o, o + n) for o, n in zip(offset, phantom.voxels.shape))] = phantom.voxels
    ijk_to_ras = phantom.ijk_to_ras.copy()
    ijk_to_ras[:3, 3] -= ijk_to_ras[:3, :3] @ offset
    return CTVolume(voxels=voxels, ijk_to_ras=ijk_to_ras), truth, patient.markers_reference


def image_side(volume, tool):
    times = {}
    start = time.perf_counter()
    segmentation = threshold_ct(volume)
    times["denoise + threshold + components (the box holding something)"] = time.perf_counter() - start
    start = time.perf_counter()
    detection = detect_marker_spheres(volume, segmentation, tool_markers=tool)
    times[MARKERS] = time.perf_counter() - start
    start = time.perf_counter()
    segmentation = with_bone(volume, segmentation, reference_body_spheres(detection))
    times["bone recognition (the object without spheres, its cortex)"] = time.perf_counter() - start
    start = time.perf_counter()
    surface = bone_surface(volume, segmentation)
    times["bone surface (IPC), metal zone left out"] = time.perf_counter() - start
    return times, surface, detection


def marching_cubes_pass(voxels, level):
    cubes = vtkMarchingCubes()
    cubes.SetInputData(image_data(voxels))
    cubes.SetValue(0, level)
    cubes.ComputeNormalsOff()
    cubes.Update()
    return cubes.GetOutput().GetNumberOfPoints()


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    arguments = parser.parse_args()
    volume, truth, tool = big_ct()
    print(f"CT {' x '.join(map(str, volume.voxels.shape))} voxels of 0.5 x 0.5 x 0.625 mm, {arguments.repeats} repeats")
    load = os.getloadavg()[0]
    runs, passes = [], []
    whole = volume.voxels.astype(np.float32)
    for _ in range(arguments.repeats):  # interleaved, so that both see the same load
        runs.append(image_side(volume, tool))
        start = time.perf_counter()
        points = marching_cubes_pass(whole, 700.0)
        passes.append(time.perf_counter() - start)
    steps = {name: statistics.median(run[0][name] for run in runs) for name in runs[0][0]}
    total = statistics.median(sum(run[0].values()) for run in runs)
    baseline = statistics.median(passes)
    print(f"\n{'step':<66} {'median (s)':>10} {'share':>7}")
    for name, seconds in steps.items():
        print(f"{name:<66} {seconds:10.2f} {seconds / total:7.2f}")
    print(f"{'whole image side: IPC + marker centres':<66} {total:10.2f} {1.0:7.2f}")
    print(f"{'baseline: one vtkMarchingCubes pass over the whole volume':<66} {baseline:10.2f}")
    ratio, share = total / baseline, steps[MARKERS] / total
    print(
        f"\nwhole image side / marching-cubes pass: {ratio:.2f} (target <= {TARGET_RATIO}: "
        f"{'met' if ratio <= TARGET_RATIO else 'NOT met'}); marker step {100 * share:.0f} % of the whole (target <= "
        f"{100 * TARGET_MARKER_SHARE:.0f} %: {'met' if share <= TARGET_MARKER_SHARE else 'NOT met'}); "
        f"load average {load:.1f} at the start"
    )
    surface, detection = runs[0][1], runs[0][2]
    errors = [np.linalg.norm(truth.marker_centres[s.number - 1] - s.centre) for s in detection.spheres if s.number]
    print(
        f"IPC {len(surface.points):,} points ({surface.left_out:,} left out next to the pin); "
        f"{len(detection.ok_centres)} clean marker spheres, {max(errors):.4f} mm from the truth at most; "
        f"the marching-cubes pass gave {points:,} points (spheres, bracket, pin and all)"
    )


if __name__ == "__main__":
    main()
