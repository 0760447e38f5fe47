"""Segmentation and IPC on analytic volumes (a sphere, a hollow cylinder) with known answers."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from RAMSICPRegistrationLib.image import bone_recognition, ct_segmentation, dim_parts, plugs
from RAMSICPRegistrationLib.image.ct_segmentation import (
    bone_surface,
    fill_axis,
    otsu_threshold,
    outside_reconstruction,
    resample_points,
    segment_bone,
)
from RAMSICPRegistrationLib.image.marker_spheres import fit_sphere

from conftest import analytic_volume, sphere_sdf

CENTRE = np.array([10.3, -19.6, 30.2])


@pytest.mark.parametrize("rotation_deg", [0.0, 30.0])
def test_sphere_surface_lies_on_the_true_sphere(rotation_deg):
    volume = analytic_volume([(sphere_sdf(CENTRE, 9.0), 1000.0)], rotation_deg=rotation_deg, noise_hu=10.0)
    segmentation = segment_bone(volume)
    surface = bone_surface(volume, segmentation)
    radial = np.linalg.norm(surface.points - CENTRE, axis=1) - 9.0
    half_voxel = 0.5 * volume.spacing.min()
    assert np.abs(radial).max() < half_voxel  # every IPC point within half a voxel of the true surface
    assert abs(np.median(radial)) < 0.05  # the half-max level removes the blur's bias
    centre, radius, rms, _ = fit_sphere(surface.points)
    assert np.linalg.norm(centre - CENTRE) < 0.02 and abs(radius - 9.0) < 0.05 and rms < 0.05


def test_threshold_surface_is_biased_outward_by_blur_and_half_max_is_not():
    # Cortex (1400 HU) in soft tissue (40 HU): 200 HU is 12 % of the way up the blurred edge, outside it.
    volume = analytic_volume([(sphere_sdf(CENTRE, 9.0), 1400.0)], background_hu=40.0, blur_mm=0.5)
    segmentation = segment_bone(volume)
    at_threshold = bone_surface(volume, segmentation, level="threshold").points
    at_half_max = bone_surface(volume, segmentation).points
    assert np.median(np.linalg.norm(at_threshold - CENTRE, axis=1) - 9.0) > 0.1
    assert abs(np.median(np.linalg.norm(at_half_max - CENTRE, axis=1) - 9.0)) < 0.05


@pytest.mark.parametrize("tissue_mm, cortex_mm", [(2.5, 1.8), (2.0, 3.0), (3.0, 3.0)])
def test_a_cortex_under_a_thin_layer_of_tissue_with_air_beyond_has_its_surface_on_its_edge(tissue_mm, cortex_mm):
    """A tube of cortex (1,400 HU, radius 8 mm) under a few mm of soft tissue (40 HU) with air beyond, on 0.8 mm
    voxels blurred 0.7 mm: read round the bone or 1-2 mm beyond the surface, what the cortex touches is the air's
    blurred edge, and the surface lay 0.65 mm out (median) with 2.5 mm of tissue on a 1.8 mm cortex, 0.48 mm with 2 mm
    on a 3 mm one, 0.11 mm with 3 mm on 3 mm. At the CT where the cortex falls most steeply: 0.12, 0.05 and -0.08 mm."""
    axis_point = CENTRE[:2]

    def tube(radius):
        return lambda points: np.linalg.norm(points[..., :2] - axis_point, axis=-1) - radius

    shapes = [(tube(8.0 + tissue_mm), 40.0), (tube(8.0), 1400.0), (tube(8.0 - cortex_mm), 200.0)]
    volume = analytic_volume(shapes, spacing=(0.8, 0.8, 1.0), size_mm=(40.0, 40.0, 30.0), blur_mm=0.7, noise_hu=10.0)
    surface = bone_surface(volume, segment_bone(volume))
    radial = np.linalg.norm(surface.points[:, :2] - axis_point, axis=1) - 8.0
    assert abs(float(np.median(radial))) < 0.15
    assert np.mean(np.abs(radial) <= 0.5) >= 0.99


def test_the_cortexs_edge_is_its_steepest_fall_whatever_lies_beyond_it():
    """Profiles across a blurred cortex (1,500 HU from x = -3 to 0 mm) with 3 mm of tissue (50 HU) and air beyond,
    blurred by a Gaussian of 0.8 mm, read from points 0.9 mm out to 0.6 mm in: the edge found is x = 0 within 0.05 mm,
    and the CT there is the profile's own value at 0 within 10 HU (0.014 mm of its fall), half-way between the cortex
    and the tissue within 40 HU. (With 1.5 mm of tissue, under two widths of the blur, the two falls merge, and the
    steepest lies 0.38 mm out.)"""
    from scipy.stats import norm

    step = 0.1
    x = np.arange(-10.0, 10.0, step)
    # Marrow (300 HU), cortex, tissue and air, each step blurred exactly (the Gaussian's cumulative distribution).
    rises = [(-3.0, 1500.0 - 300.0), (0.0, 50.0 - 1500.0), (3.0, -1000.0 - 50.0)]
    line = 300.0 + sum(rise * norm.cdf((x - at) / 0.8) for at, rise in rises)
    image = np.repeat(np.repeat(line[:, None, None], 5, axis=1), 5, axis=2).astype(np.float32)
    spacing = np.array([step, 1.0, 1.0])
    starts = np.array([0.9, 0.5, 0.0, -0.3, -0.6])  # mm from the true edge
    points = np.stack([(starts + 10.0) / step, np.full(5, 2.0), np.full(5, 2.0)], axis=1)
    out = np.tile([1.0, 0.0, 0.0], (5, 1))
    peak, edge, at_edge, fall = ct_segmentation._cortex_edge(image, points, out, spacing)
    assert np.allclose(starts + edge, 0.0, atol=0.05)
    assert np.allclose(at_edge, 300.0 + sum(rise * norm.cdf(-at / 0.8) for at, rise in rises), atol=10.0)
    assert np.allclose(at_edge, 0.5 * (1500.0 + 50.0), atol=40.0)
    assert np.all(peak > 1400.0)
    assert np.allclose(fall, (1500.0 - 50.0) * norm.pdf(0.0) / 0.8, rtol=0.02)  # the step's slope at its edge


def _hollow_cylinder(outer=8.0, inner=5.0):
    axis_point = CENTRE[:2]

    def outer_sdf(points):
        return np.linalg.norm(points[..., :2] - axis_point, axis=-1) - outer

    def inner_sdf(points):
        return np.linalg.norm(points[..., :2] - axis_point, axis=-1) - inner

    return [(outer_sdf, 1400.0), (inner_sdf, -40.0)]  # cortex, then fatty marrow inside it


def test_cylinder_cavity_is_filled_unless_asked_to_keep_it():
    volume = analytic_volume(_hollow_cylinder(), size_mm=(30.0, 30.0, 40.0), noise_hu=20.0)
    segmentation = segment_bone(volume)
    outer = bone_surface(volume, segmentation).points
    radius = np.linalg.norm(outer[:, :2] - CENTRE[:2], axis=1)
    assert np.abs(radius - 8.0).max() < 0.5 * volume.spacing.max()
    with_cavity = bone_surface(volume, segmentation, fill_cavities=False).points
    inner_radius = np.linalg.norm(with_cavity[:, :2] - CENTRE[:2], axis=1)
    assert np.sum(np.abs(inner_radius - 5.0) < 0.5) > 0.3 * len(with_cavity)  # the marrow wall is there


def test_a_round_field_of_view_closes_the_marrow_it_cuts_and_its_cap_is_left_out():
    """A tube (cortex 8 mm, marrow 5 mm) lying across the slices, cut by a reconstruction cylinder padded with
    -3024 HU: the marrow is open to the padding, not to the outside, so only the outer wall is IPC, and the cap the
    padding makes where it cuts the tube is no IPC either (the old code kept the marrow's wall and the cap)."""
    from RAMSICPRegistrationLib.image.volume_io import CTVolume

    def along_i(radius):
        return lambda points: np.linalg.norm(points[..., 1:] - CENTRE[1:], axis=-1) - radius

    volume = analytic_volume([(along_i(8.0), 1400.0), (along_i(5.0), -40.0)], size_mm=(40.0, 40.0, 30.0))
    voxels = volume.voxels.copy()
    i, j = np.meshgrid(*[np.arange(n) for n in voxels.shape[:2]], indexing="ij")
    centre = (np.array(voxels.shape[:2]) - 1) / 2.0
    outside = np.hypot((i - centre[0]) * volume.spacing[0], (j - centre[1]) * volume.spacing[1]) > 17.0
    voxels[outside] = -3024.0
    assert np.array_equal(outside_reconstruction(voxels), outside)
    assert outside_reconstruction(volume.voxels) is None  # air (noise or not, not the lowest value everywhere)
    cut = CTVolume(voxels, volume.ijk_to_ras)
    points = bone_surface(cut, segment_bone(cut)).points
    radius = np.linalg.norm(points[:, 1:] - CENTRE[1:], axis=1)
    assert np.abs(radius - 8.0).max() < 0.5 * volume.spacing.max()


def _rod_sdf(start, end, radius):
    start, end = np.asarray(start, float), np.asarray(end, float)
    axis = (end - start) / np.linalg.norm(end - start)

    def sdf(points):
        along = np.clip((points - start) @ axis, 0.0, np.linalg.norm(end - start))
        return np.linalg.norm(points - start - along[..., None] * axis, axis=-1) - radius

    return sdf


def _off_tube(points, outer=8.0):
    """(N,) mm: how far the points (N, 3) lie off the outer surface of a tube round the z axis through CENTRE."""
    return np.abs(np.linalg.norm(points[:, :2] - CENTRE[:2], axis=1) - outer)


def _share_kept(points, bare_points, spacing):
    """The share of ``bare_points`` (the IPC of the same CT without the added part) that ``points`` still holds,
    within half the finest voxel (``spacing`` (3,) mm)."""
    return np.mean(cKDTree(points).query(bare_points)[0] < 0.5 * spacing.min())


@pytest.mark.parametrize("rod_hu", [280.0, 400.0, 600.0])
@pytest.mark.parametrize("along, radius", [((0.0, 0.0, 10.0), 3.0), ((14.0, 0.0, 0.0), 4.0)])
def test_a_dim_rod_resting_on_the_bone_adds_no_surface_to_the_ipc(rod_hu, along, radius):
    """A rod of 6 or 8 mm (a plastic bracket) resting along or across a tube of cortex (1500 HU, 8 mm, marrow 5 mm) in
    air, 0.5 mm into it: the threshold (200 HU) joins the two, and the half-max level (about 260 HU) is below the rod,
    so the rod has a surface at that level too, up to 12 mm off the tube: 18-30 % of the IPC before (family seed
    19027: a 271 HU bracket on a fibula, 1,287 IPC points 1 mm inside it). Under it the rod rises above the level by
    at most 12 % of the level's rise over the air, where the tube's cortex rises as high again (``NO_CORTEX_SHARE``);
    a 600 HU rod rises 28 % of it, but only 0.28 of the cortex's rise over the level (``DIM_PEAK_SHARE``: before it,
    up to 12 mm of the rod was in the IPC).
    The IPC is the tube's surface, and the corner the blur fills where the rod meets it (0.5-2.3 % of the IPC, within
    1.6 mm of the tube); over 99 % of the tube's surface 3 mm or more away from the rod is there as without it.
    Where the rods of 400 and 600 HU meet the tube, the CT 0.5-1 mm under the corner's surface rises above the level
    by less than 0.45 of the cortex's rise (``CORNER_PEAK_SHARE``): that corner is left out, and the IPC lies within
    0.52 mm of the tube (0.60-0.68 mm without it; the 280 HU rods' corners, 0.69 mm at most, are under the level).
    The rods of 280 and 400 HU across the tube, above the threshold, are set apart as the body's: the bone's core
    grows them beyond 7.5 mm from the tube as solid pieces of 40-100 mm^3 (``bone_recognition.MIN_GROWN_SOLID_MM3``),
    and the IPC lies within 0.04 mm of the tube (0.36-0.42 mm when they were kept), the tube's surface within 4 mm of
    them left out with the cut's margin (99.5 and 98.6 % of it 3-4 mm away kept, 100 % farther)."""
    tube = _hollow_cylinder(outer=8.0, inner=5.0)
    tube[0] = (tube[0][0], 1500.0)
    axis = CENTRE + (0.0, 8.0 + radius - 0.5, 0.0)  # the rod's axis, its side 0.5 mm into the tube's cortex
    rod = (_rod_sdf(axis - along, axis + along, radius), rod_hu)
    size = (30.0, 40.0, 30.0)
    bare = analytic_volume(tube, size_mm=size, noise_hu=10.0)
    volume = analytic_volume([rod, *tube], size_mm=size, noise_hu=10.0)
    segmentation = segment_bone(volume)
    points = bone_surface(volume, segmentation).points
    off_tube = _off_tube(points)
    assert off_tube.max() < 2.0 and np.mean(off_tube > 0.5) < 0.03
    if rod_hu >= 400.0:
        assert off_tube.max() < 0.55  # 0.47-0.51 mm measured
    bare_points = bone_surface(bare, segment_bone(bare)).points
    from_rod = np.linalg.norm(np.cross(bare_points - axis, np.asarray(along) / np.linalg.norm(along)), axis=1)
    # Past the corner; past the cut's margin (up to 3.5 mm and a cell) where the rod is set apart as the body's.
    away = from_rod > radius + (4.0 if segmentation.body is not None else 3.0)
    assert _share_kept(points, bare_points[away], volume.spacing) > 0.99


@pytest.mark.parametrize("rotation_deg", [0.0, 30.0])
def test_the_edge_of_the_corner_a_dim_rods_end_makes_with_the_bone_is_left_out(rotation_deg, monkeypatch):
    """A 150 HU rod of 6 mm (a plastic bracket) whose round end rests on a tube of thin cortex (1.5 mm of 1200 HU,
    8 mm) in air, 0.5 mm into it, blurred 0.5 mm (family seed 23093: a 154 HU bracket's end on a fibula, 15 IPC points
    0.5-2.2 mm off it). The corner rule takes the middle of the ring where the rod meets the tube; on its edge, the
    CT 0.5-1 mm under the surface still rises less than 0.7 of the cortex's rise over the level and what lies beyond
    is the rod (``CORNER_EDGE_SHARE``, ``CORNER_EDGE_MM``): without that edge the IPC reaches 0.70-0.79 mm off the
    tube; with it, every point lies within 0.5 mm (0.45-0.48 mm measured), and the tube's surface 3 mm or more from
    the rod is all there as without the rod. Where the rod meets the tube's blur (``dim_parts``) those points touch
    the rod too, and go with the corner also without its edge: 0.14 mm off at most (without either, 0.70-0.79)."""
    tube = _hollow_cylinder(outer=8.0, inner=6.5)
    tube = [(tube[0][0], 1200.0), (tube[1][0], 50.0)]
    tip = CENTRE + (0.0, 7.5, 0.0)  # the rod runs out along +y, its round end 0.5 mm into the cortex
    rod = (_rod_sdf(tip + (0.0, 3.0, 0.0), tip + (0.0, 25.0, 0.0), 3.0), 150.0)
    size = (30.0, 44.0, 30.0)
    volume = analytic_volume([rod, *tube], size_mm=size, noise_hu=20.0, blur_mm=0.5, rotation_deg=rotation_deg)
    bare = analytic_volume(tube, size_mm=size, noise_hu=20.0, blur_mm=0.5, rotation_deg=rotation_deg)
    points = bone_surface(volume, segment_bone(volume)).points
    assert _off_tube(points).max() < 0.5
    bare_points = bone_surface(bare, segment_bone(bare)).points
    away = rod[0](bare_points) > 3.0  # 3 mm or more from the rod
    assert _share_kept(points, bare_points[away], volume.spacing) > 0.99
    monkeypatch.setattr(ct_segmentation, "CORNER_EDGE_MM", 0.0)
    assert _off_tube(bone_surface(volume, segment_bone(volume)).points).max() < 0.2
    monkeypatch.setattr(dim_parts, "MARGIN_MM", 0.0)
    assert _off_tube(bone_surface(volume, segment_bone(volume)).points).max() > 0.6


def _box_sdf(low, high):
    centre, half = (np.asarray(low, float) + high) / 2.0, (np.asarray(high, float) - low) / 2.0

    def sdf(points):
        q = np.abs(points - centre) - half
        return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)

    return sdf


