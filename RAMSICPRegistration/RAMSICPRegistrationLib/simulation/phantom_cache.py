"""A CT phantom built once and read back: ``ramsicp web --demo`` and the demo scenes start from the same phantom
every time, and rendering it takes 15-40 s (``ct_phantom.make_ct_phantom``), reading it back under a second.

The cache is one ``.npz`` file per phantom in the user's cache folder (``cache_directory``), named by a key: the
SHA-256 of what the phantom depends on, i.e. the generator (``GENERATOR_VERSION`` and the source of the
``simulation`` package, so any change to how phantoms are drawn builds a new one), the bone mesh, the patient's
reference body pose and marker geometry, the seed and the options. A file is written whole or not at all
(``io.atomic_files``); one that cannot be read, or holds no valid volume, is built again and replaced. A cache
that cannot be written (read-only home, full disk) costs only the time: the phantom is still returned.
"""

import hashlib
import logging
import os
import sys
from pathlib import Path

import numpy as np

from ..image.volume_io import check_volume
from ..io.npz_cache import read_npz, write_npz

logger = logging.getLogger(__name__)

#: Raise when the phantom's meaning changes without a change to the simulation package's source (a data file).
GENERATOR_VERSION = 1
#: Environment variable naming the cache folder (tests, read-only homes); else the platform's user cache folder.
CACHE_ENVIRONMENT = "RAMSICP_CACHE_DIR"
APPLICATION = "ramsicp-navigator"


def cache_directory():
    """The folder cached phantoms live in: ``$RAMSICP_CACHE_DIR``, else the user's cache folder (XDG on Linux,
    ``~/Library/Caches`` on macOS, ``%LOCALAPPDATA%`` on Windows) / ``ramsicp-navigator``."""
    chosen = os.environ.get(CACHE_ENVIRONMENT)
    if chosen:
        return Path(chosen)
    if sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
    elif sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / APPLICATION


#: The library's packages whose code can change what is cached: the registration core (marker pairing, geometry),
#: the files and tool geometries, the image side and the simulation.
CACHED_PACKAGES = ("core", "io", "image", "simulation")


def library_sources():
    """(name, bytes) of the Python sources of ``CACHED_PACKAGES``, sorted by folder and name: any change to them
    makes every cached phantom, patient and processed CT again."""
    root = Path(__file__).resolve().parent.parent
    paths = [path for package in CACHED_PACKAGES for path in sorted((root / package).glob("*.py"))]
    return [(f"{path.parent.name}/{path.name}", path.read_bytes()) for path in paths]


def phantom_key(patient, vertices, triangles, seed, options):
    """Hex SHA-256 of everything a phantom depends on (see the module's docstring)."""
    digest = hashlib.sha256(f"ramsicp ct phantom v{GENERATOR_VERSION}".encode())
    for name, source in library_sources():
        digest.update(name.encode())
        digest.update(source)
    arrays = [vertices, triangles]
    for name, value in sorted(vars(patient).items()):  # every field the phantom may read (anatomy, cut height, IPC)
        digest.update(name.encode())
        if isinstance(value, np.ndarray):
            arrays.append(value)
        else:
            digest.update(repr(value).encode())
    for array in arrays:
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype.str}{array.shape}".encode())
        digest.update(array.tobytes())
    digest.update(repr((int(seed), sorted(options.items()))).encode())
    return digest.hexdigest()


def cached_ct_phantom(patient, vertices, triangles, seed=0, directory=None, **options):
    """The CTVolume of ``make_ct_phantom(patient, vertices, triangles, seed=seed, **options)``, read from the cache
    when a valid copy is there, else built and written to it.

    Args:
        directory: the cache folder (default ``cache_directory()``).
        options: make_ct_phantom's keyword options (plain values: they are part of the key).

    Returns:
        (CTVolume, built): ``built`` is True when the phantom was rendered now, False when it was read.
    """
    from .ct_phantom import make_ct_phantom

    directory = cache_directory() if directory is None else Path(directory)
    path = directory / f"ct-phantom-{phantom_key(patient, vertices, triangles, seed, options)[:32]}.npz"
    volume = _read(path)
    if volume is not None:
        return volume, False
    volume, _ = make_ct_phantom(patient, vertices, triangles, seed=seed, **options)
    arrays = {"voxels": volume.voxels, "ijk_to_ras": volume.ijk_to_ras}
    write_npz(path, arrays, logger, "CT phantom", "it will be built again next time")
    return volume, True


def _read(path):
    """The CTVolume in ``path``, or None when there is none or it is damaged (then it is rebuilt)."""

    def decode(stored):
        volume = check_volume(stored["voxels"], stored["ijk_to_ras"], name=f"cached phantom {path.name}")
        if not np.isfinite(volume.voxels).all():
            raise ValueError("it holds non-finite voxels")
        return volume

    return read_npz(path, decode, logger, "CT phantom", "building it again")
