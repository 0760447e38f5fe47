"""The module's workflow scenario, shared by pytest (on ``slicer-core``) and the Slicer self-test.

A virtual patient and its CT phantom stand in for the operating room; the tracked probe is simulated as
SlicerIGT's self-tests do it, by writing matrices into the transform hierarchy. ``run_workflow`` drives every
step through ``NavigationLogic`` and checks each against the known truth, raising AssertionError with a message.
"""

import numpy as np

from ..core.transforms import apply_transform, invert_transform, make_transform, probe_to_reference, rotation_about_axis
from ..simulation.ct_phantom import make_ct_phantom
from ..simulation.package_data import shipped_patient
from . import mrml_nodes
from .navigation import NavigationLogic, matrix_of, set_matrix

TIP_IN_PROBE = np.array([0.0, 0.0, 150.0])


def make_patient_and_ct(bone="right-tibia", seed=0):
    """A virtual patient and its CT phantom (about 10 s)."""
    patient, vertices, triangles = shipped_patient(bone, seed)
    volume, truth = make_ct_phantom(patient, vertices, triangles, seed=seed)
    return patient, volume, truth


def run_workflow(scene, patient, volume, truth, autosave_directory=None, clock=None, seed=5):
    """Steps 1-4 of the workflow on ``scene``; returns the state the later steps and the checks use."""
    rng = np.random.default_rng(seed)
    logic = NavigationLogic(scene, autosave_directory=autosave_directory, **({} if clock is None else {"clock": clock}))
    ct_node = mrml_nodes.volume_node(scene, volume, "CT")
    image = logic.process_ct(ct_node)
    tip_node, probe_node = logic.transform_node("ProbeTipToProbe"), logic.transform_node("ProbeToReference")
    reference_to_image = logic.transform_node("ReferenceToImage")
    logic.build_hierarchy(tip_node, probe_node, reference_to_image)
    pivot_poses = []
    for _ in range(40):
        rotation = rotation_about_axis(rng.normal(size=3), np.radians(rng.uniform(-25, 25)))
        pivot_poses.append(make_transform(rotation, np.array([20.0, 30.0, 40.0]) - rotation @ TIP_IN_PROBE))
    pivot = logic.pivot_calibrate(np.array(pivot_poses), tip_node)
    markers_patient = logic.markers_patient_node()
    ppc_node = scene.AddNewNodeByClass("vtkMRMLMarkupsFiducialNode", "PPC")
    trial = patient.simulate_trial(rng, marker_fle_mm=0.0, probe_noise_mm=0.0)
    reference_to_tracker = make_transform(rotation_about_axis((1.0, 2.0, 3.0), 1.0), (100.0, -200.0, -1500.0))
    for point in trial.ppc:  # each touch: the tracker streams both tools, eq. 2 gives ProbeToReference
        probe_to_tracker = reference_to_tracker @ make_transform(np.eye(3), point - TIP_IN_PROBE)
        set_matrix(probe_node, probe_to_reference(reference_to_tracker, probe_to_tracker))
        logic.note_update(probe_node)
        logic.collect_point(ppc_node, probe_node, tip_node)
    result = logic.register(image.ipc_model, ppc_node, image.markers_image, markers_patient)
    nodes = dict(
        tip=tip_node,
        probe=probe_node,
        reference_to_image=reference_to_image,
        markers_patient=markers_patient,
        ppc=ppc_node,
        ct=ct_node,
    )
    return dict(
        scene=scene,
        logic=logic,
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
    distance = state["logic"].tip_to_surface_mm(
        image.ipc_model, nodes["probe"], nodes["tip"], nodes["reference_to_image"]
    )
    assert distance < 1.0, f"step 5: the tip on the bone reads {distance:.2f} mm from the surface"
    return {"marker_error_mm": float(error), "target_error_mm": float(worst), "tip_to_surface_mm": distance}