@pytest.mark.parametrize("rotation_deg", [0.0, 30.0])
def test_the_bone_under_a_dim_block_resting_on_it_is_at_its_own_half_max(rotation_deg, monkeypatch):
    """A flat bone in air (a 26 x 26 x 6 mm plate: 1.5 mm of 1500 HU cortex round 350 HU) with a 150 HU block (10 x 10
    x 6 mm, a plastic bracket) resting on its top. The half-max level read round the bone (about 175 HU) is half-way
    up from air; under the block the bone's blur runs into 150 HU, so that level lies out in the blur, 1.0 mm up in
    the block (family seed 26087: 53 IPC points 0.5-1 mm off the bone). Half-way between the cortex and the block,
    the surface there is the plate's top: within 0.3 mm of it (0.17 and 0.27 mm measured), and nothing else moves.
    (Where ``dim_parts`` finds the block meeting the bone, the points that touch it are left out instead: under it,
    none is left, and the plate's surface 3 mm or more from it is there.)"""
    top = CENTRE[2] + 3.0
    plate = (_box_sdf(CENTRE - (13.0, 13.0, 3.0), CENTRE + (13.0, 13.0, 3.0)), 1500.0)
    inside = (_box_sdf(CENTRE - (11.0, 11.0, 1.5), CENTRE + (11.0, 11.0, 1.5)), 350.0)
    block = (_box_sdf(CENTRE + (-5.0, -5.0, 3.0), CENTRE + (5.0, 5.0, 9.0)), 150.0)
    volume = analytic_volume(
        [plate, inside, block], size_mm=(36.0, 36.0, 26.0), blur_mm=0.5, noise_hu=10.0, rotation_deg=rotation_deg
    )
    segmentation = segment_bone(volume)
    found = bone_surface(volume, segmentation).points
    monkeypatch.setattr(dim_parts, "MARGIN_MM", 0.0)
    own = bone_surface(volume, segmentation).points
    level = bone_surface(volume, segmentation, own_half_max=False).points
    assert own.shape == level.shape  # the same points, some moved

    def under_the_block(points):  # 1.5 mm or more inside its footprint, on the plate's top
        return np.all(np.abs(points[:, :2] - CENTRE[:2]) < 3.5, axis=1) & (points[:, 2] > CENTRE[2])

    under = under_the_block(own)
    assert under.sum() > 50
    assert np.abs(own[under, 2] - top).max() < 0.3 and abs(np.median(own[under, 2] - top)) < 0.12
    assert np.median(level[under_the_block(level), 2] - top) > 0.8  # out in the blur at the level read round it
    away = np.any(np.abs(level[:, :2] - CENTRE[:2]) > 8.0, axis=1)  # 3 mm or more from the block
    assert np.array_equal(own[away], level[away])
    assert not under_the_block(found).any()
    assert _share_kept(found, own[away], volume.spacing) > 0.995  # 1.0 and 0.999 measured


