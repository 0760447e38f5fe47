"""The processed-CT cache (``ramsicp web --demo`` reads its IPC, labels and marker spheres from it): what is read
back is what ``process_ct`` gives, bit for bit (the denoised copy aside); a damaged or half-written file is made
again; another CT, threshold, option, tool or image code is another key; a cache that cannot be written costs only
time. CT phantoms of the shipped tibia at 1 mm voxels: a clean one, one with a steel pin (metal left out of the
IPC), and one with a partial marker sphere (a flagged sphere and its warning)."""

import logging
from dataclasses import replace

import numpy as np
import pytest

from RAMSICPRegistrationLib.image.ct_pipeline import process_ct
from RAMSICPRegistrationLib.io.ndi_tools import DEFAULT_REFERENCE_TOOL, tool_marker_geometry
from RAMSICPRegistrationLib.navigation import image_side_cache
from RAMSICPRegistrationLib.navigation.image_side_cache import cached_image_side, image_side_key
from RAMSICPRegistrationLib.simulation.ct_phantom import make_ct_phantom
from RAMSICPRegistrationLib.simulation.package_data import bone_mesh

from conftest import damage_npz

PHANTOMS = {
    "clean": {},
    "steel pin": {"metal": "pin"},
    "partial marker": {"defects": {2: "partial"}},
}
TOOL = tool_marker_geometry(DEFAULT_REFERENCE_TOOL)


@pytest.fixture(scope="module", params=[*sorted(PHANTOMS), "air around"])
def ct(request, tibia_patient):
    options = {"spacing": (1.0, 1.0, 1.0), "below_cut_mm": 20.0, **PHANTOMS.get(request.param, {})}
    volume = make_ct_phantom(tibia_patient, *bone_mesh("right-tibia"), seed=4, **options)[0]
    if request.param == "air around":  # the segmentation then covers only the box holding something
        voxels = np.pad(volume.voxels, 30, constant_values=-1000).astype(volume.voxels.dtype)
        shift = np.eye(4)
        shift[:3, 3] = -30.0
        volume = replace(volume, voxels=voxels, ijk_to_ras=volume.ijk_to_ras @ shift)
    return volume, process_ct(volume, tool_markers=TOOL)


def assert_same_result(read, made):
    np.testing.assert_array_equal(read.segmentation.labels, made.segmentation.labels)
    assert read.segmentation.labels.dtype == made.segmentation.labels.dtype
    assert read.segmentation.threshold_hu == made.segmentation.threshold_hu
    assert read.segmentation.bone_label == made.segmentation.bone_label
    assert read.segmentation.object_labels == made.segmentation.object_labels
    assert read.segmentation.smoothed is None  # not kept (module docstring)
    assert read.segmentation.box == made.segmentation.box
    assert read.segmentation.volume_shape == made.segmentation.volume_shape
    assert read.segmentation.body_margin_mm == made.segmentation.body_margin_mm
    assert (read.segmentation.body is None) == (made.segmentation.body is None)
    if made.segmentation.body is not None:
        np.testing.assert_array_equal(read.segmentation.body, made.segmentation.body)
    np.testing.assert_array_equal(read.segmentation.labelmap(), made.segmentation.labelmap())
    assert read.surface.left_out_body == made.surface.left_out_body
    assert read.surface.left_out_base == made.surface.left_out_base
    np.testing.assert_array_equal(read.surface.points, made.surface.points)
    np.testing.assert_array_equal(read.surface.triangles, made.surface.triangles)
    assert read.surface.left_out == made.surface.left_out
    assert (read.surface.metal is None) == (made.surface.metal is None)
    if made.surface.metal is not None:
        for name in ("metal_mm3", "margin_mm", "reach_mm"):
            assert getattr(read.surface.metal, name) == getattr(made.surface.metal, name)
        for name in ("metal_ijk", "spacing"):
            np.testing.assert_array_equal(getattr(read.surface.metal, name), getattr(made.surface.metal, name))
        if made.surface.metal.centre is None:
            assert read.surface.metal.centre is None
        else:
            np.testing.assert_array_equal(read.surface.metal.centre, made.surface.metal.centre)
    assert len(read.spheres) == len(made.spheres)
    for sphere_read, sphere_made in zip(read.spheres, made.spheres):
        np.testing.assert_array_equal(sphere_read.centre, sphere_made.centre)
        assert {**vars(sphere_read), "centre": None} == {**vars(sphere_made), "centre": None}
    assert read.warnings == made.warnings


