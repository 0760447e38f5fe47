"""A stand-in for the robot controller (the paper's UR5): an OpenIGTLink endpoint that accepts a tool path,
moves a simulated tool-centre point (TCP) along it at a set speed and reports its pose back (``robot_link``'s
protocol, over a real socket).

The robot is told its TCP (``tcp_in_flange``, from the four-point calibration, ``core.robot.tcp_four_point``) and
moves its flange so that this TCP follows the path; the tool's real TCP (``true_tcp_in_flange``) may differ, as may
each reached flange position (``repeatability_mm``, RMS). It reports, as a real controller does, the TCP its
kinematics compute from the reached flange and the TCP it was told. A tracker (``live_scenario.robot_tool_poses``)
sees the real tool. Motion runs in steps of ``1 / rate_hz`` of simulated time, one report each: the TCP advances
``speed_mm_s / rate_hz`` per report whatever the machine's load, and with ``realtime`` the reports are paced at
``rate_hz`` (without it they go as fast as the client reads, for tests).

A path is refused (REFUSED, with the reason) when it breaks the protocol, holds a pose that is not rigid, lies
beyond the robot's reach, or arrives while the robot moves. A STOP message, or the client going away, stops the
robot where it is (STOPPED).

Run it alone with ``python -m OpenIGTLinkBridgeLib.robot_simulator --port 18945 --speed 20``.
"""

import argparse
import logging
import select
import socket
import threading
import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from . import igtl_messages as igtl
from .igtl_server import BackgroundServing
from .robot_link import PATH_DEVICE, POSE_DEVICE, ROBOT_PORT, STATUS_DEVICE, STOP, PathAssembler, PathError

logger = logging.getLogger(__name__)

#: Reach of a UR5 from the centre of its base (mm).
UR5_REACH_MM = 850.0
#: A pose received as float32 is rigid when its rotation is orthonormal to this tolerance.
RIGID_TOLERANCE = 1e-4
#: Turning the tool counts as this many mm of travel per radian (a pure re-orientation takes time too).
TURN_MM_PER_RAD = 100.0


@dataclass
class _Motion:
    """A path being followed: its poses, the arc length at each pose, and how far along the TCP is (mm)."""

    poses: np.ndarray
    arc_mm: np.ndarray
    travelled_mm: float = 0.0
    passed: int = 0