def _capsule_sdf(start, end, radius):
    start, end = np.asarray(start, float), np.asarray(end, float)
    axis = end - start

    def sdf(points):
        along = np.clip(((points - start) @ axis) / (axis @ axis), 0.0, 1.0)
        return np.linalg.norm(points - (start + along[..., None] * axis), axis=-1) - radius

    return sdf


@pytest.mark.parametrize("rotation_deg", [0.0, 30.0])
def test_the_base_of_a_wire_in_the_bone_leaves_no_surface_in_the_ipc(rotation_deg, monkeypatch):
    """A shaft in soft tissue (radius 9 mm, 2.5 mm of 1100 HU cortex round 250 HU) with a 3 mm wire of 1400 HU
    inserted square to it, to its axis, 13 mm out. The wire is cut off the bone's object, but its first millimetres
    stay with it, and their surface went into the IPC: 26 and 33 points 0.5-1.8 mm off the shaft. Now none is 0.3 mm
    off it, and the shaft's surface is all there 5 mm or more from the wire (the ring it hides, within 3 mm, goes)."""
    start, end = CENTRE + (-22.0, 0.0, 0.0), CENTRE
    shaft = _hollow_cylinder(outer=9.0, inner=6.5)
    shapes = [(shaft[0][0], 1100.0), (shaft[1][0], 250.0), (_capsule_sdf(start, end, 1.5), 1400.0)]
    volume = analytic_volume(
        shapes, size_mm=(56.0, 34.0, 40.0), background_hu=40.0, blur_mm=0.5, noise_hu=15.0, rotation_deg=rotation_deg
    )
    segmentation = segment_bone(volume)
    surface = bone_surface(volume, segmentation)
    points = surface.points
    off_shaft = _off_tube(points, outer=9.0)
    assert off_shaft.max() < 0.3
    # The points left out are counted (``ramsicp ipc`` reports them): without the rule, the IPC has that many more.
    monkeypatch.setattr(ct_segmentation, "CUT_BASE_MM", 0.0)
    without = bone_surface(volume, segmentation)
    assert surface.left_out_base > 50 and without.left_out_base == 0
    assert len(without.points) - len(points) == surface.left_out_base
    # Every point of the shaft's surface 5 mm or more from the wire, and 8 mm from the volume's ends, has an IPC point
    # within 0.5 mm.
    angles, heights = np.meshgrid(np.linspace(0.0, 2.0 * np.pi, 180), np.linspace(-12.0, 12.0, 45))
    truth = np.stack([9.0 * np.cos(angles), 9.0 * np.sin(angles), heights], axis=-1).reshape(-1, 3) + CENTRE
    far = _capsule_sdf(start, end, 0.0)(truth) >= 5.0
    assert far.sum() > 7000 and cKDTree(points).query(truth[far])[0].max() < 0.5


