"""The stub of a bracket the cut left on the bone (``image.bracket_stub``), on shapes whose geometry is known."""

import numpy as np

from RAMSICPRegistrationLib.image.bracket_stub import bracket_stub

SPACING = np.array([0.5, 0.5, 0.5])


def _grid(shape):
    return np.stack(np.meshgrid(*[np.arange(n) * s for n, s in zip(shape, SPACING)], indexing="ij"), axis=-1)


def _bone_and_rod(bone_radius, rod_radius, stub_mm):
    """A bone along axis 0 (a filled cylinder of ``bone_radius`` mm round (*, 20, 20)) and a rod of ``rod_radius``
    along axis 2 standing on it at x = 30 mm: its first ``stub_mm`` past the bone's surface are the bone's voxels
    (the stub), the rest the body's. Returns (mask, body, stub truth, distance past the bone's surface)."""
    points = _grid((120, 80, 100))
    bone = np.hypot(points[..., 1] - 20.0, points[..., 2] - 20.0) <= bone_radius
    rod = (np.hypot(points[..., 0] - 30.0, points[..., 1] - 20.0) <= rod_radius) & (points[..., 2] >= 20.0)
    past = points[..., 2] - 20.0 - np.sqrt(np.maximum(bone_radius**2 - (points[..., 1] - 20.0) ** 2, 0.0))
    stub = rod & ~bone & (past <= stub_mm)
    return bone | stub, rod & ~bone & ~stub, stub, past


def test_the_stub_of_a_rod_on_a_thick_bone_is_found_and_nothing_of_the_bone():
    mask, body, stub, past = _bone_and_rod(bone_radius=10.0, rod_radius=3.0, stub_mm=5.0)
    found = bracket_stub(mask, body, SPACING)
    assert found[stub & (past >= 1.5)].all()  # the stub but for its foot, in the corner the opening keeps
    assert not found[mask & ~stub].any()


def test_a_bone_thinner_than_the_bracket_is_not_taken_for_its_stub():
    """A bone 2.5 mm in radius under a rod of 3 mm: the whole bone is thinner than the opening; the piece the
    opening takes reaches farther than a stub from the body, so none is taken."""
    mask, body, stub, _ = _bone_and_rod(bone_radius=2.5, rod_radius=3.0, stub_mm=5.0)
    assert not bracket_stub(mask, body, SPACING).any()


def test_no_body_no_stub():
    mask, body, _, _ = _bone_and_rod(bone_radius=10.0, rod_radius=3.0, stub_mm=5.0)
    assert not bracket_stub(mask, np.zeros_like(body), SPACING).any()
