"""What one teleoperation session costs in CPU: the figure that decides how many workers one
machine serves. Each (task, mode) runs in a fresh child process; see benchmarks/README.md.

    .venv/bin/python benchmarks/session.py --tasks lift --runs 3 --json out/session.json
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import psutil
import typer
from aiortc import RTCRtpCodecParameters
from aiortc.codecs import get_encoder
from rich.console import Console
from rich.table import Table

from _measure import MIB, machine_facts, median
from crowdteleop.control.command import DeviceCommand
from crowdteleop.control.config import ControlConfig
from crowdteleop.control.scripted import ScriptedOperator
from crowdteleop.control.scripted.episode import SUCCESS_HOLD_STEPS
from crowdteleop.control.teleoperator import Teleoperator
from crowdteleop.sim import SimConfig, make_simulation
from crowdteleop.tasks import get_task
from crowdteleop.teleop.config import VideoConfig
from crowdteleop.teleop.video import (
    RTP_CLOCK_HZ,
    TIME_BASE,
    YuvConverter,
    configure_encoder_bitrates,
)
from sim import _console, _parse_tasks, facts_table

app = typer.Typer(add_completion=False)
MARKER = "BENCH-SESSION "
MODES = ("busy", "idle")
TARGET_PERCENT = {"busy": 20.0, "idle": 3.0}  # of one core: >= 8 busy sessions on 2 cores
WARMUP_TICKS = 20  # unpaced and unmeasured: GL context, renderer, encoder, first IK solves
PHASES = ("command", "step", "render", "encode")
DEFAULT_TASKS = "lift,pick-place-can,nut-assembly-round"


@dataclass
class SessionResult:
    """One session's measurement window (the warm-up excluded)."""

    task: str
    mode: str
    wall_s: float
    cpu_s: float  # user + system of every thread of the child process
    user_cpu_s: float  # of which the scripted operator (the remote worker, not the server)
    ticks: int
    overruns: int
    encoded: int
    episodes: int
    successes: int
    rss_mib: float
    phase_ms: dict[str, float | None]  # median per tick

    @property
    def cpu_percent(self) -> float:
        """The server's share: a real worker's commands arrive over the network, so the
        scripted operator standing in for them is not the session's cost."""
        return 100.0 * (self.cpu_s - self.user_cpu_s) / self.wall_s


def make_encoder() -> Any:
    """The encoder the teleop server's video sender uses, at the server's default bitrates:
    its options, its thread count and its RTP packetization, so `encode ms` is the server's."""
    video = VideoConfig()
    configure_encoder_bitrates(video)
    return get_encoder(RTCRtpCodecParameters(mimeType=video.mime_type, clockRate=RTP_CLOCK_HZ))