@pytest.mark.parametrize("rotation_deg", [0.0, 30.0])
def test_what_a_metal_bracket_joins_to_the_bone_gives_no_surface(rotation_deg):
    """A shaft in air (radius 9 mm, 2.5 mm of 1100 HU cortex round 250 HU) with a 5 mm steel bracket (3000 HU)
    inserted square to it, to its axis, 26 mm out, its end held in a hollow clamp (12 x 12 x 18 mm, 2 mm walls of
    800 HU) that reaches 10 mm past it. The metal makes the clamp one object with the bone; its walls are no solid
    part for the bone's recognition to cut off, and the metal zone (3 mm round the metal, its own slices) does not
    reach their far side: without ``beyond_metal`` their surface went into the IPC, 2,497 and 1,751 points up to 25 mm
    off the shaft. Now none is 0.3 mm off it, and outside the metal zone the shaft's surface is there (below)."""
    start, end = CENTRE + (-26.0, 0.0, 0.0), CENTRE
    shaft = _hollow_cylinder(outer=9.0, inner=6.5)
    clamp = _box_sdf(CENTRE + (-34.0, -6.0, -6.0), CENTRE + (-22.0, 6.0, 12.0))
    hollow = _box_sdf(CENTRE + (-32.0, -4.0, -4.0), CENTRE + (-24.0, 4.0, 10.0))
    bracket = _capsule_sdf(start, end, 2.5)
    shapes = [(shaft[0][0], 1100.0), (shaft[1][0], 250.0), (clamp, 800.0), (hollow, 0.0), (bracket, 3000.0)]
    volume = analytic_volume(
        shapes,
        size_mm=(76.0, 34.0, 44.0),
        centre=CENTRE + (-8.0, 0.0, 2.0),
        blur_mm=0.5,
        noise_hu=15.0,
        rotation_deg=rotation_deg,
    )
    surface = bone_surface(volume, segment_bone(volume))
    off_shaft = np.abs(np.linalg.norm(surface.points[:, :2] - CENTRE[:2], axis=1) - 9.0)
    assert off_shaft.max() < 0.3
    angles, heights = np.meshgrid(np.linspace(0.0, 2.0 * np.pi, 180), np.linspace(-16.0, 16.0, 61))
    truth = np.stack([9.0 * np.cos(angles), 9.0 * np.sin(angles), heights], axis=-1).reshape(-1, 3) + CENTRE
    zone = surface.metal.contains(volume, truth)
    clear = cKDTree(truth[zone]).query(truth)[0] >= 1.0  # a millimetre or more from the metal zone (its edge)
    # The envelope (a closing by a 14 mm cube) takes the corner the bracket makes with the shaft for a notch, and the
    # grid's lines between the clamp and the shaft's face towards it for the inside of one object (the clamp stays in
    # the bone's mask, see ``beyond_metal``): there the shaft's surface may go, within 13 mm of the bracket's axis
    # and on the face towards the clamp (x under -6 mm); elsewhere it is all there.
    ijk = volume.ras_to_ijk_points(truth)
    in_view = np.all(
        (ijk * volume.spacing >= 3.0) & ((np.array(volume.voxels.shape) - 1 - ijk) * volume.spacing >= 3.0), 1
    )
    far = clear & in_view & (_capsule_sdf(start, end, 0.0)(truth) >= 13.0) & (truth[:, 0] - CENTRE[0] > -6.0)
    assert far.sum() > 2000 and cKDTree(surface.points).query(truth[far])[0].max() < 0.5


