"""Homogeneous rigid transforms (paper eq. 1) as (4, 4) float64 arrays.

A transform named ``AToB`` maps coordinates in frame A to frame B (SlicerIGT/PLUS convention), so
``AToC = BToC @ AToB``.
"""

import numpy as np


def make_transform(rotation=None, translation=None):
    """Build a (4, 4) transform from a (3, 3) rotation and a (3,) translation in mm (eq. 1)."""
    transform = np.eye(4)
    if rotation is not None:
        transform[:3, :3] = rotation
    if translation is not None:
        transform[:3, 3] = translation
    return transform


def rotation_about_axis(axis, angle_rad):
    """(3, 3) rotation by ``angle_rad`` about the unit vector along ``axis`` (Rodrigues' formula)."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    cross = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle_rad) * cross + (1.0 - np.cos(angle_rad)) * (cross @ cross)


def invert_transform(transform):
    """Inverse of a rigid (4, 4) transform, using R^T rather than a general matrix inverse."""
    rotation = transform[:3, :3]
    return make_transform(rotation.T, -rotation.T @ transform[:3, 3])


def apply_transform(transform, points):
    """Map (N, 3) points (mm) through a (4, 4) transform; returns a new (N, 3) array."""
    return points @ transform[:3, :3].T + transform[:3, 3]


def probe_to_reference(reference_to_tracker, probe_to_tracker):
    """Paper eq. 2: ``ProbeToReference = inv(ReferenceToTracker) @ ProbeToTracker``, both (4, 4)."""
    return invert_transform(reference_to_tracker) @ probe_to_tracker


def rotation_angle_deg(transform):
    """Angle (degrees) of the rotation part of a (4, 4) transform."""
    cosine = (np.trace(transform[:3, :3]) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))