class Session:
    """One worker's session per tick: a command, `Teleoperator.step`, a render, a VP8 encode.

    busy: a `ScriptedOperator` works the task (reset with the next seed when an episode ends), so
    the arm and objects really move and every frame is new. idle: the worker is connected but the
    clutch is released; a frame identical to the previous one is not encoded (nothing to send)."""

    def __init__(self, task: str, busy: bool, opts: dict[str, Any]) -> None:
        control = ControlConfig(controller=opts["controller"])
        config = SimConfig(task=task, robot=opts["robot"], action_mode=control.action_mode)
        self.sim = make_simulation(config)
        self.teleop = Teleoperator(self.sim, control)
        first_seed = int(opts.get("first_seed", 0))
        self.operator = ScriptedOperator(self.sim, mapping=control.mapping, seed=first_seed)
        self.busy, self.camera = busy, opts["camera"]
        self.size = (opts["width"], opts["height"])
        self.encoder = make_encoder()
        self.pts_step = round(self.sim.control_dt * RTP_CLOCK_HZ)
        self.yuv = YuvConverter()
        self.max_steps = round(get_task(task).time_limit_s / self.sim.control_dt)
        self.previous: np.ndarray | None = None
        self.seed, self.pts = first_seed, 0
        self.clear()
        self.new_episode()

    def new_episode(self) -> None:
        self.teleop.reset(self.seed)
        self.operator.reset()
        self.seed += 1
        self.steps = self.held = 0

    def tick(self) -> None:
        t0, cpu0 = time.perf_counter(), time.process_time()
        # idle: the default DeviceCommand has the clutch released (engaged=False)
        command = self.operator.command() if self.busy else DeviceCommand(seq=self.pts)
        t1 = time.perf_counter()
        self.user_cpu_s += time.process_time() - cpu0
        success = self.teleop.step(command).result.success
        t2 = time.perf_counter()
        frame = self.sim.render(self.camera, *self.size)
        t3 = time.perf_counter()
        unchanged = not self.busy and (
            frame is self.previous
            or (self.previous is not None and np.array_equal(frame, self.previous))
        )
        if not unchanged:
            video = self.yuv.convert(frame)  # as the teleop server converts: one swscale context
            video.pts, video.time_base = self.pts * self.pts_step, TIME_BASE
            self.encoder.encode(video)  # RTP payloads discarded: sending is not measured here
            self.encoded += 1
        self.previous, self.pts = frame, self.pts + 1
        t4 = time.perf_counter()
        for name, start, end in zip(PHASES, (t0, t1, t2, t3), (t1, t2, t3, t4), strict=True):
            self.phases[name].append((end - start) * 1e3)
        if self.busy:
            self.steps += 1
            self.held = self.held + 1 if success else 0
            won = self.held >= SUCCESS_HOLD_STEPS  # as `run_episode` ends an episode
            if won or self.steps >= self.max_steps or (self.operator.finished and not success):
                self.episodes, self.successes = self.episodes + 1, self.successes + won
                self.new_episode()

    def clear(self) -> None:
        """Forget the warm-up."""
        self.encoded = self.episodes = self.successes = 0
        self.user_cpu_s = 0.0
        self.phases: dict[str, list[float]] = {name: [] for name in PHASES}


def paced(tick: Callable[[], None], period: float, seconds: float) -> dict[str, Any]:
    """Run `tick` at wall-clock slots start + k * period for `seconds`; return wall and CPU
    seconds, ticks and overruns. Slots are absolute, so sleep error does not accumulate. A tick
    that ends after the next slot is an overrun: the next tick starts at once and slots missed
    entirely are dropped, as a live session drops frames rather than bursting to catch up.
    CPU is `time.process_time()`: user + system of every thread (llvmpipe's included)."""
    start, cpu_start = time.perf_counter(), time.process_time()
    ticks = overruns = slot = 0
    while True:
        tick()
        ticks += 1
        now = time.perf_counter()
        if now - start >= seconds:
            break
        slot += 1
        if now > start + slot * period:
            overruns += 1
            slot = max(slot, int((now - start) / period))
        else:
            time.sleep(start + slot * period - now)
    wall_s, cpu_s = time.perf_counter() - start, time.process_time() - cpu_start
    return {"wall_s": wall_s, "cpu_s": cpu_s, "ticks": ticks, "overruns": overruns}


READY_MARKER = "BENCH-READY"


def run_child(task: str, mode: str, opts: dict[str, Any]) -> SessionResult:
    """The measured process: build one session, warm it up, run the paced loop.

    With ``wait_for_go`` it says so on stdout once warm and starts the loop on a line from
    stdin: `at_once.py` starts many sessions' measured windows together that way."""
    session = Session(task, mode == "busy", opts)
    for _ in range(WARMUP_TICKS):
        session.tick()
    if opts.get("wait_for_go"):
        print(READY_MARKER, flush=True)
        sys.stdin.readline()
    session.clear()
    loop = paced(session.tick, session.sim.control_dt, opts["seconds"])
    rss_mib = psutil.Process().memory_info().rss / MIB
    phase_ms = {name: median(values) for name, values in session.phases.items()}
    counts = {name: getattr(session, name) for name in ("encoded", "episodes", "successes")}
    session.sim.close()
    return SessionResult(
        task,
        mode,
        **loop,
        user_cpu_s=session.user_cpu_s,
        **counts,
        rss_mib=rss_mib,
        phase_ms=phase_ms,
    )


