"""The browser view driven as a person would, in a real headless Chromium: for the tests and the benchmark.

* ``start_web_view`` runs ``ramsicp web ...`` in its own process and waits for the address it prints;
* ``launch_chromium`` starts Debian's Chromium through Playwright for Python (``executable_path``: no browser
  download is possible or needed), offline, with a new empty profile;
* ``view_image`` finds a Slicer view's ``<img>`` on the page (``ThreeD``, ``Red``, ``Green``, ``Yellow``).

Playwright is imported only here, and only when a browser is launched.
"""

import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

#: Chromium's switches: no sandbox (root in CI), /tmp instead of a small /dev/shm, and nothing that reaches out.
CHROMIUM_ARGS = (
    "--no-sandbox",
    "--disable-dev-shm-usage",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)
READY_PREFIX = "RAMSICP Navigator web view: "


def chromium_executable():
    """The Chromium binary of Debian's ``chromium`` package (under its lib folder, not the wrapper script on PATH);
    RuntimeError saying how to install it when missing."""
    try:
        listing = subprocess.run(["dpkg", "-L", "chromium"], capture_output=True, text=True, check=False).stdout
    except FileNotFoundError:
        listing = ""
    for line in listing.split():
        path = Path(line)
        if path.name == "chromium" and "lib" in path.parts and path.is_file():
            return str(path)
    raise RuntimeError("Debian's chromium package is not installed: apt-get install chromium (.ci/run does)")


def launch_chromium(playwright):
    """A headless Chromium browser (Playwright ``Browser``) from Debian's package."""
    return playwright.chromium.launch(executable_path=chromium_executable(), args=list(CHROMIUM_ARGS), headless=True)


def start_web_view(arguments, timeout_s=600.0, log_path=None):
    """Run ``ramsicp web <arguments>`` (add ``--port 0`` for any free port); returns (process, url) once the page
    is served. RuntimeError with the command's output when it exits or stays silent for ``timeout_s``."""
    command = [sys.executable, "-m", "RAMSICPRegistrationLib.commands", "web", *map(str, arguments)]
    log = open(log_path, "w") if log_path is not None else subprocess.DEVNULL  # noqa: SIM115 (the process keeps it)
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=log, text=True)
    lines = queue.Queue()

    def read():
        for line in process.stdout:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=read, name="ramsicp web output", daemon=True).start()
    deadline = time.monotonic() + timeout_s
    seen = []
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=max(0.1, deadline - time.monotonic()))
        except queue.Empty:
            break
        if line is None:
            break
        seen.append(line)
        if line.startswith(READY_PREFIX):
            return process, line[len(READY_PREFIX) :].split()[0]
    stop_web_view(process)
    raise RuntimeError(f"ramsicp web did not serve its page; it printed: {''.join(seen)!r}")


def stop_web_view(process, timeout_s=20.0):
    """End the view's process as Ctrl+C does; kill it if it does not stop in time. Returns its exit code."""
    import signal

    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
    return process.returncode


NUMBER = r"-?\d+\.\d+"


