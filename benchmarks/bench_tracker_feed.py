"""Latency and lost frames of the live tracker feed at 60 Hz and 400 Hz (Vega XT), on loopback.

Vega simulator -> our NDI driver -> our OpenIGTLink server, read at the same time by two clients:

* ours: ``TrackerReceiver`` writing MRML transform nodes (real MRML from slicer-core) and ProbeToReference;
* baseline: a bare socket client that only decodes the messages (the least any client can do).

Latency is from the server's timestamp (taken when the tracker's TX reply arrives) to the moment the client
has applied the pose; frames lost compare the frames the server sent with those each client applied.

Run: python benchmarks/bench_tracker_feed.py [--seconds 60]
"""

import argparse
import socket
import threading
import time

import numpy as np
import slicer

from OpenIGTLinkBridgeLib import igtl_messages as igtl
from OpenIGTLinkBridgeLib.igtl_server import TrackerServer
from OpenIGTLinkBridgeLib.live_scenario import demo_simulator
from OpenIGTLinkBridgeLib.ndi_driver import open_tracker
from OpenIGTLinkBridgeLib.receiver import TrackerReceiver


def baseline_client(port, stop, latencies):
    sock = socket.create_connection(("127.0.0.1", port))
    sock.settimeout(0.2)
    buffer = b""
    while not stop.is_set():
        try:
            chunk = sock.recv(65536)
        except (TimeoutError, socket.timeout):
            continue
        if not chunk:
            break
        messages, buffer = igtl.decode_available(buffer + chunk)
        for message in messages:
            if message.type == "TRANSFORM" and message.device == "ProbeToTracker":
                latencies.append((message.timestamp_s, time.time()))
    sock.close()


def run(rate_hz, seconds):
    simulator, _ = demo_simulator(np.zeros((2, 3)), rate_hz=rate_hz)
    simulator.start()

    server = TrackerServer(lambda: open_tracker("127.0.0.1", simulator.address[1]), port=0, rate_hz=rate_hz).start()
    stop = threading.Event()
    baseline = []
    thread = threading.Thread(target=baseline_client, args=(server.address[1], stop, baseline), daemon=True)
    thread.start()
    ours = []
    receiver = TrackerReceiver(slicer.vtkMRMLScene(), port=server.address[1])

    def record(device, matrix, stamp):
        if device == "ProbeToTracker":
            ours.append((stamp, time.time()))

    receiver.on_update = record

    def poll_for(duration_s):
        end = time.monotonic() + duration_s
        while time.monotonic() < end:
            receiver.poll()
            time.sleep(0.0005)

    poll_for(1.0)  # connect, create the nodes
    window_start, start_frames = time.time(), server.frames_sent
    poll_for(seconds)
    window_end, sent = time.time(), server.frames_sent - start_frames
    poll_for(0.2)  # let the last frames of the window arrive
    stop.set()
    thread.join()
    receiver.close()
    server.stop()
    simulator.stop()

    def in_window(samples):
        return [arrival - stamp for stamp, arrival in samples if window_start <= stamp < window_end]

    return sent, in_window(ours), in_window(baseline)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    arguments = parser.parse_args()
    print(f"{arguments.seconds:g} s per rate; latency from the server's timestamp to the applied pose")
    print(
        f"\n{'rate':>6} {'client':<34} {'median (ms)':>12} {'p99 (ms)':>9} {'sent':>7} {'applied':>8} {'lost':>6}"
        f" {'p99 ratio':>10}"
    )
    for rate in (60.0, 400.0):
        sent, ours, baseline = run(rate, arguments.seconds)
        base_p99 = np.percentile(baseline, 99)
        for label, values in (("baseline: socket + decode only", baseline), ("ours: receiver -> MRML nodes", ours)):
            values_ms = 1000 * np.array(values)
            lost = max(0, sent - len(values) - 1)  # one frame may straddle the window's edge
            ratio = np.percentile(values, 99) / base_p99
            print(
                f"{rate:6.0f} {label:<34} {np.median(values_ms):12.2f} {np.percentile(values_ms, 99):9.2f} "
                f"{sent:7d} {len(values):8d} {lost:6d} {ratio:10.2f}"
            )


if __name__ == "__main__":
    main()
