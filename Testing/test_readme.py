"""The README's Python example runs as written, on files like those ``ramsicp ipc`` and a probe session write."""

import re
from pathlib import Path

import numpy as np

from RAMSICPRegistrationLib.core.registration import register
from RAMSICPRegistrationLib.io.marker_files import write_markers
from RAMSICPRegistrationLib.io.point_files import write_points
from RAMSICPRegistrationLib.io.surface_files import write_surface

README = Path(__file__).resolve().parents[1] / "README.md"


def test_the_python_example_runs(tmp_path, monkeypatch, tibia_patient):
    """Issue 14: the example passed ``read_points(...)`` (a PointSet) where (N, 3) arrays are needed."""
    block = re.search(r"^## Python\n\n```python\n(.*?)^```", README.read_text(encoding="utf-8"), re.S | re.M)[1]
    trial = tibia_patient.simulate_trial(np.random.default_rng(3), marker_fle_mm=1.0)
    write_surface(tmp_path / "bone.vtp", tibia_patient.ipc[::10])
    write_points(tmp_path / "probe_points.mrk.json", trial.ppc)
    write_markers(tmp_path / "markers_ct.mrk.json", trial.markers_image, [1, 2, 3, 4], ["ok"] * 4)
    write_points(tmp_path / "markers_tool.fcsv", trial.markers_patient)
    write_points(tmp_path / "planned_cut.mrk.json", trial.targets_image)
    monkeypatch.chdir(tmp_path)
    names = {}
    exec(compile(block, "README.md", "exec"), names)
    result, paper = names["result"], names["paper"]
    assert result.method == "cr-fused" and paper.method == "cr-ramsicp" and paper.scale_policy == "rms-plateau"
    direct = register(tibia_patient.ipc[::10], trial.ppc, trial.markers_image, trial.markers_patient)
    np.testing.assert_allclose(result.reference_to_image, direct.reference_to_image, atol=1e-6)
    np.testing.assert_allclose(names["cut_points"], trial.targets_image, atol=1e-9)
    assert result.alarms == () and len(result.predicted_error_mm(trial.targets_image)) == 4


def test_every_name_the_python_section_lists_is_public():
    """The paragraph after the example names the public API; each name must come from the package's top."""
    import RAMSICPRegistrationLib

    paragraph = re.search(r"^Files: (.*?)\n\n", README.read_text(encoding="utf-8"), re.S | re.M)[1]
    names = set(re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", paragraph)) - {"vtkMRMLScalarVolumeNode"}  # Slicer's
    assert len(names) > 25
    assert sorted(names - set(RAMSICPRegistrationLib.__all__)) == []
