"""PLUS sequence files (OpenIGTLinkBridgeLib.plus_sequence): the real PlusLibData recordings, exact round trips,
Slicer's own reader on our files, and one clear line for every broken file."""

from pathlib import Path

import numpy as np
import pytest

from OpenIGTLinkBridgeLib.plus_sequence import (
    SequenceFileError,
    SequenceRecorder,
    TrackedFrame,
    read_sequence,
    write_sequence,
)

DATA = Path(__file__).parent / "Data"
CALIBRATION = DATA / "ReferenceToRASCalibration.igs.mha"
WATER_TANK = DATA / "WaterTankBottomTranslationTrackerBuffer-trimmed.igs.mha"


def test_reads_the_real_recordings_field_for_field():
    calibration = read_sequence(CALIBRATION)
    assert len(calibration.frames) == 93 and calibration.transform_names == ["ReferenceToTracker", "StylusToTracker"]
    first = calibration.frames[0]
    assert first.timestamp_s == 196.7208142857271  # Seq_Frame0000_Timestamp, as written
    np.testing.assert_array_equal(
        first.transforms["StylusToTracker"][0], [0.3903989045413856, 0.9175945537919958, -0.07489279126961652, 19.58]
    )
    np.testing.assert_array_equal(first.transforms["StylusToTracker"][3], [0, 0, 0, 1])
    assert first.is_valid("StylusToTracker") and first.fields == {"ImageStatus": "INVALID"}
    assert calibration.header["DimSize"] == "0 0 93" and calibration.header["ElementDataFile"] == "LOCAL"
    tank = read_sequence(WATER_TANK)
    assert len(tank.frames) == 801 and tank.transform_names == [
        "ProbeToTracker",
        "ReferenceToTracker",
        "StylusToTracker",
    ]
    last = tank.frames[800]
    assert last.timestamp_s == 7436.385229 and last.fields["FrameNumber"] == "333152"
    assert last.transforms["StylusToTracker"][2, 0] == 8.6288e-005  # PLUS's three-digit exponents
    matrices, valid = tank.matrices("ProbeToTracker")
    assert matrices.shape == (801, 4, 4) and valid.all()


@pytest.mark.parametrize("path", [CALIBRATION, WATER_TANK], ids=["calibration", "water-tank"])
def test_a_real_recording_written_and_read_back_is_bit_identical(tmp_path, path):
    original = read_sequence(path)
    copy = read_sequence(write_sequence(tmp_path / "copy.seq.mha", original.frames))
    assert len(copy.frames) == len(original.frames)
    for before, after in zip(original.frames, copy.frames):
        assert after.timestamp_s == before.timestamp_s and after.statuses == before.statuses
        assert after.fields == before.fields and list(after.transforms) == list(before.transforms)
        for name, matrix in before.transforms.items():
            assert after.transforms[name].tobytes() == matrix.tobytes()


def _awkward_frames(rng, count=50):
    """Frames whose numbers need all 17 digits, with tiny, huge and negative-zero values, and invalid poses."""
    frames = []
    for index in range(count):
        probe = rng.normal(size=(4, 4)) * 10.0 ** rng.integers(-8, 8, size=(4, 4))
        probe[3] = (0.0, -0.0, 5e-324, 1.0)
        reference = np.eye(4)
        reference[:3, 3] = rng.uniform(-2000, 2000, 3)
        statuses = {"ProbeToTracker": "OK" if index % 7 else "INVALID", "ReferenceToTracker": "OK"}
        frames.append(
            TrackedFrame(1e9 + index / 3.0, {"ProbeToTracker": probe, "ReferenceToTracker": reference}, statuses)
        )
    return frames


