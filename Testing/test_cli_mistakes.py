"""Issue 14: every ``ramsicp`` command meets a user's ordinary mistakes with one line and exit code 2, before any
work: outputs that cannot be written, numbers that make no sense, files that are empty or folders."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from RAMSICPRegistrationLib.commands import main
from RAMSICPRegistrationLib.io.file_checks import PointFileError, check_output_file, check_output_folder


def _run(argv, capsys):
    """(exit code, stdout, stderr) of ``ramsicp argv`` run in this process."""
    code = main([str(argument) for argument in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err.strip()


def _assert_one_line(code, err, command, words):
    assert code == 2, err
    assert err.startswith(f"ramsicp {command}: error:"), err
    assert "\n" not in err and "Traceback" not in err, err
    assert words in err, err


@pytest.fixture
def no_work(monkeypatch):
    """Every command's first piece of work fails the test if it is reached: the checks must come before it."""
    from OpenIGTLinkBridgeLib import plus_sequence
    from RAMSICPRegistrationLib.core import robot, tool_path
    from RAMSICPRegistrationLib.experiments import cut_trial, demo, experiments
    from RAMSICPRegistrationLib.image import volume_io
    from RAMSICPRegistrationLib.io import surface_files
    from RAMSICPRegistrationLib.simulation import package_data

    def work(*args, **kwargs):
        raise AssertionError("the command started its work before refusing its arguments")

    for module, name in (
        (demo, "run_demo"),
        (experiments, "run_experiments"),
        (volume_io, "load_volume"),
        (surface_files, "read_surface_points"),
        (package_data, "shipped_patient"),
        (plus_sequence, "read_sequence"),
        (tool_path, "plan_osteotomy"),
        (robot, "tcp_four_point"),
        (cut_trial, "run_cut_trial"),
    ):
        monkeypatch.setattr(module, name, work)


@pytest.fixture
def unwritable(tmp_path):
    """A folder in which no file can be created: read-only for a normal user; for root (who may write anywhere),
    Linux's /proc, where creating a file fails."""
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    for folder in (locked, Path("/proc")):
        try:
            (folder / "probe.txt").touch()
        except OSError:
            yield folder
            break
        (folder / "probe.txt").unlink()
    else:
        pytest.skip("no folder here refuses files (root on a system without /proc)")
    locked.chmod(0o700)


#: command, its arguments before the output, the output option, the suffix it writes. Inputs need not exist: the
#: output is refused before any input is read.
FILE_OUTPUTS = [
    ("register", ["--ipc", "i.vtp", "--ppc", "p.csv", "--markers-image", "a.fcsv", "--markers-patient", "b.fcsv"],
     "--json", ".json"),
    ("demo", [], "--json", ".json"),
    ("demo", [], "--screenshot", ".png"),
    ("demo", ["--live"], "--record", ".igs.mha"),
    ("ipc", ["ct.nrrd", "--out", "OUT"], "--labelmap", ".nrrd"),
    ("ipc", ["ct.nrrd", "--out", "OUT"], "--markers", ".mrk.json"),
    ("ipc", ["ct.nrrd", "--out", "OUT"], "--json", ".json"),
    ("ipc", ["ct.nrrd"], "--out", ".vtp"),
    ("collect", ["--recording", "r.igs.mha", "--tip", "0", "0", "0", "--out", "OUT"], "--json", ".json"),
    ("collect", ["--recording", "r.igs.mha", "--tip", "0", "0", "0"], "--out", ".csv"),
    ("plan", ["--ipc", "i.vtp", "--plane", "0", "0", "0", "0", "0", "1"], "--out", ".json"),
    ("tcp", ["--flange-poses", "poses.json"], "--json", ".json"),
]  # fmt: skip


@pytest.mark.parametrize("command, before, option, suffix", FILE_OUTPUTS)
@pytest.mark.parametrize("mistake", ["missing folder", "a folder", "unwritable folder", "wrong suffix"])
def test_every_output_file_is_checked_before_any_work(
    tmp_path, capsys, no_work, unwritable, command, before, option, suffix, mistake
):
    """Issue 14, items 6 and 7 (``demo --screenshot /missing/s.png``, ``demo --json /missing/d.json``, ``ipc
    --labelmap /missing/l.nrrd``, ``ipc --out <unwritable>`` with VTK's C++ text)."""
    path, words = {
        "missing folder": (tmp_path / "missing" / f"x{suffix}", f"the folder {tmp_path / 'missing'} does not exist"),
        "a folder": (tmp_path, "is a folder; give a file name"),
        "unwritable folder": (unwritable / f"x{suffix}", f"cannot write in {unwritable}"),
        "wrong suffix": (tmp_path / "x.data", "give a file name ending in"),
    }[mistake]
    if mistake == "wrong suffix" and option == "--markers":
        words = "keeps each marker's number and status"
    arguments = [str(tmp_path / "ok.vtp") if value == "OUT" and command == "ipc" else value for value in before]
    arguments = [str(tmp_path / "ok.csv") if value == "OUT" else value for value in arguments]
    code, out, err = _run([command, *arguments, option, path], capsys)
    _assert_one_line(code, err, command, words)
    assert out == "" and "ERROR: In" not in err and "0x" not in err  # no VTK C++ text with a pointer
    assert list(tmp_path.glob("ok.*")) == []  # no other output was written either


