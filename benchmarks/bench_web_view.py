"""Tracker pose -> updated image in the browser: latency and frame rate of the browser view's 3D view at 60 Hz.

Two servers, each read by a real headless Chromium, fed by the same tracker chain (Vega simulator -> our NDI driver
-> our OpenIGTLink server at 60 Hz) whose probe this script moves (``HandHeldProbe``):

* ours: ``ramsicp web --demo --tracker ...`` after a pivot, 8 points and a registration done from the page, so the
  needle moves over the CT and the three slices follow the tip;
* baseline: a bare trame-slicer app (SlicerApp, one remote 3D view, the same receiver polled the same way, a needle
  model under ProbeToReference; no CT, no slices, no panel, no controller).

Latency: the probe jumps between two touch points; for each jump, the time from the pose change (this process's
clock) to the first image of the 3D view whose pixels differ, as the page receives and decodes it (the page's clock;
both are this machine's clock). Frame rate: images per second of the 3D view while the probe slides steadily.
The bare view renders after every tracker frame (each transform update makes Slicer's displayable managers ask for a
render); ours only when the needle moved. Frames are counted when their pixels differ from the previous one, so
both rates are distinct pictures per second, capped by trame-rca's target of 30 frames per second.

Run: python benchmarks/bench_web_view.py [--jumps 60] [--seconds 8]
"""

import argparse
import asyncio
import sys
import tempfile
import time

import numpy as np

# A frame's time and a checksum of its pixels, recorded by the page for the 3D view's <img> as it loads.
WATCH_FRAMES = """() => {
    window.frames3d = [];
    const canvas = document.createElement('canvas');
    const context = canvas.getContext('2d', {willReadFrequently: true});
    document.addEventListener('load', (event) => {
        const image = event.target;
        if (!(image instanceof HTMLImageElement) || !image.matches('div:has(> #view-ThreeD) img')) return;
        const time = Date.now();
        canvas.width = image.naturalWidth / 2; canvas.height = image.naturalHeight / 2;
        context.drawImage(image, 0, 0, canvas.width, canvas.height);
        // 32-bit words and integer arithmetic: the page must not spend the CPU that the views are measured with.
        const words = new Uint32Array(context.getImageData(0, 0, canvas.width, canvas.height).data.buffer);
        let sum = 0;
        for (let index = 0; index < words.length; index += 1) sum = (Math.imul(sum, 31) + words[index]) | 0;
        window.frames3d.push([time, sum]);
    }, true);
}"""


def measure(page, probe, points, jumps, seconds):
    """(latencies ms (jumps,), frames per second) of the 3D view on a page already showing the needle, the probe
    held on ``points[0]``."""
    page.evaluate(WATCH_FRAMES)
    latencies = []
    for jump in range(jumps):
        target = points[(jump + 1) % 2]
        time.sleep(0.5)  # let the view settle on the last pose
        before = page.evaluate("() => window.frames3d.length ? window.frames3d[window.frames3d.length - 1][1] : null")
        start_ms = time.time() * 1000.0
        probe.touch(target)
        arrived = page.wait_for_function(
            "([start, before]) => { const frame = window.frames3d.find(f => f[0] >= start && f[1] !== before);"
            " return frame ? frame[0] : null; }",
            arg=[start_ms, before],
            timeout=10_000,
        ).json_value()
        latencies.append(arrived - start_ms)
    probe.slide(points[0], points[1], period_s=2.0)
    time.sleep(1.0)
    page.evaluate("() => { window.frames3d.length = 0; }")
    time.sleep(seconds)
    frames = page.evaluate("() => window.frames3d.map(f => f[1])")
    distinct = sum(1 for index, value in enumerate(frames) if index == 0 or value != frames[index - 1])
    probe.touch(points[0])
    return np.array(latencies), distinct / seconds