def test_frames_written_and_read_back_are_equal_at_float64(tmp_path):
    frames = _awkward_frames(np.random.default_rng(1))
    recording = read_sequence(write_sequence(tmp_path / "session.igs.mha", frames))
    for written, read in zip(frames, recording.frames):
        assert read.timestamp_s == written.timestamp_s and read.statuses == written.statuses
        for name, matrix in written.transforms.items():
            assert read.transforms[name].tobytes() == matrix.tobytes()  # -0.0 and subnormals included
    assert [frame.is_valid("ProbeToTracker") for frame in recording.frames] == [i % 7 != 0 for i in range(50)]
    assert recording.header["DimSize"] == "0 0 50"


def test_slicer_reads_our_files_as_it_reads_plus_files(tmp_path):
    """Slicer's Sequences reader (vtkMRMLLinearTransformSequenceStorageNode, C++) on a file we wrote."""
    slicer = pytest.importorskip("slicer", reason="slicer-core (real MRML) needs Python >= 3.10")
    from vtkmodules.vtkCommonMath import vtkMatrix4x4

    frames = _awkward_frames(np.random.default_rng(2), count=5)
    path = write_sequence(tmp_path / "session.seq.mha", frames)
    scene = slicer.vtkMRMLScene()
    sequence = scene.AddNewNodeByClass("vtkMRMLSequenceNode")
    storage = slicer.vtkMRMLLinearTransformSequenceStorageNode()
    scene.AddNode(storage)
    storage.SetFileName(str(path))
    assert storage.ReadData(sequence) == 1
    assert sequence.GetNumberOfDataNodes() == 5 and sequence.GetAttribute("Sequences.Source") == "ProbeToTracker"
    for index, frame in enumerate(frames):
        matrix = vtkMatrix4x4()
        sequence.GetNthDataNode(index).GetMatrixTransformToParent(matrix)
        read = np.array([[matrix.GetElement(row, column) for column in range(4)] for row in range(4)])
        np.testing.assert_array_equal(read, frame.transforms["ProbeToTracker"])
        assert sequence.GetNthIndexValue(index) == f"{frame.timestamp_s:.3f}"


def test_the_recorder_leaves_a_complete_file_after_every_frame(tmp_path):
    """A session cut short (the process killed) loses nothing it recorded: each add() leaves a readable file."""
    frames = _awkward_frames(np.random.default_rng(3), count=4)
    path = tmp_path / "live.igs.mha"
    recorder = SequenceRecorder(path)
    for count, frame in enumerate(frames, start=1):
        recorder.add(frame)
        snapshot = read_sequence(path)  # read while still recording, as after a crash
        assert len(snapshot.frames) == count and snapshot.header["DimSize"] == f"0 0 {count}"
    recorder.close()
    assert path.read_text().endswith("ElementDataFile = LOCAL\n")


def _broken(tmp_path, text):
    path = tmp_path / "broken.igs.mha"
    path.write_text(text)
    return path


GOOD = CALIBRATION.read_text()


@pytest.mark.parametrize(
    "make, expected",
    [
        (lambda p: p / "missing.igs.mha", "missing.igs.mha: no such file"),
        (lambda p: p, "is a folder"),
        (lambda p: _broken(p, ""), "is empty"),
        (lambda p: _broken(p, "NRRD0004\ntype: short\n"), "line 1 has no '='"),
        (lambda p: _broken(p, "ObjectType = Mesh\n"), "not a MetaImage sequence file"),
        (
            lambda p: _broken(
                p, GOOD[: GOOD.index("Seq_Frame0050_StylusToTrackerTransform") + 80] + "\nElementDataFile = LOCAL\n"
            ),
            r"frame 50, StylusToTrackerTransform: \d numbers, expected 16",
        ),
        (lambda p: _broken(p, GOOD[: GOOD.index("Seq_Frame0000_")]), "before its first frame: the file was cut short"),
        (
            lambda p: _broken(p, GOOD[: GOOD.index("Seq_Frame0000_Timestamp")]),
            "in its first frame: the file was cut short before any complete frame",
        ),
        (
            lambda p: _broken(p, GOOD.replace("Frame0007_Timestamp = 197.19", "Frame0007_Timestamp = x197.19")),
            "frame 7, Timestamp: 'x197.19.*' is not a number",
        ),
        (
            lambda p: _broken(p, GOOD.replace("Seq_Frame0003_Timestamp", "Seq_Frame0003_Timestanp")),
            "frame 3, Timestamp: missing",
        ),
        (
            lambda p: _broken(p, GOOD.replace("60.6 -0.005603734062377132", "nan -0.005603734062377132", 1)),
            "frame 0, ReferenceToTrackerTransform: 'nan' is not a finite number",
        ),
        (lambda p: _broken(p, GOOD.replace("Seq_Frame0004_", "Seq_Frame0104_")), "frame 4: missing"),
    ],
    ids=[
        "missing",
        "folder",
        "empty",
        "nrrd",
        "not-an-image",
        "truncated-line",
        "cut-in-header",
        "cut-in-frame-0",
        "bad-number",
        "no-timestamp",
        "nan",
        "gap",
    ],
)
def test_broken_files_give_one_line_naming_file_frame_and_field(tmp_path, make, expected):
    path = make(tmp_path)
    with pytest.raises(SequenceFileError, match=expected) as error:
        read_sequence(path)
    assert "\n" not in str(error.value) and str(path) in str(error.value)