def child_command(task: str, mode: str, opts: dict[str, Any], first_seed: int = 0) -> list[str]:
    """The command line of one measured session process (`--child`)."""
    command = [sys.executable, str(Path(__file__).resolve()), "--child", f"{task}:{mode}"]
    for name in ("seconds", "controller", "camera", "width", "height", "robot"):
        command += [f"--{name}", str(opts[name])]
    command += ["--first-seed", str(first_seed)]
    return command + (["--wait-for-go"] if opts.get("wait_for_go") else [])


def parse_child_output(label: str, stdout: str, stderr: str, returncode: int) -> SessionResult:
    for line in reversed(stdout.splitlines()):
        if line.startswith(MARKER):
            return SessionResult(**json.loads(line.removeprefix(MARKER)))
    tail = "\n".join((stderr or stdout).splitlines()[-15:])
    raise RuntimeError(f"session {label} failed (exit {returncode}):\n{tail}")


def run_in_subprocess(task: str, mode: str, opts: dict[str, Any]) -> SessionResult:
    """A fresh process per (task, mode): no shared caches or heap, memory released after."""
    timeout = opts["seconds"] + 600
    command = child_command(task, mode, opts)
    done = subprocess.run(command, capture_output=True, text=True, timeout=timeout, check=False)
    return parse_child_output(f"{task}/{mode}", done.stdout, done.stderr, done.returncode)


def sessions_per_machine(busy_percent: float) -> int:
    return math.floor(len(os.sched_getaffinity(0)) * 100.0 / busy_percent)