# -- the bare trame-slicer baseline (run in its own process: --bare TRACKER_PORT) ---------------------------------
def serve_bare(tracker_port):
    from RAMSICPRegistrationLib.web.app import POLL_INTERVAL_S, TARGET_FPS, check_port_free, configure_environment

    configure_environment()
    from trame.app import get_server
    from trame_slicer.core import LayoutManager, SlicerApp
    from trame_slicer.rca_view import register_rca_factories
    from trame_slicer.views import Layout, LayoutDirection, ViewLayoutDefinition
    from trame_vuetify.ui.vuetify3 import SinglePageLayout

    from OpenIGTLinkBridgeLib.live_scenario import PROBE_TIP_MM
    from OpenIGTLinkBridgeLib.receiver import TrackerReceiver
    from RAMSICPRegistrationLib.web.panel import three_d_view_gutter
    from RAMSICPRegistrationLib.web.scene_display import NEEDLE_COLOUR, needle_poly_data

    server = get_server(None, client_type="vue3")
    slicer_app = SlicerApp()
    register_rca_factories(
        slicer_app.view_manager, server, three_d_view_ui_f=three_d_view_gutter, target_fps=TARGET_FPS, blur_fps=None
    )
    layout = LayoutManager(slicer_app.scene, slicer_app.view_manager, server)
    layout.register_layout("3D", Layout(LayoutDirection.Vertical, [ViewLayoutDefinition.threed_view()]))
    layout.set_layout("3D")
    for view in slicer_app.view_manager.get_views():
        view.render_window().SetMultiSamples(0)
    receiver = TrackerReceiver(slicer_app.scene, port=tracker_port)
    probe = slicer_app.scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ProbeToReference")
    tip = slicer_app.scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ProbeTipToProbe")
    tip.SetAndObserveTransformNodeID(probe.GetID())
    needle = slicer_app.scene.AddNewNodeByClass("vtkMRMLModelNode", "Needle")
    needle.SetAndObservePolyData(needle_poly_data(PROBE_TIP_MM))
    needle.CreateDefaultDisplayNodes()
    needle.GetDisplayNode().SetColor(*NEEDLE_COLOUR)
    from RAMSICPRegistrationLib.navigation.navigation import set_matrix

    translation = np.eye(4)
    translation[:3, 3] = PROBE_TIP_MM
    set_matrix(tip, translation)
    needle.SetAndObserveTransformNodeID(tip.GetID())
    with SinglePageLayout(server, full_height=True) as page, page.content:
        layout.initialize_layout_grid(page)

    async def poll():
        while True:
            receiver.poll()
            await asyncio.sleep(POLL_INTERVAL_S)

    port = check_port_free("127.0.0.1", 0)

    def ready(**_):
        asyncio.ensure_future(poll())
        print(f"RAMSICP Navigator web view: http://127.0.0.1:{port}/ (bare)", flush=True)

    server.controller.on_server_ready.add(ready)
    for _ in range(400):  # the first poses, so the camera can frame the needle
        receiver.poll()
        time.sleep(0.005)
    slicer_app.display_manager.reset_views()
    server.start(host="127.0.0.1", port=port, open_browser=False, show_connection_info=False, timeout=0)


def start_bare(tracker_port):
    import queue
    import subprocess
    import threading

    process = subprocess.Popen(
        [sys.executable, __file__, "--bare", str(tracker_port)], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL
    )
    lines = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line) for line in process.stdout], daemon=True).start()
    line = lines.get(timeout=300).decode()
    return process, line.split(": ", 1)[1].split()[0]


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--jumps", type=int, default=60, help="probe jumps per server (default 60)")
    parser.add_argument("--seconds", type=float, default=8.0, help="seconds of steady motion for the frame rate")
    parser.add_argument("--bare", type=int, help=argparse.SUPPRESS)
    arguments = parser.parse_args()
    if arguments.bare is not None:
        return serve_bare(arguments.bare)

    from playwright.sync_api import sync_playwright

    from OpenIGTLinkBridgeLib.live_scenario import HandHeldProbe, default_touch_points, serve_hand_held_probe
    from RAMSICPRegistrationLib.web.headless import (
        NavigationPage,
        launch_chromium,
        start_web_view,
        stop_web_view,
        wait_for_views,
    )

    points = default_touch_points()
    jump_points = (points[0], points[20])
    probe = HandHeldProbe()
    probe.touch(points[0])
    simulator, tracker = serve_hand_held_probe(probe)
    port = tracker.address[1]
    results = {}
    with tempfile.TemporaryDirectory() as output, sync_playwright() as playwright:
        browser = launch_chromium(playwright)
        for name in ("ours", "bare"):
            if name == "ours":
                arguments_web = ["--demo", "--tracker", f"127.0.0.1:{port}", "--port", 0, "--output", output]
                process, url = start_web_view(arguments_web)
            else:
                process, url = start_bare(port)
            try:
                page = NavigationPage(browser.new_page(viewport={"width": 1500, "height": 950}))
                page.page.goto(url)
                views = ("ThreeD", "Red", "Green", "Yellow") if name == "ours" else ("ThreeD",)
                wait_for_views(page.page, views)
                if name == "ours":  # the needle over the CT: pivot, 8 points, register
                    page.pivot(probe, points[0])
                    page.collect(probe, points[::5])
                    page.register()
                probe.touch(points[0])
                results[name] = measure(page.page, probe, jump_points, arguments.jumps, arguments.seconds)
                page.page.close()
            finally:
                stop_web_view(process)
        browser.close()
    tracker.stop()
    simulator.stop()

    print(f"tracker pose -> image of the 3D view in the browser; tracker at 60 Hz, {arguments.jumps} jumps per server")
    print(f"{'':<24}{'ours':>10}{'bare':>10}{'ours/bare':>11}")
    for label, value in (
        ("latency p50 (ms)", lambda r: np.percentile(r[0], 50)),
        ("latency p99 (ms)", lambda r: np.percentile(r[0], 99)),
        ("latency max (ms)", lambda r: r[0].max()),
        ("distinct frames / s", lambda r: r[1]),
    ):
        ours, bare = value(results["ours"]), value(results["bare"])
        print(f"{label:<24}{ours:>10.1f}{bare:>10.1f}{ours / bare:>11.2f}")
    print("target for the 3D view: p99 <= 150 ms, >= 15 frames / s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
