"""The measured result of a simulated osteotomy, the paper's Fig. 6b: the cut planned on the bone in the image, run
by the robot simulator through the whole chain, and the executed cut's four endpoints against the planned ones.

The chain, each link with its own error (the constants below):

1. registration: cr-fused on one trial of the demo (markers placed by hand with the paper's error, 40 probe
   points, probe noise 0.25 mm);
2. robot to tracker (eq. 3): the calibrator's groove at 3 positions 150 mm apart, each reached within the robot's
   repeatability and seen by the tracker as the mean of 30 frames of its noise;
3. the TCP (four-point method, ``core.robot.tcp_four_point``): 4 flange poses tilted 45 degrees about two axes;
4. the path: ``ImageToRobotBase`` (eq. 4) from 1-3, sent over OpenIGTLink to the robot simulator, which moves its
   flange so that the TCP it was told follows the path, each reached flange position off by its repeatability.

The real blade sweeps the executed cut: the plane fitted to the corners of its cutting edge over the whole run. Its
edge on the bone is where that plane meets the bone's mesh, and each planned endpoint is compared with the point of
that edge nearest to it: the executed endpoint. (A whole-bone cut's endpoints are its section's extremes along
directions; with the plane tilted by a tenth of a degree such an extreme slides a millimetre along the curved
surface, to another place on the bone, so the extremes of the two sections are not the same points.) Meanwhile
the tracker follows the tool's markers and the live guidance (``core.guidance``) compares the blade, as the
navigation sees it through its own registration, with the plan: it shows the robot's errors (2-4), not the
registration's, which the navigation cannot see. (The navigation knows the blade on its marker body from the tool's
own calibration, here exact, not from the robot's TCP.) ``ChainErrors`` switches each error on or off.
"""

import time
from dataclasses import dataclass

import numpy as np

from ..core.guidance import cut_guidance
from ..core.osteotomy import plan_cut
from ..core.registration import register
from ..core.robot import image_to_robot_base, robot_base_to_tracker, tcp_four_point
from ..core.surface_index import SurfaceIndex
from ..core.tool_path import plan_osteotomy
from ..core.transforms import apply_transform, invert_transform, make_transform, rotation_about_axis
from ..simulation.package_data import BONES, shipped_patient
from .demo import PAPER_TRE_MM, PROBE_NOISE_MM

#: The tracker's noise on one pose (mm, RMS 3-D; NDI gives 0.12 mm RMS for the Polaris Vega).
TRACKER_NOISE_MM = 0.12
#: Tracker frames averaged for each calibrator position.
FRAMES_PER_POSITION = 30
#: The robot's repeatability (mm, RMS 3-D of a reached flange position; UR e-series +-0.03 mm).
ROBOT_REPEATABILITY_MM = 0.03
#: The three calibrator positions of eq. 3, in robot-base coordinates around the cut (mm).
CALIBRATOR_SPAN_MM = 150.0
#: The saw blade's TCP on the flange (mm), and the tool's marker body on the flange.
TRUE_TCP_MM = np.array([0.8, -0.5, 185.0])
MARKER_TO_FLANGE = make_transform(rotation_about_axis((0.0, 1.0, 0.0), np.pi / 2), (0.0, 70.0, 60.0))
ROBOT_SPEED_MM_S = 20.0
ROBOT_RATE_HZ = 125.0
#: Every this many robot steps the tracker measures the tool for the guidance.
GUIDANCE_EVERY = 4


@dataclass(frozen=True)
class ChainErrors:
    """The errors of the simulated chain. ``registration``: cr-fused on a simulated trial (False: the true
    ReferenceToImage); the tracker's noise and the robot's repeatability (mm, RMS 3-D); ``tcp_error_mm``: None for
    the four-point calibration's own error, else (3,) the robot is told the true TCP plus this (flange frame)."""

    registration: bool = True
    tracker_noise_mm: float = TRACKER_NOISE_MM
    repeatability_mm: float = ROBOT_REPEATABILITY_MM
    tcp_error_mm: tuple = None

    @classmethod
    def none(cls, tcp_error_mm=(0.0, 0.0, 0.0)):
        """Every error off (but a TCP error, if given)."""
        return cls(registration=False, tracker_noise_mm=0.0, repeatability_mm=0.0, tcp_error_mm=tcp_error_mm)


