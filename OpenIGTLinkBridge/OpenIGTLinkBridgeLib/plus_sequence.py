"""PLUS sequence files (``.igs.mha``, ``.seq.mha``): recorded tracking, read and written as PLUS does.

The format is PLUS Toolkit's (``vtkPlusMetaImageSequenceIO``, read by PLUS's SavedDataSource and by Slicer's
Sequences module): a MetaImage text header (``ObjectType = Image`` first, ``DimSize = 0 0 N`` when there are
no pixels) followed by one ``Seq_FrameNNNN_<Field> = value`` line per frame field, and ``ElementDataFile =
LOCAL`` last; pixel data, if any, follows that line and is ignored here. The frame fields used:

- ``<Name>Transform``: 16 numbers, the row-major (4, 4) matrix of transform ``<Name>`` (e.g. StylusToTracker),
  translation in mm;
- ``<Name>TransformStatus``: ``OK``, or anything else (PLUS writes ``INVALID``) for a pose that is not valid;
- ``Timestamp``: the frame's time in s. Other fields (``FrameNumber``, ``UnfilteredTimestamp``,
  ``ImageStatus``...) are kept as text.

Numbers are written with Python's shortest round-trip form, so a file written and read back gives the same
float64 bits (PLUS itself writes 16 significant digits). Lines stay under PLUS's 1000-character limit.
A file that cannot be read gives ``SequenceFileError``: one line naming the file, the frame and the field.

A file cut short (a recorder killed while writing, a copy interrupted: no ``ElementDataFile`` line) is read up to
the cut: a last line without its end of line is a value cut in the middle and is left out, and so is the last
frame when it lacks fields the frame before it has; the frames before the cut are returned with a warning
(``Recording.warnings``, also logged) saying how many were kept. Only a file cut before its first complete frame
is refused.
"""

import logging
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

SUFFIXES = (".igs.mha", ".seq.mha", ".mha")
FRAME_PREFIX = "Seq_Frame"
TRANSFORM_SUFFIX = "Transform"
STATUS_SUFFIX = "TransformStatus"
MAX_LINE_LENGTH = 1000  # PLUS and Slicer read header lines with fgets(line, 1000)
#: PLUS pads DimSize to this width so that the frame count can be rewritten in place as frames are added.
_DIMSIZE_WIDTH = 40
_FRAME_FIELD = re.compile(r"Seq_Frame(\d+)_(.+)")
_NAME = re.compile(r"[A-Za-z0-9_]+")
_IDENTITY = np.eye(4)
logger = logging.getLogger(__name__)

#: The header PLUS writes for a tracking-only sequence (vtkPlusMetaImageSequenceIO), in its order.
_HEADER = (
    ("ObjectType", "Image"),
    ("NDims", "3"),
    ("AnatomicalOrientation", "RAI"),
    ("BinaryData", "True"),
    ("BinaryDataByteOrderMSB", "False"),
    ("CenterOfRotation", "0 0 0"),
    ("CompressedData", "False"),
    ("DimSize", None),  # "0 0 N", padded
    ("Kinds", "domain domain list"),
    ("ElementNumberOfChannels", "1"),
    ("ElementSpacing", "1 1 1"),
    ("ElementType", "MET_UCHAR"),
    ("Offset", "0 0 0"),
    ("TransformMatrix", "1 0 0 0 1 0 0 0 1"),
    ("UltrasoundImageOrientation", "XX"),
    ("UltrasoundImageType", "XX"),
)


class SequenceFileError(ValueError):
    """A sequence file that cannot be read or written; the message names the file, frame and field."""


@dataclass(frozen=True)
class TrackedFrame:
    """One frame of a recording.

    ``transforms``: name (e.g. ``"StylusToTracker"``) -> (4, 4) float64 matrix, in the order of the file;
    ``statuses``: name -> status text (``"OK"`` when valid); ``fields``: the other frame fields, as text.
    """

    timestamp_s: float
    transforms: dict
    statuses: dict = field(default_factory=dict)
    fields: dict = field(default_factory=dict)

    def is_valid(self, name):
        """True when the frame holds transform ``name`` with status OK (PLUS compares case-insensitively)."""
        return name in self.transforms and self.statuses.get(name, "OK").strip().upper() == "OK"