def test_a_bone_in_two_pieces_across_a_metal_nail_keeps_both():
    """A shaft broken in two (radius 9 mm, 2.5 mm of 1100 HU cortex round 250 HU, a 4 mm gap) held by a steel nail
    (3000 HU, 6 mm) along its canal. Without the nail's edge the two pieces are apart; each is as large as the other,
    so both are the bone's: outside the metal zone, the surface of each is in the IPC."""
    axis_yz = CENTRE[1:]

    def outer(points):
        return np.linalg.norm(points[..., 1:] - axis_yz, axis=-1) - 9.0

    def inner(points):
        return np.linalg.norm(points[..., 1:] - axis_yz, axis=-1) - 6.5

    def gap(points):  # the 4 mm break across the shaft, filled with soft tissue
        return np.abs(points[..., 0] - CENTRE[0]) - 2.0

    nail = _capsule_sdf(CENTRE - (24.0, 0.0, 0.0), CENTRE + (24.0, 0.0, 0.0), 3.0)
    shapes = [(outer, 1100.0), (inner, 250.0), (gap, 40.0), (nail, 3000.0)]
    volume = analytic_volume(shapes, size_mm=(60.0, 34.0, 34.0), background_hu=40.0, blur_mm=0.5, noise_hu=15.0)
    surface = bone_surface(volume, segment_bone(volume))
    angles, along = np.meshgrid(np.linspace(0.0, 2.0 * np.pi, 180), np.linspace(-20.0, 20.0, 81))
    truth = np.stack([along, 9.0 * np.cos(angles), 9.0 * np.sin(angles)], axis=-1).reshape(-1, 3) + CENTRE
    seen = ~surface.metal.contains(volume, truth) & (np.abs(truth[:, 0] - CENTRE[0]) >= 5.0)
    distance = cKDTree(surface.points).query(truth)[0]
    for piece in (truth[:, 0] < CENTRE[0], truth[:, 0] > CENTRE[0]):
        assert (seen & piece).sum() > 1000 and distance[seen & piece].max() < 0.5


def test_bone_is_the_largest_object_and_the_rest_are_candidates():
    shapes = [(sphere_sdf(CENTRE, 10.0), 1200.0), (sphere_sdf(CENTRE + (0, 0, 16.0), 3.0), 800.0)]
    segmentation = segment_bone(analytic_volume(shapes, size_mm=(40.0, 40.0, 50.0)))
    bone = segmentation.bone_mask
    assert len(segmentation.object_labels) == 1
    volume_mm3 = bone.sum() * 0.5 * 0.5 * 0.625
    assert volume_mm3 == pytest.approx(4 / 3 * np.pi * 10.0**3, rel=0.03)


def test_automatic_threshold_splits_tissue_and_bone():
    values = np.concatenate(
        [np.random.default_rng(0).normal(40, 20, 50000), np.random.default_rng(1).normal(1200, 60, 20000)]
    )
    assert 200 < otsu_threshold(values) < 1000
    volume = analytic_volume([(sphere_sdf(CENTRE, 9.0), 1000.0)], background_hu=40.0, noise_hu=10.0)
    assert 300 < segment_bone(volume, "auto").threshold_hu < 800


def test_no_voxel_above_threshold_says_what_to_change():
    volume = analytic_volume([(sphere_sdf(CENTRE, 9.0), 100.0)], size_mm=(20.0, 20.0, 20.0))
    with pytest.raises(ValueError, match="no voxel is above the threshold of 200 HU .* lower the threshold"):
        segment_bone(volume)
    with pytest.raises(ValueError, match="give a number of HU or 'auto'"):
        segment_bone(volume, threshold_hu="high")


def test_resampling_keeps_one_point_per_cell():
    grid = np.stack(np.meshgrid(np.arange(0, 10, 0.1), np.arange(0, 10, 0.1), [0.0], indexing="ij"), -1).reshape(-1, 3)
    thinned = resample_points(grid + 0.001, 1.0)
    assert len(thinned) == 100  # a 10 x 10 mm sheet, one point per 1 mm cell
    with pytest.raises(ValueError, match="give a positive number"):
        resample_points(grid, 0.0)


def test_cavities_are_filled_across_the_axis_the_scan_cuts():
    # A plate cut by the field of view at its bottom (k = 0) but longer along i: slices across k enclose its core.
    mask = np.zeros((60, 20, 30), dtype=bool)
    mask[5:55, 8:12, 0:25] = True
    assert fill_axis(mask, np.ones(3)) == 2
    mask[5:55, 8:12, 0] = False  # inside the field of view everywhere: across its longest extent
    assert fill_axis(mask, np.ones(3)) == 0
    assert fill_axis(mask, np.array([1.0, 1.0, 3.0])) == 2  # 72 mm along k against 50 mm along i


