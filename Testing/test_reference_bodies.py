"""Marker centres on real reference bodies (issue 12): spheres fused to bright posts and frames, metal streaks,
low-dose noise, a turned scanner grid, a sphere cut by the field of view. True centres come from the generator."""

import json

import numpy as np
import pytest

from RAMSICPRegistrationLib.commands import main
from RAMSICPRegistrationLib.core.transforms import apply_transform
from RAMSICPRegistrationLib.image.ct_pipeline import process_ct
from RAMSICPRegistrationLib.image.ct_segmentation import segment_bone
from RAMSICPRegistrationLib.image.marker_spheres import detect_marker_spheres
from RAMSICPRegistrationLib.image.volume_io import save_nrrd
from RAMSICPRegistrationLib.io.marker_files import read_markers
from RAMSICPRegistrationLib.io.ndi_tools import tool_marker_geometry
from RAMSICPRegistrationLib.simulation.ct_painting import (
    MetalRod,
    ReferenceBodyModel,
    capsule_distance,
    reference_body_feet,
    rotated_direction,
)
from RAMSICPRegistrationLib.simulation.reference_body_phantom import body_pose, make_reference_body_phantom

RADIUS = 5.75
TOOL = tool_marker_geometry()
DENSE = ReferenceBodyModel(post_material="dense-polymer", frame_material="dense-polymer")
ALUMINIUM = ReferenceBodyModel(post_material="aluminium", frame_material="aluminium")
#: The issue's target is 0.1 mm; isolated spheres gave 0.012 mm at most before, which the new detector keeps.
TARGET_MM = 0.1
KEPT_MM = 0.012


def _rod_with_a_streak_across(marker):
    """A 5 mm steel rod 20 mm beside the shaft, level with ``marker`` (1-based), its first streak aimed at it."""
    centre = apply_transform(body_pose(TOOL), TOOL)[marker - 1]
    return MetalRod(start=(20.0, -10.0, centre[2]), end=(20.0, 25.0, centre[2]), streak_towards=tuple(centre))


VARIANTS = {
    "sphere fused to a post as bright as the sphere": {"body": ReferenceBodyModel(post_material="marker")},
    "posts and frame of dense polymer, 1000 HU": {"body": DENSE},
    "posts and frame of aluminium, 2500 HU": {"body": ALUMINIUM},
    "non-identity direction matrix": {"body": ALUMINIUM, "direction": rotated_direction(25.0)},
    "low-dose noise, 60 HU": {"body": ALUMINIUM, "noise_hu": 60.0},
    "metal streaks across sphere 2": {"body": DENSE, "metal": _rod_with_a_streak_across(2)},
}


@pytest.fixture(scope="module")
def aluminium():
    """The aluminium body (volume, truth, ImageSideResult), rendered once for the tests that only read it."""
    volume, truth = make_reference_body_phantom(**VARIANTS["posts and frame of aluminium, 2500 HU"])
    return volume, truth, process_ct(volume, tool_markers=TOOL)


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_four_clean_spheres_give_their_centres_in_tool_order(variant, request):
    if variant == "posts and frame of aluminium, 2500 HU":
        volume, truth, image = request.getfixturevalue("aluminium")
    else:
        volume, truth = make_reference_body_phantom(**VARIANTS[variant])
        image = process_ct(volume, tool_markers=TOOL)
    if variant != "sphere fused to a post as bright as the sphere":
        # The variant is what it claims: spheres, posts and frame are one object above the bone threshold.
        assert len(image.segmentation.object_labels) == 1
    assert [(sphere.number, sphere.status) for sphere in image.spheres] == [(n, "ok") for n in (1, 2, 3, 4)]
    errors = np.linalg.norm(image.centres - truth.marker_centres, axis=1)
    assert errors.max() < KEPT_MM < TARGET_MM
    assert all(abs(sphere.radius_mm - RADIUS) < 0.1 for sphere in image.spheres)
    assert not any("sphere" in warning for warning in image.warnings)


def test_the_streak_really_crosses_the_sphere():
    """The streak variant's known answer holds: the streak changes the sphere's edge by well over 100 HU."""
    rod = VARIANTS["metal streaks across sphere 2"]["metal"]
    with_metal, truth = make_reference_body_phantom(body=DENSE, metal=rod)
    without, _ = make_reference_body_phantom(body=DENSE)
    grid = np.argwhere(np.ones(with_metal.voxels.shape, dtype=bool)[::2, ::2, ::2]) * 2
    edge = grid[
        np.abs(np.linalg.norm(with_metal.ijk_to_ras_points(grid) - truth.marker_centres[1], axis=1) - RADIUS) < 1.0
    ]
    change = with_metal.voxels[tuple(edge.T)].astype(float) - without.voxels[tuple(edge.T)]
    assert np.abs(change).max() > 150.0


