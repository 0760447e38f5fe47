"""Which fused registration? Mean TRE (mm) of cr-fused's variants beside CR, CR-ICP and CR-RAMSICP.

The conditions of issue 11's prototype table, on the demo's right tibia (IPC sampled on the mesh) and on the right
ilium (IPC from its CT phantom, the paper's kind of bone), ``--trials`` simulated registrations per cell, the
same trials for every method:

* the paper's marker error (set for a CR TRE of 1.33 mm), 40 probe points in 8 sub-areas;
* automatic markers (0.05 mm), FLE 2.5 mm, 5 points in sub-area 1 only, 8 points one per sub-area;
* a disturbed IPC: on the tibia an inner cortical wall 3.5 mm inside added to it; on the ilium the CT's IPC with
  the inner cortical surfaces kept (``--keep-cavities``, the paper's threshold IPC).

Variants (``core.fused``): the default (point-to-plane Gauss-Newton, closest IPC point, Huber's loss, surface
noise re-estimated from the residuals), then one change at a time.

Run: python benchmarks/compare_fused_variants.py [--trials 30] [--bones right-tibia right-ilium]
"""

import argparse
import time

import numpy as np

from RAMSICPRegistrationLib.core.fused import FUSED_DEFAULTS, FusedWeights, fused_fit, marker_fle, surface_sigma
from RAMSICPRegistrationLib.core.metrics import target_registration_error
from RAMSICPRegistrationLib.core.paired_point import fit_rigid_transform
from RAMSICPRegistrationLib.core.registration import register
from RAMSICPRegistrationLib.core.surface_index import SurfaceIndex
from RAMSICPRegistrationLib.image.ct_pipeline import process_ct
from RAMSICPRegistrationLib.image.ct_segmentation import bone_surface
from RAMSICPRegistrationLib.simulation.ct_phantom import make_ct_phantom
from RAMSICPRegistrationLib.simulation.package_data import shipped_patient
from RAMSICPRegistrationLib.simulation.virtual_patient import sample_surface

PROBE_NOISE_MM = 0.25
VARIANTS = {
    "fused (default)": {},
    "point-to-point SVD": {"solver": "point-to-point"},
    "RAMSICP ranges (L = 5)": {"correspondence": "ramsicp"},
    "least squares": {"loss": "least-squares"},
    "weights fixed": {"variance": "fixed"},
    "both noises re-estimated (VCE)": {"variance": "vce"},
}


def image_sides(bone, patient, vertices, triangles):
    """(name of the IPC, clean SurfaceIndex, disturbed SurfaceIndex) for a bone."""
    if bone == "right-ilium":
        volume, _ = make_ct_phantom(patient, vertices, triangles)
        image = process_ct(volume, tool_markers=patient.markers_reference)
        walls = bone_surface(volume, image.segmentation, fill_cavities=False).points
        return "CT phantom", SurfaceIndex(image.surface.points), SurfaceIndex(walls), "inner cortical surfaces kept"
    points, normals = sample_surface(vertices, triangles, 200_000, np.random.default_rng(7))
    walled = np.vstack((patient.ipc, points - 3.5 * normals))
    return "mesh samples", SurfaceIndex(patient.ipc), SurfaceIndex(walled), "inner wall 3.5 mm inside added"


def fused_tre(index, data, options):
    coarse = fit_rigid_transform(data.markers_patient, data.markers_image)
    fle, source = marker_fle(coarse.fre_mm, len(data.markers_patient))
    sigma = surface_sigma(PROBE_NOISE_MM, index.spacing_mm)
    weights = FusedWeights(fle, sigma, source, "prior", PROBE_NOISE_MM, index.spacing_mm)
    fit = fused_fit(index, data.ppc, data.markers_patient, data.markers_image, coarse.transform, weights, **options)
    return target_registration_error(fit.transform, data.targets_patient, data.targets_image)


def row(index, patient, rng, trials, fle, **acquisition):
    values = []
    for _ in range(trials):
        data = patient.simulate_trial(rng, fle, PROBE_NOISE_MM, **acquisition)
        common = dict(
            ipc=index,
            ppc=data.ppc,
            markers_image=data.markers_image,
            markers_patient=data.markers_patient,
            targets_image=data.targets_image,
            targets_patient=data.targets_patient,
        )
        sweep = register(method="cr-ramsicp", sweep=True, policy="rms-plateau", **common)
        values.append(
            [
                register(method="cr", **common).tre_mm,
                register(method="cr-icp", **common).tre_mm,
                sweep.tre_mm,
                min(entry.tre_mm for entry in sweep.sweep),
            ]
            + [fused_tre(index, data, options) for options in VARIANTS.values()]
        )
    return np.mean(values, axis=0)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--bones", nargs="+", default=["right-tibia", "right-ilium"])
    arguments = parser.parse_args()
    print(f"fused defaults: {FUSED_DEFAULTS}; {arguments.trials} trials per cell, mean TRE (mm)")
    columns = ["CR", "CR-ICP", "CR-RAMSICP rms-plateau", "CR-RAMSICP paper's L", *VARIANTS]
    for bone in arguments.bones:
        clock = time.perf_counter()
        patient, vertices, triangles = shipped_patient(bone)
        source, index, disturbed, disturbance = image_sides(bone, patient, vertices, triangles)
        paper_fle = patient.marker_fle_for_cr_tre(1.33)
        conditions = {
            f"paper's marker error (FLE {paper_fle:.2f} mm), 40 points": (index, paper_fle, {}),
            "automatic markers (FLE 0.05 mm)": (index, 0.05, {}),
            "FLE 2.5 mm": (index, 2.5, {}),
            "5 points, sub-area 1 only": (index, paper_fle, {"sub_areas": (1,)}),
            "8 points, one per sub-area": (index, paper_fle, {"points_per_area": 1}),
            f"IPC with the {disturbance}": (disturbed, paper_fle, {}),
        }
        print(f"\n{bone}, IPC from the {source}\n")
        print("| condition | " + " | ".join(columns) + " |")
        print("|---|" + "---|" * len(columns))
        rng = np.random.default_rng(1)
        for name, (surface, fle, acquisition) in conditions.items():
            means = row(surface, patient, rng, arguments.trials, fle, **acquisition)
            best = int(np.argmin(means))
            cells = [f"**{m:.2f}**" if k == best else f"{m:.2f}" for k, m in enumerate(means)]
            print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
        print(f"({time.perf_counter() - clock:.0f} s)")


if __name__ == "__main__":
    main()