def test_a_plate_cut_by_the_scan_is_filled_between_its_tables():
    # An ilium-like plate: two cortical tables (1.5 mm) around a cancellous core, 7 mm thick, 50 mm long in x,
    # closed at its ends and top, running out of the scan at the bottom. Its core is enclosed only in slices across
    # z, the axis the scan cuts it along, not across x, its longest extent.
    def box(half_y, half_x, top):
        return lambda p: np.maximum(
            np.maximum(np.abs(p[..., 1] - CENTRE[1]) - half_y, np.abs(p[..., 0] - CENTRE[0]) - half_x), p[..., 2] - top
        )

    shapes = [(box(3.5, 25.0, CENTRE[2] + 10.0), 1400.0), (box(2.0, 23.5, CENTRE[2] + 8.5), 300.0)]
    volume = analytic_volume(shapes, size_mm=(60.0, 20.0, 40.0), background_hu=40.0, noise_hu=10.0)
    segmentation = segment_bone(volume)
    points = bone_surface(volume, segmentation).points
    across = np.abs(points[:, 1] - CENTRE[1])
    height = points[:, 2] - CENTRE[2]
    on_the_tables = (np.abs(points[:, 0] - CENTRE[0]) < 20.0) & (height < 6.0) & (height > -15.0)
    assert np.all(np.abs(across[on_the_tables] - 3.5) < 0.5)  # only the outer faces, none at the core's 2 mm
    with_walls = bone_surface(volume, segmentation, fill_cavities=False).points
    assert np.sum(np.abs(np.abs(with_walls[:, 1] - CENTRE[1]) - 2.0) < 0.3) > 0.2 * len(with_walls)


def test_real_pelvis_keeps_its_ring_when_cavities_are_filled():
    # The example CT holds the whole pelvis: the slice-by-slice fill must not close the pelvic ring or the gap
    # between the iliac wings and the sacrum, which would take their inner surfaces out of the IPC.
    from scipy.spatial import cKDTree

    from RAMSICPRegistrationLib.image.volume_io import load_volume

    volume = load_volume(Path(__file__).parent / "Data" / "example_ct.nii.gz")
    segmentation = segment_bone(volume)
    filled = bone_surface(volume, segmentation).points
    raw = bone_surface(volume, segmentation, fill_cavities=False).points
    distances, _ = cKDTree(filled).query(raw)
    assert np.mean(distances > 3.0) < 0.02  # the fill took out less than 2 % of the surface (small cavities)


def test_marrow_opened_by_a_hole_is_enclosed_along_the_lines_and_the_outside_is_not():
    # A hollow box (a 2-voxel cortex round a 10-voxel cavity, 1 mm voxels) with a 4-voxel hole through its top, as
    # a bracket makes: the 3-D fill sees the cavity open; along the grid's lines it is enclosed, the hole too (the
    # cortex round it is near on two axes, the opposite cortex on the third), and nothing outside.
    from RAMSICPRegistrationLib.image.ct_segmentation import _enclosed_along_lines

    mask = np.zeros((20, 20, 20), dtype=bool)
    mask[4:16, 4:16, 4:16] = True
    mask[6:14, 6:14, 6:14] = False  # the cavity
    mask[8:12, 8:12, 14:16] = False  # the hole in the top
    on_edge = [(False, False)] * 3
    enclosed = _enclosed_along_lines(mask, on_edge, np.ones(3))
    assert enclosed[6:14, 6:14, 6:14].all() and enclosed[8:12, 8:12, 14:16].all()  # cavity and hole
    assert not enclosed[:, :, 16:].any()  # above the hole
    assert not enclosed[:4].any() and not enclosed[16:].any() and not enclosed[:, :, :4].any()  # outside
    # Wider than MAX_CAVITY_MM (30 mm) apart, two walls enclose nothing (a pelvic ring's inside is outside).
    wide = np.zeros((5, 5, 40), dtype=bool)
    wide[:, :, 0] = wide[:, :, 39] = True
    assert not _enclosed_along_lines(wide, on_edge, np.ones(3)).any()


def enclosed_by_walking_the_lines(mask, on_edge, spacing, padding):
    """The line enclosure by its definition, voxel by voxel: the nearest bone before and after along each axis."""
    from scipy import ndimage

    from RAMSICPRegistrationLib.image.ct_segmentation import MAX_CAVITY_MM

    enclosed = np.zeros(mask.shape, dtype=bool)
    # Where a box's side is the CT's, the bone's cut face (its slice there, holes filled) walls the lines beyond it.
    faces = [
        [
            ndimage.binary_fill_holes(np.take(mask, side, axis=axis)) if on_edge[axis][k] else None
            for k, side in enumerate((0, -1))
        ]
        for axis in range(3)
    ]
    for voxel in zip(*np.nonzero(~mask)):
        narrow, closed = 0, True
        for axis in range(3):
            line = list(mask[tuple(slice(None) if a == axis else v for a, v in enumerate(voxel))])
            across = tuple(v for a, v in enumerate(voxel) if a != axis)
            low_face, high_face = faces[axis]
            line = ([bool(low_face[across])] if low_face is not None else []) + line
            line += [bool(high_face[across])] if high_face is not None else []
            here, reach = voxel[axis] + (low_face is not None), MAX_CAVITY_MM / spacing[axis]
            before = [i for i in range(here + 1) if line[i]]
            after = [i for i in range(here, len(line)) if line[i]]
            narrow += bool(before and after and after[0] - before[-1] <= reach)
            near = (before and here - before[-1] <= reach) or (after and after[0] - here <= reach)
            walled = padding is not None and axis < 2
            shift, last = int(low_face is not None), mask.shape[axis] - 1  # the walls repeat the padding's rows
            past = (
                [
                    padding[tuple(min(max(i - shift, 0), last) if a == axis else voxel[a] for a in range(2))]
                    for i in range(len(line))
                ]
                if walled
                else []
            )
            closed_before = on_edge[axis][0] or bool(before) or (walled and any(past[: here + 1]))
            closed_after = on_edge[axis][1] or bool(after) or (walled and any(past[here:]))
            closed &= bool(near or (closed_before and closed_after))
        enclosed[voxel] = closed and narrow >= 2
    return enclosed


@pytest.mark.parametrize("seed", range(2))
def test_line_enclosure_matches_its_definition_on_random_masks(seed):
    from scipy import ndimage

    from RAMSICPRegistrationLib.image.ct_segmentation import _enclosed_along_lines

    rng = np.random.default_rng(seed)
    for _ in range(12):
        shape = tuple(int(n) for n in rng.integers(2, 16, size=3))
        mask = ndimage.gaussian_filter(rng.normal(size=shape), rng.uniform(0.5, 2.0)) > rng.uniform(-0.5, 0.5)
        spacing = rng.uniform(1.5, 6.0, size=3)  # 5 to 20 voxels of reach: walls both near and far apart
        on_edge = [tuple(bool(side) for side in rng.random(2) < 0.3) for _ in range(3)]
        padding = rng.random(shape[:2]) < 0.1 if rng.random() < 0.5 else None
        np.testing.assert_array_equal(
            _enclosed_along_lines(mask, on_edge, spacing, padding),
            enclosed_by_walking_the_lines(mask, on_edge, spacing, padding),
        )


