"""The ``ramsicp`` command line, one module per command: each has ``add_parser(commands)`` (its arguments, help and
description) and ``run(arguments) -> exit code``. This package owns the console; the library only logs.

Only what the parsers need is imported up front (numpy and light constants), so that ``--help`` and a mistyped
argument answer at once; each command imports its own machinery (scipy, VTK, the image side) when it runs.
"""

import importlib
import logging
import sys

from .. import __version__
from ..io.command_line import OneLineParser
from ._console import ReaderMayLeave, close_progress_bars
from .exit_codes import EXIT_ALARM, EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_TOO_FEW_MARKERS

#: The commands in the order ``--help`` lists them: the surgeon's workflow, then the demonstrations.
COMMANDS = (
    "ipc",
    "pivot",
    "collect",
    "register",
    "plan",
    "tcp",
    "web",
    "demo",
    "cut_demo",
    "reproduce",
    "phantom",
    "simulate_collection",
)


def build_parser():
    """The whole ``ramsicp`` parser; the command reference in Documentation/ is generated from it."""
    parser = OneLineParser(
        prog="ramsicp",
        description="CR-RAMSICP patient-to-image registration for robot-assisted long-bone osteotomy.",
        epilog=f"Exit codes: 0 done; {EXIT_BAD_INPUT} bad input (one line, before any work); "
        f"{EXIT_TOO_FEW_MARKERS} ipc --markers: fewer usable marker centres than the tool has (files written); "
        f"{EXIT_ALARM} register: the result failed a check (printed and written, led by WARNING lines); "
        f"{EXIT_INTERRUPTED} stopped by Ctrl-C (no output file half-written).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log what happens")
    commands = parser.add_subparsers(dest="command", required=True, metavar="command")
    for name in COMMANDS:
        importlib.import_module(f".{name}", __name__).add_parser(commands)
    return parser


def main(argv=None):
    """Entry point of the console script; returns the process exit code."""
    command = None
    try:
        try:
            arguments = build_parser().parse_args(argv)
        except SystemExit as stop:  # --help, --version, or an argument error already said in one line
            return stop.code
        command = arguments.command
        logging.basicConfig(
            level=logging.DEBUG if arguments.verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s"
        )
        return _run(arguments)
    except KeyboardInterrupt:
        close_progress_bars()
        print(f"ramsicp{'' if command is None else ' ' + command}: stopped by Ctrl-C", file=sys.stderr)
        return EXIT_INTERRUPTED


def _run(arguments):
    sys.stdout = ReaderMayLeave(sys.stdout)
    try:
        code = arguments.run(arguments)
        sys.stdout.flush()
        return code
    except (ValueError, OSError) as error:
        close_progress_bars()
        message = " ".join(str(error).split())
        print(f"ramsicp {arguments.command}: error: {message}", file=sys.stderr)
        return EXIT_BAD_INPUT
    finally:
        sys.stdout = sys.stdout.stream
