"""Record (or find) the demo campaign and report how long it took.

``python -m bayesdoor.door.datasets [--calibration-runs N] [--test-runs-per-state N]`` prints JSON:
the cache file, the number of runs, whether it was generated now and the seconds taken. With
``BAYESDOOR_DATA`` set to an empty folder it times a fresh generation.
"""

from __future__ import annotations

import argparse
import json
import time

from ._demo import demo_paths, load_demo_campaign


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m bayesdoor.door.datasets", description=__doc__)
    parser.add_argument("--calibration-runs", type=int, default=10)
    parser.add_argument("--test-runs-per-state", type=int, default=100)
    opts = parser.parse_args()
    sizes = {
        "calibration_runs": opts.calibration_runs,
        "test_runs_per_state": opts.test_runs_per_state,
    }
    path, _ = demo_paths(**sizes)
    generated = not path.is_file()
    start = time.perf_counter()
    campaign = load_demo_campaign(**sizes)
    seconds = time.perf_counter() - start
    runs = campaign.sizes["run"]
    print(
        json.dumps(
            {
                "path": str(path),
                "runs": runs,
                "generated": generated,
                "seconds": round(seconds, 1),
                "seconds_per_run": round(seconds / runs, 3),
            }
        )
    )


if __name__ == "__main__":
    main()