def _sheets_with_a_wall(n_i, n_j):
    """A sheet of 1 mm squares (i < n_i, j < n_j; two triangles each) and a second one 0.5 mm above it that no edge
    joins to it: vertices (M, 3), triangles, and booleans for the first sheet."""
    i, j = np.meshgrid(np.arange(n_i), np.arange(n_j), indexing="ij")
    sheet = np.column_stack([i.ravel(), j.ravel(), np.zeros(i.size)]).astype(float)
    corner = (i[:-1, :-1] * n_j + j[:-1, :-1]).ravel()
    first_half = np.column_stack([corner, corner + n_j, corner + n_j + 1])
    triangles = np.concatenate([first_half, np.column_stack([corner, corner + n_j + 1, corner + 1])])
    vertices = np.concatenate([sheet, sheet + [0.0, 0.0, 0.5]])
    return vertices, np.concatenate([triangles, triangles + i.size]), np.arange(2 * i.size) < i.size


def test_a_holes_mouth_is_the_surface_near_its_wall_along_the_mesh_that_faces_as_the_wall_does():
    # On the first sheet (21 x 21 vertices) the vertices i <= 5 are an inner wall (126 mm^2), and i, j = 15..16 a speck
    # (4 mm^2: no hole's wall). Down the gradient the vertices face +k up to i = 7 and +i from i = 8 (the rim, turning
    # to the bone's outer surface). The mouth: i = 6 and 7 (1 and 2 mm along the edges; i = 8 is 3 mm away but faces
    # the other way: a third of the surface near the wall), every j: 42 mm^2. Nothing of the second sheet.
    from RAMSICPRegistrationLib.image.ct_segmentation import MAX_MOUTH_MM2, MIN_WALL_MM2, MOUTH_MM, RIM_SHARE, _mouths

    assert MOUTH_MM == 3.0 and 4.0 < MIN_WALL_MM2 < 126.0 and 42.0 < MAX_MOUTH_MM2 < 138.0 and RIM_SHARE < 1.0 / 3.0
    vertices, triangles, first = _sheets_with_a_wall(21, 21)
    at_i, at_j = vertices[:, 0], vertices[:, 1]
    inner = first & ((at_i <= 5) | ((at_i >= 15) & (at_i <= 16) & (at_j >= 15) & (at_j <= 16)))

    def facing_up_to(last_i):
        return np.where((at_i <= last_i)[:, None], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])

    mouth = _mouths(vertices, triangles, inner, facing_up_to(7), np.ones(3))
    np.testing.assert_array_equal(mouth, first & (at_i >= 6) & (at_i <= 7))
    # The edges are measured in mm: with voxels 1.5 mm along i, i = 6 lies 1.5 mm from the wall, i = 7 (the rim now)
    # 3 mm.
    mouth = _mouths(vertices, triangles, inner, facing_up_to(6), np.array([1.5, 1.0, 1.0]))
    np.testing.assert_array_equal(mouth, first & (at_i == 6))
    # With no rim (all the surface near the wall faces as it does), the wall is a patch of the outer surface.
    assert not _mouths(vertices, triangles, inner, facing_up_to(20), np.ones(3)).any()
    # A wall 69 mm long has a mouth (i = 6, 7) of 138 mm^2, larger than the ring round any bracket: no hole's.
    vertices, triangles, first = _sheets_with_a_wall(21, 70)
    at_i = vertices[:, 0]
    assert not _mouths(vertices, triangles, first & (at_i <= 5), facing_up_to(7), np.ones(3)).any()


def _tube_with_a_dim_rod(hole_mm=11.0, inner=14.0, outer=16.0):
    """A CT (70 x 70 x 40 voxels of 1 mm) holding a tube along k through it (cortex 1,000 HU from ``inner`` to
    ``outer`` mm round (35, 35), marrow -50 HU, tissue 0 HU) and a square rod of 150 HU, ``hole_mm`` wide, along i
    from the marrow (i = 25) out through the cortex to i = 64: below a surface level of 500 HU, it joins the marrow to
    the outside. Returns the volume, the image of the box round the tube (5 voxels in from the CT's i and j sides; the
    k sides are the CT's), the tube's mask there, the box's corners, and the rod's cells just outside the cortex
    (where ``dim_parts`` finds it meeting the bone's blur) in the box."""
    from RAMSICPRegistrationLib.image.volume_io import CTVolume

    shape = (70, 70, 40)
    i, j, k = np.meshgrid(*[np.arange(n, dtype=float) for n in shape], indexing="ij")
    radius = np.hypot(i - 35.0, j - 35.0)
    rod = (np.abs(j - 35.0) <= hole_mm / 2.0) & (np.abs(k - 20.0) <= hole_mm / 2.0) & (i >= 25.0) & (i <= 64.0)
    bone = (radius >= inner) & (radius <= outer) & ~rod
    image = np.where(bone, 1000.0, np.where(radius < inner, -50.0, 0.0))
    image[rod] = 150.0
    volume = CTVolume(voxels=np.zeros(shape, np.float32), ijk_to_ras=np.eye(4))
    low, high = np.array([5, 5, 0]), np.array([65, 65, 40])
    box = tuple(slice(a, b) for a, b in zip(low, high))
    contacts = np.argwhere(rod[box] & (np.abs(i[box] - 53.5) <= 1.0)).astype(float)
    return volume, image[box], bone[box], low, high, contacts


