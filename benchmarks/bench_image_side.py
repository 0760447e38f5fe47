"""Speed of the image side: a 512 x 512 x 400 CT at 0.5 mm -> IPC plus marker-sphere centres.

The tibia CT phantom is placed in a 512 x 512 x 400 volume of noisy air, the size of a C-arm CT at the paper's
resolution. Its reference body is the hard case for the marker detector (issue 12): aluminium posts and frame,
so spheres, posts and frame are one bright object, and a steel pin with streaks through the shaft, so the IPC
leaves out a metal zone. Each step is timed (median of the repeats) and shown as a share of the whole; beside
it, in the same run, VTK's vtkMarchingCubes over the whole uncropped volume, the route without our crop to the
bone, as a ratio.

Target (issues 4 and 12): IPC plus marker centres in at most 10 s.

Run: python benchmarks/bench_image_side.py [--repeats N]
"""

import argparse
import statistics
import time

import numpy as np
from vtkmodules.vtkFiltersCore import vtkMarchingCubes

from RAMSICPRegistrationLib.image.ct_segmentation import bone_surface, segment_bone
from RAMSICPRegistrationLib.image.marker_spheres import detect_marker_spheres
from RAMSICPRegistrationLib.image.volume_io import CTVolume
from RAMSICPRegistrationLib.io.vtk_arrays import image_data
from RAMSICPRegistrationLib.simulation.ct_painting import ReferenceBodyModel
from RAMSICPRegistrationLib.simulation.ct_phantom import HU, make_ct_phantom
from RAMSICPRegistrationLib.simulation.package_data import shipped_patient

TARGET_SECONDS = 10.0
SHAPE = (512, 512, 400)


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
    return CTVolume(voxels=voxels, ijk_to_ras=ijk_to_ras), truth


def image_side(volume):
    times = {}
    start = time.perf_counter()
    segmentation = segment_bone(volume)
    times["denoise + threshold + components"] = time.perf_counter() - start
    start = time.perf_counter()
    surface = bone_surface(volume, segmentation)
    times["bone surface (IPC), metal zone left out"] = time.perf_counter() - start
    start = time.perf_counter()
    detection = detect_marker_spheres(volume, segmentation)
    times["marker spheres (fused aluminium body)"] = time.perf_counter() - start
    return times, surface, detection


def uncropped_marching_cubes(smoothed, level):
    cubes = vtkMarchingCubes()
    cubes.SetInputData(image_data(smoothed))
    cubes.SetValue(0, level)
    cubes.ComputeNormalsOff()
    cubes.Update()
    return cubes.GetOutput().GetNumberOfPoints()


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    arguments = parser.parse_args()
    volume, truth = big_ct()
    print(f"CT {' x '.join(map(str, volume.voxels.shape))} voxels of 0.5 x 0.5 x 0.625 mm, {arguments.repeats} repeats")
    runs = [image_side(volume) for _ in range(arguments.repeats)]
    steps = {name: statistics.median(run[0][name] for run in runs) for name in runs[0][0]}
    total = statistics.median(sum(run[0].values()) for run in runs)
    smoothed = segment_bone(volume).smoothed
    start = time.perf_counter()
    uncropped_points = uncropped_marching_cubes(smoothed, 700.0)
    uncropped = time.perf_counter() - start
    print(f"\n{'step':<58} {'median (s)':>10} {'share / ratio':>14}")
    for name, seconds in steps.items():
        print(f"{name:<58} {seconds:10.2f} {seconds / total:14.2f}")
    print(f"{'whole image side: IPC + marker centres':<58} {total:10.2f} {1.0:14.2f}")
    print(
        f"{'baseline: vtkMarchingCubes on the whole uncropped volume':<58} {uncropped:10.2f} "
        f"{uncropped / steps['bone surface (IPC), metal zone left out']:14.2f}  (vs our bone-surface step)"
    )
    surface, detection = runs[0][1], runs[0][2]
    errors = [min(np.linalg.norm(truth.marker_centres - centre, axis=1)) for centre in detection.ok_centres]
    print(
        f"\nIPC {len(surface.points):,} points ({surface.left_out:,} left out next to the pin); "
        f"{len(detection.ok_centres)} clean marker spheres, {max(errors):.4f} mm from the truth at most; "
        f"uncropped marching cubes gave {uncropped_points:,} points (spheres, bracket, pin and all)"
    )
    print(f"target <= {TARGET_SECONDS:.0f} s: {'met' if total <= TARGET_SECONDS else 'NOT met'} ({total:.2f} s)")


if __name__ == "__main__":
    main()
