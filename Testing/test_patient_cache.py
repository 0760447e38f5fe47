"""The virtual-patient cache (``ramsicp web --demo`` reads the demo's patient from it, once per process): the
patient read back is the one built, bit for bit, with its mesh; a damaged or half-written file is built again;
another bone, seed, tool, mesh file or simulation code is another key; a cache that cannot be written costs only
time. A long bone and a flat bone, at two seeds."""

import dataclasses
import logging

import numpy as np
import pytest

from RAMSICPRegistrationLib.simulation import package_data, patient_cache
from RAMSICPRegistrationLib.simulation.package_data import shipped_patient
from RAMSICPRegistrationLib.simulation.patient_cache import cached_shipped_patient, patient_key, shared_shipped_patient

from conftest import damage_npz

CASES = [("right-tibia", 0), ("right-ilium", 3)]


@pytest.fixture(scope="module", params=CASES, ids=[f"{bone}-seed{seed}" for bone, seed in CASES])
def built(request):
    bone, seed = request.param
    return bone, seed, shipped_patient(bone, seed)


def assert_same_patient(read, made):
    patient, vertices, triangles = read
    np.testing.assert_array_equal(vertices, made[1])
    np.testing.assert_array_equal(triangles, made[2])
    for field in dataclasses.fields(patient):
        value, expected = getattr(patient, field.name), getattr(made[0], field.name)
        if field.name == "sub_area_points":
            assert len(value) == len(expected)
            for points, expected_points in zip(value, expected):
                np.testing.assert_array_equal(points, expected_points)
        elif isinstance(expected, np.ndarray):
            np.testing.assert_array_equal(value, expected)
            assert value.dtype == expected.dtype
        else:
            assert value == expected and type(value) is type(expected)


def test_the_second_call_reads_the_patient_the_first_built(tmp_path, built):
    bone, seed, made = built
    *first, was_built = cached_shipped_patient(bone, seed, directory=tmp_path)
    assert was_built
    assert_same_patient(first, made)
    (path,) = tmp_path.iterdir()  # one file, no temporary one beside it
    *read, was_read_built = cached_shipped_patient(bone, seed, directory=tmp_path)
    assert not was_read_built
    assert_same_patient(read, made)
    # the patient's own simulation draws the same touches from it
    trial = read[0].simulate_trial(np.random.default_rng(1), 0.5)
    expected = made[0].simulate_trial(np.random.default_rng(1), 0.5)
    np.testing.assert_array_equal(trial.ppc, expected.ppc)


@pytest.mark.parametrize("damage", ["truncated", "sub-areas that do not add up", "a matrix of the wrong shape"])
def test_a_damaged_cache_file_is_built_again_and_replaced(tmp_path, built, caplog, damage):
    bone, seed, made = built
    cached_shipped_patient(bone, seed, directory=tmp_path)
    (path,) = tmp_path.iterdir()
    whole = path.read_bytes()
    edits = {
        "truncated": None,
        "sub-areas that do not add up": lambda arrays: arrays.update(
            patient_sub_area_sizes=arrays["patient_sub_area_sizes"] + 1
        ),
        "a matrix of the wrong shape": lambda arrays: arrays.update(patient_reference_to_image=np.eye(3)),
    }
    damage_npz(path, edits[damage])
    with caplog.at_level(logging.WARNING, logger=patient_cache.__name__):
        *read, was_built = cached_shipped_patient(bone, seed, directory=tmp_path)
    assert was_built and "damaged" in caplog.text and "building it again" in caplog.text
    assert_same_patient(read, made)
    assert path.read_bytes() == whole  # replaced by a whole copy


def test_a_cache_that_cannot_be_written_still_gives_the_patient(tmp_path, built, caplog):
    bone, seed, made = built
    blocked = tmp_path / "not-a-folder"
    blocked.write_text("a file where the cache folder should be")
    with caplog.at_level(logging.WARNING, logger=patient_cache.__name__):
        *read, was_built = cached_shipped_patient(bone, seed, directory=blocked)
    assert was_built and "could not be cached" in caplog.text
    assert_same_patient(read, made)


def test_the_key_changes_with_every_input(monkeypatch, tmp_path):
    key = patient_key("right-tibia", 0)
    assert patient_key("right-tibia", 0) == key
    assert patient_key("left-tibia", 0) != key
    assert patient_key("right-tibia", 1) != key
    sources = patient_cache.library_sources()
    names = dict(sources)
    assert "simulation/virtual_patient.py" in names and "io/surface_files.py" in names
    changed = [
        (name, text + (b"\n# changed" if name == "simulation/virtual_patient.py" else b"")) for name, text in sources
    ]
    monkeypatch.setattr(patient_cache, "library_sources", lambda: changed)
    assert patient_key("right-tibia", 0) != key
    monkeypatch.setattr(patient_cache, "library_sources", lambda: sources)
    moved_tool = patient_cache.tool_marker_geometry(patient_cache.DEFAULT_REFERENCE_TOOL) + 0.01
    monkeypatch.setattr(patient_cache, "tool_marker_geometry", lambda tool: moved_tool)
    assert patient_key("right-tibia", 0) != key
    monkeypatch.undo()
    mesh = tmp_path / "mesh.stl"
    mesh.write_bytes(package_data.bone_mesh_path("right-tibia").read_bytes() + b"\n")
    monkeypatch.setattr(package_data, "bone_mesh_path", lambda bone: mesh)
    assert patient_key("right-tibia", 0) != key  # the mesh file
    monkeypatch.undo()
    monkeypatch.setattr(patient_cache, "PATIENT_VERSION", patient_cache.PATIENT_VERSION + 1)
    assert patient_key("right-tibia", 0) != key


def test_the_shared_patient_is_made_once_per_process_and_cannot_be_changed(built):
    bone, seed, made = built
    first, second = shared_shipped_patient(bone, seed), shared_shipped_patient(bone, seed)
    assert first[0] is second[0]  # the same patient, not built twice
    assert_same_patient(first, made)
    with pytest.raises(ValueError, match="read-only"):
        first[0].ipc[0, 0] = 0.0
    with pytest.raises(ValueError, match="read-only"):
        first[0].sub_area_points[0][0, 0] = 0.0
    first[1][0, 0] += 1.0  # the mesh is the caller's own copy
    assert second[1][0, 0] == made[1][0, 0]
    with pytest.raises(ValueError, match="bone 'no-bone'"):
        shared_shipped_patient("no-bone")