def test_the_marrow_a_dim_rods_hole_joins_to_the_outside_is_enclosed_once_plugged():
    """Below the level (500 HU), the rod (150 HU) joins the tube's marrow (-50 HU) to the outside through its 11 mm
    hole, so the 3-D fill finds no inside. Plugged within PLUG_MM of where the rod leaves the cortex, the marrow is
    enclosed, and so is the rod's part within the tube; nothing outside the tube is."""
    volume, image, bone, low, high, contacts = _tube_with_a_dim_rod()
    walls = np.zeros(image.shape, dtype=bool)
    levels = (500.0, 200.0)
    i, j = np.meshgrid(*[np.arange(n) + 5.0 for n in image.shape[:2]], indexing="ij")
    radius = np.hypot(i - 35.0, j - 35.0)[:, :, None] * np.ones(image.shape[2])
    unplugged = ct_segmentation._enclosed(image, levels, walls, low, high, volume)
    assert not unplugged[radius < 12.0].any()  # the marrow leaks out along the rod
    on_edge = [(False, False), (False, False), (True, True)]
    inside = ct_segmentation._plugged_inside(image, levels, walls, contacts, bone, on_edge, None, low, high, volume)
    assert inside[radius < 13.0].all()  # the marrow, to within a voxel of its wall
    assert not inside[radius > 16.5].any()  # nothing outside the tube: not the rod, not the tissue round it
    # The box's k sides are the CT's: a voxel of the marrow has the tube on both sides along i, j and k (along j and
    # k where the rod's hole opens its line along i); one outside it, along k alone (or i or j too where the tube
    # lies across its line).
    sides = plugs.between_sides(bone, on_edge, None)
    assert (sides[radius < 13.0] >= 2).all() and np.mean(sides[radius < 13.0] == 3) > 0.8
    assert (
        sides[(radius > 17.0) & (np.abs(i - 35.0)[:, :, None] > 17.0) & (np.abs(j - 35.0)[:, :, None] > 17.0)] == 1
    ).all()


def _plate_with_a_dim_rod(inside_hu, hole_mm=9.0):
    """A flat bone 12 mm thick aslant a 50 mm CT (its normal along (1, 0, 1)), ending 15 mm from the middle on one side
    and cut by the CT's sides elsewhere: two tables of 1.5 mm of 1,400 HU round an ``inside_hu`` inside, in 20 HU
    tissue, and a 120 HU rod ``hole_mm`` wide through its upper table (a plastic bracket inserted into it), on 0.7 mm
    voxels."""
    normal, along = np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0), np.array([1.0, 0.0, -1.0]) / np.sqrt(2.0)

    def slab(half_mm, end_mm):
        return lambda points: np.maximum(
            np.abs((points - CENTRE) @ normal) - half_mm, -end_mm - (points - CENTRE) @ along
        )

    plate = (slab(6.0, 15.0), 1400.0)
    inside = (slab(4.5, 13.5), inside_hu)
    rod = (_rod_sdf(CENTRE + 3.0 * normal, CENTRE + 16.0 * normal, hole_mm / 2.0), 120.0)
    tissue = (lambda points: np.full(points.shape[:-1], -100.0), 20.0)
    return analytic_volume([tissue, plate, inside, rod], spacing=(0.7, 0.7, 0.7), size_mm=(50.0, 50.0, 50.0))


def test_a_flat_bone_whose_inside_a_dim_rods_hole_joins_to_the_outside_is_bone_once_plugged(monkeypatch):
    """The flat bone's 150 HU inside is below the threshold, and the rod's hole joins it to the tissue above; aslant
    the grid, no slice encloses it either: to the fill the bone was its two tables, 4 mm thick where they meet, too
    thin for a bone (family seed 40232 with wide brackets, a flat bone the CT cuts on five sides: refused as a solid
    frame, 115 cm^3 of bone in view). Its holes up to 10 mm wide plugged (``bone_recognition._ObjectShape._plugged``),
    it encloses its inside, and its rim is its cortex: bone, 11 mm thick, its rim 1,081 HU brighter than its inside.
    A plate solid through (its inside as bright as its tables) is no bone for being plugged: the rod's blind hole is
    enclosed, but its deepest cells are the plate's own (rim -9 HU)."""
    recognition = segment_bone(_plate_with_a_dim_rod(150.0)).recognition
    verdict = next(v for v in recognition.objects if v.label == recognition.label)
    assert recognition.has_cortex and verdict.verdict == "bone"
    assert verdict.cortex_hu > 1000.0 and 2.0 * verdict.half_thickness_mm > 10.0
    solid = segment_bone(_plate_with_a_dim_rod(1400.0)).recognition
    assert not solid.has_cortex
    assert next(v for v in solid.objects if v.label == solid.label).verdict == "bone without a cortex"
    monkeypatch.setattr(bone_recognition._ObjectShape, "_plugged", lambda shape: None)
    with pytest.raises(ValueError, match="too small or thin"):
        segment_bone(_plate_with_a_dim_rod(150.0))


def test_a_plug_over_a_groove_in_the_bones_outside_encloses_nothing():
    """The tube without the rod, its cortex 11 mm thick, a groove 5 mm wide, 8.5 mm deep and 12 mm long cut into it
    from outside, and a dim part meeting the bone over the groove's mouth (a plate resting there): the plug fills the
    groove's outer 5 mm and closes the rest, a pocket of tissue (about 200 mm^3) between the cortex's sides along two
    axes; grown into the plug, it took 481 mm^3 (and the groove's walls from the IPC). Under MIN_PLUGGED_MM3 it is no
    bone's inside: nothing is enclosed beyond the marrow the fill finds anyway."""
    volume, image, bone, low, high, _ = _tube_with_a_dim_rod(hole_mm=0.0, inner=6.0, outer=17.0)
    i, j, k = np.meshgrid(*[np.arange(n) + offset for n, offset in zip(image.shape, (5.0, 5.0, 0.0))], indexing="ij")
    radius = np.hypot(i - 35.0, j - 35.0)
    groove = (i > 35.0) & (radius > 8.5) & (np.abs(j - 35.0) <= 2.5) & (k >= 14) & (k < 26)
    bone &= ~groove
    image[groove] = 0.0
    mouth = (i > 35.0) & (radius > 17.0) & (radius <= 18.5) & (np.abs(j - 35.0) <= 3.5) & (k >= 13) & (k < 27)
    contacts = np.argwhere(mouth).astype(float)
    walls = np.zeros(image.shape, dtype=bool)
    on_edge = [(False, False), (False, False), (True, True)]
    levels = (500.0, 200.0)
    found = ct_segmentation._enclosed(image, levels, walls, low, high, volume)
    assert not found[groove].any()
    inside = ct_segmentation._plugged_inside(
        image, levels, walls, contacts, bone | found, on_edge, None, low, high, volume
    )
    assert not inside.any()
