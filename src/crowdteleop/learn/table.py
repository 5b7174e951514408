"""``learn table``: trained and evaluated runs gathered into the paper's Table 1 layout (mean
± std of the final policies' return, and their success rate, per task and demonstration
count), beside the paper's own figures, and their learning curves as a PNG."""

from __future__ import annotations

import csv
import json
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, get_args

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from matplotlib.axes import Axes

from crowdteleop.learn.config import RlAlgo

# The paper's Table 1: return out of 1000 after 24 h (can) / 48 h (round nut), 10 seeds.
PAPER_TABLE = {
    "Bin Picking (Can)": {
        "0": "0 ± 0",
        "1": "278 ± 351",
        "10": "273 ± 417",
        "100": "385 ± 466",
        "1000": "641 ± 421",
    },
    "Nut-and-peg Assembly (Round)": {
        "0": "0 ± 0",
        "1": "381 ± 467",
        "10": "663 ± 435",
        "100": "575 ± 470",
        "1000": "775 ± 388",
    },
}


# what each run.json's ``algo`` is called in the tables
METHODS = {
    "ppo": "demo-guided PPO",
    "sac": "SAC, demos in its buffer",
    "ibrl": "SAC + IBRL (frozen clone proposes)",
    "bc": "BC-RNN",
}
# how a row names the simulation its runs were evaluated in (``learn eval --sim``)
SIM_LABELS = {"ours": "ours", "robosuite": "plain robosuite"}
RL_ALGOS = get_args(RlAlgo)  # the runs that train by interaction, with curves and step counts

Curve = tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]  # steps, success rate


@dataclass(frozen=True)
class RunResult:
    path: Path
    algo: str
    task: str
    demos: int
    seed: int
    sim: str
    mean_return: float | None  # None for a BC evaluation, which counts successes only
    success_rate: float
    steps: int | None = None  # PPO: environment steps trained
    seconds: float | None = None  # PPO: wall time trained
    train_return: float | None = None  # PPO: mean return of its last training episodes


def collect(roots: list[Path], sim: str = "ours") -> list[RunResult]:
    """Every run under ``roots`` with a ``run.json`` and an ``eval.json`` holding ``sim``."""
    results = []
    for root in roots:
        for run_file in sorted(root.rglob("run.json")):
            run = run_file.parent
            evaluation = run / "eval.json"
            if not evaluation.exists():
                continue
            info = json.loads(run_file.read_text())
            summary = json.loads(evaluation.read_text())["results"].get(sim)
            if summary is None:
                continue
            results.append(
                RunResult(
                    run,
                    info["algo"],
                    info["task"],
                    int(info["demos"]),
                    int(info["seed"]),
                    sim,
                    summary.get("mean_return"),
                    float(summary["success_rate"]),
                    *_training(run),
                )
            )
    return results


def _training(run: Path) -> tuple[int | None, float | None, float | None]:
    """A PPO run's steps and seconds (``state.json``) and the mean return of its last
    training episodes (sb3's ``rollout/ep_rew_mean``, demonstration starts included)."""
    state_path, progress_path = run / "state.json", run / "progress.csv"
    if not state_path.exists():
        return None, None, None
    state = json.loads(state_path.read_text())
    rows = list(csv.DictReader(progress_path.open())) if progress_path.exists() else []
    returns = [float(r["rollout/ep_rew_mean"]) for r in rows if r.get("rollout/ep_rew_mean")]
    return int(state["steps"]), float(state["seconds"]), (returns[-1] if returns else None)


@dataclass(frozen=True)
class Cell:
    runs: int
    returns: list[float]
    success: list[float]

    def text(self) -> str:
        ret = f"{np.mean(self.returns):.0f} ± {np.std(self.returns):.0f}" if self.returns else "-"
        return f"{ret} ({np.mean(self.success):.0%}, n={self.runs})"


def cells(results: list[RunResult]) -> dict[tuple[str, str], dict[int, Cell]]:
    """(algo, task) -> demonstration count -> the runs' final return and success."""
    grouped: dict[tuple[str, str], dict[int, list[RunResult]]] = defaultdict(
        lambda: defaultdict(list)
    )
    for result in results:
        grouped[(result.algo, result.task)][result.demos].append(result)
    return {
        key: {
            demos: Cell(
                len(runs),
                [r.mean_return for r in runs if r.mean_return is not None],
                [r.success_rate for r in runs],
            )
            for demos, runs in sorted(by_demos.items())
        }
        for key, by_demos in sorted(grouped.items())
    }


