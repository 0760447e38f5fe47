"""Streaming the tool path to the robot over OpenIGTLink on loopback: how long a path takes to reach the robot
simulator and be accepted, against the least any client and server can do with the same bytes.

* ours: ``RobotLink.send_path`` -> ``RobotSimulator`` (decode every message, assemble and check the path, answer
  ACCEPTED) -> ``RobotLink.wait_for('ACCEPTED')``;
* baseline: a bare socket sends the same bytes to a bare server that reads until it has them all and answers one
  byte.

Paths: the demo tibia's cut (``ramsicp cut-demo``), and longer zigzags. Medians of 21 runs, interleaved.

Run: python benchmarks/bench_robot_link.py
"""

import socket
import threading
import time

import numpy as np

from OpenIGTLinkBridgeLib.robot_link import RobotLink, encode_path
from OpenIGTLinkBridgeLib.robot_simulator import RobotSimulator
from RAMSICPRegistrationLib.core.transforms import make_transform, rotation_about_axis

RUNS = 21


def tibia_path():
    from RAMSICPRegistrationLib.experiments.cut_trial import _plan
    from RAMSICPRegistrationLib.simulation.package_data import shipped_patient

    patient, vertices, triangles = shipped_patient("right-tibia")
    _, path = _plan(patient, vertices, triangles, "right-tibia")
    return path.poses + make_transform(translation=(-150.0, -250.0, -250.0)) - np.eye(4)  # within the robot's reach


def zigzag(count):
    rotation = rotation_about_axis((1.0, 2.0, 0.5), 2.0)
    steps = np.arange(count)
    positions = np.column_stack((steps // 40 * 8.0, np.zeros(count), np.abs((steps % 80) - 40) * 2.0))
    return np.array([make_transform(rotation, (300.0, 0.0, 200.0) + rotation @ p) for p in positions])


class BareServer:
    """Reads until ``expected`` bytes arrived, then answers one byte; one client at a time."""

    def __init__(self):
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.address = self.listener.getsockname()
        self.expected = 0
        threading.Thread(target=self.serve, daemon=True).start()

    def serve(self):
        while True:
            try:
                client, _ = self.listener.accept()
            except OSError:
                return
            with client:
                client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                while True:
                    received = 0
                    while received < self.expected:
                        chunk = client.recv(1 << 16)
                        if not chunk:
                            break
                        received += len(chunk)
                    if received < self.expected:
                        break
                    client.sendall(b"!")


def main():
    robot = RobotSimulator(reach_mm=5000.0, realtime=True, rate_hz=10.0, speed_mm_s=1e-3).start()
    bare = BareServer()
    print(f"{'path':<22}{'poses':>7}{'bytes':>10}   {'median (ms)':>12}{'poses/s':>10}   {'baseline (ms)':>14}   ratio")
    for name, poses in (("demo tibia cut", tibia_path()), ("zigzag", zigzag(2000)), ("zigzag", zigzag(20000))):
        data = encode_path(poses, "bench")
        bare.expected = len(data)
        ours, baseline = [], []
        link = RobotLink(*robot.address[:2])
        plain = socket.create_connection(bare.address[:2])
        plain.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for _ in range(RUNS):
            clock = time.perf_counter()
            link.send_path(poses)
            assert link.wait_for(("ACCEPTED", "REFUSED"), 30.0) == "ACCEPTED", link.status_text
            ours.append(time.perf_counter() - clock)
            link.stop()  # the robot stops at once, ready for the next path
            assert link.wait_for(("STOPPED",), 5.0) == "STOPPED"
            clock = time.perf_counter()
            plain.sendall(data)
            assert plain.recv(1) == b"!"
            baseline.append(time.perf_counter() - clock)
        link.close()
        plain.close()
        median, floor = np.median(ours), np.median(baseline)
        print(
            f"{name:<22}{len(poses):>7}{len(data):>10}   {1000 * median:>12.2f}{len(poses) / median:>10.0f}   "
            f"{1000 * floor:>14.2f}   {median / floor:5.1f}"
        )
    robot.stop()


if __name__ == "__main__":
    main()
