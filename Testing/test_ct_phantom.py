"""The CT phantom: geometry, intensities and ground truth as documented; the real CT runs through the pipeline."""

import json
from pathlib import Path

import nibabel
import numpy as np
import pytest

from RAMSICPRegistrationLib.commands import main
from RAMSICPRegistrationLib.image.ct_segmentation import bone_surface, segment_bone
from RAMSICPRegistrationLib.image.volume_io import load_volume, save_nrrd
from RAMSICPRegistrationLib.io.point_files import read_points
from RAMSICPRegistrationLib.io.surface_files import read_surface_points
from RAMSICPRegistrationLib.simulation.ct_phantom import HU, PAPER_SPACING_MM, signed_distance_to_mesh, write_phantom

DATA = Path(__file__).parent / "Data"


def test_phantom_grid_and_intensities(tibia_phantom):
    volume, truth = tibia_phantom
    np.testing.assert_allclose(volume.spacing, PAPER_SPACING_MM)
    assert volume.voxels.dtype == np.int16
    centres_ijk = np.round(volume.ras_to_ijk_points(truth.marker_centres)).astype(int)
    for i, j, k in centres_ijk:
        assert abs(volume.voxels[i, j, k] - HU["marker"]) < 100  # noise 25 HU
    corner = volume.voxels[:10, :10, :10]
    assert abs(corner.mean() - HU["air"]) < 5 and 20 < corner.std() < 30


def test_phantom_ipc_lies_on_the_true_bone_surface(tibia_phantom):
    volume, truth = tibia_phantom
    surface = bone_surface(volume, segment_bone(volume))
    offsets = signed_distance_to_mesh(
        surface.points, truth.bone_vertices, truth.bone_triangles, np.random.default_rng(1)
    )
    assert abs(np.median(offsets)) < 0.05 and np.percentile(np.abs(offsets), 99) < 0.25
    assert 80_000 < len(surface.points) < 200_000  # the paper's IPC: 194,568 points (both cortical walls)


def test_phantom_writes_nrrd_truth_and_surface(tibia_phantom, tmp_path):
    volume, truth = tibia_phantom
    paths = write_phantom(tmp_path, volume, truth)
    loaded = load_volume(paths["ct"])
    np.testing.assert_allclose(loaded.ijk_to_ras, volume.ijk_to_ras)
    np.testing.assert_array_equal(loaded.voxels, volume.voxels)
    document = json.loads(paths["truth"].read_text())
    np.testing.assert_allclose(document["marker_centres"], truth.marker_centres)
    np.testing.assert_allclose(document["reference_to_image"], truth.reference_to_image)
    assert document["spacing_mm"] == list(PAPER_SPACING_MM)
    # Every file states its frame (issue 14, item 10): truth.json is RAS and says so, the others are LPS files.
    assert document["coordinate_system"] == "RAS" and document["units"] == "mm"
    files = document["files"]
    assert files["truth"]["frame"].startswith("RAS") and files["ct"]["frame"].startswith("LPS")
    assert files["bone_surface"]["frame"].startswith("LPS") and "field of view" in files["bone_surface"]["extent"]
    assert '"coordinateSystem": "LPS"' in paths["marker_centres"].read_text()
    np.testing.assert_allclose(read_points(paths["marker_centres"]).points, truth.marker_centres, atol=1e-9)
    # The surface is the true one cut to the CT's box of voxel centres: nothing outside it, and it reaches the
    # box's lower face (the bone runs on below the field of view).
    surface = read_surface_points(tmp_path / files["bone_surface"]["file"])
    ijk = volume.ras_to_ijk_points(surface)
    last = np.array(volume.voxels.shape) - 1
    assert (ijk > -1e-6).all() and (ijk < last + 1e-6).all()
    assert ijk[:, 2].min() < 1e-6 and truth.bone_vertices[:, 2].min() < volume.ijk_to_ras[2, 3] - 50.0
    on_mesh = signed_distance_to_mesh(surface, truth.bone_vertices, truth.bone_triangles, np.random.default_rng(2))
    assert np.abs(on_mesh).max() < 0.05


def test_phantom_command_numbers_markers_from_1_and_states_frames(tmp_path, capsys):
    """``phantom --partial 1`` damages the tool's first marker, as ``ipc`` then names it (issue 14, item 9)."""
    out = tmp_path / "phantom"
    assert main(["phantom", "--out", str(out), "--partial", "1", "--deformed", "4", "--noise", "10"]) == 0
    printed = capsys.readouterr().out
    for name in ("ct.nrrd", "truth.json", "bone_surface.vtp", "marker_centres.mrk.json"):
        line = next(line for line in printed.splitlines() if line.rstrip().split("  [")[0].endswith(name))
        assert "[LPS" in line or "[RAS" in line
    document = json.loads((out / "truth.json").read_text())
    assert document["marker_defects"] == {"1": "partial", "4": "deformed"}
    assert main(["ipc", str(out / "ct.nrrd"), "--out", str(out / "ipc.vtp"), "--markers", str(out / "m.fcsv")]) == 3
    captured = capsys.readouterr()
    assert "marker 1" in captured.out and "partial" in captured.out.split("marker 1", 1)[1].splitlines()[0]
    assert "deformed" in captured.out.split("marker 4", 1)[1].splitlines()[0]
    assert "only 2 of 4 marker centres are usable (not usable: marker 1, 4)" in captured.err
    assert read_points(out / "m.fcsv").labels == ("M1 partial", "M2 ok", "M3 ok", "M4 deformed")
    truth_centres = np.array(document["marker_centres"])
    np.testing.assert_allclose(read_points(out / "m.fcsv").points[1:3], truth_centres[1:3], atol=0.1)
    assert main(["phantom", "--out", str(out), "--partial", "0"]) == 2  # markers are numbered 1 to 4
    assert "invalid choice: 0" in capsys.readouterr().err