@dataclass(frozen=True)
class Recording:
    """The frames of a sequence file, its non-frame header fields (text, in file order) and what was wrong with the
    file but did not stop it being read (``warnings``: one line each, e.g. the file was cut short)."""

    frames: list
    header: dict
    path: Path = None
    warnings: tuple = ()

    @property
    def transform_names(self):
        """Transform names in the order they first appear."""
        names = {}
        for frame in self.frames:
            names.update(dict.fromkeys(frame.transforms))
        return list(names)

    @property
    def timestamps_s(self):
        return np.array([frame.timestamp_s for frame in self.frames])

    def matrices(self, name):
        """(N, 4, 4) matrices of ``name`` and (N,) bool validity; frames without it give identity, invalid."""
        matrices = np.array([frame.transforms.get(name, _IDENTITY) for frame in self.frames], dtype=np.float64)
        valid = np.array([frame.is_valid(name) for frame in self.frames], dtype=bool)
        return matrices.reshape(-1, 4, 4), valid


# -- reading --------------------------------------------------------------------------------------------------
def read_sequence(path):
    """Read a PLUS sequence file; raises SequenceFileError with one line naming the file, frame and field. A file
    cut short gives the frames before the cut and a warning (the module's docstring)."""
    path = Path(path)
    text_lines, ended, terminated = _header_lines(path)
    if not ended and not terminated:
        text_lines = text_lines[:-1]  # the last line was cut in the middle of its value
    header, raw_frames = {}, {}
    for number, line in enumerate(text_lines, start=1):
        if not line.strip():
            continue
        name, equals, value = line.partition("=")
        name, value = name.strip(), value.strip()
        if not equals:
            raise SequenceFileError(f"{path}: line {number} has no '=' ({_shorten(line)!r}); not a sequence header")
        if number == 1 and (name, value) != ("ObjectType", "Image"):
            raise SequenceFileError(
                f"{path}: not a MetaImage sequence file (first line {_shorten(line)!r}, expected 'ObjectType = Image')"
            )
        if name == "ElementDataFile":
            header[name] = value
            break
        match = _FRAME_FIELD.fullmatch(name)
        if match is None:
            header[name] = value
            continue
        index, field_name = int(match.group(1)), match.group(2)
        fields = raw_frames.setdefault(index, {})
        if field_name in fields:
            raise SequenceFileError(f"{path}: frame {index}, {field_name}: given twice (line {number})")
        fields[field_name] = value
    warnings = ()
    if not ended:
        raw_frames, warnings = _frames_before_the_cut(path, header, raw_frames)
    if not raw_frames:
        raise SequenceFileError(f"{path}: holds no frames (no Seq_FrameNNNN_ fields)")
    missing = sorted(set(range(max(raw_frames) + 1)) - set(raw_frames))
    if missing:
        raise SequenceFileError(f"{path}: frame {missing[0]}: missing (frames are numbered 0 to {max(raw_frames)})")
    frames = [_parse_frame(path, index, raw_frames[index]) for index in range(len(raw_frames))]
    for warning in warnings:
        logger.warning(warning)
    return Recording(frames, header, path, warnings)


