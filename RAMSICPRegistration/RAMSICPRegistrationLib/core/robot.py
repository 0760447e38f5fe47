"""Robot to tracker calibration (paper eqs. 3-4) with a tracked calibrator point on the robot's tool.

The robot moves its tool centre point, which coincides with the calibrator's groove point, to three
non-collinear positions ``p1, p2, p3``, known in robot-base coordinates from the kinematics and measured in
tracker coordinates. Both triples define one auxiliary frame A (origin p1, x towards p2, z normal to the three),
so ``RobotBaseToTracker = AToTracker @ inv(AToRobotBase)`` (eq. 3), and the transform that sends planned image
coordinates to the robot (eq. 4) is ``ImageToRobotBase = inv(RobotBaseToTracker) @ ReferenceToTracker @
inv(ReferenceToImage)``.

The robot's tool-centre point (TCP) itself, ``ToolToFlange``, comes from the four-point method the paper cites
([29]): the robot holds the TCP on one fixed point while its flange takes four (or more) orientations; each flange
pose ``(R_i, t_i)`` (``FlangeToRobotBase``, from the kinematics) then satisfies ``R_i p + t_i = q``, a linear least
squares in the TCP offset ``p`` (flange frame) and the point ``q`` (robot base), the pivot calibration's fit.
"""

from dataclasses import dataclass

import numpy as np

from .fixed_point import fixed_point_fit
from .transforms import invert_transform, make_transform
from .validation import as_points, as_transform, check_distinct, check_not_collinear


def auxiliary_frame(points):
    """(4, 4) AToX of the frame A built on three points (3, 3) given in frame X (eq. 3's auxiliary frame)."""
    x_axis = points[1] - points[0]
    x_axis /= np.linalg.norm(x_axis)
    z_axis = np.cross(x_axis, points[2] - points[0])
    z_axis /= np.linalg.norm(z_axis)
    return make_transform(np.column_stack((x_axis, np.cross(z_axis, x_axis), z_axis)), points[0])


def robot_base_to_tracker(points_robot, points_tracker):
    """Paper eq. 3: RobotBaseToTracker (4, 4) from the same 3 calibrator positions in both frames (mm).

    Raises:
        ValueError: not exactly 3 points, NaN, coincident or collinear positions, or distances that disagree
            by more than 2 mm between the frames (the robot and tracker saw different positions).
    """
    points_robot = as_points(points_robot, "calibrator positions (robot)", min_count=3)
    points_tracker = as_points(points_tracker, "calibrator positions (tracker)", min_count=3)
    for points, name in (
        (points_robot, "calibrator positions (robot)"),
        (points_tracker, "calibrator positions (tracker)"),
    ):
        if len(points) != 3:
            raise ValueError(f"{name}: give exactly 3 positions, got {len(points)}")
        check_distinct(points, name)
        check_not_collinear(points, name)
    spacing_robot = np.linalg.norm(points_robot[:, None] - points_robot[None], axis=2)
    spacing_tracker = np.linalg.norm(points_tracker[:, None] - points_tracker[None], axis=2)
    mismatch = float(np.abs(spacing_robot - spacing_tracker).max())
    if mismatch > 2.0:
        raise ValueError(
            f"the 3 calibrator positions are {mismatch:.1f} mm apart differently in the robot and "
            "tracker frames; check that the groove point did not move, then record them again"
        )
    return auxiliary_frame(points_tracker) @ invert_transform(auxiliary_frame(points_robot))


def image_to_robot_base(robot_base_to_tracker_transform, reference_to_tracker, reference_to_image):
    """Paper eq. 4: ImageToRobotBase (4, 4) = inv(RobotBaseToTracker) @ ReferenceToTracker @ inv(ReferenceToImage)."""
    return (
        invert_transform(robot_base_to_tracker_transform) @ reference_to_tracker @ invert_transform(reference_to_image)
    )


#: The four-point method needs at least this many flange poses.
MIN_TCP_POSES = 4
#: Two flange orientations closer than this (degrees) repeat one pose: together they tell nothing about the TCP.
MIN_TCP_TURN_DEG = 5.0
#: The orientations must also turn this much (degrees, RMS) about their least-turned axis; flange turns about one
#: axis only (flange positions on one circle, in one plane) leave the TCP's offset along that axis undetermined.
MIN_TCP_SPREAD_DEG = 5.0
#: A pose whose TCP lands farther than this (mm) from the common point means the TCP slipped off it.
MAX_TCP_RESIDUAL_MM = 1.0


