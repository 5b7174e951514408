"""What the dataset path costs: recording per control step (scripted lift episodes through the
real control path), upload of one demonstration to a local S3-compatible server (moto's, over
HTTP, checksum verified), and `dataset build` throughput.

    .venv/bin/python benchmarks/data.py
    .venv/bin/python benchmarks/data.py --episodes 10 --uploads 30 --json out/bench-data.json
"""

from __future__ import annotations

import json
import logging
import math
import platform
import socket
import statistics
import tempfile
import time
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from crowdteleop.dataset.build import BuildOptions, build_dataset
from crowdteleop.dataset.scripted import scripted_rig
from crowdteleop.recording.s3 import S3Config, S3Storage
from crowdteleop.recording.wal_codec import encode_steps

app = typer.Typer(add_completion=False)


class TimedRecording:
    """A teleoperator's `step` with the recording lines of ``TeleopSession._step`` around it,
    timed: the board's raw command on the event loop's side, then (simulation thread) the
    state before the step, a ``StepRecord`` and ``EpisodeTracker.record``."""

    NAMES = ("step", "record", "step_cpu", "record_cpu", "state_cpu", "raw_cpu")

    def __init__(self, sim: Any, step_once: Any) -> None:
        self.sim, self.step_once = sim, step_once
        self.timing = dict.fromkeys(self.NAMES, 0.0)
        self.records: list[Any] = []  # every recorded step, to time the flusher's packing after
        self.tracker: Any = None  # this episode's, set by `episode`
        self.board: Any = None

    def episode(self, tracker: Any) -> None:
        from crowdteleop.teleop.commands import CommandBoard

        self.tracker, self.board = tracker, CommandBoard()

    def raw_command(self, command: Any) -> tuple[Any, float]:
        """The phone's pose message to the board, and the raw command read back (on the event
        loop in TeleopSession.tick) with its CPU seconds."""
        from crowdteleop.teleop.protocol import PoseCommand

        self.board.apply_pose(
            "bench",
            PoseCommand(
                seq=self.board.last_seq + 1,
                client_time_ms=1000 * time.time(),
                device="phone",
                position=tuple(command.position.tolist()),
                quaternion=tuple(command.quaternion.tolist()),
                engaged=command.engaged,
                gripper=command.gripper_closed,
            ),
        )
        raw_cpu = time.thread_time()
        raw = self.board.raw_command()
        return raw, time.thread_time() - raw_cpu

    def __call__(self, command: Any) -> Any:
        from crowdteleop.teleop.episode import step_record

        raw, raw_cpu = self.raw_command(command)
        tracker = self.tracker
        tracker.maybe_start(command.engaged)
        # from here on as in TeleopSession._step (the simulation thread). Wall windows hold
        # perf_counter calls only: thread_time is a system call here (~4 us), so the CPU
        # readings sit outside them and carry that cost themselves.
        cpu = time.thread_time()
        wall = time.perf_counter()
        recording = tracker.recording
        state = self.sim.get_state() if recording else None
        state_wall = time.perf_counter()
        state_cpu = time.thread_time()
        started_wall, started = time.time(), time.perf_counter()
        step = self.step_once(command)
        duration = time.perf_counter() - started
        record_cpu = time.thread_time()
        record_wall = time.perf_counter()
        if recording:
            record = step_record(tracker.steps, state, step, raw, started_wall, duration)
            tracker.record(record)
        end_wall = time.perf_counter()
        end_cpu = time.thread_time()
        if recording:  # steps before the clutch is first pressed are not recorded
            self.records.append(record)
            timing = self.timing
            timing["step"] += duration
            timing["step_cpu"] += record_cpu - state_cpu
            timing["record"] += (end_wall - record_wall) + (state_wall - wall)
            timing["record_cpu"] += (end_cpu - record_cpu) + (state_cpu - cpu)
            timing["state_cpu"] += state_cpu - cpu
            timing["raw_cpu"] += raw_cpu
        return step

    def per_step(self, episodes: int, steps: int) -> dict[str, Any]:
        """The figures per recorded step, with the flusher's packing timed over all of them."""
        pack_cpu = time.thread_time()
        for start in range(0, len(self.records), 20):  # one flush a second at 20 Hz
            encode_steps(self.records[start : start + 20])
        pack_cpu = time.thread_time() - pack_cpu
        timing = self.timing
        return {
            "episodes": episodes,
            "steps": steps,
            "step_ms": 1000 * timing["step"] / steps,
            "record_us": 1e6 * timing["record"] / steps,
            "overhead_pct": 100 * timing["record"] / timing["step"],
            "step_cpu_ms": 1000 * timing["step_cpu"] / steps,
            "record_cpu_us": 1e6 * timing["record_cpu"] / steps,
            "overhead_cpu_pct": 100 * timing["record_cpu"] / timing["step_cpu"],
            "get_state_cpu_us": 1e6 * timing["state_cpu"] / steps,
            "append_cpu_us": 1e6 * (timing["record_cpu"] - timing["state_cpu"]) / steps,
            "raw_command_cpu_us": 1e6 * timing["raw_cpu"] / steps,
            "flusher_pack_cpu_us": 1e6 * pack_cpu / len(self.records),
        }


