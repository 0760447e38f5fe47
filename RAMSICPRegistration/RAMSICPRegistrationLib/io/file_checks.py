"""Paths checked before any work: an input that is missing, a folder or empty, an output that cannot be written.

Every command and every loader calls these, so a mistake in a path costs one line and no computing: a result is
never computed and then lost because its file cannot be written. Each check raises ``PointFileError`` (a
``ValueError``) whose message starts with the option and the path, says what is wrong and what to do.
"""

import tempfile
from pathlib import Path


class PointFileError(ValueError):
    """A point, surface or volume file that cannot be read or written; the message names the file and the problem."""

    def __init__(self, path, problem):
        super().__init__(f"{path}: {problem}")
        self.path = str(path)
        self.problem = problem


def check_input_file(path, what="file"):
    """Raise PointFileError unless ``path`` is an existing, non-empty file; returns it as a Path.

    ``what`` names the expected file in the message (e.g. 'point file', 'CT volume').
    """
    path = Path(path)
    if path.is_dir():
        raise PointFileError(path, f"is a folder; give the {what} itself")
    if not path.is_file():
        raise PointFileError(path, "no such file")
    if path.stat().st_size == 0:
        raise PointFileError(path, f"is empty (0 bytes); give a {what} that holds data")
    return path


def check_output_file(path, option, suffixes=None, inputs=()):
    """Raise PointFileError unless a file can be written at ``path``; None passes (an output not asked for).

    Checked: the path is not a folder, its name ends with one of ``suffixes`` (any name when None), it is none of
    the command's ``inputs`` (paths, None ignored: an output never overwrites what the user collected), its folder
    exists and a file can be created in it (tried, then removed). ``option`` (e.g. '--json') starts the message.
    """
    if path is None:
        return
    path = Path(path)
    name = f"{option} {path}"
    for source in inputs:
        if source is not None and path.exists() and Path(source).exists() and path.samefile(source):
            raise PointFileError(name, f"is an input of this command ({source}); give another name for the output")
    if path.is_dir():
        example = f"{path / 'result'}{suffixes[0]}" if suffixes else f"{path / 'result'}"
        raise PointFileError(name, f"is a folder; give a file name, e.g. {example}")
    if suffixes is not None and not path.name.lower().endswith(tuple(suffixes)):
        raise PointFileError(name, f"give a file name ending in {_listed(suffixes)}")
    folder = path.parent
    if not folder.is_dir():
        what = "is a file, not a folder" if folder.exists() else "does not exist"
        raise PointFileError(name, f"the folder {folder} {what}; create it or write somewhere else")
    _check_writable(name, folder)


def check_output_folder(path, option):
    """Raise PointFileError unless ``path`` is, or can be created as, a folder to write files in.

    A missing folder is not created here (nothing is made before the work); its nearest existing parent must be a
    writable folder.
    """
    path = Path(path)
    name = f"{option} {path}"
    if path.exists() and not path.is_dir():
        raise PointFileError(name, "is a file; give a folder for the files (it is created when missing)")
    existing = path
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise PointFileError(name, f"{existing} is a file, so the folder cannot be created there")
    _check_writable(name, existing)


def _check_writable(name, folder):
    """Create and remove a file in ``folder``: the one test that answers for permissions, read-only mounts and
    special file systems alike (``os.access`` says yes to root everywhere)."""
    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".ramsicp-write-test-"):
            pass
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise PointFileError(name, f"cannot write in {folder} ({reason}); write somewhere else") from None


def _listed(suffixes):
    suffixes = list(suffixes)
    return suffixes[0] if len(suffixes) == 1 else f"{', '.join(suffixes[:-1])} or {suffixes[-1]}"
