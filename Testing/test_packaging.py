"""The extension's packaging: the Extensions Index descriptions and the CTest registration of this suite.

* Slicer 5.6's extension build and index read only ``.s4ext`` description files, 5.8 on the JSON ones: both ship,
  with the fields of Slicer 5.6's ``SlicerExtensionDescriptionSpec.cmake``, and say the same as ``CMakeLists.txt``;
* the index's checkers (ExtensionsIndex ``scripts/check_description_files.py``, branches 5.6 to main) accept the
  names: the repository's starts with "Slicer", the extension's does not and is the CMake project's;
* CTest runs this suite with the Slicer build's Python (``PYTHON_EXECUTABLE``, Slicer's PythonSlicer) and writes
  no cache or bytecode into the source tree: the registration is configured with the real ``cmake`` and the
  command CTest would run is run on a copy of the sources.
"""

import json
import os
import re
import shutil
import subprocess
import sys
import urllib.parse
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXTENSION = "RAMSICPNavigator"

#: Slicer 5.6's Extensions/CMake/SlicerExtensionDescriptionSpec.cmake: required, then optional metadata.
S4EXT_REQUIRED = ("scm", "scmurl", "scmrevision")
S4EXT_OPTIONAL = ("depends", "build_subdirectory", "homepage", "contributors", "category", "iconurl")
S4EXT_OPTIONAL += ("description", "screenshoturls", "enabled", "status")


def parse_s4ext(path):
    """As ExtensionsIndex 5.6's ``parse_s4ext``: first token the keyword, the rest of the line the value."""
    metadata = {}
    for line in path.read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        fields = [field.strip() for field in line.split(" ", 1)]
        metadata[fields[0]] = fields[1] if len(fields) == 2 else None
    return metadata


def cmake_settings():
    """{name: value} of the top-level CMakeLists.txt's ``set(EXTENSION_... "...")`` lines, and its project name."""
    text = (ROOT / "CMakeLists.txt").read_text()
    settings = dict(re.findall(r'^set\((EXTENSION_\w+) "([^"]*)"\)', text, flags=re.MULTILINE))
    settings["project"] = re.search(r"^project\(\s*([^\s)]+)", text, flags=re.MULTILINE).group(1)
    return settings


def repository_name(url):
    """As the index's ``check_git_repository_name``: the last path segment of the scm url, without .git."""
    return os.path.splitext(urllib.parse.urlsplit(url.strip().strip("/")).path.split("/")[-1])[0]


def test_both_descriptions_ship_and_say_what_cmake_says():
    s4ext = parse_s4ext(ROOT / f"{EXTENSION}.s4ext")
    catalog = json.loads((ROOT / f"{EXTENSION}.json").read_text())
    cmake = cmake_settings()
    assert set(s4ext) == set(S4EXT_REQUIRED + S4EXT_OPTIONAL)
    assert all(s4ext[name] for name in S4EXT_REQUIRED)
    assert s4ext["scm"] == catalog["scm_type"] == "git"
    assert s4ext["scmurl"] == catalog["scm_url"] and s4ext["scmrevision"] == catalog["scm_revision"]
    assert s4ext["depends"] == cmake["EXTENSION_DEPENDS"] == "NA" and catalog["build_dependencies"] == []
    assert s4ext["build_subdirectory"] == "." and s4ext["enabled"] == "1"
    assert s4ext["category"] == catalog["category"] == cmake["EXTENSION_CATEGORY"]
    for field, setting in (
        ("homepage", "EXTENSION_HOMEPAGE"),
        ("contributors", "EXTENSION_CONTRIBUTORS"),
        ("iconurl", "EXTENSION_ICONURL"),
        ("description", "EXTENSION_DESCRIPTION"),
        ("screenshoturls", "EXTENSION_SCREENSHOTURLS"),
    ):
        assert s4ext[field] == cmake[setting], field
    assert cmake["EXTENSION_HOMEPAGE"].startswith(catalog["scm_url"].removesuffix(".git"))


def test_the_index_checkers_accept_the_names():
    """ExtensionsIndex 5.6 and 5.8 want 'slicer' in the repository's name; 5.10 and main want it to start with
    'Slicer' and the extension's name (the description file's, which must be the CMake project's) not to."""
    catalog = json.loads((ROOT / f"{EXTENSION}.json").read_text())
    s4ext = parse_s4ext(ROOT / f"{EXTENSION}.s4ext")
    for url in (catalog["scm_url"], s4ext["scmurl"]):
        assert urllib.parse.urlsplit(url).scheme in ("git", "https")
        assert repository_name(url) == "SlicerRAMSICPNavigator"
        assert repository_name(url).startswith("Slicer")
    assert cmake_settings()["project"] == EXTENSION and not EXTENSION.lower().startswith("slicer")
    assert b"\r" not in (ROOT / f"{EXTENSION}.json").read_bytes()  # the JSON checker wants LF line endings
    homepage = cmake_settings()["EXTENSION_HOMEPAGE"]
    for module in ("RAMSICPRegistration", "OpenIGTLinkBridge"):
        assert f'DOCUMENTATION_URL = "{homepage}#' in (ROOT / module / f"{module}.py").read_text()


