"""What an operator of docs/deploy.md's Ray cluster waits for (issue 30): the guide's deployment
run as its test runs it (tests/fixtures/deploy_guide_check.py: two machines in network
namespaces, the guide's node commands, config file, unit and Caddyfile, four bots through
Caddy), several times, medians reported.

Per run: the coordinator's start (exec to READY, each of its starts), its graceful stop under
SIGTERM with every slot in use (`systemctl stop`), and, after a SIGKILL and 2 s down, how long
after it is READY again until every demonstration stored meanwhile is counted (the teleop
servers' report outboxes retry with a backoff capped at 5 s). Plain robosuite's Lift step is
measured in the same run, to compare machines.

Needs root (network namespaces) and the machine's PostgreSQL (a database it makes and drops).
Usage: python benchmarks/deploy.py [--runs 3] [--json out/bench-deploy.json]"""

from __future__ import annotations

import json
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Annotated, Any

import psycopg
import typer

ROOT = Path(__file__).parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]

from tests.fixtures.netns import run_check  # noqa: E402

CHECK = ROOT / "tests" / "fixtures" / "deploy_guide_check.py"
ADMIN_DB = "postgresql://postgres@127.0.0.1/postgres"


def one_run(index: int) -> dict[str, Any]:
    name = f"bench_deploy_{index}_{int(time.time())}"
    with psycopg.connect(ADMIN_DB, autocommit=True) as db:
        db.execute(f"CREATE DATABASE {name}")
    try:
        with tempfile.TemporaryDirectory() as work:
            started = time.monotonic()
            results = run_check(
                CHECK, work, name, marker="DEPLOY_GUIDE", network="ip link set lo up"
            )
            results["wall_s"] = time.monotonic() - started
            return results
    finally:
        with psycopg.connect(ADMIN_DB, autocommit=True) as db:
            db.execute(f"DROP DATABASE IF EXISTS {name} WITH (FORCE)")


def main(
    runs: Annotated[int, typer.Option(min=1)] = 3,
    json_path: Annotated[Path | None, typer.Option("--json")] = None,
) -> None:
    figures = []
    for index in range(runs):
        results = one_run(index)
        codes = sum(bool(r["code"]) for r in results["reports"])
        figures.append(
            {
                "first_ready_s": results["ready_s"][0],
                "restart_ready_s": statistics.median(results["ready_s"][1:]),
                "sigterm_stop_s": results["sigterm_s"],
                "sigterm_exit": results["sigterm_exit"],
                "uncounted_at_restart": results["uncounted_at_restart"],
                "reports_landed_s": results["reports_landed_s"],
                "codes": codes,
                "wall_s": results["wall_s"],
            }
        )
        print(json.dumps(figures[-1]), flush=True)
    from learning import robosuite_lift_step_ms  # benchmarks/learning.py, as the others

    lift = robosuite_lift_step_ms()
    print(f"\n{runs} runs, medians (plain robosuite Lift step now: {lift:.2f} ms)")
    for key in figures[0]:
        values = [f[key] for f in figures]
        print(f"  {key:22s} {statistics.median(values):8.2f}   runs: {values}")
    if json_path is not None:
        json_path.write_text(json.dumps({"runs": figures, "robosuite_lift_step_ms": lift}))


if __name__ == "__main__":
    typer.run(main)
