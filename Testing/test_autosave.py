"""Nothing the surgeon collected is lost: the autosave survives a failure mid-write and a ``kill -9``.

Tested the way it fails: a write that dies half-way (injected), and a collecting process killed without warning
while it keeps writing its points file. The file must always parse and hold every point reported as collected.
"""

import json
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from RAMSICPRegistrationLib.io import point_files
from RAMSICPRegistrationLib.io.point_files import read_points, write_points_atomic


def test_a_write_that_dies_half_way_leaves_the_previous_file_intact(tmp_path, monkeypatch):
    path = tmp_path / "ProbePoints.mrk.json"
    before = np.arange(30.0).reshape(10, 3)
    write_points_atomic(path, before)

    def dies_half_way(target, points, labels):
        text = json.dumps({"markups": [{"controlPoints": [{"position": list(p)} for p in points]}]})
        target.write_text(text[: len(text) // 2])  # the disk holds half a file when the process dies
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(point_files, "_write_markups_json", dies_half_way)
    with pytest.raises(OSError, match="No space left"):
        write_points_atomic(path, np.vstack([before, [[1.0, 2.0, 3.0]]]))
    np.testing.assert_array_equal(read_points(path).points, before)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ProbePoints.mrk.json"]  # no stray partial file


def test_a_new_folder_and_every_format_are_written_whole(tmp_path):
    points = np.array([[1.25, -2.5, 3.0], [4.0, 5.5, -6.75]])
    for name in ("a.mrk.json", "b.fcsv", "c.csv", "d.npy"):
        path = tmp_path / "new" / "folder" / name
        write_points_atomic(path, points)
        np.testing.assert_array_equal(read_points(path).points, points)
    assert not [p for p in (tmp_path / "new" / "folder").iterdir() if ".partial" in p.name]


COLLECTOR = textwrap.dedent(
    """
    import sys
    import numpy as np
    import slicer
    from RAMSICPRegistrationLib.navigation.controller import NavigationController
    from RAMSICPRegistrationLib.navigation.navigation import set_matrix

    scene = slicer.vtkMRMLScene()
    controller = NavigationController(scene, autosave_directory=sys.argv[1])
    probe = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ProbeToReference")
    tip = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ProbeTipToProbe")
    controller.parameters.probeToReference, controller.parameters.probeTipToProbe = probe, tip
    for index in range(100000):
        pose = np.eye(4)
        pose[:3, 3] = (index, 2.0 * index, -0.5 * index)  # point i is at (i, 2i, -i/2)
        set_matrix(probe, pose)
        if controller.run("collect_point") != index:
            raise SystemExit(controller.status().message)
        print(index, flush=True)  # reported to the surgeon as collected
    """
)


@pytest.mark.parametrize("kill_after", [150, 400, 700])
def test_every_point_reported_survives_a_kill_9_of_the_collecting_process(tmp_path, kill_after):
    pytest.importorskip("slicer", reason="slicer-core (real MRML) needs Python >= 3.10")
    child = subprocess.Popen(
        [sys.executable, "-c", COLLECTOR, str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    reported = -1
    for line in child.stdout:
        reported = int(line)
        if reported + 1 >= kill_after:
            break
    os.kill(child.pid, signal.SIGKILL)  # no clean-up, no flush: as a crash or a pulled plug
    child.wait()
    assert reported + 1 == kill_after, child.stderr.read()
    saved = read_points(tmp_path / "ProbePoints.mrk.json").points  # always a whole, parseable file
    assert len(saved) >= kill_after  # every reported point, perhaps one more written before the kill
    index = np.arange(len(saved))
    np.testing.assert_array_equal(saved, np.column_stack([index, 2.0 * index, -0.5 * index]))