def test_the_second_call_reads_what_the_first_processed(tmp_path, ct):
    volume, direct = ct
    made = cached_image_side(volume, tool_markers=TOOL, directory=tmp_path)
    assert "cache_read" not in made.seconds
    assert_same_result(made, direct)
    (path,) = tmp_path.iterdir()  # one file, no temporary one beside it
    assert path.name.startswith("image-side-") and path.suffix == ".npz"
    read = cached_image_side(volume, tool_markers=TOOL, directory=tmp_path)
    assert "cache_read" in read.seconds
    assert_same_result(read, direct)


def test_each_phantom_exercises_its_part_of_the_file(request, ct):
    """The family covers the file's layout: metal found (points left out, a warning) or not, a sphere flagged."""
    _, direct = ct
    name = request.node.callspec.params["ct"]
    statuses = [sphere.status for sphere in direct.spheres]
    assert direct.surface.metal.found == (name == "steel pin")
    assert (direct.surface.left_out > 0) == (name == "steel pin")
    assert statuses == (["ok", "partial", "ok", "ok"] if name == "partial marker" else ["ok"] * 4)
    assert bool(direct.warnings) == (name in ("steel pin", "partial marker"))
    # With air around it the segmentation covers only the box holding something, not the whole CT.
    assert (direct.segmentation.labels.shape != direct.segmentation.volume_shape) == (name == "air around")


@pytest.mark.parametrize("damage", ["truncated", "labels of another CT", "triangles out of range"])
def test_a_damaged_cache_file_is_made_again_and_replaced(tmp_path, ct, caplog, damage):
    volume, direct = ct
    cached_image_side(volume, tool_markers=TOOL, directory=tmp_path)
    (path,) = tmp_path.iterdir()
    whole = path.read_bytes()
    edits = {
        "truncated": None,
        "labels of another CT": lambda arrays: arrays.update(label_shape=arrays["label_shape"] + 1),
        "triangles out of range": lambda arrays: arrays.update(
            surface_triangles=arrays["surface_triangles"] + len(arrays["surface_points"])
        ),
    }
    damage_npz(path, edits[damage])
    with caplog.at_level(logging.WARNING, logger=image_side_cache.__name__):
        result = cached_image_side(volume, tool_markers=TOOL, directory=tmp_path)
    assert "damaged" in caplog.text and "processing the CT again" in caplog.text
    assert "cache_read" not in result.seconds
    assert_same_result(result, direct)
    assert path.read_bytes() == whole  # replaced by a whole copy


def test_a_cache_that_cannot_be_written_still_gives_the_result(tmp_path, ct, caplog):
    volume, direct = ct
    blocked = tmp_path / "not-a-folder"
    blocked.write_text("a file where the cache folder should be")
    with caplog.at_level(logging.WARNING, logger=image_side_cache.__name__):
        result = cached_image_side(volume, tool_markers=TOOL, directory=blocked)
    assert "could not be cached" in caplog.text
    assert_same_result(result, direct)


def test_the_key_changes_with_every_input(monkeypatch, ct):
    volume, _ = ct
    key = image_side_key(volume, 200.0, True, TOOL)
    assert image_side_key(volume, 200.0, True, TOOL.copy()) == key  # the same inputs: the same key
    one_voxel = volume.voxels.copy()
    one_voxel[tuple(np.array(one_voxel.shape) // 2)] += 1
    assert image_side_key(type(volume)(one_voxel, volume.ijk_to_ras), 200.0, True, TOOL) != key
    shifted = volume.ijk_to_ras.copy()
    shifted[0, 3] += 0.5
    assert image_side_key(type(volume)(volume.voxels, shifted), 200.0, True, TOOL) != key
    assert image_side_key(volume, 250.0, True, TOOL) != key  # the threshold
    assert image_side_key(volume, "auto", True, TOOL) != key
    assert image_side_key(volume, 200.0, False, TOOL) != key  # fill_cavities
    assert image_side_key(volume, 200.0, True, None) != key  # no tool
    moved = TOOL.copy()
    moved[0, 0] += 0.01
    assert image_side_key(volume, 200.0, True, moved) != key
    sources = image_side_cache.library_sources()
    assert "image/ct_segmentation.py" in dict(sources)
    changed = [(name, text + (b"\n# changed" if name == "image/ct_segmentation.py" else b"")) for name, text in sources]
    monkeypatch.setattr(image_side_cache, "library_sources", lambda: changed)
    assert image_side_key(volume, 200.0, True, TOOL) != key  # the image code
    monkeypatch.setattr(image_side_cache, "library_sources", lambda: sources)
    monkeypatch.setattr(image_side_cache, "IMAGE_SIDE_VERSION", image_side_cache.IMAGE_SIDE_VERSION + 1)
    assert image_side_key(volume, 200.0, True, TOOL) != key