def median_run(runs: list[SessionResult]) -> SessionResult:
    """The run whose CPU share is the median (the lower middle one for an even count)."""
    ordered = sorted(runs, key=lambda r: r.cpu_percent)
    return ordered[(len(ordered) - 1) // 2]


def results_table(measured: dict[tuple[str, str], list[SessionResult]], opts: dict) -> Table:
    runs = opts["runs"]
    table = Table(
        title="CPU per teleoperation session",
        caption=(
            f"{opts['seconds']:g} s per session at 20 Hz, {opts['controller']}, {opts['camera']} "
            f"{opts['width']}x{opts['height']}, VP8 as the teleop server encodes it (aiortc's "
            "encoder, the server's bitrates); CPU = (process time - the scripted operator's) / "
            f"wall, median of {runs} run(s), each its own process; other columns from the median "
            "run, ms = median per tick; sessions = floor(usable cores x 100 / busy CPU %)"
        ),
    )
    columns = ["task", "mode", "CPU\n% core", "runs\n% core", "target\n%", "loop\nHz"]
    columns += ["over-\nruns", *(f"{name}\nms" for name in PHASES)]
    columns += ["encoded\n%", "episodes\n(success)", "RSS\nMiB", "sessions\nhere"]
    for name in columns:
        table.add_column(name, justify="left" if name in ("task", "mode") else "right")
    for (task, mode), results in measured.items():
        r = median_run(results)
        share, target = r.cpu_percent, TARGET_PERCENT[mode]
        verdict = "[green]ok[/]" if share <= target else "[red]over[/]"
        each = " ".join(f"{run.cpu_percent:.1f}" for run in results)
        cells = [task, mode, f"{share:.1f}", each, f"<= {target:g} {verdict}"]
        cells += [f"{r.ticks / r.wall_s:.1f}", str(r.overruns)]
        cells += ["-" if r.phase_ms[p] is None else f"{r.phase_ms[p]:.2f}" for p in PHASES]
        cells += [f"{100.0 * r.encoded / r.ticks:.0f}"]
        busy = mode == "busy"
        cells += [f"{r.episodes} ({r.successes})" if busy else "-", f"{r.rss_mib:.0f}"]
        table.add_row(*cells, str(sessions_per_machine(share)) if busy else "-")
    return table


# The command-line options a session takes, shared with `at_once.py`.
TasksOption = Annotated[str, typer.Option(help="comma-separated task names")]
SecondsOption = Annotated[float, typer.Option(min=1, help="measured seconds per session")]
ControllerOption = Annotated[str, typer.Option(help="ik-velocity or osc")]
CameraOption = Annotated[str, typer.Option(help="camera streamed to the worker")]
PixelsOption = Annotated[int, typer.Option(min=16)]
RobotOption = Annotated[str, typer.Option(help="robosuite arm")]
JsonOption = Annotated[Path | None, typer.Option("--json", help="also write raw values here")]


def session_options(
    seconds: float, controller: str, camera: str, width: int, height: int, robot: str
) -> dict[str, Any]:
    """What every session child is told, checked."""
    if controller not in ("ik-velocity", "osc"):
        raise typer.BadParameter(f"controller is ik-velocity or osc, got {controller!r}")
    opts = {"seconds": seconds, "controller": controller, "camera": camera}
    return opts | {"width": width, "height": height, "robot": robot}


@app.command()
def main(
    tasks: TasksOption = DEFAULT_TASKS,
    seconds: SecondsOption = 20.0,
    controller: ControllerOption = "ik-velocity",
    camera: CameraOption = "frontview",
    width: PixelsOption = 320,
    height: PixelsOption = 240,
    robot: RobotOption = "Sawyer",
    json_path: JsonOption = None,
    runs: Annotated[int, typer.Option(min=1, help="runs per (task, mode); medians shown")] = 3,
    child: Annotated[str | None, typer.Option(hidden=True, help="TASK:MODE, internal")] = None,
    first_seed: Annotated[int, typer.Option(hidden=True, help="child's first scene seed")] = 0,
    wait_for_go: Annotated[bool, typer.Option(hidden=True, help="child waits on stdin")] = False,
) -> None:
    """Measure the CPU share of a busy and an idle session per task and print one table."""
    opts = session_options(seconds, controller, camera, width, height, robot)
    if child is not None:
        task, mode = child.split(":")
        child_opts = opts | {"first_seed": first_seed, "wait_for_go": wait_for_go}
        print(MARKER + json.dumps(asdict(run_child(task, mode, child_opts))), flush=True)
        return
    task_names = _parse_tasks(tasks)
    console = _console()
    facts = machine_facts()
    console.print(facts_table(facts))
    measured: dict[tuple[str, str], list[SessionResult]] = {
        (task, mode): [] for task in task_names for mode in MODES
    }
    # Round robin over the sessions, so a drift in the machine's speed reaches every task alike.
    with Console(stderr=True).status("") as status:
        for run in range(runs):
            for (task, mode), results in measured.items():
                status.update(f"run {run + 1}/{runs}, {task}: {mode} ({seconds:g} s, own process)")
                results.append(run_in_subprocess(task, mode, opts))
    console.print(results_table(measured, opts | {"runs": runs}))
    medians = {key: median_run(results) for key, results in measured.items()}
    worst = max(r.cpu_percent for (_, mode), r in medians.items() if mode == "busy")
    console.print(
        f"this machine holds {sessions_per_machine(worst)} busy sessions "
        f"(worst task, {worst:.1f}% of a core each; target >= 8 on 2 cores)"
    )
    if any(r.overruns for results in measured.values() for r in results):
        console.print("[yellow]overruns: those sessions did not keep 20 Hz; their share is a floor")
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        rows = [
            asdict(r) | {"cpu_percent": r.cpu_percent, "run": index}
            for results in measured.values()
            for index, r in enumerate(results)
        ]
        report = {"machine": facts, "options": opts | {"tasks": task_names, "runs": runs}}
        report["results"] = rows
        report["median_cpu_percent"] = {
            f"{task}:{mode}": r.cpu_percent for (task, mode), r in medians.items()
        }
        report["sessions_per_machine"] = sessions_per_machine(worst)
        json_path.write_text(json.dumps(report, indent=2))
        console.print(f"raw values written to {json_path}")


if __name__ == "__main__":
    app()
