"""``ramsicp-tracker-server``: the program that serves a tracker over OpenIGTLink as PLUS does.

It chooses the source (an NDI tracker on the network or a serial line, the Vega simulator, or a recorded PLUS
sequence file replayed at its timing), checks every argument and file before anything starts, and runs
``igtl_server.TrackerServer`` until Ctrl-C or the end of a replay. The server itself knows nothing of where its
poses come from, so this module, not ``igtl_server``, imports the replay and the simulator.
"""

import errno
import logging
import math
import signal
import socket
import sys
import threading
from pathlib import Path

from RAMSICPRegistrationLib.io.command_line import EXIT_BAD_INPUT, OneLineParser

from .igtl_server import DEFAULT_NAMES, DEFAULT_PORT, DEFAULT_RATE_HZ, TrackerServer, TrackerSource
from .ndi_driver import NDI_PORT, parse_ndi_address

logger = logging.getLogger(__name__)

MAX_RATE_HZ = 1000.0


def _parser():
    parser = OneLineParser(
        prog="ramsicp-tracker-server",
        description="Stream an NDI tracker (or its simulator, or a recorded PLUS sequence file) over OpenIGTLink "
        "as PLUS does: ProbeToTracker and ReferenceToTracker as TRANSFORM messages, the tracker's state as STATUS, "
        "to every client (3D Slicer with SlicerOpenIGTLink, or the OpenIGTLinkBridge module).",
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--ndi", metavar="HOST[:PORT]", help=f"NDI Vega on the network (port {NDI_PORT} by default)")
    source.add_argument("--serial", metavar="DEV", help="NDI Polaris on a serial line, e.g. /dev/ttyUSB0")
    source.add_argument("--simulate", action="store_true", help="start the Vega simulator on loopback and use it")
    source.add_argument(
        "--replay",
        metavar="FILE",
        type=Path,
        help="replay a PLUS sequence file (.igs.mha, .seq.mha) at its recorded timing, starting with the first "
        "client; the server exits when the replay is done",
    )
    parser.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    parser.add_argument(
        "--port", type=int, default=DEFAULT_PORT, help=f"OpenIGTLink port to serve on (default {DEFAULT_PORT})"
    )
    parser.add_argument(
        "--rate",
        type=float,
        default=DEFAULT_RATE_HZ,
        help=f"tracker polls per second (default {DEFAULT_RATE_HZ:g}); each new tracker frame is sent once, "
        "so poll at least as fast as the tracker measures",
    )
    parser.add_argument(
        "--header-version",
        type=int,
        choices=(1, 2),
        default=1,
        help="OpenIGTLink header version (default 1: invalid poses are not sent; 2: sent with TransformStatus)",
    )
    parser.add_argument(
        "--probe-name", default=DEFAULT_NAMES["Probe"], help="device name of the probe's pose (default ProbeToTracker)"
    )
    parser.add_argument(
        "--reference-name",
        default=DEFAULT_NAMES["Reference"],
        help="device name of the reference body's pose (default ReferenceToTracker)",
    )
    parser.add_argument("--reference-rom", type=Path, help="reference body .rom file (default NDI 8700339)")
    parser.add_argument("--probe-rom", type=Path, help="probe .rom file (default NDI 8700340)")
    parser.add_argument(
        "--tool-rom",
        type=Path,
        help="also track the cutting tool's markers (.rom file), sent as --tool-name; for the live guidance of a cut",
    )
    parser.add_argument(
        "--tool-name", default="ToolToTracker", help="device name of the cutting tool's pose (default ToolToTracker)"
    )
    parser.add_argument("--loop", action="store_true", help="with --replay: start again after the last frame")
    parser.add_argument(
        "--speed", type=float, default=1.0, help="with --replay: playback speed (default 1, the recorded speed)"
    )
    parser.add_argument(
        "--rename",
        action="append",
        metavar="OLD=NEW",
        help="with --replay: rename a recorded transform, e.g. Stylus=Probe sends StylusToTracker as "
        "ProbeToTracker (repeatable)",
    )
    return parser


def _check_arguments(arguments):
    """Every argument and file checked before anything starts; raises ValueError with one line."""
    if not 0 <= arguments.port <= 65535:
        raise ValueError(f"--port {arguments.port}: give a port from 1 to 65535 (OpenIGTLink's is {DEFAULT_PORT})")
    # (--port 0 is accepted: the system picks a free port, which the log line gives)
    if not (math.isfinite(arguments.rate) and 0 < arguments.rate <= MAX_RATE_HZ):
        raise ValueError(f"--rate {arguments.rate:g}: give a rate above 0 and at most {MAX_RATE_HZ:g} per second")
    if arguments.replay is None and (arguments.loop or arguments.rename or arguments.speed != 1.0):
        raise ValueError("--loop, --speed and --rename only apply to --replay FILE")
    if arguments.ndi is not None:
        try:
            arguments.ndi_address = parse_ndi_address(arguments.ndi)
        except ValueError as error:
            raise ValueError(f"--ndi {error}") from None
    for option, path in (
        ("--reference-rom", arguments.reference_rom),
        ("--probe-rom", arguments.probe_rom),
        ("--tool-rom", arguments.tool_rom),
    ):
        if path is not None:
            _check_rom(option, path)


def _check_rom(option, path):
    if not path.exists():
        raise ValueError(f"{option} {path}: no such file")
    if path.is_dir():
        raise ValueError(f"{option} {path}: is a folder; give the tool's .rom file")
    try:
        data = path.read_bytes()
    except OSError as error:
        raise ValueError(f"{option} {path}: cannot be read ({error.strerror or error})") from None
    if not data.startswith(b"NDI") or not 64 <= len(data) <= 1024:
        raise ValueError(
            f"{option} {path}: not an NDI tool definition (a .rom file starts with 'NDI' and has 64 to 1024 "
            f"bytes; this one has {len(data)}); export the tool's .rom from NDI's software"
        )


def _listen(host, port):
    try:
        return socket.create_server((host, port))
    except OSError as error:
        if error.errno == errno.EADDRINUSE:
            raise ValueError(
                f"port {port} on {host} is in use (another ramsicp-tracker-server or PlusServer?); stop it or "
                "give another --port"
            ) from None
        raise ValueError(f"cannot serve on {host}:{port} ({error.strerror or error})") from None


def _stop_on_terminate():
    """SIGTERM (a shell stopping the server: ``tracker_process.TrackerProcess.stop``, ``kill``) ends the server as
    Ctrl-C does, closing the tracker and the clients, instead of killing it mid-frame."""

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    if threading.current_thread() is threading.main_thread():  # Python allows handlers in the main thread only
        signal.signal(signal.SIGTERM, interrupt)


def main(argv=None):
    """``ramsicp-tracker-server (--ndi HOST[:PORT] | --serial DEV | --simulate | --replay FILE)``."""
    _stop_on_terminate()
    arguments = _parser().parse_args(argv)
    try:
        _check_arguments(arguments)
        source = None
        if arguments.replay is not None:
            from .plus_sequence import read_sequence
            from .replay import ReplaySource, parse_renames

            recording = read_sequence(arguments.replay)
            source = ReplaySource(recording, arguments.speed, arguments.loop, parse_renames(arguments.rename))
        listener = _listen(arguments.host, arguments.port)
    except ValueError as error:
        print(f"ramsicp-tracker-server: error: {' '.join(str(error).split())}", file=sys.stderr)
        return EXIT_BAD_INPUT
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
    simulator = None
    if source is None:
        from RAMSICPRegistrationLib.io.ndi_tools import tool_rom_path

        from .ndi_driver import open_tracker

        roms = {
            "Reference": arguments.reference_rom or tool_rom_path("8700339"),
            "Probe": arguments.probe_rom or tool_rom_path("8700340"),
        }
        if arguments.tool_rom is not None:
            roms["Tool"] = arguments.tool_rom
        host, port = arguments.ndi_address if arguments.ndi else (None, NDI_PORT)
        if arguments.simulate:
            from .live_scenario import demo_simulator

            simulator, _ = demo_simulator()
            simulator.start()
            host, port = simulator.address[0], simulator.address[1]

        def connect():
            return open_tracker(host, port, arguments.serial, roms)

        names = {"Probe": arguments.probe_name, "Reference": arguments.reference_name, "Tool": arguments.tool_name}
        source = TrackerSource(connect, names, arguments.rate)
    server = TrackerServer(source=source, listener=listener, header_version=arguments.header_version)
    logger.info("serving OpenIGTLink on %s:%d", *server.address[:2])
    try:
        server.serve()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
        if simulator is not None:
            simulator.stop()
    if server.finished.is_set():
        logger.info("%s", server.source.status[2] if server.source.status else "done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