@pytest.fixture(scope="module")
def cut_sphere():
    volume, truth = make_reference_body_phantom(body=ALUMINIUM, cut_marker=3)
    return volume, truth


def test_sphere_cut_by_the_field_of_view_is_flagged_and_not_used(cut_sphere):
    volume, truth = cut_sphere
    image = process_ct(volume, tool_markers=TOOL)
    by_number = {sphere.number: sphere for sphere in image.spheres}
    assert sorted(by_number) == [1, 2, 3, 4]
    assert by_number[3].status == "partial" and "cut by the edge of the field of view" in by_number[3].note
    assert [sphere.number for sphere in image.usable] == [1, 2, 4]
    for number in (1, 2, 4):
        assert np.linalg.norm(by_number[number].centre - truth.marker_centres[number - 1]) < KEPT_MM
    assert any("is partial: cut by the edge of the field of view" in warning for warning in image.warnings)
    assert any("only 3 of 4 spheres are clean" in warning for warning in image.warnings)


def test_damaged_spheres_on_an_aluminium_body_are_flagged():
    volume, truth = make_reference_body_phantom(body=ALUMINIUM, defects={2: "partial", 4: "deformed"})
    image = process_ct(volume, tool_markers=TOOL)
    assert [(sphere.number, sphere.status) for sphere in image.spheres] == [
        (1, "ok"),
        (2, "partial"),
        (3, "ok"),
        (4, "deformed"),
    ]
    assert [sphere.number for sphere in image.usable] == [1, 3]


def test_labelmap_shows_the_spheres_not_the_posts_and_frame(aluminium):
    volume, truth, image = aluminium
    labels = image.segmentation.labelmap([sphere.label for sphere in image.spheres])
    feet, _ = reference_body_feet(truth.reference_to_image, TOOL, ALUMINIUM)
    for index, (centre, foot) in enumerate(zip(truth.marker_centres, feet)):
        voxels = np.argwhere(labels == index + 2)
        distance = np.linalg.norm(volume.ijk_to_ras_points(voxels) - centre, axis=1)
        assert distance.max() <= RADIUS + 1.0  # the sphere's own voxels: no post, no frame
        assert voxels.shape[0] * np.prod(volume.spacing) == pytest.approx(4.0 / 3.0 * np.pi * RADIUS**3, rel=0.15)
        # The post below the sphere is bright and joined to it, yet not labelled as the sphere.
        along_post = centre + np.linspace(RADIUS + 1.5, 11.0, 5)[:, None] * (foot - centre) / np.linalg.norm(
            foot - centre
        )
        on_post = tuple(np.rint(volume.ras_to_ijk_points(along_post)).astype(int).T)
        in_box = tuple(np.array(on_post) - image.segmentation.origin[:, None])
        assert (image.segmentation.labels[in_box] > 0).all() and (labels[on_post] != index + 2).all()


def test_pin_through_the_shaft_leaves_no_metal_or_streak_in_the_ipc():
    volume, truth = make_reference_body_phantom(body=DENSE, metal="pin")
    image = process_ct(volume, tool_markers=TOOL)
    points = image.surface.points
    along = (points[:, 2] > truth.shaft_z_mm[0] + 1.0) & (points[:, 2] < truth.shaft_z_mm[1] - 1.0)
    radial = np.hypot(points[:, 0], points[:, 1]) - truth.shaft_radius_mm
    assert np.abs(radial[along]).max() < 0.15  # only the shaft's true surface: no pin, no streak
    pin = capsule_distance(points, np.array(truth.metal.start), np.array(truth.metal.end), truth.metal.radius_mm)
    assert pin.min() > 2.0  # the zone reaches 3 mm beyond the voxels above 2500 HU, which sit inside the pin
    assert image.surface.left_out > 1000 and any("metal in the CT" in warning for warning in image.warnings)
    assert [(sphere.number, sphere.status) for sphere in image.spheres] == [(n, "ok") for n in (1, 2, 3, 4)]


def test_a_missing_sphere_is_located_where_the_other_three_put_it(aluminium, tmp_path, capsys):
    """Marker 3's sphere blanked out: the other three are paired by the tool's distances and marker 3's centre is
    expected where they put it, inside the field of view."""
    volume, truth, _ = aluminium
    centre = truth.marker_centres[2]
    blanked = _blanked(volume, [centre])
    image = process_ct(blanked, tool_markers=TOOL)
    assert [sphere.number for sphere in image.usable] == [1, 2, 4]
    (missing,) = image.missing
    assert missing.number == 3 and missing.in_field_of_view
    assert np.linalg.norm(missing.expected - centre) < 0.05
    assert any(
        warning.startswith("marker 3 not found: the other markers put its centre at") for warning in image.warnings
    )
    # ramsicp ipc prints where it is expected and puts it in the JSON, with the pairing.
    save_nrrd(tmp_path / "ct.nrrd", blanked)
    arguments = [
        "ipc",
        str(tmp_path / "ct.nrrd"),
        "--out",
        str(tmp_path / "ipc.vtp"),
        "--json",
        str(tmp_path / "i.json"),
    ]
    assert main(arguments) == 0
    printed = capsys.readouterr().out
    assert "marker 3         not found; the other markers put it at (" in printed and "inside the CT\n" in printed
    document = json.loads((tmp_path / "i.json").read_text(encoding="utf-8"))
    (entry,) = document["missing_markers"]
    assert entry["number"] == 3 and np.linalg.norm(np.array(entry["expected"]) - centre) < 0.05
    assert entry["in_field_of_view"] is True and entry["cut_by_field_of_view"] is False
    assert document["pairing"]["indices"][2] == -1 and document["bone"]["reference_body_cut_off"] is False


