"""``ramsicp web``: the surgeon's navigation view served to a browser (trame-slicer) over the same controller as
the Slicer module."""

import sys
from pathlib import Path


def add_parser(commands):
    web = commands.add_parser(
        "web",
        help="the navigation view in a web browser (trame-slicer): tracker, pivot, points, registration, verification",
        description="Serve the surgeon's navigation view to a browser on this machine (a second screen or a tablet). "
        "The page opens no file: the scene comes from --scene or --demo, and saves go into --output.",
    )
    source = web.add_mutually_exclusive_group()
    source.add_argument(
        "--demo",
        action="store_true",
        help="the demo patient's CT phantom and, without --tracker, a simulated tracker (pivot, then 40 touches)",
    )
    source.add_argument("--scene", type=Path, help="a Slicer scene to navigate on (.mrb, or .mrml with its files)")
    web.add_argument(
        "--tracker", metavar="HOST:PORT", help="OpenIGTLink server of the tracker (PLUS or ramsicp-tracker-server)"
    )
    web.add_argument(
        "--host", default="127.0.0.1", help="address to serve the page on (default 127.0.0.1: this machine only)"
    )
    web.add_argument(
        "--port", type=int, default=8080, help="port to serve the page on (default 8080; 0: any free port)"
    )
    web.add_argument(
        "--output",
        type=Path,
        default=Path("ramsicp-web"),
        help="folder for the autosaved points and the saved scenes (default ./ramsicp-web)",
    )
    web.set_defaults(run=run)


def run(arguments):
    try:
        import trame_slicer  # noqa: F401
    except ImportError:
        raise ValueError(
            "the browser view needs trame-slicer: pip install 'ramsicp-navigator[web]' (Python >= 3.10)"
        ) from None
    from ..web.app import (
        NavigationWebApp,
        check_output_directory,
        check_port_free,
        check_scene_path,
        parse_tracker_address,
    )

    tracker = None if arguments.tracker is None else parse_tracker_address(arguments.tracker)
    if arguments.scene is not None:
        check_scene_path(arguments.scene)
    check_output_directory(arguments.output)
    if not 0 <= arguments.port <= 65535:
        raise ValueError(f"--port {arguments.port}: give a port from 1 to 65535 (0: any free port)")
    check_port_free(arguments.host, arguments.port)  # before the slow set-up, so a busy port fails at once
    if arguments.host not in ("127.0.0.1", "localhost", "::1"):
        print(
            f"ramsicp web: warning: serving on {arguments.host}: anyone who can reach this address can drive the "
            "navigation; use a closed network, or the default 127.0.0.1",
            file=sys.stderr,
        )
    app = NavigationWebApp(arguments.output)
    if arguments.scene is not None:
        app.load_scene(arguments.scene)
    app.start_workflow()
    if arguments.demo:
        print("ramsicp web: the demo patient's CT phantom and its IPC (30-60 s the first time) ...", flush=True)
        app.add_demo_patient()
    if tracker is not None:
        app.connect_tracker(*tracker)
    elif arguments.demo:
        app.start_simulator()

    def ready(url):
        print(f"RAMSICP Navigator web view: {url}  (Ctrl+C to stop)", flush=True)

    app.serve(arguments.host, arguments.port, on_ready=ready)
    return 0
