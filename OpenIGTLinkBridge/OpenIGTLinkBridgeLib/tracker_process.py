"""``ramsicp-tracker-server`` in its own process, started and stopped by a shell, its log kept (Qt-free).

Why a process: inside Slicer, PythonQt keeps Python's lock while Qt's event loop waits, so Python threads advance
only while the GUI thread runs Python. A tracker server and simulator running as threads of Slicer's process then
starve: with the module's 20 ms poll timer, 15 to 18 of the tracker's 60 poses a second reached the scene
(``Testing/test_slicer_host.py`` emulates that loop). In a process of its own the server runs at the tracker's
rate, and the module connects to it as to PLUS.

Slicer starts Python programs this way itself: ``slicer.util._executePythonModule`` (Slicer 5.6 to 5.10) runs
``PythonSlicer -m <module>`` (``shutil.which("PythonSlicer")``: Slicer's launcher puts it on the PATH) with
``subprocess`` in Slicer's environment, the console window hidden on Windows (``launchConsoleProcess``). The
shell hands that executable in; plain Python hands in ``sys.executable``. The child finds our packages through
``PYTHONPATH`` (an extension's modules are on Slicer's ``sys.path``, not on its environment's).

The child's output (the server's log) goes to a file, read back without waiting by ``log_lines()``: no pipe to
drain, no thread. ``stop()`` asks the child to end (SIGTERM, which ``tracker_server`` turns into a clean stop), and
the child also ends by itself when its standard input closes, i.e. when the process that started it has gone
(``python -m OpenIGTLinkBridgeLib.tracker_process``), so a crashed Slicer leaves no server holding the port and the
tracker.
"""

import logging
import os
import signal
import subprocess
import sys
import threading
from collections import deque
from pathlib import Path

logger = logging.getLogger(__name__)

#: The log lines kept for the shell to show.
LOG_LINES = 200
STOP_TIMEOUT_S = 3.0


def package_paths():
    """The folders holding our two packages, for the child's ``PYTHONPATH``."""
    import OpenIGTLinkBridgeLib
    import RAMSICPRegistrationLib

    folders = []
    for package in (OpenIGTLinkBridgeLib, RAMSICPRegistrationLib):
        folder = str(Path(package.__file__).resolve().parent.parent)
        if folder not in folders:
            folders.append(folder)
    return folders


class TrackerProcess:
    """One ``ramsicp-tracker-server`` process.

    Args:
        python: the Python executable to run it with (Slicer: ``PythonSlicer``).
        arguments: the server's arguments, e.g. ``["--simulate", "--port", "18944"]``.
        log_path: the file its output goes to (created; replaced when it exists).
    """

    def __init__(self, python, arguments, log_path):
        self.python, self.arguments, self.log_path = str(python), [str(a) for a in arguments], Path(log_path)
        self.process = None
        self._log = deque(maxlen=LOG_LINES)
        self._read_to = 0
        self._partial = b""

    @property
    def command(self):
        return [self.python, "-m", "OpenIGTLinkBridgeLib.tracker_process", *self.arguments]

    def start(self):
        """Start the process; returns self. Raises OSError saying which executable could not be started."""
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        environment = dict(os.environ)
        environment["PYTHONPATH"] = os.pathsep.join([*package_paths(), environment.get("PYTHONPATH", "")]).rstrip(
            os.pathsep
        )
        environment["PYTHONUNBUFFERED"] = "1"  # each log line reaches the file when it is written
        options = {}
        if os.name == "nt":  # as slicer.util.launchConsoleProcess: no console window
            startup = subprocess.STARTUPINFO()
            startup.dwFlags |= subprocess.STARTF_USESHOWWINDOW
            startup.wShowWindow = 0
            options["startupinfo"] = startup
        with open(self.log_path, "wb") as log:
            try:
                self.process = subprocess.Popen(
                    self.command,
                    stdin=subprocess.PIPE,
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    env=environment,
                    **options,
                )
            except OSError as error:
                raise OSError(
                    f"cannot start the tracker server with {self.python} ({error.strerror or error}); check that "
                    "this Python executable exists"
                ) from None
        self._log.clear()
        self._read_to, self._partial = 0, b""
        logger.info("tracker server started (pid %d): %s", self.process.pid, " ".join(self.command))
        return self

    @property
    def running(self):
        return self.process is not None and self.process.poll() is None

    @property
    def exit_code(self):
        """The process's exit code once it has ended, else None."""
        return None if self.process is None else self.process.poll()

    def log_lines(self):
        """The last ``LOG_LINES`` lines of its log, with what was written since the last call; never waits."""
        try:
            with open(self.log_path, "rb") as log:
                log.seek(self._read_to)
                data = log.read()
        except OSError:
            return list(self._log)
        self._read_to += len(data)
        *lines, self._partial = (self._partial + data).split(b"\n")
        self._log.extend(line.decode("utf-8", "replace").rstrip("\r") for line in lines)
        return list(self._log)

    def stop(self, timeout_s=STOP_TIMEOUT_S):
        """Ask the process to end and wait for it (it closes the tracker and its clients within a fraction of a
        second); kill it when it does not end within ``timeout_s``. Returns its exit code."""
        if self.process is None:
            return None
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                logger.warning("tracker server (pid %d) did not stop within %g s: killed", self.process.pid, timeout_s)
                self.process.kill()
                self.process.wait()
        if self.process.stdin is not None:
            self.process.stdin.close()
        self.log_lines()
        return self.process.returncode


def _stop_when_the_parent_goes():
    """End this process (as Ctrl-C does) when standard input closes: the process that started it has gone."""
    import _thread

    def watch():
        try:  # the raw descriptor, not sys.stdin: a buffered reader's lock would stall the interpreter's exit
            while os.read(0, 1 << 10):
                pass
        except OSError:
            pass
        if os.name == "posix":  # a real SIGINT: it also wakes a main thread blocked in a system call
            os.kill(os.getpid(), signal.SIGINT)
        else:  # sets the flag the main thread checks between bytecodes (no signal to send to oneself on Windows)
            _thread.interrupt_main()

    threading.Thread(target=watch, name="parent watch", daemon=True).start()


def _main(argv=None):
    """``python -m OpenIGTLinkBridgeLib.tracker_process <ramsicp-tracker-server arguments>``."""
    from . import tracker_server

    # A parent that ignores SIGINT (an application, a test runner) passes that on through exec, and Python then
    # leaves Ctrl-C ignored: this process must stop on it, as the parent watch and the Stop button rely on.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    _stop_when_the_parent_goes()
    return tracker_server.main(argv)


if __name__ == "__main__":
    sys.exit(_main())
