"""Point files: round trips keep coordinates (LPS <-> RAS), and malformed files give one-line errors."""

import json

import numpy as np
import pytest

from RAMSICPRegistrationLib.io.point_files import PointFileError, read_points, write_points

POINTS_RAS = np.array([[12.5, -40.25, 101.0], [-3.0, 7.125, -0.5], [100.0, 200.0, 300.0]])


@pytest.mark.parametrize("name", ["points.mrk.json", "points.fcsv", "points.csv", "points.txt", "points.npy"])
def test_round_trip_keeps_ras_coordinates(tmp_path, name):
    path = tmp_path / name
    write_points(path, POINTS_RAS, labels=["a", "b", "c"])
    read = read_points(path)
    np.testing.assert_allclose(read.points, POINTS_RAS, atol=1e-9)
    if name.endswith((".mrk.json", ".fcsv")):
        assert read.labels == ("a", "b", "c")


def test_markups_json_is_written_in_lps_like_slicer(tmp_path):
    path = tmp_path / "f.mrk.json"
    write_points(path, POINTS_RAS)
    markup = json.loads(path.read_text())["markups"][0]
    assert markup["coordinateSystem"] == "LPS"
    assert markup["controlPoints"][0]["position"] == [-12.5, 40.25, 101.0]


def test_markups_json_in_ras_is_read_as_ras(tmp_path):
    path = tmp_path / "ras.mrk.json"
    document = {
        "markups": [
            {
                "type": "Fiducial",
                "coordinateSystem": "RAS",
                "controlPoints": [
                    {"label": "M1", "position": [1.0, 2.0, 3.0]},
                    {"label": "skip", "position": [0.0, 0.0, 0.0], "positionStatus": "undefined"},
                ],
            }
        ]
    }
    path.write_text(json.dumps(document))
    read = read_points(path)
    np.testing.assert_array_equal(read.points, [[1.0, 2.0, 3.0]])
    assert read.labels == ("M1",)


@pytest.mark.parametrize(
    "header, expected",
    [
        ("# CoordinateSystem = 0", [1.0, 2.0, 3.0]),  # Slicer < 4.11: 0 is RAS
        ("# CoordinateSystem = RAS", [1.0, 2.0, 3.0]),
        ("# CoordinateSystem = 1", [-1.0, -2.0, 3.0]),
        ("# CoordinateSystem = LPS", [-1.0, -2.0, 3.0]),
    ],
)
def test_fcsv_coordinate_system_header(tmp_path, header, expected):
    path = tmp_path / "f.fcsv"
    path.write_text(
        f"# Markups fiducial file version = 4.10\n{header}\n"
        "# columns = id,x,y,z,ow,ox,oy,oz,vis,sel,lock,label,desc,associatedNodeID\n"
        "vtkMRMLMarkupsFiducialNode_0,1,2,3,0,0,0,1,1,1,0,F-1,,\n"
    )
    np.testing.assert_array_equal(read_points(path).points, [expected])


def test_text_file_with_header_comment_and_separators(tmp_path):
    path = tmp_path / "p.txt"
    path.write_text("# SPACE=LPS\nx y z\n1, 2, 3\n4\t5\t6\n\n7;8;9\n")
    np.testing.assert_array_equal(read_points(path).points, [[-1, -2, 3], [-4, -5, 6], [-7, -8, 9]])


def test_untagged_files_follow_the_given_space(tmp_path):
    path = tmp_path / "p.npy"
    np.save(path, POINTS_RAS)
    np.testing.assert_array_equal(read_points(path, untagged_space="LPS").points, POINTS_RAS * [-1, -1, 1])


@pytest.mark.parametrize(
    "name, content, problem",
    [
        ("bad.mrk.json", "{not json", "not valid JSON"),
        ("nomarkups.mrk.json", '{"a": 1}', "no 'markups' list"),
        ("empty.mrk.json", '{"markups": [{"controlPoints": []}]}', "no defined control points"),
        (
            "short.mrk.json",
            '{"markups": [{"controlPoints": [{"position": [1, 2]}]}]}',
            "control point 1 has no 3-number",
        ),
        ("two.csv", "1,2\n", "line 1: expected 3 numbers x y z, got 2"),
        ("words.csv", "1,2,3\n4,five,6\n", "line 2: expected 3 numbers"),
        ("nan.csv", "1,2,3\nnan,1,1\n", "point(s) 2 (counted from 1) contain NaN"),
        ("empty.txt", "# nothing\n", "holds no points"),
        ("bad.fcsv", "# columns = id,x,y,z\n1,2,abc,4\n", "line 2: expected id,x,y,z"),
        ("points.xyz", "1 2 3\n", "unknown point file type"),
    ],
)
def test_malformed_files_name_file_and_problem(tmp_path, name, content, problem):
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(PointFileError) as error:
        read_points(path)
    message = str(error.value)
    assert message.startswith(str(path)) and problem in message and "\n" not in message


def test_wrong_npy_shape_and_missing_file(tmp_path):
    np.save(tmp_path / "flat.npy", np.zeros((4, 2)))
    with pytest.raises(PointFileError, match="expected an \\(N, 3\\) array, got shape \\(4, 2\\)"):
        read_points(tmp_path / "flat.npy")
    with pytest.raises(PointFileError, match="no such file"):
        read_points(tmp_path / "missing.csv")