def test_a_missing_sphere_at_the_edge_of_the_field_of_view_is_said_to_be_cut(aluminium):
    """Marker 3's sphere blanked out and the CT cropped 2.75 mm above its centre: its expected centre is in the CT,
    but a sphere there would reach out of it. The warning says so (scan the whole body), not 'hidden by metal'."""
    volume, truth, _ = aluminium
    centre = truth.marker_centres[2]
    top = int(np.ceil(volume.ras_to_ijk_points(centre[None])[0][2] + 2.75 / volume.spacing[2]))
    voxels = np.ascontiguousarray(_blanked(volume, [centre]).voxels[:, :, : top + 1])
    image = process_ct(type(volume)(voxels=voxels, ijk_to_ras=volume.ijk_to_ras), tool_markers=TOOL)
    assert [sphere.number for sphere in image.usable] == [1, 2, 4]
    (missing,) = image.missing
    assert missing.number == 3 and missing.in_field_of_view and missing.cut_by_field_of_view
    assert np.linalg.norm(missing.expected - centre) < 0.05
    (warning,) = [warning for warning in image.warnings if warning.startswith("marker 3 not found")]
    assert "a sphere there reaches out of it (cut by its edge): scan the whole reference body" in warning


def _blanked(volume, centres):
    """The CT with the marker spheres at ``centres`` (RAS mm) set to air, 0.8 mm beyond their radius."""
    voxels = volume.voxels.copy()
    for centre in centres:
        low = np.floor(volume.ras_to_ijk_points(centre[None])[0] - 16).astype(int)
        grid = np.argwhere(np.ones((33, 33, 33), dtype=bool)) + low
        grid = grid[(grid >= 0).all(axis=1) & (grid < voxels.shape).all(axis=1)]
        near = np.linalg.norm(volume.ijk_to_ras_points(grid) - centre, axis=1) < RADIUS + 0.8
        voxels[tuple(grid[near].T)] = -1000
    return type(volume)(voxels=voxels, ijk_to_ras=volume.ijk_to_ras)


def test_a_rod_or_a_frame_alone_is_no_marker(aluminium):
    """A reference body whose spheres are blanked out: its posts and frame give no sphere."""
    volume, truth, _ = aluminium
    blanked = _blanked(volume, truth.marker_centres)  # each sphere blanked; its post stub stays
    detection = detect_marker_spheres(blanked, segment_bone(blanked))
    assert detection.spheres == () and detection.rejected > 0
    assert any("found 0 marker-sphere candidates" in warning for warning in detection.warnings)


def test_ipc_writes_every_sphere_found_and_exits_3_unless_fewer_are_accepted(cut_sphere, tmp_path, capsys):
    """Issue 12, item 4: with 3 of 4 centres usable the markers file is written with each status, exit 3."""
    volume, truth = cut_sphere
    save_nrrd(tmp_path / "ct.nrrd", volume)
    arguments = ["ipc", str(tmp_path / "ct.nrrd"), "--out", str(tmp_path / "ipc.vtp"), "--markers"]
    assert main(arguments + [str(tmp_path / "m.mrk.json")]) == 3
    error = capsys.readouterr().err.strip()
    assert error.startswith("ramsicp ipc: error: only 3 of 4 marker centres are usable (not usable: marker 3)")
    assert "\n" not in error and "--accept-fewer" in error
    markers = read_markers(tmp_path / "m.mrk.json")
    assert markers.numbers == (1, 2, 3, 4) and markers.statuses == ("ok", "ok", "partial", "ok")
    np.testing.assert_allclose(markers.points, truth.marker_centres, atol=TARGET_MM)
    assert main(arguments + [str(tmp_path / "accepted.fcsv"), "--accept-fewer"]) == 0
    assert capsys.readouterr().err == ""
    assert main(arguments + [str(tmp_path / "m.csv")]) == 2  # a csv file would lose the numbers and statuses
    assert "use .mrk.json or .fcsv" in capsys.readouterr().err