@pytest.mark.parametrize(
    "cut, kept, incomplete",
    [
        ("Seq_Frame0050_Timestamp", 50, True),  # frame 50 has its transforms but not its time: left out
        ("Seq_Frame0050_ReferenceToTrackerTransform", 50, False),  # cut exactly between frames 49 and 50
        ("Seq_Frame0050_StylusToTrackerTransform = ", 50, True),  # cut in the middle of a line's value
        ("ElementDataFile", 93, False),  # every frame there, only the closing line missing
    ],
)
def test_a_file_cut_short_keeps_the_frames_before_the_cut_with_a_warning(tmp_path, caplog, cut, kept, incomplete):
    """A recording cut off (a recorder killed, a copy interrupted): its complete frames are usable, equal to the
    whole file's, and the warning says how many and why; a value cut in the middle of a line is never read."""
    end = GOOD.index(cut) + (len(cut) + 7 if cut.endswith("= ") else 0)  # 7 characters into the line's value
    path = _broken(tmp_path, GOOD[:end])
    whole = read_sequence(CALIBRATION)
    with caplog.at_level("WARNING"):
        recording = read_sequence(path)
    assert len(recording.frames) == kept
    for frame, original in zip(recording.frames, whole.frames):
        assert frame.timestamp_s == original.timestamp_s and frame.statuses == original.statuses
        for name, matrix in original.transforms.items():
            np.testing.assert_array_equal(frame.transforms[name], matrix)
    (warning,) = recording.warnings
    assert warning.startswith(f"{path}: the file was cut short (no 'ElementDataFile = LOCAL' line): {kept} complete")
    assert "of the 93 its header announces" in warning
    assert ("frame 50 was cut in the middle and is left out" in warning) == incomplete
    assert warning in caplog.text  # logged as well


def test_binary_pixels_after_the_header_are_ignored(tmp_path):
    path = tmp_path / "with_pixels.igs.mha"
    path.write_bytes(GOOD.encode("ascii") + bytes(range(256)) * 4)
    assert len(read_sequence(path).frames) == 93


def test_frames_that_cannot_be_written_are_refused(tmp_path):
    bad = TrackedFrame(0.0, {"ProbeToTracker": np.full((4, 4), np.nan)})
    with pytest.raises(SequenceFileError, match="frame 0, ProbeToTrackerTransform: not a finite 4x4 matrix"):
        write_sequence(tmp_path / "bad.igs.mha", [bad])
    assert not (tmp_path / "bad.igs.mha").exists()  # nothing half-written replaces a file
    with pytest.raises(SequenceFileError, match="is a folder"):
        SequenceRecorder(tmp_path)
    with pytest.raises(SequenceFileError, match="cannot be written"):
        SequenceRecorder(tmp_path / "no" / "such" / "folder.igs.mha")