def record(directory: Path, episodes: int) -> tuple[dict[str, Any], list[Path]]:
    """Step time vs recording time, each control step recorded as ``TeleopSession._step`` does.

    Scripted lift episodes drive the real control path; each step's device command reaches a
    ``CommandBoard`` as the phone's pose message would, and the recording lines of
    ``TeleopSession._step`` run as written there (the state before the step, a ``StepRecord``,
    ``EpisodeTracker.record`` -> ``EpisodeRecorder.append``; the periodic write + fsync run in
    the recorder's flusher thread). Recording costs: ``get_state`` (taken for the recording
    only) and the append, on the control thread; ``raw_command`` on the event loop's thread.
    """
    from crowdteleop.control.scripted import ScriptedOperator, run_episode
    from crowdteleop.recording.versions import runtime_versions
    from crowdteleop.teleop.episode import EpisodeTracker

    steps = 0
    paths = []
    with scripted_rig("lift") as rig:
        sim, teleop, control = rig.sim, rig.teleop, rig.control
        timed = TimedRecording(sim, teleop.step)
        for seed in range(episodes):
            tracker = EpisodeTracker(
                control_dt=sim.control_dt,
                time_limit_s=math.inf,  # run_episode decides when the episode ends
                success_hold_steps=2**31,
                recordings=directory,
                metadata=rig.metadata.model_copy(
                    update={"session_id": f"bench-{seed}", "reset_seed": seed}
                ),
            )
            timed.episode(tracker)
            operator = ScriptedOperator(sim, control.mapping, seed=seed)
            teleop.step = timed  # type: ignore[method-assign]
            try:
                result = run_episode(teleop, operator, seed)
            finally:
                teleop.step = timed.step_once  # type: ignore[method-assign]
            finished = tracker.end("success" if result.success else "timeout")
            assert finished is not None and finished.recorder is not None
            extra = {
                "versions": runtime_versions(),
                "interface": "phone",
                "worker_id": f"w{seed % 3}",
            }
            paths.append(finished.recorder.finalize(finished.outcome, extra))
            steps += finished.steps
    return timed.per_step(episodes, steps), paths


def upload(paths: list[Path], uploads: int) -> dict[str, Any]:
    """Seconds per verified put of one episode file (new key each time)."""
    from moto.server import ThreadedMotoServer

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    server = ThreadedMotoServer("127.0.0.1", port, verbose=False)
    server.start()
    try:
        config = S3Config(
            bucket="bench",
            endpoint_url=f"http://127.0.0.1:{port}",
            access_key_id="bench",
            secret_access_key="bench",
            prefix="bench",
        )
        store = S3Storage(config)
        store._client.create_bucket(Bucket="bench")
        times = []
        for i in range(uploads):
            path = paths[i % len(paths)]
            started = time.perf_counter()
            store.put(path, f"success/{i}-{path.name}")
            times.append(time.perf_counter() - started)
        again = time.perf_counter()
        store.put(paths[0], f"success/0-{paths[0].name}")  # idempotent retry: HEAD only
        retry = time.perf_counter() - again
    finally:
        server.stop()
    size_kib = statistics.mean(p.stat().st_size for p in paths) / 1024
    return {
        "uploads": uploads,
        "file_kib": size_kib,
        "median_ms": 1000 * statistics.median(times),
        "p95_ms": 1000 * sorted(times)[int(0.95 * (len(times) - 1))],
        "retry_ms": 1000 * retry,
    }


