"""The CT phantom cache (``ramsicp web --demo`` starts from it): the phantom read back is the one built, bit for
bit; a damaged or half-written file is built again; another seed or option is another phantom; a cache that cannot
be written costs only time. Phantoms at 2 mm voxels (a second each), on the shipped tibia."""

import logging

import numpy as np
import pytest

from RAMSICPRegistrationLib.simulation import phantom_cache
from RAMSICPRegistrationLib.simulation.ct_phantom import make_ct_phantom
from RAMSICPRegistrationLib.simulation.package_data import bone_mesh
from RAMSICPRegistrationLib.simulation.phantom_cache import cache_directory, cached_ct_phantom

COARSE = {"spacing": (2.0, 2.0, 2.0), "below_cut_mm": 20.0}


@pytest.fixture(scope="module")
def mesh():
    return bone_mesh("right-tibia")


@pytest.fixture(scope="module")
def direct(tibia_patient, mesh):
    """The phantom made without the cache."""
    return make_ct_phantom(tibia_patient, *mesh, seed=2, **COARSE)[0]


def test_the_second_call_reads_the_phantom_the_first_built(tmp_path, tibia_patient, mesh, direct):
    built, was_built = cached_ct_phantom(tibia_patient, *mesh, seed=2, directory=tmp_path, **COARSE)
    np.testing.assert_array_equal(built.voxels, direct.voxels)
    (path,) = tmp_path.glob("ct-phantom-*.npz")
    read, was_read_built = cached_ct_phantom(tibia_patient, *mesh, seed=2, directory=tmp_path, **COARSE)
    assert was_built and not was_read_built
    np.testing.assert_array_equal(read.voxels, direct.voxels)
    np.testing.assert_array_equal(read.ijk_to_ras, direct.ijk_to_ras)
    assert read.voxels.dtype == direct.voxels.dtype
    assert not [p for p in tmp_path.iterdir() if p != path]  # no temporary file left beside it
    # another seed: another phantom, another file
    other, built_again = cached_ct_phantom(tibia_patient, *mesh, seed=3, directory=tmp_path, **COARSE)
    assert built_again and not np.array_equal(other.voxels, direct.voxels)
    assert len(list(tmp_path.glob("ct-phantom-*.npz"))) == 2


@pytest.mark.parametrize("damage", ["truncated", "wrong arrays"])
def test_a_damaged_cache_file_is_built_again_and_replaced(tmp_path, tibia_patient, mesh, direct, caplog, damage):
    path = tmp_path / f"ct-phantom-{phantom_cache.phantom_key(tibia_patient, *mesh, 2, COARSE)[:32]}.npz"
    with open(path, "wb") as stream:  # what a first start wrote
        np.savez(stream, voxels=direct.voxels, ijk_to_ras=direct.ijk_to_ras)
    whole = path.read_bytes()
    assert not cached_ct_phantom(tibia_patient, *mesh, seed=2, directory=tmp_path, **COARSE)[1]
    if damage == "truncated":  # a write cut short by a crash of an older version, a full disk
        path.write_bytes(whole[: len(whole) // 2])
    else:
        np.savez(path, voxels=np.zeros(5), ijk_to_ras=np.eye(4))  # a 1-D "volume"
    with caplog.at_level(logging.WARNING, logger=phantom_cache.__name__):
        volume, built = cached_ct_phantom(tibia_patient, *mesh, seed=2, directory=tmp_path, **COARSE)
    assert built and "damaged" in caplog.text and "building it again" in caplog.text
    np.testing.assert_array_equal(volume.voxels, direct.voxels)
    assert path.read_bytes() == whole  # replaced by a whole copy


def test_a_cache_that_cannot_be_written_still_gives_the_phantom(tmp_path, tibia_patient, mesh, caplog):
    blocked = tmp_path / "not-a-folder"
    blocked.write_text("a file where the cache folder should be")
    with caplog.at_level(logging.WARNING, logger=phantom_cache.__name__):
        volume, built = cached_ct_phantom(tibia_patient, *mesh, seed=2, directory=blocked, **COARSE)
    assert built and volume.voxels.ndim == 3 and "could not be cached" in caplog.text


def test_the_cache_folder_is_the_environments_or_the_users(monkeypatch, tmp_path):
    monkeypatch.setenv(phantom_cache.CACHE_ENVIRONMENT, str(tmp_path / "chosen"))
    assert cache_directory() == tmp_path / "chosen"
    monkeypatch.delenv(phantom_cache.CACHE_ENVIRONMENT)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setattr(phantom_cache.sys, "platform", "linux")
    assert cache_directory() == tmp_path / "xdg" / "ramsicp-navigator"


def test_a_change_to_the_generator_is_another_key(monkeypatch, tibia_patient, mesh):
    key = phantom_cache.phantom_key(tibia_patient, *mesh, 0, {})
    sources = phantom_cache.library_sources()
    changed = [(name, text + (b"\n# changed" if name == "simulation/ct_phantom.py" else b"")) for name, text in sources]
    monkeypatch.setattr(phantom_cache, "library_sources", lambda: changed)
    assert phantom_cache.phantom_key(tibia_patient, *mesh, 0, {}) != key
    monkeypatch.setattr(phantom_cache, "library_sources", lambda: sources)
    assert phantom_cache.phantom_key(tibia_patient, *mesh, 0, {"spacing": (2.0, 2.0, 2.5)}) != key  # an option
    assert phantom_cache.phantom_key(tibia_patient, *mesh, 1, {}) != key  # the seed
    monkeypatch.setattr(phantom_cache, "GENERATOR_VERSION", phantom_cache.GENERATOR_VERSION + 1)
    assert phantom_cache.phantom_key(tibia_patient, *mesh, 0, {}) != key