class RobotSimulator(BackgroundServing):
    """The robot controller's OpenIGTLink server, one client at a time; ``start()`` runs it in a thread.

    Args:
        host, port: where to listen (port 0: a free port; ``address`` says which).
        speed_mm_s: TCP speed along the path (mm/s of simulated time).
        rate_hz: motion steps and pose reports per second.
        tcp_in_flange: the TCP the controller was told, (3,) mm in the flange frame.
        true_tcp_in_flange: where the tool's centre point really is (default: as told).
        repeatability_mm: RMS 3-D error of each reached flange position.
        reach_mm: the largest distance of a pose from the base.
        start_pose: the TCP's pose (4, 4) in robot-base coordinates before any path.
        realtime: pace the reports in wall-clock time.
        seed: of the repeatability noise.
    """

    def __init__(
        self,
        host="127.0.0.1",
        port=0,
        speed_mm_s=20.0,
        rate_hz=125.0,
        tcp_in_flange=(0.0, 0.0, 0.0),
        true_tcp_in_flange=None,
        repeatability_mm=0.0,
        reach_mm=UR5_REACH_MM,
        start_pose=None,
        realtime=True,
        seed=0,
    ):
        if not (np.isfinite(speed_mm_s) and speed_mm_s > 0 and np.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"robot speed {speed_mm_s} mm/s and rate {rate_hz} Hz: give values above 0")
        self.speed_mm_s, self.rate_hz, self.reach_mm, self.realtime = speed_mm_s, rate_hz, reach_mm, realtime
        self.told_tcp = _translation(tcp_in_flange)
        self.true_tcp = self.told_tcp if true_tcp_in_flange is None else _translation(true_tcp_in_flange)
        self.repeatability_mm = repeatability_mm
        self._rng = np.random.default_rng(seed)
        start = np.eye(4) if start_pose is None else np.asarray(start_pose, dtype=np.float64)
        self._flange = start @ np.linalg.inv(self.told_tcp)
        self._lock = threading.Lock()
        self._motion = None
        self.trajectory = []  # the real TCP's pose (4, 4) in robot-base coordinates after every motion step
        self.paths = []  # every accepted Path
        self.state = "IDLE"
        self.server = socket.create_server((host, port))
        self.server.setblocking(False)
        self.address = self.server.getsockname()
        self._stop = threading.Event()
        self._thread = None

    # -- what the robot and the tool really do -------------------------------------------------------------
    def flange_pose(self):
        """(4, 4) FlangeToRobotBase where the flange really is now."""
        with self._lock:
            return self._flange.copy()

    def tool_pose(self):
        """(4, 4) the tool's real TCP in robot-base coordinates now."""
        return self.flange_pose() @ self.true_tcp

    def reported_pose(self):
        """(4, 4) the TCP the controller reports: the reached flange with the TCP it was told."""
        return self.flange_pose() @ self.told_tcp

    # -- server --------------------------------------------------------------------------------------------
    thread_name = "RobotSimulator"

    def _release(self):
        self.server.close()

    def serve(self):
        while not self._stop.is_set():
            readable, _, _ = select.select([self.server], [], [], 0.1)
            if not readable:
                continue
            try:
                client, address = self.server.accept()
            except OSError:
                continue
            logger.info("robot: navigation connected from %s:%d", *address[:2])
            with client:
                client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._session(client)
            if self._motion is not None:
                self._halt("the navigation's connection closed")

    def _session(self, client):
        assembler, buffer = PathAssembler(), b""
        client.settimeout(2.0)  # sends: a client that stops reading for 2 s is dropped, and the robot stops
        due = time.monotonic()
        while not self._stop.is_set():
            wait = max(0.0, due - time.monotonic()) if self._motion is not None else 0.1
            readable, _, _ = select.select([client], [], [], wait if self.realtime or self._motion is None else 0.0)
            if readable:
                try:
                    chunk = client.recv(1 << 16)
                except OSError:
                    chunk = b""
                if not chunk:
                    return
                buffer += chunk
                try:
                    messages, buffer = igtl.decode_available(buffer)
                except igtl.MessageError as error:
                    self._send(client, "REFUSED", f"unreadable message ({error}); connection closed", code=10)
                    return
                for message in messages:
                    if not self._take(client, assembler, message):
                        return
            if self._motion is not None and (not self.realtime or time.monotonic() >= due):
                due = max(due + 1.0 / self.rate_hz, time.monotonic() - 1.0)
                if not self._step(client):
                    return

    def _take(self, client, assembler, message):
        """Apply one message from the navigation; False when the connection is to be closed."""
        if message.device == PATH_DEVICE and message.type == "STATUS" and message.content.error_name == STOP:
            if self._motion is not None:
                self._halt("STOP received", logging.INFO)
                return self._send(client, "STOPPED", "STOP received")
            return True
        try:
            path = assembler.add(message)
        except PathError as error:
            return self._send(client, "REFUSED", str(error), code=10)
        if path is None:
            return True
        problem = self._check(path.poses)
        if problem is not None:
            return self._send(client, "REFUSED", f"path {path.path_id}: {problem}", code=10)
        poses = _orthonormalised(path.poses)
        steps = np.diff(poses[:, :3, 3], axis=0)
        turns = [_angle(a[:3, :3], b[:3, :3]) for a, b in zip(poses[:-1], poses[1:])]
        lengths = np.maximum(np.linalg.norm(steps, axis=1), TURN_MM_PER_RAD * np.array(turns))
        with self._lock:
            # from where the TCP is now to the path's first pose, then along the path
            here = self._flange @ self.told_tcp
            approach = max(np.linalg.norm(poses[0, :3, 3] - here[:3, 3]), TURN_MM_PER_RAD * _angle(here, poses[0]))
            self._motion = _Motion(
                poses=np.concatenate((here[None], poses)),
                arc_mm=np.concatenate(([0.0, approach], approach + np.cumsum(lengths))),
            )
            self.paths.append(path)
            self.state = "MOVING"
        logger.info("robot: path %s accepted, %d poses", path.path_id, len(poses))
        return self._send(client, "ACCEPTED", f"{len(poses)} {path.path_id}")

    def _check(self, poses):
        if self._motion is not None:
            return "the robot is still moving along the last path; send STOP first"
        rotations = poses[:, :3, :3]
        gram = np.einsum("nji,njk->nik", rotations, rotations) - np.eye(3)
        bad = np.flatnonzero((np.abs(gram).max(axis=(1, 2)) > RIGID_TOLERANCE) | (np.linalg.det(rotations) < 0))
        if bad.size:
            return f"pose {bad[0] + 1} is not a rigid transform (its rotation scales, shears or mirrors)"
        if not np.allclose(poses[:, 3], (0.0, 0.0, 0.0, 1.0)):
            return "a pose's last row is not 0 0 0 1"
        reach = np.linalg.norm((poses @ np.linalg.inv(self.told_tcp))[:, :3, 3], axis=1)
        far = int(np.argmax(reach))
        if reach[far] > self.reach_mm:
            distance = f"{reach[far]:.0f} mm from the base, out of its {self.reach_mm:.0f} mm reach"
            return f"pose {far + 1} puts the flange {distance}"
        return None

    def _step(self, client):
        """One motion step and its report; False when the client has gone."""
        motion = self._motion
        motion.travelled_mm = min(motion.travelled_mm + self.speed_mm_s / self.rate_hz, motion.arc_mm[-1])
        target = _along(motion.poses, motion.arc_mm, motion.travelled_mm)
        flange = target @ np.linalg.inv(self.told_tcp)
        if self.repeatability_mm:
            flange[:3, 3] += self._rng.normal(scale=self.repeatability_mm / np.sqrt(3.0), size=3)
        with self._lock:
            self._flange = flange
            self.trajectory.append(flange @ self.true_tcp)
        sent = self._send_pose(client, flange @ self.told_tcp)
        passed = int(np.searchsorted(motion.arc_mm, motion.travelled_mm + 1e-9, side="right")) - 1  # 0: the start
        if passed > motion.passed:
            motion.passed = passed
            sent = sent and self._send(client, "MOVING", f"{passed} of {len(motion.poses) - 1}")
        if motion.travelled_mm >= motion.arc_mm[-1]:
            with self._lock:
                self._motion, self.state = None, "DONE"
            sent = sent and self._send(client, "DONE", f"{len(motion.poses) - 1} poses")
        return sent

    def _halt(self, why, level=logging.WARNING):
        with self._lock:
            self._motion, self.state = None, "STOPPED"
        logger.log(level, "robot stopped: %s", why)

    def _send(self, client, name, text, code=1):
        return self._write(client, igtl.encode_status(STATUS_DEVICE, igtl.Status(code, 0, name, text), time.time()))

    def _send_pose(self, client, pose):
        return self._write(client, igtl.encode_transform(POSE_DEVICE, pose, time.time()))

    def _write(self, client, data):
        try:
            client.sendall(data)
            return True
        except OSError:
            self._halt("the navigation stopped reading")
            return False