def build(directory: Path, out: Path, episodes: int) -> dict[str, Any]:
    results = {}
    for label, tolerance in (("with_drift_check", 1e-6), ("without", None)):
        options = BuildOptions(drift_tolerance=tolerance)
        report = build_dataset([directory], out / f"{label}.hdf5", options)
        results[label] = {"seconds": report.seconds, "demos_per_s": episodes / report.seconds}
    return results


@app.command()
def main(
    episodes: Annotated[int, typer.Option(help="scripted lift episodes to record")] = 8,
    uploads: Annotated[int, typer.Option(help="puts to time")] = 20,
    json_out: Annotated[Path | None, typer.Option("--json", help="write figures here")] = None,
    recording_only: Annotated[bool, typer.Option(help="skip the upload and build")] = False,
    runs: Annotated[int, typer.Option(min=1, help="recording runs; figures are medians")] = 5,
) -> None:
    console = Console()
    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # moto's per-request log lines
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp) / "episodes"
        runs_figures, paths = [], []
        for run in range(runs):
            figures, run_paths = record(directory / f"run{run}", episodes)
            runs_figures.append(figures)
            paths = paths or run_paths  # the first run's files are uploaded and built
            console.print(
                f"recording run {run + 1}/{runs}: {figures['overhead_pct']:.2f} % of "
                f"{figures['step_ms']:.2f} ms"
            )
        recording = {
            name: statistics.median(f[name] for f in runs_figures) for name in runs_figures[0]
        }
        recording["runs"] = runs_figures
        uploading = {} if recording_only else upload(paths, uploads)
        building = {} if recording_only else build(directory / "run0", Path(tmp), episodes)
    table = Table("measure", f"value (recording: medians of {runs} runs)")
    table.add_row("control step (lift, ik-velocity)", f"{recording['step_ms']:.2f} ms")
    table.add_row("recording per step (get_state + append)", f"{recording['record_us']:.0f} us")
    table.add_row(
        "recording overhead",
        f"{recording['overhead_pct']:.2f} % of step time (median of {runs} runs: "
        + ", ".join(f"{f['overhead_pct']:.2f}" for f in runs_figures)
        + ")",
    )
    table.add_row(
        "same, CPU time of the control thread",
        f"{recording['record_cpu_us']:.0f} us of {recording['step_cpu_ms']:.2f} ms = "
        f"{recording['overhead_cpu_pct']:.2f} %",
    )
    table.add_row(
        "  of which get_state / StepRecord + append",
        f"{recording['get_state_cpu_us']:.0f} us / {recording['append_cpu_us']:.0f} us",
    )
    table.add_row(
        "raw_command (event loop thread, CPU)", f"{recording['raw_command_cpu_us']:.1f} us"
    )
    table.add_row(
        "packing + checksum per step (flusher thread, CPU)",
        f"{recording['flusher_pack_cpu_us']:.1f} us",
    )
    if uploading:
        table.add_row(
            f"upload one demo ({uploading['file_kib']:.0f} KiB) to local S3",
            f"median {uploading['median_ms']:.1f} ms, p95 {uploading['p95_ms']:.1f} ms",
        )
        table.add_row("idempotent re-put (already stored)", f"{uploading['retry_ms']:.1f} ms")
    for label, figures in building.items():
        table.add_row(
            f"build {episodes} demos ({label.replace('_', ' ')})",
            f"{figures['seconds']:.2f} s = {figures['demos_per_s']:.1f} demos/s",
        )
    console.print(table)
    if json_out is not None:
        figures = {
            "machine": platform.platform(),
            "recording": recording,
            "upload": uploading,
            "build": building,
        }
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(figures, indent=2))


if __name__ == "__main__":
    app()
