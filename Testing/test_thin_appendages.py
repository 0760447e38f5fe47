"""Wires joined to the bone (``image.thin_appendages``), on shapes whose geometry is known."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.image.thin_appendages import GRID_MM, PROTRUDES_MM, wires_on_bone


def _grid(shape, spacing):
    return np.stack(np.meshgrid(*[np.arange(n) * s for n, s in zip(shape, spacing)], indexing="ij"), axis=-1)


def _to_segment(points, start, end):
    """(...) distance (mm) of points (..., 3) to the segment ``start``-``end``."""
    start, end = np.asarray(start, float), np.asarray(end, float)
    axis = end - start
    along = np.clip(((points - start) @ axis) / (axis @ axis), 0.0, 1.0)
    return np.linalg.norm(points - (start + along[..., None] * axis), axis=-1)


def _shaft(points, radius=10.0):
    """A filled cylinder along axis 0 round (*, 30, 30) mm."""
    return np.hypot(points[..., 1] - 30.0, points[..., 2] - 30.0) <= radius


@pytest.mark.parametrize("spacing", [(0.5, 0.5, 0.5), (0.3, 0.3, 0.7), (1.0, 1.0, 1.0)])
def test_a_wire_through_the_bone_is_found_and_nothing_of_the_bone(spacing):
    """A wire 1.6 mm wide crossing a shaft 20 mm wide at a slant, 14-19 mm out on either side: taken from 2 mm
    (a grid cell and a voxel) off the bone's surface to its end; no voxel of the shaft taken."""
    spacing = np.asarray(spacing)
    points = _grid(np.ceil(np.array([60.0, 60.0, 60.0]) / spacing).astype(int), spacing)
    shaft = _shaft(points)
    wire = _to_segment(points, (18.0, 2.0, 30.0), (42.0, 58.0, 34.0)) <= 0.8
    found = wires_on_bone(shaft | wire, spacing)
    off_bone = np.hypot(points[..., 1] - 30.0, points[..., 2] - 30.0) - 10.0
    assert not found[shaft].any()
    assert found[wire & (off_bone >= GRID_MM + spacing.max() + 1.0)].all()


@pytest.mark.parametrize("spacing", [(0.86, 0.86, 1.0), (0.5, 0.5, 0.5)])
def test_a_wire_off_a_bone_thinner_than_the_opening_is_found_and_nothing_of_the_bone(spacing):
    """A shaft 8 mm wide (family wide seed 40258's fibula in air), too thin to hold the opening's cube of 2 x 2 mm on
    cells of 0.86 mm (6 mm: it keeps nothing), and a wire 1.6 mm wide leaving it at 45 degrees for 30 mm: the
    narrower opening (``THIN_RADIUS_MM``) keeps the shaft and takes the wire, from 3 mm off the shaft to its end;
    no voxel of the shaft is taken."""
    spacing = np.asarray(spacing)
    points = _grid(np.ceil(np.array([70.0, 50.0, 50.0]) / spacing).astype(int), spacing)
    shaft = (np.hypot(points[..., 1] - 10.0, points[..., 2] - 10.0) <= 4.0) & (np.abs(points[..., 0] - 35.0) <= 30.0)
    start = np.array([35.0, 10.0, 10.0])
    wire = _to_segment(points, start, start + 30.0 * np.array([0.0, 1.0, 1.0]) / np.sqrt(2.0)) <= 0.8
    found = wires_on_bone(shaft | wire, spacing)
    off_bone = np.hypot(points[..., 1] - 10.0, points[..., 2] - 10.0) - 4.0
    assert not found[shaft].any()
    assert found[wire & (off_bone >= 3.0)].all()


