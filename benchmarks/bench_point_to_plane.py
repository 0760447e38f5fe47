"""cr-icp-plane against Open3D's ``registration_icp`` with ``TransformationEstimationPointToPlane``: same answer?

Both start from the same CR on the same data (the shipped right tibia's virtual patient, IPC sampled on its mesh,
the paper's marker error, 40 probe points) and fit the probe points to the IPC by point-to-plane ICP
(``core.plane_icp``). Open3D runs twice: with the IPC's own normals (``SurfaceIndex.normals``, so that only the
solvers differ) and with its own ``estimate_normals`` (16 nearest neighbours, as a user of Open3D would run it).
Every correspondence counts (``max_correspondence_distance`` 50 mm; ours has no limit) and Open3D stops when its
fitness and RMSE change by less than 1e-9 (relative) or after 100 iterations.

Prints, over the trials: how far the two poses put the probe points and the targets apart (median and largest,
mm), the TRE of each (eq. 11) beside the paper's CR-ICP and cr-fused, and the median time of one registration with
its ratio to ours: ours with the KD-tree and the normals built once (as the library runs it), ours building its
KD-tree in the call as Open3D does (and the normals of its matches), and Open3D (the target's normals given).

Needs the ``benchmark`` extra (``pip install open3d``). Run: python benchmarks/bench_point_to_plane.py [--trials 20]
"""

import argparse
import os
import statistics
import time

import numpy as np

from RAMSICPRegistrationLib.core.metrics import target_registration_error
from RAMSICPRegistrationLib.core.paired_point import fit_rigid_transform
from RAMSICPRegistrationLib.core.plane_icp import icp_point_to_plane
from RAMSICPRegistrationLib.core.registration import register
from RAMSICPRegistrationLib.core.surface_index import NORMAL_NEIGHBOURS, SurfaceIndex
from RAMSICPRegistrationLib.core.transforms import apply_transform
from RAMSICPRegistrationLib.simulation.package_data import shipped_patient

#: Poses within this at every probe point and target count as the same answer (mm).
AGREEMENT_MM = 0.01


def open3d_icp(o3d, source_points, target, initial):
    """Open3D's point-to-plane ICP of ``source_points`` (N, 3) onto ``target`` (a PointCloud with normals)."""
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source_points))
    criteria = o3d.pipelines.registration.ICPConvergenceCriteria(
        relative_fitness=1e-9, relative_rmse=1e-9, max_iteration=100
    )
    result = o3d.pipelines.registration.registration_icp(
        source, target, 50.0, initial, o3d.pipelines.registration.TransformationEstimationPointToPlane(), criteria
    )
    return np.asarray(result.transformation)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--bone", default="right-tibia")
    arguments = parser.parse_args()
    import open3d as o3d

    patient = shipped_patient(arguments.bone)[0]
    clock = time.perf_counter()
    index = SurfaceIndex(patient.ipc)
    normals = index.normals(np.arange(len(index)))
    build_ours = time.perf_counter() - clock
    given = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(index.points))
    given.normals = o3d.utility.Vector3dVector(normals)
    clock = time.perf_counter()
    estimated = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(index.points))
    estimated.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(NORMAL_NEIGHBOURS))
    build_open3d = time.perf_counter() - clock

    fle = patient.marker_fle_for_cr_tre(1.33)
    rng = np.random.default_rng(2024)
    rows = {"ours": [], "ours, new KD-tree": [], "open3d, our normals": [], "open3d, its normals": []}
    apart = {"open3d, our normals": [], "open3d, its normals": []}
    tre = {name: [] for name in ("CR", "CR-ICP", "ours", "open3d, our normals", "open3d, its normals", "cr-fused")}
    for _ in range(arguments.trials):
        data = patient.simulate_trial(rng, fle)
        coarse = fit_rigid_transform(data.markers_patient, data.markers_image).transform
        clock = time.perf_counter()
        ours = icp_point_to_plane(index, data.ppc, coarse).transform
        rows["ours"].append(time.perf_counter() - clock)
        clock = time.perf_counter()  # as Open3D runs it: the KD-tree built in the call (normals of the matches only)
        icp_point_to_plane(SurfaceIndex(patient.ipc), data.ppc, coarse)
        rows["ours, new KD-tree"].append(time.perf_counter() - clock)
        checked = np.vstack((data.ppc, data.targets_patient))
        for name, target in (("open3d, our normals", given), ("open3d, its normals", estimated)):
            clock = time.perf_counter()
            theirs = open3d_icp(o3d, data.ppc, target, coarse)
            rows[name].append(time.perf_counter() - clock)
            moved = apply_transform(ours, checked) - apply_transform(theirs, checked)
            apart[name].append(np.linalg.norm(moved, axis=1).max())
            tre[name].append(target_registration_error(theirs, data.targets_patient, data.targets_image))
        tre["ours"].append(target_registration_error(ours, data.targets_patient, data.targets_image))
        case = (data.ppc, data.markers_image, data.markers_patient, data.targets_image, data.targets_patient)
        for name, method in (("CR", "cr"), ("CR-ICP", "cr-icp"), ("cr-fused", "cr-fused")):
            tre[name].append(register(index, *case, method=method).tre_mm)

    print(
        f"{arguments.bone}: {len(index):,} IPC points, 40 probe points, {arguments.trials} trials, "
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    )
    print(f"normals of the whole IPC: ours {build_ours:.2f} s (KD-tree + PCA), Open3D {build_open3d:.2f} s")
    print(f"{'registration':<22} {'median ms':>10} {'x ours':>7} {'apart median (mm)':>18} {'apart max (mm)':>15}")
    base = statistics.median(rows["ours"])
    for name, times in rows.items():
        spread = apart.get(name)
        columns = f"{np.median(spread):18.2e} {np.max(spread):15.2e}" if spread else f"{'-':>18} {'-':>15}"
        print(f"{name:<22} {1000 * statistics.median(times):10.2f} {statistics.median(times) / base:7.2f} {columns}")
    for name, spread in apart.items():
        agree = int(np.sum(np.array(spread) <= AGREEMENT_MM))
        print(f"{name}: the same pose (within {AGREEMENT_MM} mm at every probe point and target) in {agree} of "
              f"{len(spread)} trials")  # fmt: skip
    print("TRE (eq. 11), mean +- sd over the trials (mm):")
    for name, values in tre.items():
        label = "cr-icp-plane (ours)" if name == "ours" else name
        print(f"  {label:<22} {np.mean(values):.3f} +- {np.std(values, ddof=1):.3f}")


if __name__ == "__main__":
    main()