@pytest.mark.parametrize(
    "command, before", [("phantom", []), ("reproduce", ["--experiment", "fig8"]), ("cut-demo", [])]
)
@pytest.mark.parametrize("mistake", ["a file", "unwritable folder", "under a file"])
def test_every_output_folder_is_checked_before_any_work(
    tmp_path, capsys, no_work, unwritable, command, before, mistake
):
    """``phantom --out <a file>`` said ``[Errno 17] File exists`` after the phantom was made; ``reproduce --out``
    failed after three minutes of experiments."""
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    path, words = {
        "a file": (a_file, "is a file; give a folder"),
        "unwritable folder": (unwritable / "new", f"cannot write in {unwritable}"),
        "under a file": (a_file / "new", f"{a_file} is a file, so the folder cannot be created there"),
    }[mistake]
    code, out, err = _run([command, *before, "--out", path], capsys)
    _assert_one_line(code, err, command, words)
    assert not (unwritable / "new").exists()


@pytest.mark.parametrize(
    "argv, words",
    [
        (["register", "--fle", "-1"], "argument --fle: '-1': give a positive number of mm"),
        (["register", "--fle", "nan"], "argument --fle: 'nan': give a positive number of mm"),
        (["register", "--fle", "inf"], "argument --fle: 'inf': give a positive number of mm"),
        (["register", "--scale", "nan"], "argument --scale: 'nan': give a finite number"),
        (["register", "--scales", "1", "x", "0.2"], "argument --scales: 'x': give a finite number"),
        (["demo", "--trials", "0"], "argument --trials: '0': give a whole number, 1 or more"),
        (["demo", "--seed", "-1"], "argument --seed: '-1': give a whole number, 0 or more"),
        (["ipc", "ct.nrrd", "--out", "o.vtp", "--threshold", "nan"], "'nan': give a number of HU or 'auto'"),
        (["ipc", "ct.nrrd", "--out", "o.vtp", "--spacing", "-1"], "argument --spacing: '-1': give a positive"),
        (["reproduce", "--subjects", "0"], "argument --subjects: '0': give a whole number, 1 or more"),
        (["collect", "--recording", "r.mha", "--tip", "nan", "0", "0", "--out", "p.csv"], "'nan': give a finite"),
        (["demo", "--live", "--json", "d.json"], "the live demo (--live) writes neither"),
        (["cut-demo", "--seed", "-1"], "argument --seed: '-1': give a whole number, 0 or more"),
        (["cut-demo", "--speed", "0"], "argument --speed: '0': give a speed above 0 mm/s"),
        (["cut-demo", "--speed", "nan"], "argument --speed: 'nan': give a speed above 0 mm/s"),
        (["plan", "--ipc", "i.vtp", "--plane", *"000001", "--out", "p.json", "--wedge", "nan"], "'nan': give a finite"),
    ],
)  # fmt: skip
def test_numbers_that_make_no_sense_are_one_line(capsys, no_work, argv, words):
    """Issue 14, items 2 and 8: ``--fle -1`` printed negative predicted TREs, ``--fle nan`` printed NaNs, ``phantom
    --noise -5`` said ``scale < 0``. Now one line naming the option, before anything is read."""
    required = ["--ipc", "i.vtp", "--ppc", "p.csv", "--markers-image", "a.fcsv", "--markers-patient", "b.fcsv"]
    code, out, err = _run(argv + (required if argv[0] == "register" else []), capsys)
    _assert_one_line(code, err, argv[0], words)
    assert err.endswith(f"(see ramsicp {argv[0]} --help)") or "--live" in words


def test_a_missing_command_or_option_is_one_line(capsys):
    for argv, command, words in (
        ([], "", "the following arguments are required: command"),
        (["register"], " register", "the following arguments are required: --ipc, --ppc"),
        (["frobnicate"], "", "invalid choice: 'frobnicate'"),
    ):
        code, out, err = _run(argv, capsys)
        assert code == 2 and err.startswith(f"ramsicp{command}: error:") and words in err and "\n" not in err


def test_empty_files_and_folders_given_for_files_are_named(tmp_path, capsys):
    """Issue 14, item 8: ``ramsicp ipc empty.nrrd`` said ``cannot read as a volume (StopIteration: )`` and
    ``register --ipc <a folder>`` said ``no such file``."""
    (tmp_path / "empty.nrrd").touch()
    (tmp_path / "empty.vtp").touch()
    code, _, err = _run(["ipc", tmp_path / "empty.nrrd", "--out", tmp_path / "ipc.vtp"], capsys)
    _assert_one_line(code, err, "ipc", "empty.nrrd: is empty (0 bytes)")
    (tmp_path / "cut.nrrd").write_text("NRRD0004\ntype: short\n")
    code, _, err = _run(["ipc", tmp_path / "cut.nrrd", "--out", tmp_path / "ipc.vtp"], capsys)
    _assert_one_line(code, err, "ipc", "cut.nrrd: cannot read as a volume (")
    assert "StopIteration" not in err
    others = ["--ppc", "p.csv", "--markers-image", "a.fcsv", "--markers-patient", "b.fcsv"]
    code, _, err = _run(["register", "--ipc", tmp_path, *others], capsys)
    _assert_one_line(code, err, "register", f"{tmp_path}: is a folder; give the surface file itself")
    code, _, err = _run(["register", "--ipc", tmp_path / "empty.vtp", *others], capsys)
    _assert_one_line(code, err, "register", "empty.vtp: is empty (0 bytes)")
    assert "vtkXMLPolyDataReader" not in err