@dataclass(frozen=True)
class CutResult:
    """Planned and executed cut (image RAS, mm): endpoints and their labels, each endpoint's distance and its part
    along the planned normal, the registration's true and predicted error there, the executed plane's tilt (deg),
    the guidance during the cut, the path and how it was streamed, and the plan's and the run's geometry."""

    bone: str
    labels: tuple
    planned: np.ndarray
    executed: np.ndarray
    distance_mm: np.ndarray
    normal_mm: np.ndarray
    registration_error_mm: np.ndarray
    predicted_error_mm: np.ndarray
    tilt_deg: float
    guidance: dict
    path: dict
    streaming: dict
    calibration: dict
    seconds: float
    plan: object  # the CutPlan
    executed_plan: object  # the CutPlan of the executed plane
    path_positions: np.ndarray  # (P, 3) the planned TCP positions, image
    pass_index: np.ndarray
    mesh: tuple  # (vertices, triangles) of the bone
    blade_pose: np.ndarray  # (4, 4) one tracked blade pose mid-cut, as the navigation sees it (image)
    blade_guidance: object  # its CutGuidance

    @property
    def directions(self):
        """Where each endpoint lies on the bone, in words: 'anterior', 'medial', ..."""
        lateral = "right" if BONES[self.bone]["lateral"][0] > 0 else "left"
        medial = "left" if lateral == "right" else "right"
        words = {lateral: "lateral", medial: "medial"}
        return tuple(
            ", ".join(words.get(word, word) for word in text.split(", ")) for text in self.plan.endpoint_directions
        )

    @property
    def rms_mm(self):
        """The executed endpoints' RMS distance from the planned ones (eq. 11's form)."""
        return float(np.sqrt(np.mean(self.distance_mm**2)))

    def to_dict(self):
        return {
            "bone": self.bone,
            "labels": list(self.labels),
            "directions": list(self.directions),
            "planned_endpoints": self.planned.tolist(),
            "executed_endpoints": self.executed.tolist(),
            "distance_mm": self.distance_mm.tolist(),
            "along_normal_mm": self.normal_mm.tolist(),
            "rms_mm": self.rms_mm,
            "registration_error_mm": self.registration_error_mm.tolist(),
            "predicted_registration_error_mm": self.predicted_error_mm.tolist(),
            "executed_plane_tilt_deg": self.tilt_deg,
            "guidance": self.guidance,
            "path": self.path,
            "streaming": self.streaming,
            "calibration": self.calibration,
            "seconds": self.seconds,
        }


