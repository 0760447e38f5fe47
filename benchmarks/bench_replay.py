"""Recorded tracking, measured: the real PlusLibData recordings' frame timing, the touches the hold-still detector
finds in them, and how faithfully ``ramsicp-tracker-server --replay`` reproduces their timing.

Each recording is replayed at its recorded speed through our OpenIGTLink server into our receiver (real MRML
nodes, slicer-core); for every frame, the time its first message arrived is compared with its recorded time
(both taken from the first frame): the lag's median, 99th percentile and maximum, and the replayed frame rate
against the recorded one (the baseline, ratio 1.00).

Run: python benchmarks/bench_replay.py
"""

import time
from pathlib import Path

import numpy as np
import slicer

from OpenIGTLinkBridgeLib.igtl_server import TrackerServer
from OpenIGTLinkBridgeLib.plus_sequence import read_sequence
from OpenIGTLinkBridgeLib.receiver import TrackerReceiver
from OpenIGTLinkBridgeLib.recorded_touches import find_recorded_touches, frame_timing
from OpenIGTLinkBridgeLib.replay import ReplaySource

DATA = Path(__file__).resolve().parents[1] / "Testing" / "Data"
RECORDINGS = ("ReferenceToRASCalibration.igs.mha", "WaterTankBottomTranslationTrackerBuffer-trimmed.igs.mha")
TIP = (203.772, -12.283, 1.17469)  # StylusTipToStylus of PlusLibData's fCal test configuration (an assumption)
SETTINGS = ((1.5, 0.2), (1.0, 0.5), (2.0, 0.3))  # collect's defaults, the previous defaults, a looser hold


def replay_timing(recording):
    server = TrackerServer(source=ReplaySource(recording), port=0).start()
    receiver = TrackerReceiver(slicer.vtkMRMLScene(), port=server.address[1])
    arrivals = {}
    receiver.on_update = lambda device, matrix, stamp: arrivals.setdefault(stamp, time.monotonic())
    deadline = time.monotonic() + recording.timestamps_s[-1] - recording.timestamps_s[0] + 10
    while time.monotonic() < deadline and not server.finished.is_set():
        receiver.poll()
        time.sleep(0.001)
    receiver.poll()
    receiver.close()
    server.stop()
    arrived = np.array([arrivals[stamp] for stamp in sorted(arrivals)])
    recorded = recording.timestamps_s
    lag_ms = 1000 * ((arrived - arrived[0]) - (recorded[: len(arrived)] - recorded[0]))
    replayed_rate = (len(arrived) - 1) / (arrived[-1] - arrived[0])
    rate_ratio = replayed_rate / ((len(recorded) - 1) / (recorded[-1] - recorded[0]))
    return len(arrived), lag_ms, rate_ratio


def main():
    print(f"{'recording':<58} {'frames':>6} {'s':>6} {'Hz':>6}  interval ms: median   SD   min   max")
    recordings = {name: read_sequence(DATA / name) for name in RECORDINGS}
    for name, recording in recordings.items():
        t = frame_timing(recording)
        print(
            f"{name:<58} {t['frames']:6d} {t['duration_s']:6.1f} {t['rate_hz']:6.1f}  {t['interval_median_ms']:19.1f} "
            f"{t['interval_sd_ms']:5.1f} {t['interval_min_ms']:5.1f} {t['interval_max_ms']:5.1f}"
        )
    print("\ntouches found (tool tip at TIP; tool in ReferenceToTracker)")
    for name, recording in recordings.items():
        for tool in [n for n in recording.transform_names if n != "ReferenceToTracker"]:
            for still_mm, still_s in SETTINGS:
                found = find_recorded_touches(recording, tool, "ReferenceToTracker", TIP, still_mm, still_s)
                spreads = ", ".join(f"{touch.kind} {touch.spread_mm:.2f}" for touch in found.touches) or "-"
                print(
                    f"  {name[:30]:<30} {tool:<16} {still_mm:g} mm / {still_s:g} s: {len(found.touches)} touches "
                    f"and rests; spread (mm RMS) {spreads}"
                )
    print(f"\n{'replay (speed 1) -> receiver':<58} {'frames':>6}  lag ms: median   p99    max   rate ratio")
    for name, recording in recordings.items():
        count, lag_ms, ratio = replay_timing(recording)
        print(
            f"{name:<58} {count:6d}  {np.median(lag_ms):14.1f} {np.percentile(lag_ms, 99):6.1f} "
            f"{lag_ms.max():6.1f}   {ratio:10.3f}"
        )


if __name__ == "__main__":
    main()
