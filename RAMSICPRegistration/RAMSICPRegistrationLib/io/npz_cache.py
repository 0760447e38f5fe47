"""One cached result per ``.npz`` file: read back when it is whole and valid, else made again; written whole or not
at all (``io.atomic_files``). The CT phantom, the virtual patient and the processed CT are cached so.

A file that cannot be read, or whose arrays do not make a valid result (the ``decode`` raises), is damaged: a
warning says so and the caller makes the result again and replaces the file. A cache that cannot be written (a
read-only home, a full disk) costs only the time: a warning, and the result is still returned.
"""

import zipfile

import numpy as np

from .atomic_files import atomic_path

#: What reading a damaged file raises: a file cut short, not a zip, a missing or malformed array.
DAMAGED = (OSError, ValueError, KeyError, IndexError, TypeError, EOFError, zipfile.BadZipFile)


def read_npz(path, decode, logger, what, again):
    """``decode(stored)`` of the arrays in ``path`` (an ``np.load`` of it, no pickle), or None when there is no such
    file or it is damaged (then ``logger`` warns: "the cached {what} ... is damaged (...): {again}")."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as stored:
            return decode(stored)
    except DAMAGED as error:
        logger.warning("the cached %s %s is damaged (%s): %s", what, path, error, again)
        return None


def write_npz(path, arrays, logger, what, again):
    """Write the named ``arrays`` to ``path`` (its folder made), whole or not at all; when it cannot be written,
    ``logger`` warns: "the {what} could not be cached in ... (...); {again}"."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as temporary, open(temporary, "wb") as stream:
            np.savez(stream, **arrays)
    except OSError as error:
        logger.warning("the %s could not be cached in %s (%s); %s", what, path, error, again)