class NavigationPage:
    """The navigation page in a Playwright ``Page``, read and clicked as a person does; every wait is for what the
    page shows (``timeout_ms`` each), never a fixed sleep."""

    def __init__(self, page, timeout_ms=60_000):
        self.page = page
        page.set_default_timeout(timeout_ms)

    def text(self, selector):
        return self.page.locator(selector).inner_text()

    def numbers(self, selector):
        """The decimal numbers in an element's text, (K,) array."""
        import re

        import numpy as np

        return np.array([float(value) for value in re.findall(NUMBER, self.text(selector))])

    def wait_for_text(self, selector, pattern):
        """Wait until the element's text matches the regular expression ``pattern``."""
        self.page.wait_for_function(
            "([selector, pattern]) => { const element = document.querySelector(selector);"
            " return element !== null && new RegExp(pattern).test(element.innerText); }",
            arg=[selector, pattern],
        )

    def wait_for_count(self, selector, minimum):
        """Wait until the first whole number in the element's text is at least ``minimum``."""
        self.page.wait_for_function(
            r"""([selector, minimum]) => { const element = document.querySelector(selector);
                const found = element && element.innerText.match(/\d+/);
                return Boolean(found) && Number(found[0]) >= minimum; }""",
            arg=[selector, minimum],
        )

    def wait_for_tool(self, name, state):
        """Wait until a tracking chip reads e.g. 'ProbeToTracker: valid'."""
        self.wait_for_text(f"#tool-{name}", f"{name}: {state}$")

    def wait_for_tip_at(self, point, tolerance_mm=0.1):
        """Wait until the tip readout (reference frame, mm) shows ``point`` (3,)."""
        self.page.wait_for_function(
            """([point, tolerance]) => {
                const element = document.querySelector('#tip-reference');
                if (element === null) return false;
                const values = (element.innerText.match(/-?\\d+\\.\\d+/g) || []).map(Number);
                return values.length === 3 && values.every((value, axis) => Math.abs(value - point[axis]) <= tolerance);
            }""",
            arg=[[float(value) for value in point], tolerance_mm],
        )

    def button(self, name):
        return self.page.get_by_role("button", name=name)

    def click(self, name):
        """Click a button once the page enables it."""
        button = self.button(name)
        button.wait_for()
        self.page.wait_for_function("(button) => !button.disabled", arg=button.element_handle())
        button.click()

    def view_pixels(self, view):
        """(H, W, 3) int RGB of a view's image as the page shows it."""
        import io

        import numpy as np
        from PIL import Image

        return np.asarray(Image.open(io.BytesIO(view_image(self.page, view).screenshot())).convert("RGB"), dtype=int)

    # -- the workflow, as a surgeon clicks it ------------------------------------------------------------------
    def pivot(self, probe, divot, poses=300):
        """Swivel ``probe`` (a HandHeldProbe) in ``divot`` while the page records ``poses`` poses."""
        probe.pivot(divot)
        self.click("Start pivot")
        self.wait_for_count("#pivot-poses", poses)
        self.click("Stop pivot")
        self.wait_for_text("#tip-offset", NUMBER)

    def collect(self, probe, points):
        """Touch each point and collect it from the page, waiting for the tip readout and the point count."""
        start = int(self.text("#probe-points"))
        for number, point in enumerate(points, start=start + 1):
            probe.touch(point)
            self.wait_for_tip_at(point)
            self.click("Collect point")
            self.wait_for_text("#probe-points", f"^{number}$")

    def choose(self, name, value):
        """Pick ``value`` in the select ``name`` ('method' or 'policy') as a person does, and wait until the page
        shows it chosen (the server wrote it into the parameter node and sent it back)."""
        self.page.locator(f"#{name}").click(force=True)
        self.page.get_by_role("option", name=value, exact=True).click()
        self.page.wait_for_function(
            "([name, value]) => { const select = document.querySelector('#' + name).closest('.v-select');"
            " return select !== null && select.innerText.split('\\n').includes(value); }",
            arg=[name, value],
        )

    def register(self):
        """Register from the page; returns the (FRE, TRE) texts it shows."""
        self.click("Register")
        self.wait_for_text("#fre", NUMBER)
        return self.text("#fre"), self.text("#tre")


def view_image(page, view):
    """Playwright locator of a view's ``<img>``: view is 'ThreeD', 'Red', 'Green' or 'Yellow'."""
    return page.locator(f"div:has(> #view-{view}) img.image-display-area")


def wait_for_views(page, views=("ThreeD", "Red", "Green", "Yellow"), timeout_ms=120_000):
    """Wait until every view shows a loaded image of its own size on the page (the first frames have come)."""
    for view in views:
        view_image(page, view).wait_for(state="visible", timeout=timeout_ms)
    page.wait_for_function(
        """(views) => views.every(view => {
            const image = document.querySelector(`div:has(> #view-${view}) img.image-display-area`);
            return image && image.complete && image.naturalWidth > 0
                && Math.abs(image.naturalWidth - image.clientWidth) <= 2;
        })""",
        arg=list(views),
        timeout=timeout_ms,
    )