def _frames_before_the_cut(path, header, raw_frames):
    """The complete frames of a file cut short (no ElementDataFile line), and the warning that says so."""
    if not raw_frames:
        raise SequenceFileError(
            f"{path}: ends before 'ElementDataFile = LOCAL', the header's last line, and before its first frame: "
            "the file was cut short"
        )
    last = max(raw_frames)
    complete = dict(raw_frames)
    incomplete = ""
    if "Timestamp" not in complete[last] or (last > 0 and set(complete[last]) != set(complete.get(last - 1, ()))):
        del complete[last]
        incomplete = f"; frame {last} was cut in the middle and is left out"
    if not complete:
        raise SequenceFileError(
            f"{path}: ends before 'ElementDataFile = LOCAL', the header's last line, in its first frame: the file "
            "was cut short before any complete frame"
        )
    announced = header.get("DimSize", "").split()
    of = f" of the {announced[-1]} its header announces" if len(announced) == 3 and announced[-1] != "0" else ""
    warning = (
        f"{path}: the file was cut short (no 'ElementDataFile = LOCAL' line): {len(complete)} complete frames "
        f"read{of}{incomplete}"
    )
    return complete, (warning,)


def _header_lines(path):
    """The text lines up to and including ElementDataFile (pixel bytes after it are never decoded), whether that
    line was found, and whether the last line read ended with an end of line."""
    if not path.exists():
        raise SequenceFileError(f"{path}: no such file")
    if path.is_dir():
        raise SequenceFileError(f"{path}: is a folder; give a .igs.mha or .seq.mha sequence file")
    try:
        data = path.read_bytes()
    except OSError as error:
        raise SequenceFileError(f"{path}: cannot be read ({error.strerror or error})") from None
    if not data.strip():
        raise SequenceFileError(f"{path}: is empty; a sequence file starts with 'ObjectType = Image'")
    lines = []
    raw_lines = data.split(b"\n")
    for raw in raw_lines:
        try:
            line = raw.decode("ascii").rstrip("\r")
        except UnicodeDecodeError:
            raise SequenceFileError(
                f"{path}: line {len(lines) + 1} is not text; not a MetaImage sequence file"
            ) from None
        lines.append(line)
        if line.split("=", 1)[0].strip() == "ElementDataFile":
            return lines, True, True
    return lines, False, data.endswith(b"\n")


def _parse_frame(path, index, fields):
    transforms, statuses, others = {}, {}, {}
    for name, value in fields.items():
        if name.endswith(STATUS_SUFFIX) and len(name) > len(STATUS_SUFFIX):
            if not value:
                raise SequenceFileError(f"{path}: frame {index}, {name}: empty status (PLUS writes OK or INVALID)")
            statuses[name[: -len(STATUS_SUFFIX)]] = value
        elif name.endswith(TRANSFORM_SUFFIX) and len(name) > len(TRANSFORM_SUFFIX):
            transforms[name[: -len(TRANSFORM_SUFFIX)]] = _matrix(path, index, name, value)
        else:
            others[name] = value
    for name in statuses:
        if name not in transforms:
            raise SequenceFileError(f"{path}: frame {index}, {name}{STATUS_SUFFIX}: a status without its transform")
    if "Timestamp" not in others:
        raise SequenceFileError(f"{path}: frame {index}, Timestamp: missing")
    timestamp = _float(path, index, "Timestamp", others.pop("Timestamp"))
    return TrackedFrame(timestamp, transforms, statuses, others)


def _matrix(path, index, name, value):
    numbers = value.split()
    if len(numbers) != 16:
        raise SequenceFileError(
            f"{path}: frame {index}, {name}: {len(numbers)} numbers, expected 16 (a row-major 4x4 matrix)"
        )
    return np.array([_float(path, index, name, number) for number in numbers], dtype=np.float64).reshape(4, 4)


def _float(path, index, name, text):
    try:
        value = float(text)
    except ValueError:
        raise SequenceFileError(f"{path}: frame {index}, {name}: {_shorten(text)!r} is not a number") from None
    if not math.isfinite(value):
        raise SequenceFileError(f"{path}: frame {index}, {name}: {text!r} is not a finite number")
    return value


def _shorten(text, limit=60):
    return text if len(text) <= limit else text[: limit - 3] + "..."