def test_phantom_is_deterministic_under_its_seed(tibia_patient):
    from RAMSICPRegistrationLib.simulation.ct_phantom import make_ct_phantom
    from RAMSICPRegistrationLib.simulation.package_data import bone_mesh

    vertices, triangles = bone_mesh("right-tibia")
    first, _ = make_ct_phantom(tibia_patient, vertices, triangles, seed=3, below_cut_mm=20.0)
    second, _ = make_ct_phantom(tibia_patient, vertices, triangles, seed=3, below_cut_mm=20.0)
    np.testing.assert_array_equal(first.voxels, second.voxels)


def test_cli_ipc_on_the_phantom(tibia_phantom, tibia_patient, tmp_path, capsys):
    volume, truth = tibia_phantom
    save_nrrd(tmp_path / "ct.nrrd", volume)
    arguments = [
        "ipc",
        str(tmp_path / "ct.nrrd"),
        "--out",
        str(tmp_path / "ipc.vtp"),
        "--markers",
        str(tmp_path / "markers.mrk.json"),
        "--json",
        str(tmp_path / "ipc.json"),
        "--labelmap",
        str(tmp_path / "labels.nrrd"),
    ]
    assert main(arguments) == 0
    markers = read_points(tmp_path / "markers.mrk.json")
    np.testing.assert_allclose(markers.points, truth.marker_centres, atol=0.1)  # in the tool's marker order
    assert all(label.endswith("ok") for label in markers.labels)
    document = json.loads((tmp_path / "ipc.json").read_text())
    assert document["ipc_points"] == len(read_surface_points(tmp_path / "ipc.vtp"))
    assert set(document["seconds"]) == {"load", "segmentation", "surface", "marker_spheres"}
    labels = load_volume(tmp_path / "labels.nrrd")
    np.testing.assert_allclose(labels.ijk_to_ras, volume.ijk_to_ras)
    assert set(np.unique(labels.voxels)) == {0, 1, 2, 3, 4, 5}
    for number, centre in enumerate(truth.marker_centres):  # sphere n+2 sits at marker n's true centre
        i, j, k = np.round(volume.ras_to_ijk_points(centre[None])[0]).astype(int)
        assert labels.voxels[i, j, k] == number + 2
    assert main(arguments[:4] + ["--spacing", "1.0"]) == 0
    assert len(read_surface_points(tmp_path / "ipc.vtp")) < 0.5 * document["ipc_points"]
    capsys.readouterr()


def test_cli_ipc_bad_inputs(tmp_path, capsys):
    nibabel.save(nibabel.Nifti1Image(np.zeros((5, 5), np.int16), np.eye(4)), str(tmp_path / "flat.nii"))
    assert main(["ipc", str(tmp_path / "flat.nii"), "--out", str(tmp_path / "x.vtp")]) == 2
    assert "expected a 3-D volume, got 2 dimension(s)" in capsys.readouterr().err
    nibabel.save(nibabel.Nifti1Image(np.zeros((5, 5, 5), np.int16), np.eye(4)), str(tmp_path / "air.nii"))
    assert main(["ipc", str(tmp_path / "air.nii"), "--out", str(tmp_path / "x.vtp")]) == 2
    assert "no voxel is above the threshold of 200 HU" in capsys.readouterr().err
    assert main(["ipc", str(tmp_path / "air.nii"), "--threshold", "bright", "--out", str(tmp_path / "x.vtp")]) == 2
    assert "give a number of HU or 'auto'" in capsys.readouterr().err


@pytest.mark.parametrize(
    "options, message",
    [
        (["--noise", "-5"], "noise -5.0 HU: give a standard deviation of 0 or more"),
        (["--oblique", "nan"], "grid rotation nan degrees: give a finite angle"),
        (["--post-diameter", "-1"], "post diameter -1.0 mm: give a positive number of mm"),
        (["--partial", "2", "--deformed", "2"], "--partial and --deformed name the same marker"),
    ],
)
def test_phantom_bad_options_are_one_line_before_any_work(tmp_path, capsys, options, message):
    assert main(["phantom", "--out", str(tmp_path / "p"), *options]) == 2
    error = capsys.readouterr().err.strip()
    assert message in error and "\n" not in error and "Traceback" not in error
    assert not (tmp_path / "p").exists()
    (tmp_path / "file").write_text("")
    assert main(["phantom", "--out", str(tmp_path / "file")]) == 2
    assert "is a file; give a folder" in capsys.readouterr().err