def markdown(results: list[RunResult]) -> str:
    """The table in Markdown: ours per (algo, task), then the paper's rows."""
    table = cells(results)
    counts = sorted({d for row in table.values() for d in row} | {0, 1, 10, 100, 1000})
    lines = [
        "| task | method | " + " | ".join("None" if c == 0 else str(c) for c in counts) + " |",
        "|---|---|" + "---|" * len(counts),
    ]
    where = " and ".join(sorted({SIM_LABELS.get(r.sim, r.sim) for r in results}))
    for (algo, task), row in table.items():
        method = METHODS.get(algo, algo)
        lines.append(
            f"| {task} ({where}) | {method} | "
            + " | ".join(row[c].text() if c in row else "" for c in counts)
            + " |"
        )
    for task, paper in PAPER_TABLE.items():
        lines.append(
            f"| {task} (paper) | demo-guided PPO | "
            + " | ".join(paper.get(str(c), "") for c in counts)
            + " |"
        )
    return "\n".join(lines) + "\n" + training_markdown(results)


def training_markdown(results: list[RunResult]) -> str:
    """The RL runs' training per method, task and demonstration count: steps, speed, and the
    return of their last training episodes (PPO's: most start from a demo's state)."""
    trained = [r for r in results if r.algo in RL_ALGOS and r.steps is not None]
    if not trained:
        return ""
    lines = [
        "",
        "| method | task | demos | runs | env steps per run | steps / s "
        "| training return at the end |",
        "|---|---|---|---|---|---|---|",
    ]
    groups: dict[tuple[str, str, int], list[RunResult]] = defaultdict(list)
    for result in trained:
        groups[(result.algo, result.task, result.demos)].append(result)
    for (algo, task, demos), runs in sorted(groups.items()):
        steps = [float(r.steps or 0) for r in runs]
        rates = [float(r.steps or 0) / max(1e-9, r.seconds or 0.0) for r in runs]
        returns = [r.train_return for r in runs if r.train_return is not None]
        lines.append(
            f"| {METHODS.get(algo, algo)} | {task} | {demos} | {len(runs)} "
            f"| {np.mean(steps):,.0f} | {np.mean(rates):.0f} | "
            + (f"{np.mean(returns):.1f} ± {np.std(returns):.1f}" if returns else "-")
            + " |"
        )
    return "\n".join(lines) + "\n"


def plot_curves(results: list[RunResult], output: Path) -> None:
    """Per task and RL method (columns), against environment steps: the success rate from
    normal resets (top) and the mean return of the training episodes (bottom); the mean over
    seeds per demonstration count, each seed faint behind it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    trained = [r for r in results if r.algo in RL_ALGOS]
    columns = sorted({(r.task, r.algo) for r in trained})
    if not columns:
        raise ValueError("no RL runs with curves to plot")
    fig, axes = plt.subplots(2, len(columns), figsize=(6 * len(columns), 7.5), squeeze=False)
    panels = (
        ("curve.csv", "steps", "success_rate", "success rate, normal resets"),
        ("progress.csv", "time/total_timesteps", "rollout/ep_rew_mean", "training return"),
    )
    for row, (file, x_key, y_key, label) in enumerate(panels):
        for axis, (task, algo) in zip(axes[row], columns, strict=True):
            runs = [r for r in trained if (r.task, r.algo) == (task, algo)]
            _plot_panel(axis, runs, file, x_key, y_key)
            axis.set_title(f"{task}: {METHODS.get(algo, algo)}")
            axis.set_xlabel("environment steps")
            axis.set_ylabel(label)
            axis.grid(alpha=0.3)
            if axis.get_legend_handles_labels()[0]:  # a short run may have logged no episode
                axis.legend(fontsize=8)
        if row == 0:
            for axis in axes[0]:
                axis.set_ylim(-0.02, 1.02)
    fig.tight_layout()
    output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(output, dpi=110)
    plt.close(fig)


def _plot_panel(axis: Axes, runs: list[RunResult], file: str, x_key: str, y_key: str) -> None:
    by_demos: dict[int, list[Curve]] = defaultdict(list)
    for run in runs:
        path = run.path / file
        rows = [r for r in csv.DictReader(path.open()) if r.get(y_key)] if path.exists() else []
        if rows:
            x = np.array([float(r[x_key]) for r in rows])
            by_demos[run.demos].append((x, np.array([float(r[y_key]) for r in rows])))
    for index, (demos, curves) in enumerate(sorted(by_demos.items())):
        color = f"C{index}"
        for x, y in curves:
            axis.plot(x, y, color=color, alpha=0.25, linewidth=0.8)
        length = min(len(x) for x, _ in curves)
        mean = np.mean([y[:length] for _, y in curves], axis=0)
        label = f"{demos} demos" if demos else "pure RL"
        axis.plot(curves[0][0][:length], mean, color=color, label=f"{label} (n={len(curves)})")
