"""The phone's camera mode (issue 12, item 2), measured end to end: Chromium's fake camera plays
the marker seen along a known path, the phone page recovers the pose and drives a real teleop
server (tests/e2e/test_phone_camera.py does one run and prints its figures). This runs it
--runs times and gives the median and the worst run of each figure, with the Lift step of the
same moment (these VMs change speed from day to day).

    .venv/bin/python benchmarks/phone_camera.py --runs 3 --json out/phone-camera.json
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

from rich.console import Console
from rich.progress import track
from rich.table import Table

from learning import robosuite_lift_step_ms

ROOT = Path(__file__).resolve().parents[1]
TEST = "tests/e2e/test_phone_camera.py"
FIGURES = {  # key: (label, worse is higher)
    "start_error_mm": ("pose error at rest, start (mm, largest)", True),
    "start_error_deg": ("rotation error at rest, start (deg, largest)", True),
    "end_error_mm": ("pose error at rest, end (mm, largest)", True),
    "end_error_deg": ("rotation error at rest, end (deg, largest)", True),
    "off_path_mm": ("recovered position off the path (mm, largest)", True),
    "hand_error_mm": ("hand displacement error (mm)", True),
    "hand_error_deg": ("hand rotation error (deg)", True),
    "framesPerS": ("camera frames searched per second", False),
    "posesPerS": ("poses per second", False),
    "detectMs": ("detection + pose per frame (ms, median)", True),
    "latencyMs": ("frame to pose (ms, median)", True),
}


def one_run() -> dict[str, float]:
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-s", "-p", "no:cacheprovider", TEST],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    for line in done.stdout.splitlines():
        if line.startswith("CAMERA_FIGURES "):
            return json.loads(line.removeprefix("CAMERA_FIGURES "))  # type: ignore[no-any-return]
    tail = done.stdout[-3000:]
    raise SystemExit(f"the test printed no figures (exit {done.returncode}):\n{tail}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    runs = [one_run() for _ in track(range(args.runs), description="camera-mode runs")]
    lift_ms = robosuite_lift_step_ms()
    table = Table(title=f"phone camera mode, {args.runs} runs (Lift step {lift_ms:.2f} ms)")
    for column in ("figure", "median", "worst run"):
        table.add_column(column)
    for key, (label, higher_is_worse) in FIGURES.items():
        values = [run[key] for run in runs]
        worst = max(values) if higher_is_worse else min(values)
        table.add_row(label, f"{statistics.median(values):.2f}", f"{worst:.2f}")
    Console().print(table)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"lift_step_ms": lift_ms, "runs": runs}, indent=1))


if __name__ == "__main__":
    main()
