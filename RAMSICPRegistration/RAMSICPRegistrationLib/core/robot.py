"""Robot to tracker calibration (paper eqs. 3-4) with a tracked calibrator point on the robot's tool.

The robot moves its tool centre point, which coincides with the calibrator's groove point, to three
non-collinear positions ``p1, p2, p3``, known in robot-base coordinates from the kinematics and measured in
tracker coordinates. Both triples define one auxiliary frame A (origin p1, x towards p2, z normal to the three),
so ``RobotBaseToTracker = AToTracker @ inv(AToRobotBase)`` (eq. 3), and the transform that sends planned image
coordinates to the robot (eq. 4) is ``ImageToRobotBase = inv(RobotBaseToTracker) @ ReferenceToTracker @
inv(ReferenceToImage)``.
"""

import numpy as np

from .transforms import invert_transform, make_transform
from .validation import as_points, check_distinct, check_not_collinear


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
