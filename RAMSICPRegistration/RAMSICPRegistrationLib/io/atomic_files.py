"""Output files written whole or not at all: a Ctrl-C, a crash or a full disk never leaves half a file.

Every file the program writes (JSON, point files, surfaces, NRRD, PNG, the report's files) is written to a
temporary file beside it (same folder, so same file system; same suffix, so writers that choose the format by the
name still do), then renamed over the target with ``os.replace``, which is atomic on POSIX and Windows. Anything
raised while writing, ``KeyboardInterrupt`` included, removes the temporary file and leaves what was there before.
"""

import os
from contextlib import contextmanager
from pathlib import Path

#: What a temporary file's name carries, between the target's stem and its suffix (so ``ls`` shows what it is).
PARTIAL = ".partial"


def _suffix(path):
    name = path.name.lower()
    for double in (".mrk.json", ".nii.gz", ".seq.mha", ".igs.mha"):
        if name.endswith(double):
            return path.name[-len(double) :]
    return path.suffix


@contextmanager
def atomic_path(path, durable=False):
    """Yield a temporary path beside ``path`` to write to; on success it replaces ``path``, on any exception it is
    removed and ``path`` is left as it was.

    ``durable``: flush the file and its folder to the disk (fsync) before and after the rename, so that a power cut
    keeps either file whole too (the autosave of collected points).
    """
    path = Path(path)
    suffix = _suffix(path)
    stem = path.name[: len(path.name) - len(suffix)] if suffix else path.name
    temporary = path.with_name(f".{stem}{PARTIAL}-{os.getpid()}{suffix}")
    try:
        yield temporary
        if durable:
            with open(temporary, "rb+") as stream:
                os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    if durable and hasattr(os, "O_DIRECTORY"):  # make the rename itself durable (POSIX)
        folder = os.open(path.parent, os.O_RDONLY | os.O_DIRECTORY)
        try:
            os.fsync(folder)
        finally:
            os.close(folder)


def write_text_atomic(path, text):
    """Write ``text`` (UTF-8) to ``path`` whole or not at all."""
    with atomic_path(path) as temporary:
        Path(temporary).write_text(text, encoding="utf-8")


def write_json_atomic(path, document):
    """Write ``document`` as indented JSON to ``path`` whole or not at all."""
    import json

    write_text_atomic(path, json.dumps(document, indent=2))


@contextmanager
def atomic_folder(directory):
    """Yield a temporary folder beside ``directory`` to write a set of files in (a report, a phantom); on success
    each file is moved into ``directory`` (created when missing) by ``os.replace``, on any exception the temporary
    folder is removed and ``directory`` is left as it was: a report is never left with half its files."""
    import shutil

    directory = Path(directory)
    directory.parent.mkdir(parents=True, exist_ok=True)
    temporary = directory.with_name(f".{directory.name}{PARTIAL}-{os.getpid()}")
    temporary.mkdir()
    try:
        yield temporary
        directory.mkdir(exist_ok=True)
        for item in sorted(temporary.iterdir()):
            os.replace(item, directory / item.name)
    finally:
        shutil.rmtree(temporary, ignore_errors=True)
