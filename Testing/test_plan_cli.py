"""``ramsicp plan`` and ``ramsicp tcp`` end to end on files: the cylinder's known endpoints in the JSON, the same
plan in robot-base coordinates, the tool path's poses, and bad input as one line with exit code 2."""

import json

import numpy as np
import pytest

from RAMSICPRegistrationLib.commands import main
from RAMSICPRegistrationLib.core.transforms import apply_transform, make_transform, rotation_about_axis
from RAMSICPRegistrationLib.io.surface_files import write_surface

from conftest import CYLINDER_RADIUS_MM as R
from conftest import cylinder_mesh

IMAGE_TO_BASE = make_transform(rotation_about_axis((1.0, -2.0, 0.5), 1.1), (420.0, -60.0, 130.0))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("plan")
    write_surface(folder / "cylinder.vtp", *cylinder_mesh())  # written in LPS, tagged: read back in RAS
    np.savetxt(folder / "image_to_robot_base.txt", IMAGE_TO_BASE)
    np.savetxt(folder / "three_by_three.txt", np.eye(3))
    np.savetxt(folder / "scaled.txt", np.diag([2.0, 2.0, 2.0, 1.0]))
    return folder


def _plan(folder, *extra):
    return ["plan", "--ipc", str(folder / "cylinder.vtp"), "--plane", "0", "0", "50", "0", "0", "1", *extra]


def test_plan_writes_the_endpoints_and_the_tool_path_in_image_and_robot_base_coordinates(files, capsys):
    out = files / "plan.json"
    arguments = _plan(files, "--depth", "0", "1", "0", "--image-to-robot-base", str(files / "image_to_robot_base.txt"))
    assert main([*arguments, "--out", str(out)]) == 0
    document = json.loads(out.read_text())
    expected = np.array([(R, 0, 50), (-R, 0, 50), (0, R, 50), (0, -R, 50)])
    np.testing.assert_allclose(document["endpoints"], expected, atol=1e-5)  # the file holds float32 vertices
    assert document["plane"]["normal"] == [0.0, 0.0, 1.0] and document["extent_mm"] is None
    poses = np.array(document["tool_path"])
    assert poses.shape[1:] == (4, 4) and len(poses) == document["tool"]["poses"]
    assert np.abs(poses[:, 2, 3] - 50.0).max() < 1e-9  # every TCP on the plane z = 50
    robot = document["robot_base"]
    np.testing.assert_allclose(robot["image_to_robot_base"], IMAGE_TO_BASE, atol=1e-12)
    np.testing.assert_allclose(robot["endpoints"], apply_transform(IMAGE_TO_BASE, expected), atol=1e-5)
    np.testing.assert_allclose(robot["tool_path"], IMAGE_TO_BASE @ poses, atol=1e-9)
    printed = capsys.readouterr().out
    assert "section exact (mesh)" in printed and "+across end    (15.00 0.00 50.00)" in printed


def test_plan_with_an_extent_a_wedge_and_a_burr(files):
    out = files / "wedge.json"
    arguments = _plan(files, "--depth", "0", "1", "0", "--extent", "20", "--wedge", "8", "--tool", "burr")
    assert main([*arguments, "--out", str(out)]) == 0
    document = json.loads(out.read_text())
    y = np.sqrt(R**2 - 10.0**2)
    corners = np.array(document["endpoints"])
    np.testing.assert_allclose(np.abs(corners[:, :2]), np.tile((10.0, y), (4, 1)), atol=1e-3)  # the corners
    assert document["tool"]["tool"] == "burr" and document["tool"]["width_mm"] == 4.0
    assert set(document["tool_path_cut"]) == {0, 1} and len(document["wedge"]["endpoints"]) == 4
    normal = np.array(document["wedge"]["plane"]["normal"])
    assert np.degrees(np.arccos(abs(normal @ (0.0, 0.0, 1.0)))) == pytest.approx(8.0)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda a, f: a[:4] + ["0", "0", "150", "0", "0", "1"], "does not cross the bone"),
        (lambda a, f: a[:4] + ["0", "0", "50", "0", "0", "0"], "normal is (0, 0, 0)"),
        (lambda a, f: a + ["--extent", "50", "--tool-width", "60"], "narrower than the 60 mm saw"),
        (lambda a, f: a + ["--image-to-robot-base", str(f / "three_by_three.txt")], "expected a 4 x 4 matrix"),
        (lambda a, f: a + ["--image-to-robot-base", str(f / "cylinder.vtp")], "give numbers only"),
        (lambda a, f: a + ["--image-to-robot-base", str(f / "scaled.txt")], "is not a rotation"),
        (lambda a, f: a + ["--image-to-robot-base", str(f / "missing.txt")], "no such file"),
        (lambda a, f: ["plan", "--ipc", str(f / "nothing.vtp"), *a[3:]], "no such file"),
    ],
)
def test_plan_bad_input_is_one_line_and_exit_2(files, capsys, change, message):
    assert main([*change(_plan(files), files), "--out", str(files / "bad.json")]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith("ramsicp plan: error:") and message in error
    assert not (files / "bad.json").exists()


def test_plan_refuses_a_folder_or_a_non_json_output_before_any_work(files, capsys):
    assert main([*_plan(files), "--out", str(files)]) == 2
    assert "is a folder" in capsys.readouterr().err
    assert main([*_plan(files), "--out", str(files / "plan.txt")]) == 2
    assert "give a file name ending in .json" in capsys.readouterr().err


def test_tcp_from_a_file_of_flange_poses(tmp_path, capsys):
    tcp, point = np.array([1.2, -0.8, 185.0]), np.array([450.0, -120.0, 210.0])
    poses = []
    for axis, degrees in (((1, 0, 0), 40), ((1, 0, 0), -40), ((0, 1, 0), 40), ((0, 1, 0), -40)):
        rotation = np.diag([1.0, -1.0, -1.0]) @ rotation_about_axis(axis, np.radians(degrees))
        poses.append(make_transform(rotation, point - rotation @ tcp))
    np.savetxt(tmp_path / "flange.txt", np.array(poses).reshape(-1, 16))
    assert main(["tcp", "--flange-poses", str(tmp_path / "flange.txt"), "--json", str(tmp_path / "tcp.json")]) == 0
    np.testing.assert_allclose(json.loads((tmp_path / "tcp.json").read_text())["tcp_in_flange_mm"], tcp, atol=1e-6)
    assert "TCP in flange    (1.20 -0.80 185.00) mm" in capsys.readouterr().out
    (tmp_path / "three.json").write_text(json.dumps(np.array(poses[:3]).tolist()))
    assert main(["tcp", "--flange-poses", str(tmp_path / "three.json")]) == 2
    assert "3 flange poses given, at least 4 needed" in capsys.readouterr().err