def _testing_block():
    """The ``if(BUILD_TESTING) ... endif()`` block of the top-level CMakeLists.txt that registers the pytest suite."""
    text = (ROOT / "CMakeLists.txt").read_text()
    start = text.index("if(BUILD_TESTING)")
    end = text.index("\nendif()", start) + len("\nendif()")
    block = text[start:end]
    assert "RAMSICPNavigatorPytest" in block
    return block


def test_ctest_runs_the_suite_with_the_slicer_builds_python_and_writes_nothing_into_the_sources(tmp_path):
    """Configure the registration with cmake (``PYTHON_EXECUTABLE`` as Slicer's configuration sets it; here this
    Python), read the command, folder and environment CTest would use (``ctest --show-only=json-v1``), run that
    command on a copy of the sources with one small test module, and check that the packages came from the copy
    and that the copy holds no ``.pytest_cache`` or ``__pycache__`` afterwards."""
    block = _testing_block()
    assert "${PYTHON_EXECUTABLE} -m pytest" in block and ".venv" not in block
    cmake, ctest = shutil.which("cmake"), shutil.which("ctest")
    assert cmake and ctest, "cmake and ctest are needed (Debian: apt-get install cmake)"
    source = tmp_path / "source"
    for folder in ("RAMSICPRegistration", "OpenIGTLinkBridge", "Testing"):
        shutil.copytree(ROOT / folder, source / folder, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    shutil.copy(ROOT / "pyproject.toml", source / "pyproject.toml")
    (source / "CMakeLists.txt").write_text(
        "cmake_minimum_required(VERSION 3.16.3...3.22.6)\nproject(RAMSICPNavigator NONE)\nenable_testing()\n"
        f"set(BUILD_TESTING ON)\n{block}\n"
    )
    (source / "Testing" / "test_where_from.py").write_text(
        "import sys\n\nimport OpenIGTLinkBridgeLib\nimport RAMSICPRegistrationLib\n\n\n"
        "def test_the_packages_come_from_the_sources():\n"
        f"    assert RAMSICPRegistrationLib.__file__.startswith({str(source)!r})\n"
        f"    assert OpenIGTLinkBridgeLib.__file__.startswith({str(source)!r})\n"
        f"    assert sys.executable == {sys.executable!r}\n"
    )
    build = tmp_path / "build"
    subprocess.run(
        [cmake, "-S", source, "-B", build, f"-DPYTHON_EXECUTABLE={sys.executable}"], check=True, capture_output=True
    )
    shown = json.loads(
        subprocess.run([ctest, "--show-only=json-v1"], cwd=build, check=True, capture_output=True).stdout
    )
    (test,) = [entry for entry in shown["tests"] if entry["name"] == "RAMSICPNavigatorPytest"]
    command = test["command"]
    properties = {entry["name"]: entry["value"] for entry in test["properties"]}
    assert command[:4] == [sys.executable, "-m", "pytest", "-q"] and "no:cacheprovider" in command
    assert command[-1] == str(source / "Testing")
    environment = dict(os.environ)
    environment.update(line.split("=", 1) for line in properties["ENVIRONMENT"])
    assert environment["PYTHONDONTWRITEBYTECODE"] == "1"
    subset = [
        *command[:-1],
        str(source / "Testing" / "test_where_from.py"),
        str(source / "Testing" / "test_metrics.py"),
    ]
    result = subprocess.run(
        subset, cwd=properties["WORKING_DIRECTORY"], env=environment, capture_output=True, text=True
    )
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    assert re.search(r"\d+ passed", result.stdout)
    written = [
        path for path in source.rglob("*") if path.name in ("__pycache__", ".pytest_cache") or path.suffix == ".pyc"
    ]
    assert written == []
    assert Path(properties["WORKING_DIRECTORY"]) == build


@pytest.mark.parametrize("name", ["RAMSICPRegistration", "OpenIGTLinkBridge"])
def test_the_modules_self_tests_stay_registered_with_slicer(name):
    """The modules' own tests run inside Slicer (slicer_add_python_unittest), as before."""
    cmake = (ROOT / name / "CMakeLists.txt").read_text()
    assert "slicer_add_python_unittest(SCRIPT ${MODULE_NAME}.py)" in cmake