def test_a_fin_of_bone_thinner_than_a_wire_but_wide_is_not_a_wire():
    """A blade of bone 2 mm thick and 30 mm wide along the shaft, 15 mm out: the opening takes it, it sticks out,
    but it is a plate, not a line."""
    spacing = np.array([0.5, 0.5, 0.5])
    points = _grid((120, 120, 120), spacing)
    shaft = _shaft(points)
    fin = (np.abs(points[..., 1] - 30.0) <= 1.0) & (points[..., 2] >= 30.0) & (points[..., 2] <= 55.0)
    fin &= np.abs(points[..., 0] - 30.0) <= 15.0
    assert not wires_on_bone(shaft | fin, spacing).any()


def test_a_box_of_bone_with_sharp_edges_and_a_short_spike_keeps_them():
    """A box 40 x 30 x 30 mm (the opening takes slivers off its edges, which stick out of nothing) and a spike 1.5 mm
    wide but only 3 mm long (under PROTRUDES_MM): nothing taken."""
    spacing = np.array([0.5, 0.5, 0.5])
    points = _grid((120, 100, 100), spacing)
    box = np.all((points >= 10.0) & (points <= np.array([50.0, 40.0, 40.0])), axis=-1)
    spike = _to_segment(points, (30.0, 25.0, 40.0), (30.0, 25.0, 40.0 + PROTRUDES_MM - 1.0)) <= 0.75
    assert not wires_on_bone(box | spike, spacing).any()


def test_a_bone_thinner_than_a_wire_everywhere_is_left_alone():
    """A thin bone (a rod 1.5 mm wide, 40 mm long) alone: the opening keeps nothing, so there is nothing to tell a
    wire from; the bone stays."""
    spacing = np.array([0.5, 0.5, 0.5])
    points = _grid((100, 40, 40), spacing)
    rod = _to_segment(points, (5.0, 10.0, 10.0), (45.0, 10.0, 10.0)) <= 0.75
    assert not wires_on_bone(rod, spacing).any()


def test_a_ribbon_off_a_flat_bone_is_not_a_wire():
    """A sheet 0.5 mm thick, 5 mm high and 60 mm long standing on a slab of bone 12 mm thick (what family seed 16009's
    flat bone left at its edge on the opening's grid: spread 0, 1.05 and 17.9 mm): long and narrow, but flat across,
    not round: kept."""
    spacing = np.array([0.5, 0.5, 0.5])
    points = _grid((160, 80, 80), spacing)
    slab = (np.abs(points[..., 2] - 20.0) <= 6.0) & (points[..., 1] >= 5.0) & (points[..., 0] >= 5.0)
    slab &= points[..., 0] <= 75.0
    sheet = (np.abs(points[..., 2] - 20.0) <= 0.25) & (points[..., 1] < 5.0) & (points[..., 1] >= 0.0)
    sheet &= (points[..., 0] >= 10.0) & (points[..., 0] <= 70.0)
    assert not wires_on_bone(slab | sheet, spacing).any()


def test_a_thin_rod_standing_on_the_bone_is_taken_off_it():
    """A rod 3.6 mm wide (a thin bracket) standing on a shaft 24 mm wide, 25 mm out past it: thinner than the
    opening's cube (2 x 2 mm wide, on cells of 0.75 mm: 5.25 mm); its end, from 3 mm off the shaft, is taken; the
    shaft is not. (A rod of 6.6 mm holds the cube's 7 x 7 cells standing square to the grid: kept, the IPC then takes
    it; family seed 14020's, resting across a tibia at a slant, did not and was taken.)"""
    spacing = np.array([0.75, 0.75, 0.75])
    points = _grid((100, 100, 110), spacing)
    shaft = _shaft(points, radius=12.0) & (points[..., 0] <= 70.0)
    rod = _to_segment(points, (40.0, 30.0, 30.0), (40.0, 30.0, 30.0 + 12.0 + 25.0)) <= 1.8
    found = wires_on_bone(shaft | rod, spacing)
    past = points[..., 2] - 30.0 - 12.0
    assert not found[shaft].any()
    assert found[rod & (past >= 3.0)].all()
