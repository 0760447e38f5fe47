"""How fast the command line answers ``--help`` and a mistyped argument, against Python's own start-up.

The parser imports only numpy and light constants; every command imports its own machinery (scipy, VTK, the image
side) when it runs (``cli.py``). Each line is the median wall time of ``--runs`` fresh processes, interleaved line by
line so that the machine's changing load hits all alike; the baselines are an empty Python and Python importing
numpy, which every command needs.

Run: python benchmarks/bench_cli_startup.py [--runs 15]
"""

import argparse
import subprocess
import sys
import time

import numpy as np

CASES = {
    "baseline: python -c pass": ["-c", "pass"],
    "baseline: python -c 'import numpy'": ["-c", "import numpy"],
    "ramsicp --help": ["-m", "RAMSICPRegistrationLib.commands", "--help"],
    "ramsicp register --help": ["-m", "RAMSICPRegistrationLib.commands", "register", "--help"],
    "ramsicp register --fle -1 (refused)": ["-m", "RAMSICPRegistrationLib.commands", "register", "--fle", "-1"],
    "ramsicp ipc --help": ["-m", "RAMSICPRegistrationLib.commands", "ipc", "--help"],
    "ramsicp reproduce --help": ["-m", "RAMSICPRegistrationLib.commands", "reproduce", "--help"],
    "for scale: python -c 'import scipy.stats'": ["-c", "import scipy.stats"],
}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=15)
    runs = parser.parse_args().runs
    seconds = {name: [] for name in CASES}
    for _ in range(runs):
        for name, arguments in CASES.items():
            clock = time.perf_counter()
            subprocess.run([sys.executable, *arguments], capture_output=True)
            seconds[name].append(time.perf_counter() - clock)
    numpy_median = np.median(seconds["baseline: python -c 'import numpy'"])
    print(f"{'what':<44} {'median (s)':>10}  {'ratio to importing numpy':>24}")
    for name, values in seconds.items():
        median = np.median(values)
        print(f"{name:<44} {median:10.3f}  {median / numpy_median:24.2f}")


if __name__ == "__main__":
    main()
