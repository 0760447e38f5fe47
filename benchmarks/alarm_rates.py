"""How often a correct registration raises an alarm (``RegistrationResult.alarms``): the false-alarm rate.

The demo's simulated acquisitions (the paper's manual marker error, probe noise 0.25 mm) on the right tibia and the
right ilium, with the IPC sampled on the mesh or taken from the bone's CT phantom (there also with the automatic
marker centres), are registered by every method. Nothing is wrong with any of them, so every alarm is false. The
largest move of a fine step from the CR (``fine_shift_mm``) is given beside it, to show how far correct fine steps
go.

Run: python benchmarks/alarm_rates.py [--trials 200]
"""

import argparse

import numpy as np

from RAMSICPRegistrationLib.core.registration import register
from RAMSICPRegistrationLib.core.surface_index import SurfaceIndex
from RAMSICPRegistrationLib.experiments.demo import PAPER_TRE_MM, PROBE_NOISE_MM, ct_image_side
from RAMSICPRegistrationLib.simulation.package_data import shipped_patient

METHODS = {
    "CR": {"method": "cr"},
    "CR-ICP": {"method": "cr-icp"},
    "CR-RAMSICP (L = 5)": {"method": "cr-ramsicp"},
    "CR-RAMSICP (sweep, rms-plateau)": {"method": "cr-ramsicp", "sweep": True, "policy": "rms-plateau"},
    "cr-fused": {"method": "cr-fused"},
}


def conditions(bone, source, seed=0):
    """(label, SurfaceIndex, automatic marker centres or None) for each marker mode of one bone and IPC source."""
    patient, vertices, triangles = shipped_patient(bone, seed)
    if source == "mesh":
        return patient, [("manual markers", SurfaceIndex(patient.ipc), None)]
    side = ct_image_side(patient, vertices, triangles, seed, lambda *args: None)
    index = SurfaceIndex(side.ipc)
    return patient, [("manual markers", index, None), ("automatic markers", index, side.automatic_markers)]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200, help="acquisitions per bone, mesh IPC (half with the CT)")
    trials = parser.parse_args().trials
    print(f"{'bone, IPC, markers':<44} {'method':<32} {'alarms':>9}  {'fine step from the CR: median, max (mm)':>40}")
    totals = {name: [0, 0] for name in METHODS}
    for bone in ("right-tibia", "right-ilium"):
        for source, count in (("mesh", trials), ("ct", trials // 2)):
            patient, modes = conditions(bone, source)
            fle = patient.marker_fle_for_cr_tre(PAPER_TRE_MM["CR"][0], seed=0)
            rng = np.random.default_rng(1)
            data = [patient.simulate_trial(rng, fle, PROBE_NOISE_MM) for _ in range(count)]
            for mode, index, automatic in modes:
                for name, options in METHODS.items():
                    alarms, shifts = 0, []
                    for trial in data:
                        markers = trial.markers_image if automatic is None else automatic
                        result = register(
                            index,
                            trial.ppc,
                            markers,
                            trial.markers_patient,
                            trial.targets_image,
                            trial.targets_patient,
                            **options,
                        )
                        alarms += bool(result.alarms)
                        shifts.append(result.fine_shift_mm or 0.0)
                    totals[name][0] += alarms
                    totals[name][1] += count
                    label = f"{bone}, {source}, {mode}"
                    shift = f"{np.median(shifts):.2f}, {max(shifts):.2f}" if name != "CR" else "-"
                    print(f"{label:<44} {name:<32} {alarms:4d}/{count:<4d}  {shift:>40}")
    print()
    for name, (alarms, count) in totals.items():
        print(f"all {name:<72} {alarms:4d}/{count:<4d}")


if __name__ == "__main__":
    main()