@dataclass(frozen=True)
class TcpCalibration:
    """The four-point TCP calibration: ``tcp_in_flange`` (3,) mm, the fixed point ``point_in_base`` (3,) mm, each
    pose's distance from it (``residuals_mm``), their RMS, and the least turn about any axis (``spread_deg``)."""

    tcp_in_flange: np.ndarray
    point_in_base: np.ndarray
    residuals_mm: np.ndarray
    rms_mm: float
    spread_deg: float

    @property
    def tool_to_flange(self):
        """(4, 4) ``ToolToFlange``: a translation by the TCP offset (the TCP frame keeps the flange's axes)."""
        return make_transform(translation=self.tcp_in_flange)

    def to_dict(self):
        return {
            "tcp_in_flange_mm": self.tcp_in_flange.tolist(),
            "point_in_base_mm": self.point_in_base.tolist(),
            "residuals_mm": self.residuals_mm.tolist(),
            "rms_mm": self.rms_mm,
            "spread_deg": self.spread_deg,
        }


def tcp_four_point(flange_to_base, max_residual_mm=MAX_TCP_RESIDUAL_MM):
    """The TCP offset from (N >= 4, 4, 4) ``FlangeToRobotBase`` poses taken with the TCP held on one point ([29]).

    Raises:
        ValueError: fewer than 4 poses, a pose that is not rigid, two poses with (nearly) the same orientation, turns
            about one axis only (coplanar flange positions), or a TCP that slipped (a residual over
            ``max_residual_mm``): each saying what to do.
    """
    try:
        poses = np.array(flange_to_base, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(f"flange poses: cannot read as numbers ({error}); pass (N, 4, 4) matrices") from None
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ValueError(f"flange poses: expected an (N, 4, 4) array of FlangeToRobotBase, got shape {poses.shape}")
    if len(poses) < MIN_TCP_POSES:
        raise ValueError(
            f"four-point TCP calibration: {len(poses)} flange poses given, at least {MIN_TCP_POSES} needed; hold the "
            "TCP on the point and turn the flange to more orientations"
        )
    for number, pose in enumerate(poses, start=1):
        as_transform(pose, f"flange pose {number}")
    rotations = poses[:, :3, :3]
    turns = np.degrees(np.arccos(np.clip((np.einsum("aij,bij->ab", rotations, rotations) - 1.0) / 2.0, -1.0, 1.0)))
    np.fill_diagonal(turns, np.inf)
    first, second = np.unravel_index(np.argmin(turns), turns.shape)
    if turns[first, second] < MIN_TCP_TURN_DEG:
        first, second = sorted((int(first) + 1, int(second) + 1))
        raise ValueError(
            f"flange poses {first} and {second} repeat one orientation ({turns[first - 1, second - 1]:.1f} degrees "
            f"apart); turn the flange at least {MIN_TCP_TURN_DEG:g} degrees between poses"
        )
    spread = _least_turn_deg(rotations)
    if spread < MIN_TCP_SPREAD_DEG:
        raise ValueError(
            f"the flange poses turn about one axis only (their positions lie in one plane; {spread:.1f} degrees about "
            "the least-turned axis), so the TCP's offset along that axis is undetermined; tilt the flange about a "
            f"second axis by at least {MIN_TCP_SPREAD_DEG:g} degrees"
        )
    tcp, point = fixed_point_fit(poses)
    residuals = np.linalg.norm(rotations @ tcp + poses[:, :3, 3] - point, axis=1)
    worst = int(np.argmax(residuals))
    if residuals[worst] > max_residual_mm:
        raise ValueError(
            f"flange pose {worst + 1} puts the TCP {residuals[worst]:.2f} mm from the common point (at most "
            f"{max_residual_mm:g} mm); the TCP slipped off the point: record that pose again"
        )
    return TcpCalibration(
        tcp_in_flange=tcp,
        point_in_base=point,
        residuals_mm=residuals,
        rms_mm=float(np.sqrt(np.mean(residuals**2))),
        spread_deg=spread,
    )


def _least_turn_deg(rotations):
    """RMS turn (degrees) of (N, 3, 3) rotations about the axis they turn least about.

    The fit's unknown TCP offset is undetermined along a direction ``a`` that every rotation leaves in place
    (``R_i a`` the same for all i): the smallest singular value of the stacked ``R_i - mean(R)`` measures how far
    the rotations move their least-moved direction, ``2 sin(turn / 2)`` per pose.
    """
    centred = rotations - rotations.mean(axis=0)
    smallest = np.linalg.svd(centred.reshape(-1, 3), compute_uv=False)[-1] / np.sqrt(len(rotations))
    return float(np.degrees(2.0 * np.arcsin(min(1.0, smallest / 2.0))))
