"""``crowdteleop dataset stats``: the paper's tables for a dataset.

Per task, and within it per interface, network condition, region and worker: count, hours of
trajectories, success rate, completion time mean / standard deviation / histogram (successful
demos, as the paper's tables), and the two-sample Kolmogorov-Smirnov statistic with its p-value
between every pair of groups (scipy), laid out like the paper's Tables 3-7 ("Mean | Standard
Deviation | Num. Demonstrations", and a matrix of "statistic (p)").
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from crowdteleop.dataset.files import NO_REGION, DemoSummary

GROUPINGS = {
    "interface": "interface",
    "network condition": "network",
    "region": "region",
    "worker": "worker",
}


@dataclass(frozen=True)
class GroupStats:
    group: str
    count: int  # every demo in the group
    successes: int
    success_rate: float
    hours: float  # trajectory time of every demo in the group
    mean_s: float  # completion time of the successful ones
    std_s: float
    histogram: list[int]
    bin_edges_s: list[float]


@dataclass(frozen=True)
class KsCell:
    statistic: float
    p_value: float


def group_stats(
    name: str, demos: Sequence[DemoSummary], edges: npt.NDArray[np.float64]
) -> GroupStats:
    times = np.array([d.completion_s for d in demos if d.outcome == "success"])
    counts, _ = np.histogram(times, bins=edges)
    return GroupStats(
        group=name,
        count=len(demos),
        successes=len(times),
        success_rate=len(times) / len(demos) if demos else 0.0,
        hours=sum(d.completion_s for d in demos) / 3600.0,
        mean_s=float(times.mean()) if len(times) else float("nan"),
        std_s=float(times.std(ddof=1)) if len(times) > 1 else float("nan"),
        histogram=counts.tolist(),
        bin_edges_s=edges.tolist(),
    )


def ks_matrix(groups: dict[str, list[float]]) -> dict[str, dict[str, KsCell]]:
    """Two-sample KS between every pair of groups with at least one sample each."""
    from scipy.stats import ks_2samp

    matrix: dict[str, dict[str, KsCell]] = {name: {} for name in groups}
    for a, b in itertools.combinations(groups, 2):
        if groups[a] and groups[b]:
            result = ks_2samp(groups[a], groups[b])
            cell = KsCell(float(result.statistic), float(result.pvalue))
            matrix[a][b] = matrix[b][a] = cell
    return matrix


def compute_stats(demos: Sequence[DemoSummary], bins: int = 10) -> dict[str, Any]:
    """Everything the report shows, as plain data (the JSON output)."""
    report: dict[str, Any] = {"overall": None, "tasks": {}}
    every = [d.completion_s for d in demos if d.outcome == "success"]
    report["overall"] = asdict(group_stats("all", demos, _edges(every, bins)))
    for task in sorted({d.task for d in demos}):
        in_task = [d for d in demos if d.task == task]
        times = [d.completion_s for d in in_task if d.outcome == "success"]
        edges = _edges(times, bins)
        entry: dict[str, Any] = {"all": asdict(group_stats(task, in_task, edges)), "by": {}}
        for title, attribute in GROUPINGS.items():
            names = sorted({getattr(d, attribute) for d in in_task})
            if attribute == "region" and names == [NO_REGION]:
                continue  # a campaign without regions: no table of one row
            members = {n: [d for d in in_task if getattr(d, attribute) == n] for n in names}
            samples = {
                n: [d.completion_s for d in m if d.outcome == "success"] for n, m in members.items()
            }
            entry["by"][title] = {
                "groups": [asdict(group_stats(n, members[n], edges)) for n in names],
                "ks": {
                    a: {b: asdict(c) for b, c in row.items()}
                    for a, row in ks_matrix(samples).items()
                },
            }
        report["tasks"][task] = entry
    return report


def _edges(times: Sequence[float], bins: int) -> npt.NDArray[np.float64]:
    if not times:
        return np.linspace(0.0, 1.0, bins + 1)
    low, high = min(times), max(times)
    if high - low < 1e-9:
        low, high = low - 0.5, high + 0.5
    return np.linspace(low, high, bins + 1)


def markdown(report: dict[str, Any]) -> str:
    """The paper's table layouts, one block per task and grouping."""
    overall = report["overall"]
    lines = [
        "# Dataset statistics",
        "",
        "| | Demonstrations | Successful | Success rate | Hours of trajectories |",
        "|---|---|---|---|---|",
        f"| All | {overall['count']} | {overall['successes']} | "
        f"{overall['success_rate']:.1%} | {overall['hours']:.3f} |",
    ]
    for task, entry in report["tasks"].items():
        stats = entry["all"]
        lines += [
            f"| {task} | {stats['count']} | {stats['successes']} | "
            f"{stats['success_rate']:.1%} | {stats['hours']:.3f} |",
        ]
    for task, entry in report["tasks"].items():
        for title, block in entry["by"].items():
            lines += [
                "",
                f"## Statistics on completion times of the *{task}* task across different {title}s",
                "",
                "| | Mean | Standard Deviation | Num. Demonstrations | Success rate |",
                "|---|---|---|---|---|",
            ]
            for group in block["groups"]:
                lines.append(
                    f"| {group['group']} | {_num(group['mean_s'])} | {_num(group['std_s'])} | "
                    f"{group['successes']} | {group['success_rate']:.1%} |"
                )
            names = [g["group"] for g in block["groups"]]
            if len(names) < 2:
                continue
            lines += [
                "",
                f"Kolmogorov-Smirnov statistic between distributions and p-value for "
                f"completion times in the *{task}* task across {title}s:",
                "",
                "| | " + " | ".join(names) + " |",
                "|---" * (len(names) + 1) + "|",
            ]
            for a in names:
                cells = []
                for b in names:
                    cell = block["ks"].get(a, {}).get(b)
                    cells.append(
                        "-"
                        if a == b or cell is None
                        else f"{cell['statistic']:.3f} ({cell['p_value']:.3f})"
                    )
                lines.append(f"| {a} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _num(value: float) -> str:
    return "-" if value != value else f"{value:.2f}"  # NaN: too few demos


def plot_histograms(report: dict[str, Any], directory: Path) -> list[Path]:
    """One PNG per task and grouping: completion-time histograms overlaid, as Fig. 4."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for task, entry in report["tasks"].items():
        for title, block in entry["by"].items():
            figure, axes = plt.subplots(figsize=(6, 4))
            for group in block["groups"]:
                edges = np.array(group["bin_edges_s"])
                axes.stairs(group["histogram"], edges, label=group["group"], linewidth=1.5)
            axes.set_xlabel("completion time (s)")
            axes.set_ylabel("demonstrations")
            axes.set_title(f"{task}: completion times by {title}")
            axes.legend()
            path = directory / f"{task}-{title.replace(' ', '-')}.png"
            figure.savefig(path, dpi=100, bbox_inches="tight")
            plt.close(figure)
            written.append(path)
    return written


def write_report(demos: Sequence[DemoSummary], directory: Path, bins: int = 10) -> dict[str, Any]:
    """stats.json, stats.md and the PNG plots into ``directory``; returns the report."""
    report = compute_stats(demos, bins)
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "stats.json").write_text(json.dumps(report, indent=2, allow_nan=True))
    (directory / "stats.md").write_text(markdown(report))
    report["plots"] = [str(p) for p in plot_histograms(report, directory)]
    return report