def _translation(offset):
    transform = np.eye(4)
    transform[:3, 3] = np.asarray(offset, dtype=np.float64)
    return transform


def _orthonormalised(poses):
    """Poses with their float32 rotations made exactly orthonormal (the nearest rotation, by SVD)."""
    poses = poses.copy()
    u, _, vt = np.linalg.svd(poses[:, :3, :3])
    poses[:, :3, :3] = u @ vt
    return poses


def _angle(first, second):
    """Angle (radians) between the rotations of two (4, 4) or (3, 3) matrices."""
    relative = first[:3, :3].T @ second[:3, :3]
    return float(np.arccos(np.clip((np.trace(relative) - 1.0) / 2.0, -1.0, 1.0)))


def _along(poses, arc_mm, travelled_mm):
    """The pose (4, 4) ``travelled_mm`` along the path: positions linear, orientations spherically interpolated."""
    index = int(np.clip(np.searchsorted(arc_mm, travelled_mm, side="right") - 1, 0, len(poses) - 2))
    span = arc_mm[index + 1] - arc_mm[index]
    fraction = 1.0 if span <= 0 else (travelled_mm - arc_mm[index]) / span
    first, second = poses[index], poses[index + 1]
    pose = np.eye(4)
    pose[:3, 3] = (1.0 - fraction) * first[:3, 3] + fraction * second[:3, 3]
    if _angle(first, second) < 1e-12:
        pose[:3, :3] = first[:3, :3]
    else:
        turn = Rotation.from_matrix(first[:3, :3].T @ second[:3, :3]).as_rotvec()
        pose[:3, :3] = first[:3, :3] @ Rotation.from_rotvec(fraction * turn).as_matrix()
    return pose


def _main():
    parser = argparse.ArgumentParser(description="A simulated robot controller's OpenIGTLink endpoint on loopback")
    parser.add_argument("--port", type=int, default=ROBOT_PORT)
    parser.add_argument("--speed", type=float, default=20.0, help="TCP speed, mm/s (default 20)")
    parser.add_argument("--rate", type=float, default=125.0, help="pose reports per second (default 125)")
    parser.add_argument("--tcp", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar=("X", "Y", "Z"))
    arguments = parser.parse_args()
    logging.basicConfig(level=logging.INFO)
    robot = RobotSimulator(
        port=arguments.port, speed_mm_s=arguments.speed, rate_hz=arguments.rate, tcp_in_flange=arguments.tcp
    )
    logger.info("robot simulator listening on %s:%d", *robot.address[:2])
    try:
        robot.serve()
    except KeyboardInterrupt:
        pass
    finally:
        robot.server.close()


if __name__ == "__main__":
    _main()