def run_cut_trial(bone="right-tibia", seed=0, speed_mm_s=ROBOT_SPEED_MM_S, errors=ChainErrors(), progress=None):
    """Plan, register, calibrate, stream and cut once (module docstring) with ``errors``; returns a CutResult."""
    from OpenIGTLinkBridgeLib.robot_link import RobotLink
    from OpenIGTLinkBridgeLib.robot_simulator import RobotSimulator

    clock = time.perf_counter()
    report = progress or (lambda step, done, total: None)
    rng = np.random.default_rng(seed)
    patient, vertices, triangles = shipped_patient(bone, seed)
    report("registration", 0, 4)
    fle = patient.marker_fle_for_cr_tre(PAPER_TRE_MM["CR"][0], seed=seed, trials=500)
    trial = patient.simulate_trial(rng, fle, probe_noise_mm=PROBE_NOISE_MM)
    result = register(SurfaceIndex(patient.ipc), trial.ppc, trial.markers_image, trial.markers_patient)
    reference_to_image = result.reference_to_image if errors.registration else patient.reference_to_image

    plans, path = _plan(patient, vertices, triangles, bone)
    plan = plans[0]
    truth = _operating_room(patient, plan)
    report("robot calibration", 1, 4)
    base_to_tracker, calibration = _calibrate_robot(truth, rng, errors)
    tcp = tcp_four_point(_four_point_poses(rng, errors.repeatability_mm))
    told_tcp = tcp.tcp_in_flange if errors.tcp_error_mm is None else TRUE_TCP_MM + errors.tcp_error_mm
    calibration["tcp_error_mm"] = float(np.linalg.norm(told_tcp - TRUE_TCP_MM))
    calibration["tcp_rms_mm"] = tcp.rms_mm
    image_to_base = image_to_robot_base(base_to_tracker, truth["reference_to_tracker"], reference_to_image)

    report("cut", 2, 4)
    robot_path = path.in_robot_base(image_to_base)
    robot = RobotSimulator(
        speed_mm_s=speed_mm_s,
        rate_hz=ROBOT_RATE_HZ,
        tcp_in_flange=told_tcp,
        true_tcp_in_flange=TRUE_TCP_MM,
        repeatability_mm=errors.repeatability_mm,
        start_pose=robot_path.poses[0],
        realtime=False,
        seed=seed,
    ).start()
    try:
        link = RobotLink(*robot.address[:2])
        sent = time.perf_counter()
        link.send_path(robot_path.poses)
        state = link.wait_for(("ACCEPTED", "REFUSED"), 10.0)
        accepted_s = time.perf_counter() - sent
        if state != "ACCEPTED":
            raise RuntimeError(f"the robot simulator did not accept the path: {link.status_text}")
        state = link.wait_for(("DONE", "STOPPED"), 600.0)
        link.close()
    finally:
        robot.stop()
    if state != "DONE":
        raise RuntimeError(f"the robot simulator stopped before the end of the path ({state})")
    trajectory = np.array(robot.trajectory)  # the real TCP, robot base

    report("measurement", 3, 4)
    base_to_image = (
        truth["reference_to_image"] @ invert_transform(truth["reference_to_tracker"]) @ truth["base_to_tracker"]
    )
    blade = base_to_image @ trajectory  # the real blade in the image, as the patient is
    executed_plan = _executed_plan(blade, plan, path.width_mm, vertices, triangles)
    executed = executed_plan.section.nearest(plan.endpoints)
    differences = executed - plan.endpoints
    true_to_estimated = reference_to_image @ invert_transform(truth["reference_to_image"])
    guidance, blade_pose, blade_guidance = _guidance(
        trajectory, truth, reference_to_image, plans, path, rng, errors.tracker_noise_mm
    )
    report("measurement", 4, 4)
    return CutResult(
        bone=bone,
        labels=plan.endpoint_labels,
        planned=plan.endpoints,
        executed=executed,
        distance_mm=np.linalg.norm(differences, axis=1),
        normal_mm=differences @ plan.plane.normal,
        registration_error_mm=np.linalg.norm(
            apply_transform(true_to_estimated, plan.endpoints) - plan.endpoints, axis=1
        ),
        predicted_error_mm=np.asarray(result.predicted_error_mm(plan.endpoints)) * errors.registration,
        tilt_deg=float(np.degrees(np.arccos(min(1.0, abs(executed_plan.plane.normal @ plan.plane.normal))))),
        guidance=guidance,
        path={**path.to_dict(), "robot_steps": len(trajectory), "simulated_s": len(trajectory) / ROBOT_RATE_HZ},
        streaming={
            "poses": len(robot_path.poses),
            "bytes": _path_bytes(robot_path.poses),
            "sent_and_accepted_s": accepted_s,
            "poses_per_s": len(robot_path.poses) / accepted_s,
        },
        calibration=calibration,
        seconds=time.perf_counter() - clock,
        plan=plan,
        executed_plan=executed_plan,
        path_positions=path.positions,
        pass_index=path.pass_index,
        mesh=(vertices, triangles),
        blade_pose=blade_pose,
        blade_guidance=blade_guidance,
    )


def _plan(patient, vertices, triangles, bone):
    """A horizontal cut at the demo's cut height, its blade entering medially and advancing laterally (a high
    tibial osteotomy's approach), across the whole bone, on the bone's mesh (an IPC as ``ramsicp ipc`` writes it)."""
    lateral = np.asarray(BONES[bone]["lateral"], dtype=np.float64)
    section = patient.ipc[np.abs(patient.ipc[:, 2] - patient.cut_height_mm) < 0.3]
    origin = (section.min(axis=0) + section.max(axis=0)) / 2.0
    origin[2] = patient.cut_height_mm
    return plan_osteotomy(vertices, origin, (0.0, 0.0, -1.0), depth=lateral, triangles=triangles)


def _operating_room(patient, plan):
    """The true transforms: the tracker 1.6 m in front of the patient, the robot's base 450 mm from the cut."""
    reference_to_tracker = make_transform(
        rotation_about_axis((0.0, 0.0, 1.0), 0.3) @ rotation_about_axis((1.0, 0.0, 0.0), 1.2), (40.0, 120.0, -1600.0)
    )
    cut_in_tracker = apply_transform(
        reference_to_tracker @ invert_transform(patient.reference_to_image), plan.plane.origin[None]
    )[0]
    base_rotation = rotation_about_axis((0.2, 1.0, 0.1), 2.2)
    base_to_tracker = make_transform(base_rotation, cut_in_tracker - base_rotation @ (420.0, 0.0, 150.0))
    return {
        "reference_to_image": patient.reference_to_image,
        "reference_to_tracker": reference_to_tracker,
        "base_to_tracker": base_to_tracker,
    }


