"""The tracker feed as it runs in Slicer's own process, where PythonQt keeps Python's lock while Qt's event loop
waits (emulated: the polling thread waits between its 20 ms polls in ``usleep`` called through ``ctypes.PyDLL``,
which keeps the lock; see ``Testing/test_slicer_host.py``).

Poses a second reaching the MRML scene (new ProbeToReference matrices) from the simulated Vega at 60 Hz, its
server started by the OpenIGTLink Bridge controller in its own process (ours) or, as before, as threads of the
polling process (baseline), measured one after the other in the same run.

Run: python benchmarks/bench_slicer_host.py [--seconds 5]
"""

import argparse
import ctypes
import sys
import tempfile
import time

import slicer

from OpenIGTLinkBridgeLib.bridge_controller import BridgeController

POLL_INTERVAL_S = 0.020


def scene():
    scene = slicer.vtkMRMLScene()
    selection = slicer.vtkMRMLSelectionNode()
    selection.SetSingletonTag("Singleton")
    scene.AddNode(selection)
    return scene


def poses_per_second(tracker_python, seconds):
    controller = BridgeController(scene(), tracker_python=tracker_python, log_directory=tempfile.mkdtemp())
    controller.parameters.trackerSource = "simulator"
    usleep = ctypes.PyDLL(None).usleep
    usleep.argtypes = [ctypes.c_uint]
    try:
        controller.start_tracker(0)
        deadline = time.monotonic() + 60
        while dict(controller.status().tools)["ProbeToTracker"] != "valid" and time.monotonic() < deadline:
            controller.poll()
            time.sleep(0.01)
        node = controller.scene.GetFirstNodeByName("ProbeToReference")
        poses = []
        node.AddObserver(node.TransformModifiedEvent, lambda caller, event: poses.append(1))
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            usleep(int(POLL_INTERVAL_S * 1e6))
            controller.poll()
        return len(poses) / seconds
    finally:
        controller.close()


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="measuring time per tracker run (default 5)")
    arguments = parser.parse_args()
    ours = poses_per_second(sys.executable, arguments.seconds)
    baseline = poses_per_second(None, arguments.seconds)
    print(f"{'tracker at 60 Hz, GUI thread holding the lock':<48}{'poses/s':>10}")
    print(f"{'  server in its own process (ours)':<48}{ours:>10.1f}")
    print(f"{'  server as threads of this process (before)':<48}{baseline:>10.1f}")
    print(f"{'  ratio':<48}{ours / baseline:>10.1f}")


if __name__ == "__main__":
    main()
