"""A shipped bone's virtual patient built once and read back: ``ramsicp web --demo`` starts from the same patient
every time, and building it (``VirtualPatient.from_mesh``: the dense surface, the sub-areas, the exposed surface)
takes 1.2-1.5 s on a loaded machine, reading it back a few hundredths of a second.

The cache is one ``.npz`` file per patient in the user's cache folder (``phantom_cache.cache_directory``), named
by a key: the SHA-256 of what the patient depends on, i.e. ``PATIENT_VERSION``, the source of the ``simulation``
package (how patients are drawn, and ``package_data.BONES``) and of ``io`` (how the mesh file and the NDI tool
are read), the bone's mesh file, the reference tool's marker geometry, the bone's name and the seed. The file holds
the bone's mesh too (``shipped_patient`` returns it with the patient). A file is written whole or not at all
(``io.atomic_files``); one that cannot be read, or holds arrays of the wrong shape, is built again and replaced.
A cache that cannot be written costs only the time. ``shared_shipped_patient`` reads or builds it once per process.
"""

import hashlib
import logging
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..io.ndi_tools import DEFAULT_REFERENCE_TOOL, tool_marker_geometry
from ..io.npz_cache import read_npz, write_npz
from .phantom_cache import library_sources

logger = logging.getLogger(__name__)

#: Raise when the patient's meaning or this file's layout changes without a change to the sources in the key.
PATIENT_VERSION = 1


def patient_key(bone, seed):
    """Hex SHA-256 of everything ``shipped_patient(bone, seed)`` depends on (see the module's docstring)."""
    from .package_data import bone_mesh_path  # a ValueError naming the shipped bones for another name

    digest = hashlib.sha256(f"ramsicp virtual patient v{PATIENT_VERSION} {bone} {int(seed)}".encode())
    for name, source in library_sources():
        digest.update(name.encode())
        digest.update(source)
    digest.update(bone_mesh_path(bone).read_bytes())
    digest.update(np.ascontiguousarray(tool_marker_geometry(DEFAULT_REFERENCE_TOOL), dtype=np.float64).tobytes())
    return digest.hexdigest()


def cached_shipped_patient(bone="right-tibia", seed=0, directory=None):
    """``shipped_patient(bone, seed)`` (a VirtualPatient on a shipped bone, with the bone's vertices and triangles),
    read from the cache when a valid copy is there, else built and written to it.

    Returns:
        (patient, vertices, triangles, built): ``built`` is True when the patient was built now.
    """
    from .package_data import shipped_patient
    from .phantom_cache import cache_directory

    directory = cache_directory() if directory is None else Path(directory)
    path = directory / f"patient-{patient_key(bone, seed)[:32]}.npz"
    stored = _read(path)
    if stored is not None:
        return (*stored, False)
    patient, vertices, triangles = shipped_patient(bone, seed)
    arrays = {name: value for name, value in vars(patient).items() if name != "sub_area_points"}
    arrays["exposed_points"] = np.zeros((0, 3)) if patient.exposed_points is None else patient.exposed_points
    arrays["has_exposed_points"] = patient.exposed_points is not None
    arrays["sub_area_sizes"] = [len(points) for points in patient.sub_area_points]
    arrays["sub_area_points"] = np.vstack(patient.sub_area_points).reshape(-1, 3)
    stored = {"vertices": vertices, "triangles": triangles, **{f"patient_{k}": v for k, v in arrays.items()}}
    write_npz(path, stored, logger, "virtual patient", "it will be built again")
    return patient, vertices, triangles, True


@lru_cache(maxsize=4)
def _shared(bone, seed):
    patient, vertices, triangles, _ = cached_shipped_patient(bone, seed)
    for value in vars(patient).values():
        for array in value if isinstance(value, (tuple, list)) else (value,):
            if isinstance(array, np.ndarray):
                array.flags.writeable = False
    return patient, vertices, triangles


def shared_shipped_patient(bone="right-tibia", seed=0):
    """``cached_shipped_patient(bone, seed)`` made or read once per process: ``ramsicp web --demo`` needs the same
    patient twice (the CT phantom, the simulated tracker's touches). Returns (patient, vertices, triangles); the
    patient is shared, a frozen dataclass whose arrays are read-only, so that no caller can change another's; the
    mesh is the caller's own copy."""
    patient, vertices, triangles = _shared(str(bone), int(seed))
    return patient, vertices.copy(), triangles.copy()


def _read(path):
    """(patient, vertices, triangles) from ``path``, or None when there is none or it is damaged."""
    return read_npz(path, _patient, logger, "virtual patient", "building it again")


def _patient(stored):
    """(patient, vertices, triangles) from the arrays of a cache file; ValueError when they do not make one."""
    from .virtual_patient import VirtualPatient

    arrays = {name[len("patient_") :]: stored[name] for name in stored.files if name.startswith("patient_")}
    vertices, triangles = stored["vertices"], stored["triangles"]
    sizes = arrays.pop("sub_area_sizes")
    points = arrays.pop("sub_area_points")
    if points.ndim != 2 or points.shape[1] != 3 or int(sizes.sum()) != len(points):
        raise ValueError("its sub-area points do not add up")
    has_exposed = bool(arrays.pop("has_exposed_points"))
    patient = VirtualPatient(
        sub_area_points=tuple(np.split(points, np.cumsum(sizes)[:-1])),
        cut_height_mm=float(arrays.pop("cut_height_mm")),
        anatomy=str(arrays.pop("anatomy")),
        exposed_points=arrays.pop("exposed_points") if has_exposed else None,
        **arrays,
    )
    shapes = {"ipc": (-1, 3), "reference_to_image": (4, 4), "markers_reference": (-1, 3), "targets_image": (-1, 3)}
    for name, shape in shapes.items():
        array = getattr(patient, name)
        if array.ndim != 2 or any(want not in (-1, have) for want, have in zip(shape, array.shape)):
            raise ValueError(f"its {name} is {array.shape}")
    if vertices.ndim != 2 or vertices.shape[1] != 3 or triangles.ndim != 2 or triangles.shape[1] != 3:
        raise ValueError("its mesh is not (V, 3) vertices and (K, 3) triangles")
    return patient, vertices, triangles
