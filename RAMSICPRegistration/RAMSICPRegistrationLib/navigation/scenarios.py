"""The module's workflow scenario, shared by pytest (on ``slicer-core``) and the Slicer self-test.

A virtual patient and its CT phantom stand in for the operating room; the tracked probe is simulated as
SlicerIGT's self-tests do it, by writing matrices into the transform nodes. ``run_workflow`` drives every step
through the same ``NavigationController`` the module's widget drives, choosing nodes in the parameter node as the
surgeon does in the GUI and clicking only what the GUI offers; ``check_workflow`` checks each step against the
known truth, raising AssertionError with a message.
"""

import numpy as np

from ..core.transforms import apply_transform, invert_transform, make_transform, probe_to_reference, rotation_about_axis
from ..simulation.ct_phantom import make_ct_phantom
from ..simulation.package_data import shipped_patient
from ..simulation.patient_cache import shared_shipped_patient
from ..simulation.phantom_cache import cached_ct_phantom
from . import mrml_nodes
from .controller import NavigationController
from .navigation import matrix_of, set_matrix

TIP_IN_PROBE = np.array([0.0, 0.0, 150.0])


def make_patient_and_ct(bone="right-tibia", seed=0):
    """A virtual patient and its CT phantom (15-40 s)."""
    patient, vertices, triangles = shipped_patient(bone, seed)
    volume, truth = make_ct_phantom(patient, vertices, triangles, seed=seed)
    return patient, volume, truth


def cached_patient_and_ct(bone="right-tibia", seed=0, directory=None):
    """The virtual patient and the CT volume of ``make_patient_and_ct``, the patient and the volume read from the
    user's cache (``simulation.patient_cache``, ``simulation.phantom_cache``) when they were built before: (patient,
    volume, phantom built now). The patient is shared within the process and read-only."""
    patient, vertices, triangles = shared_shipped_patient(bone, seed)
    volume, built = cached_ct_phantom(patient, vertices, triangles, seed=seed, directory=directory)
    return patient, volume, built


def run_workflow(scene, patient, volume, truth, autosave_directory=None, seed=5):
    """Steps 1-4 of the workflow on ``scene``; returns the state the later steps and the checks use."""
    rng = np.random.default_rng(seed)
    controller = NavigationController(scene, autosave_directory=autosave_directory)
    parameters = controller.parameters
    parameters.ctVolume = mrml_nodes.volume_node(scene, volume, "CT")
    image = controller.process_ct()
    probe_node = controller.steps.transform_node("ProbeToReference")  # as the tracker feed names it
    parameters.probeToReference = probe_node
    divot = np.array([20.0, 30.0, 40.0])
    set_matrix(probe_node, make_transform(np.eye(3), divot - TIP_IN_PROBE))  # the tracker sees the probe: valid
    controller.start_pivot()
    for _ in range(40):  # the tracker streams the probe swivelling about its tip in a divot
        rotation = rotation_about_axis(rng.normal(size=3), np.radians(rng.uniform(-25, 25)))
        set_matrix(probe_node, make_transform(rotation, divot - rotation @ TIP_IN_PROBE))
    pivot = controller.stop_pivot()
    markers_patient = controller.add_reference_body_markers()
    trial = patient.simulate_trial(rng, marker_fle_mm=0.0, probe_noise_mm=0.0)
    reference_to_tracker = make_transform(rotation_about_axis((1.0, 2.0, 3.0), 1.0), (100.0, -200.0, -1500.0))
    for point in trial.ppc:  # each touch: the tracker streams both tools, eq. 2 gives ProbeToReference
        probe_to_tracker = reference_to_tracker @ make_transform(np.eye(3), point - TIP_IN_PROBE)
        set_matrix(probe_node, probe_to_reference(reference_to_tracker, probe_to_tracker))
        controller.collect_point()
    result = controller.register()
    nodes = dict(
        tip=parameters.probeTipToProbe,
        probe=probe_node,
        reference_to_image=parameters.referenceToImage,
        markers_patient=markers_patient,
        ppc=parameters.probePoints,
        ct=parameters.ctVolume,
    )
    return dict(
        scene=scene,
        controller=controller,
        logic=controller.steps,
        image=image,
        truth=truth,
        trial=trial,
        pivot=pivot,
        nodes=nodes,
        result=result,
        reference_to_tracker=reference_to_tracker,
        patient=patient,
    )


def check_workflow(state):
    """The known answers of every step; raises AssertionError naming the step that is wrong."""
    image, truth, nodes, patient = state["image"], state["truth"], state["nodes"], state["patient"]
    centres = mrml_nodes.fiducial_positions(image.markers_image)
    error = np.abs(centres - truth.marker_centres).max()
    assert error < 0.1, f"step 1: automatic marker centres off by {error:.3f} mm"
    tip = matrix_of(nodes["tip"])[:3, 3]
    assert np.allclose(tip, TIP_IN_PROBE, atol=1e-6), f"step 2: pivot calibration gave tip {tip}"
    collected = mrml_nodes.fiducial_positions(nodes["ppc"])
    assert np.allclose(collected, state["trial"].ppc, atol=1e-6), "step 3: collected points differ from the touches"
    targets = apply_transform(invert_transform(patient.reference_to_image), patient.targets_image)
    registered = apply_transform(matrix_of(nodes["reference_to_image"]), targets)
    worst = np.linalg.norm(registered - patient.targets_image, axis=1).max()
    assert worst < 0.3, f"step 4: target error {worst:.2f} mm after registration"
    set_matrix(nodes["probe"], matrix_of(nodes["probe"]))  # the tracker keeps streaming the tip on the last touch
    distance = state["controller"].status().tip_to_surface_mm  # the live readout
    assert distance is not None, "step 5: no tip-to-surface readout while the probe is tracked after registration"
    assert distance < 1.0, f"step 5: the tip on the bone reads {distance:.2f} mm from the surface"
    return {"marker_error_mm": float(error), "target_error_mm": float(worst), "tip_to_surface_mm": distance}