def _calibrate_robot(truth, rng, errors):
    """Eq. 3 from three calibrator positions reached by the robot and averaged by the tracker."""
    positions = np.array(
        [(420.0, 0.0, 150.0), (420.0 + CALIBRATOR_SPAN_MM, 0.0, 150.0), (420.0, CALIBRATOR_SPAN_MM, 150.0)]
    )
    reached = positions + _noise(rng, positions.shape, errors.repeatability_mm)
    frames = _noise(rng, (FRAMES_PER_POSITION, 3, 3), errors.tracker_noise_mm).mean(axis=0)
    seen = apply_transform(truth["base_to_tracker"], reached) + frames
    estimate = robot_base_to_tracker(positions, seen)
    error = invert_transform(truth["base_to_tracker"]) @ estimate
    return estimate, {
        "eq3_rotation_error_deg": float(np.degrees(np.arccos(np.clip((np.trace(error[:3, :3]) - 1) / 2, -1, 1)))),
        "eq3_error_at_cut_mm": float(
            np.linalg.norm(apply_transform(error, np.array([(420.0, 0.0, 150.0)]))[0] - (420.0, 0.0, 150.0))
        ),
    }


def _four_point_poses(rng, repeatability_mm):
    """Flange poses with the true TCP held on one point, 45 degrees apart about two axes, with the robot's error."""
    point = np.array([420.0, 0.0, 150.0])
    poses = []
    for axis, angle in (((1, 0, 0), 45.0), ((1, 0, 0), -45.0), ((0, 1, 0), 45.0), ((0, 1, 0), -45.0)):
        rotation = np.diag([1.0, -1.0, -1.0]) @ rotation_about_axis(axis, np.radians(angle))
        poses.append(make_transform(rotation, point - rotation @ TRUE_TCP_MM + _noise(rng, 3, repeatability_mm)))
    return np.array(poses)


def _executed_plan(blade, plan, width_mm, vertices, triangles):
    """The plane swept by the real blade's edge (least squares over its corners at every step), met with the bone."""
    corners = np.concatenate([blade[:, :3, 3] + side * width_mm / 2.0 * blade[:, :3, 0] for side in (-1.0, 1.0)])
    centre = corners.mean(axis=0)
    normal = np.linalg.svd(corners - centre)[2][2]
    normal = normal if normal @ plan.plane.normal > 0 else -normal
    origin = plan.plane.origin - ((plan.plane.origin - centre) @ normal) * normal  # the plan's centre, on this plane
    return plan_cut(vertices, origin, normal, depth=plan.plane.depth, extent_mm=plan.extent_mm, triangles=triangles)


def _guidance(trajectory, truth, reference_to_image, plans, path, rng, noise_mm):
    """The live guidance as the navigation computes it from the tracked tool, every few robot steps."""
    tool_tip_to_tool = invert_transform(MARKER_TO_FLANGE) @ make_transform(translation=TRUE_TCP_MM)
    image_from_tracker = reference_to_image @ invert_transform(truth["reference_to_tracker"])
    numbers, poses, cutting = [], [], []
    for step in range(0, len(trajectory), GUIDANCE_EVERY):
        flange = trajectory[step] @ make_transform(translation=-TRUE_TCP_MM)
        tool_to_tracker = truth["base_to_tracker"] @ flange @ MARKER_TO_FLANGE
        tool_to_tracker[:3, 3] += _noise(rng, 3, noise_mm)
        pose = image_from_tracker @ tool_to_tracker @ tool_tip_to_tool
        guidance = cut_guidance(plans, pose, tool=path.tool, width_mm=path.width_mm)
        numbers.append(guidance)
        poses.append(pose)
        cutting.append(
            guidance.depth_to_far_cortex_mm is not None and guidance.depth_mm > plans[0].section.uv[:, 1].min()
        )
    inside = [index for index, flag in enumerate(cutting) if flag] or list(range(len(numbers)))
    distances = np.array([numbers[index].distance_mm for index in inside])
    angles = np.array([numbers[index].angle_deg for index in inside])
    shown = inside[len(inside) // 2]
    return (
        {
            "frames": len(inside),
            "tip_distance_mean_mm": float(distances.mean()),
            "tip_distance_max_mm": float(np.abs(distances).max()),
            "angle_mean_deg": float(angles.mean()),
            "angle_max_deg": float(angles.max()),
            "on_plan_fraction": float(np.mean([numbers[index].on_plan for index in inside])),
        },
        poses[shown],
        numbers[shown],
    )


def _path_bytes(poses):
    from OpenIGTLinkBridgeLib.robot_link import encode_path

    return len(encode_path(poses, "size"))


def _noise(rng, shape, rms_mm):
    return rng.normal(scale=rms_mm / np.sqrt(3.0), size=shape)