# -- writing --------------------------------------------------------------------------------------------------
def write_sequence(path, frames):
    """Write ``frames`` (TrackedFrame) as a PLUS sequence file, atomically (a partial file never replaces one)."""
    path = Path(path)
    temporary = path.with_name(f".{path.name}.partial")
    with SequenceRecorder(temporary) as recorder:
        for frame in frames:
            recorder.add(frame)
    os.replace(temporary, path)
    return path


class SequenceRecorder:
    """Writes a sequence file frame by frame; after every ``add`` the file on disk is complete and readable.

    Each frame is written with the closing ``ElementDataFile = LOCAL`` line in one write, the next frame
    overwriting that line, and ``DimSize`` (padded as PLUS pads it) is updated in place: a process killed
    while recording leaves a file holding every frame added so far.
    """

    def __init__(self, path):
        self.path = Path(path)
        if self.path.is_dir():
            raise SequenceFileError(f"{self.path}: is a folder; give a file name ending in .igs.mha or .seq.mha")
        try:
            self._file = open(self.path, "wb")
        except OSError as error:
            raise SequenceFileError(f"{self.path}: cannot be written ({error.strerror or error})") from None
        self.frames = 0
        header = b""
        for name, value in _HEADER:
            if name == "DimSize":
                self._dimsize_offset = len(header)
                header += _dimsize_line(0)
            else:
                header += f"{name} = {value}\n".encode("ascii")
        self._end = len(header)
        self._write_at(0, header + b"ElementDataFile = LOCAL\n")

    def add(self, frame):
        """Append one TrackedFrame; raises SequenceFileError for a matrix that is not finite (4, 4)."""
        if self._file is None:
            raise SequenceFileError(f"{self.path}: the recording is closed")
        lines = _frame_lines(self.path, self.frames, frame)
        self._write_at(self._end, lines + b"ElementDataFile = LOCAL\n")
        self._end += len(lines)
        self.frames += 1
        self._write_at(self._dimsize_offset, _dimsize_line(self.frames))
        return self.frames

    def _write_at(self, offset, data):
        try:
            self._file.seek(offset)
            self._file.write(data)
            self._file.flush()
        except OSError as error:
            raise SequenceFileError(f"{self.path}: writing failed ({error.strerror or error})") from None

    def close(self):
        if self._file is not None:
            self._file.close()
            self._file = None
        return self.path

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _dimsize_line(count):
    return f"DimSize = 0 0 {count}".ljust(_DIMSIZE_WIDTH).encode("ascii") + b"\n"


def _frame_lines(path, index, frame):
    prefix = f"{FRAME_PREFIX}{index:04d}_"
    lines = []
    for name, matrix in frame.transforms.items():
        if not _NAME.fullmatch(name):
            raise SequenceFileError(f"{path}: frame {index}: transform name {name!r} is not letters, digits and _")
        matrix = np.asarray(matrix, dtype=np.float64)
        if matrix.shape != (4, 4) or not np.isfinite(matrix).all():
            raise SequenceFileError(f"{path}: frame {index}, {name}{TRANSFORM_SUFFIX}: not a finite 4x4 matrix")
        lines.append(f"{prefix}{name}{TRANSFORM_SUFFIX} = {' '.join(repr(float(v)) for v in matrix.ravel())}")
        lines.append(f"{prefix}{name}{STATUS_SUFFIX} = {frame.statuses.get(name, 'OK')}")
    timestamp = float(frame.timestamp_s)
    if not math.isfinite(timestamp):
        raise SequenceFileError(f"{path}: frame {index}, Timestamp: {timestamp!r} is not a finite number")
    lines.append(f"{prefix}Timestamp = {timestamp!r}")
    lines.extend(f"{prefix}{name} = {value}" for name, value in frame.fields.items())
    for line in lines:
        if len(line) >= MAX_LINE_LENGTH - 1 or "\n" in line:
            raise SequenceFileError(f"{path}: frame {index}: line {line[:40]!r}... is too long for PLUS to read")
    return ("\n".join(lines) + "\n").encode("ascii")
