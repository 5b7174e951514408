"""What a rate limiter costs the coordinator's event loop per request, by how many client
addresses it tracks: a flood of new addresses must not make each request slower.

    .venv/bin/python benchmarks/limits.py                 # 1k, 10k, 100k addresses; 5 runs
    .venv/bin/python benchmarks/limits.py --keys 100000 --repeats 7

For each size, N calls of `take` from N distinct addresses (a spray: every call a new key,
the worst case for a table), then N calls of `take` from one address already over its limit
(a flood: refused, nothing stored). The table gives the median over runs of microseconds per
call, the largest single call seen, and how many calls took over 1 ms (the table's own
doublings: Python's dict resize is O(n), but happens log2(n) times in all).
"""

from __future__ import annotations

import argparse
import statistics
import time

from crowdteleop.coord.guard.limits import WindowLimiter


def one_run(keys: int) -> dict[str, float]:
    limiter = WindowLimiter(10, 60.0, max_keys=100_000)
    worst, slow = 0.0, 0
    start = time.perf_counter()
    for n in range(keys):
        t0 = time.perf_counter()
        limiter.take(f"10.{n >> 16 & 255}.{n >> 8 & 255}.{n & 255}", now=n * 1e-4)
        took = time.perf_counter() - t0
        worst, slow = max(worst, took), slow + (took > 1e-3)
    spray_us = (time.perf_counter() - start) / keys * 1e6
    start = time.perf_counter()
    for n in range(keys):
        limiter.take("203.0.113.66", now=keys * 1e-4 + n * 1e-6)
    flood_us = (time.perf_counter() - start) / keys * 1e6
    return {"spray_us": spray_us, "flood_us": flood_us, "worst_us": worst * 1e6, "slow": slow}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keys", default="1000,10000,100000")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(
        f"{'addresses':>10} {'spray us/call':>14} {'flood us/call':>14} {'worst call us':>14}"
        f" {'calls > 1 ms':>13}"
    )
    for keys in (int(k) for k in args.keys.split(",")):
        runs = [one_run(keys) for _ in range(args.repeats)]
        median = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        print(
            f"{keys:>10} {median['spray_us']:>14.2f} {median['flood_us']:>14.2f}"
            f" {median['worst_us']:>14.1f} {median['slow']:>13.0f}"
        )


if __name__ == "__main__":
    main()