def test_real_ct_surface_matches_an_independent_segmentation():
    from scipy.spatial import cKDTree

    from RAMSICPRegistrationLib.image.ct_segmentation import iso_surface

    volume = load_volume(DATA / "example_ct.nii.gz")
    surface = bone_surface(volume, segment_bone(volume))
    assert 30_000 < len(surface.points) < 100_000
    # TotalSegmentator's right femur (an independent, learned segmentation) as a surface: every part of it above
    # the scan's cut lies on our IPC to within about half a 3 mm voxel (median), most of it within 1.5 voxels.
    femur = np.asarray(nibabel.load(str(DATA / "femur_right.nii.gz")).dataobj).astype(np.float32)
    femur_surface = volume.ijk_to_ras_points(iso_surface(femur, 0.5)[0])
    above_cut = femur_surface[femur_surface[:, 2] > femur_surface[:, 2].min() + 1.5 * volume.spacing[2]]
    distances, _ = cKDTree(surface.points).query(above_cut)
    assert len(above_cut) > 1000
    assert np.median(distances) < 2.0 and np.percentile(distances, 90) < 5.0


def test_real_ct_metal_implant_and_its_streaks_are_left_out_of_the_ipc():
    """The TotalSegmentator CT's left femur holds metal (by its shape a nail with a screw into the femoral head):
    none of its surface, and no surface in the streak zone of its slices, is in the IPC; the bone beyond keeps its
    surface."""
    from scipy.spatial import cKDTree

    volume = load_volume(DATA / "example_ct.nii.gz")
    surface = bone_surface(volume, segment_bone(volume))
    metal_ijk = np.argwhere(volume.voxels >= 2500)  # the raw CT, not the library's denoised copy
    assert len(metal_ijk) > 300
    metal = volume.ijk_to_ras_points(metal_ijk)
    distance, _ = cKDTree(metal).query(surface.points)
    assert distance.min() > 6.0 - 0.5 * np.linalg.norm(volume.spacing)  # 6 mm (2 voxels) from any metal voxel
    points_ijk = volume.ras_to_ijk_points(surface.points)
    slices = np.rint(points_ijk[:, 2]).astype(int)
    for k in range(metal_ijk[:, 2].min() - 1, metal_ijk[:, 2].max() + 2):
        near = metal_ijk[np.abs(metal_ijk[:, 2] - k) <= 1][:, :2] * volume.spacing[:2]
        here = points_ijk[slices == k][:, :2] * volume.spacing[:2]
        if len(near) and len(here):
            assert cKDTree(near).query(here)[0].min() >= 30.0  # streaks lie in the scan planes
    assert surface.left_out > 2000
    # Just above the metal's slices the left hip bone has its surface again.
    above = slices == metal_ijk[:, 2].max() + 3
    assert np.sum(above & (np.linalg.norm(surface.points - metal.mean(axis=0), axis=1) < 60.0)) > 50


def test_tibia_phantom_with_an_aluminium_body_a_pin_low_dose_and_a_turned_grid(tibia_patient):
    """Everything at once on the real tibia, with soft tissue round it: the IPC is the true surface (no pin, no
    streak), the fused spheres are found to the target, in the tool's order."""
    from RAMSICPRegistrationLib.image.ct_pipeline import process_ct
    from RAMSICPRegistrationLib.simulation.ct_painting import ReferenceBodyModel, capsule_distance, rotated_direction
    from RAMSICPRegistrationLib.simulation.ct_phantom import fixation_pin, make_ct_phantom
    from RAMSICPRegistrationLib.simulation.package_data import bone_mesh

    vertices, triangles = bone_mesh("right-tibia")
    body = ReferenceBodyModel(post_material="aluminium", frame_material="aluminium")
    volume, truth = make_ct_phantom(
        tibia_patient, vertices, triangles, body=body, metal="pin", noise_hu=50.0, direction=rotated_direction(20.0)
    )
    assert not np.allclose(volume.direction, np.diag([-1.0, -1.0, 1.0]), atol=0.1)
    image = process_ct(volume, tool_markers=tibia_patient.markers_reference)
    assert [(sphere.number, sphere.status) for sphere in image.spheres] == [(n, "ok") for n in (1, 2, 3, 4)]
    assert np.linalg.norm(image.centres - truth.marker_centres, axis=1).max() < 0.1
    offsets = signed_distance_to_mesh(image.surface.points, vertices, triangles, np.random.default_rng(1))
    assert abs(np.median(offsets)) < 0.05 and np.abs(offsets).max() < 0.3
    pin = fixation_pin(tibia_patient, body)
    distance = capsule_distance(image.surface.points, np.array(pin.start), np.array(pin.end), pin.radius_mm)
    assert distance.min() > 2.0 and image.surface.left_out > 1000
