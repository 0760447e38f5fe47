"""The README's tour and the Python guide's example run as written: the tour's shell block on the shipped data,
the example on files like those ``ramsicp ipc`` and a probe session write."""

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from RAMSICPRegistrationLib.core.registration import register
from RAMSICPRegistrationLib.core.transforms import apply_transform
from RAMSICPRegistrationLib.io.marker_files import write_markers
from RAMSICPRegistrationLib.io.point_files import read_points, write_points
from RAMSICPRegistrationLib.io.surface_files import write_surface

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PYTHON_GUIDE = ROOT / "Documentation" / "python.md"


def test_the_readme_tour_runs_end_to_end(tmp_path):
    """The tour's block, run by bash with ``ramsicp`` this checkout's command line: every step exits 0, the
    registration is within 0.5 mm of the phantom's truth at the targets and the plan's endpoints lie on the
    phantom's bone."""
    block = re.search(
        r"^## A tour on shipped data\n.*?```bash\n(.*?)^```", README.read_text(encoding="utf-8"), re.S | re.M
    )[1]
    assert block.count("ramsicp ") >= 5
    script = f'ramsicp() {{ "{sys.executable}" -m RAMSICPRegistrationLib.commands "$@"; }}\nset -euo pipefail\n{block}'
    completed = subprocess.run(["bash", "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert completed.returncode == 0, completed.stderr[-2000:]
    case = tmp_path / "case"
    truth = json.loads((case / "truth.json").read_text())
    result = json.loads((case / "registration.json").read_text())
    assert result["alarms"] == [] and result["tre_mm"] < 0.5
    reference_to_image = np.array(truth["reference_to_image"])
    targets_patient = read_points(case / "session" / "targets_patient.mrk.json").points
    registered = apply_transform(np.array(result["reference_to_image"]), targets_patient)
    assert np.abs(registered - apply_transform(reference_to_image, targets_patient)).max() < 0.5
    plan = json.loads((case / "plan.json").read_text())
    targets_image = read_points(case / "session" / "targets_image.mrk.json").points
    distances = np.linalg.norm(np.array(plan["endpoints"])[:, None] - targets_image[None], axis=2).min(axis=1)
    assert distances.max() < 2.0  # the plan's section ends lie on the bone next to the targets it was placed through


def test_the_python_example_runs(tmp_path, monkeypatch, tibia_patient):
    """Issue 14: the example passed ``read_points(...)`` (a PointSet) where (N, 3) arrays are needed."""
    block = re.search(r"^```python\n(.*?)^```", PYTHON_GUIDE.read_text(encoding="utf-8"), re.S | re.M)[1]
    trial = tibia_patient.simulate_trial(np.random.default_rng(3), marker_fle_mm=1.0)
    write_surface(tmp_path / "bone.vtp", tibia_patient.ipc[::10])
    write_points(tmp_path / "probe_points.mrk.json", trial.ppc)
    write_markers(tmp_path / "markers_ct.mrk.json", trial.markers_image, [1, 2, 3, 4], ["ok"] * 4)
    write_points(tmp_path / "markers_tool.fcsv", trial.markers_patient)
    write_points(tmp_path / "planned_cut.mrk.json", trial.targets_image)
    monkeypatch.chdir(tmp_path)
    names = {}
    exec(compile(block, "python.md", "exec"), names)
    result, paper = names["result"], names["paper"]
    assert result.method == "cr-fused" and paper.method == "cr-ramsicp" and paper.scale_policy == "rms-plateau"
    direct = register(tibia_patient.ipc[::10], trial.ppc, trial.markers_image, trial.markers_patient)
    np.testing.assert_allclose(result.reference_to_image, direct.reference_to_image, atol=1e-6)
    np.testing.assert_allclose(names["cut_points"], trial.targets_image, atol=1e-9)
    assert result.alarms == () and len(result.predicted_error_mm(trial.targets_image)) == 4


def test_every_name_the_python_guide_lists_is_public():
    """The paragraph after the example names the public API; each name must come from the package's top."""
    import RAMSICPRegistrationLib

    paragraph = re.search(r"^Files: (.*?)(?:\n\n|\Z)", PYTHON_GUIDE.read_text(encoding="utf-8"), re.S | re.M)[1]
    names = set(re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", paragraph)) - {"vtkMRMLScalarVolumeNode"}  # Slicer's
    assert len(names) > 25
    assert sorted(names - set(RAMSICPRegistrationLib.__all__)) == []


def test_every_guide_the_readme_links_exists_and_the_readme_is_short():
    text = README.read_text(encoding="utf-8")
    links = set(re.findall(r"\]\((Documentation/[^)#]+)", text))
    assert len(links) >= 10 and all((ROOT / link).is_file() for link in links), sorted(links)
    assert len(text.splitlines()) <= 250


def _github_anchor(heading):
    """The anchor GitHub gives a heading: lower case, punctuation but '-' and '_' dropped, spaces to '-'."""
    text = re.sub(r"[`*]", "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def _anchors(page):
    text = re.sub(r"```.*?```", "", page.read_text(encoding="utf-8"), flags=re.S)
    return {_github_anchor(line.lstrip("#")) for line in text.splitlines() if line.startswith("#")}


def test_every_link_between_the_pages_and_every_anchor_resolves():
    pages = [README, *sorted((ROOT / "Documentation").glob("*.md"))]
    broken = []
    for page in pages:
        text = re.sub(r"```.*?```", "", page.read_text(encoding="utf-8"), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue  # a web address
            path, _, anchor = target.partition("#")
            linked = (page.parent / path).resolve() if path else page
            if not linked.exists():
                broken.append(f"{page.name}: {target} (no such file)")
            elif anchor and linked.suffix == ".md" and anchor not in _anchors(linked):
                broken.append(f"{page.name}: {target} (no such heading)")
    assert not broken, broken
    assert _github_anchor("The tracker in Slicer's process") == "the-tracker-in-slicers-process"