def test_the_output_checks_themselves(tmp_path, unwritable):
    """The one helper every command uses: None passes; a writable new file or folder passes and nothing is made."""
    folder = tmp_path / "outputs"
    folder.mkdir()
    check_output_file(None, "--json", (".json",))
    check_output_file(folder / "result.json", "--json", (".json",))
    check_output_folder(folder / "new" / "deeper", "--out")
    assert sorted(folder.iterdir()) == []  # the write test leaves nothing behind
    with pytest.raises(PointFileError, match="--json result.txt: give a file name ending in .json or .txt.json"):
        check_output_file(Path("result.txt"), "--json", (".json", ".txt.json"))
    with pytest.raises(PointFileError, match=f"cannot write in {unwritable}"):
        check_output_file(unwritable / "result.json", "--json")


def test_help_and_argument_errors_load_neither_scipy_nor_vtk():
    """``ramsicp --help`` took 2 s loading everything; the parser needs only numpy and light constants (the times
    are in ``benchmarks/bench_cli_startup.py``)."""
    script = (
        "import sys\n"
        "from RAMSICPRegistrationLib import commands\n"
        "commands.build_parser()\n"
        "heavy = ('scipy', 'vtk', 'vtkmodules', 'matplotlib', 'slicer', 'nrrd', 'nibabel', 'pydicom', 'serial',"
        " 'tqdm')\n"
        "print(sorted({name.split('.')[0] for name in sys.modules} & set(heavy)))\n"
    )
    loaded = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True).stdout
    assert loaded.strip() == "[]"
    completed = subprocess.run(
        [sys.executable, "-m", "RAMSICPRegistrationLib.commands", "register", "--fle", "-1"],
        capture_output=True,
        text=True,
    )
    assert completed.returncode == 2 and completed.stderr.count("\n") == 1 and "argument --fle" in completed.stderr


def test_unwritable_fixture_is_really_unwritable(unwritable):
    with pytest.raises(OSError):
        with open(os.path.join(unwritable, "x.txt"), "w") as stream:
            stream.write("x")


def test_an_output_never_overwrites_an_input(tmp_path, capsys, no_work):
    """``ipc ct.nrrd --labelmap ct.nrrd`` would have replaced the CT by its labelmap, ``register --json`` a markups
    file given as an input (``.mrk.json`` ends in ``.json``)."""
    ct, markers = tmp_path / "ct.nrrd", tmp_path / "markers.mrk.json"
    ct.write_bytes(b"NRRD0004\n")
    markers.write_text("{}")
    code, _, err = _run(["ipc", ct, "--out", tmp_path / "ipc.vtp", "--labelmap", ct], capsys)
    _assert_one_line(code, err, "ipc", f"--labelmap {ct}: is an input of this command")
    others = ["--ipc", "i.vtp", "--ppc", "p.csv", "--markers-patient", "b.fcsv"]
    code, _, err = _run(["register", *others, "--markers-image", markers, "--json", markers], capsys)
    _assert_one_line(code, err, "register", "give another name for the output")
    assert ct.read_bytes() == b"NRRD0004\n" and markers.read_text() == "{}"


@pytest.mark.parametrize("command", [["demo", "--trials", "200"], ["phantom", "--out", "{tmp}/phantom"]])
def test_ctrl_c_is_one_line_and_exit_130_with_nothing_written(tmp_path, command):
    """Ctrl-C during a long run printed a 20-line traceback; now one line, exit 130 (128 + SIGINT), no output."""
    import signal
    import time

    arguments = [part.replace("{tmp}", str(tmp_path)) for part in command]
    json_out = tmp_path / "demo.json"
    if command[0] == "demo":
        arguments += ["--json", str(json_out)]
    process = subprocess.Popen(
        [sys.executable, "-m", "RAMSICPRegistrationLib.commands", *arguments],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # Ctrl-C's default action, whoever started the tests: a shell starts background jobs with SIGINT ignored,
        # which a child inherits (Python then never raises KeyboardInterrupt)
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    time.sleep(4.0)  # well into the work: the imports take about 1 s
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=60)
    assert process.returncode == 130, (out, err)
    assert err in (f"ramsicp {command[0]}: stopped by Ctrl-C\n", "ramsicp: stopped by Ctrl-C\n")
    assert not json_out.exists() and not (tmp_path / "phantom").exists()
