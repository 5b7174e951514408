"""Measurements behind `benchmarks/sim.py`: one `TaskBench` per task, plus the memory probe.

Run as a script (``python benchmarks/_measure.py memory --task lift``), this module is the fresh
child process in which resident memory is measured; it prints one ``BENCH-MEMORY {json}`` line.
"""

from __future__ import annotations

import argparse
import ctypes
import ctypes.util
import gc
import json
import logging
import os
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import psutil
from scipy.spatial.transform import Rotation

# crowdteleop's import chooses MUJOCO_GL; it comes before anything that imports mujoco.
from crowdteleop.control.command import DeviceCommand
from crowdteleop.control.config import ControlConfig
from crowdteleop.control.teleoperator import Teleoperator
from crowdteleop.sim import SimConfig, make_simulation
from crowdteleop.sim.interface import Simulation
from crowdteleop.sim.types import ActionSpec
from crowdteleop.tasks import TaskSpec, get_task

MEMORY_MARKER = "BENCH-MEMORY "
MIB = 1024.0 * 1024.0

# A realistic operator: the arm keeps moving and the gripper opens and closes.
MOTION_PERIOD_S = 2.0  # one sinusoid cycle of every commanded quantity
GRIPPER_PERIOD_S = 2.0  # closed for half of it, open for the other half
JOINT_SPEED_RAD_S = 0.3  # joint-velocity amplitude (our action mode)
OSC_AMPLITUDE = 0.3  # robosuite OSC_POSE delta amplitude, of its [-1, 1] range
DEVICE_RADIUS_M = 0.05  # the virtual phone traces a 5 cm loop ...
DEVICE_TWIST_RAD = 0.2  # ... while turning +-0.2 rad about its vertical axis
DEVICE_ORIGIN = np.array([0.1, -0.2, 1.2])

WARMUP_STEPS = 5
WARMUP_FRAMES = 3
STATE_BATCH = 50  # get/set_state calls timed together; the median is over batch means


@dataclass(frozen=True)
class BenchOptions:
    """What to measure and how often."""

    robot: str = "Sawyer"
    control_hz: float = 20.0
    repeats: int = 5
    steps: int = 100
    frames: int = 10
    sizes: tuple[tuple[int, int], ...] = ((320, 240), (480, 360))
    state_calls: int = 2000
    memory: bool = True


@dataclass
class TaskResult:
    """Raw per-repeat values (ms, us, MiB); `None` where a measurement does not apply."""

    task: str
    backend: str
    build_s: float = 0.0
    step_ms: list[float] = field(default_factory=list)
    teleop_ms: list[float] = field(default_factory=list)
    robosuite_step_ms: list[float] | None = None
    render_ms: dict[str, list[float]] = field(default_factory=dict)
    robosuite_render_ms: dict[str, list[float]] | None = None
    get_state_us: list[float] = field(default_factory=list)
    set_state_us: list[float] = field(default_factory=list)
    state_size: int = 0
    memory_mib: dict[str, float] | None = None

    def to_json(self) -> dict[str, Any]:
        """Raw values and their medians."""

        def summary(values: list[float] | None) -> dict[str, Any] | None:
            return None if values is None else {"median": median(values), "values": values}

        def sized(
            values: dict[str, list[float]] | None,
        ) -> dict[str, dict[str, Any] | None] | None:
            return None if values is None else {k: summary(v) for k, v in values.items()}

        return {
            "task": self.task,
            "backend": self.backend,
            "build_s": self.build_s,
            "step_ms": summary(self.step_ms),
            "teleop_ms": summary(self.teleop_ms),
            "robosuite_step_ms": summary(self.robosuite_step_ms),
            "render_ms": sized(self.render_ms),
            "robosuite_render_ms": sized(self.robosuite_render_ms),
            "get_state_us": summary(self.get_state_us),
            "set_state_us": summary(self.set_state_us),
            "state_size": self.state_size,
            "memory_mib": self.memory_mib,
        }


def median(values: Sequence[float] | None) -> float | None:
    return statistics.median(values) if values else None


def size_key(size: tuple[int, int]) -> str:
    return f"{size[0]}x{size[1]}"


def release_memory() -> None:
    """Collect garbage and hand freed heap back to the OS, so closed environments don't pile up."""
    gc.collect()
    libc_name = ctypes.util.find_library("c")
    if sys.platform.startswith("linux") and libc_name:
        ctypes.CDLL(libc_name).malloc_trim(0)


# --- what the operator does -------------------------------------------------------------------
def gripper_command(t: float) -> float:
    """-1 open, +1 closed: a square wave."""
    return 1.0 if (t % GRIPPER_PERIOD_S) >= GRIPPER_PERIOD_S / 2 else -1.0


def joint_velocity_actions(spec: ActionSpec, dt: float, n: int) -> list[np.ndarray]:
    """Our joint-velocity actions: every joint on a sinusoid (phases spread), gripper toggling."""
    joints = spec.size - 1
    phases = np.arange(joints) * (2 * np.pi / joints)
    actions = []
    for k in range(n):
        t = k * dt
        qdot = JOINT_SPEED_RAD_S * np.sin(2 * np.pi * t / MOTION_PERIOD_S + phases)
        action = np.append(qdot, gripper_command(t))
        actions.append(np.clip(action, spec.low, spec.high))
    return actions


def osc_actions(size: int, dt: float, n: int) -> list[np.ndarray]:
    """robosuite OSC_POSE deltas (dx, dy, dz, ax, ay, az, gripper) on sinusoids."""
    phases = np.arange(size - 1) * (2 * np.pi / (size - 1))
    actions = []
    for k in range(n):
        t = k * dt
        delta = OSC_AMPLITUDE * np.sin(2 * np.pi * t / MOTION_PERIOD_S + phases)
        actions.append(np.append(delta, gripper_command(t)))
    return actions


def device_commands(dt: float, n: int) -> list[DeviceCommand]:
    """A phone held engaged, tracing a small loop and twisting, gripper toggling."""
    commands = []
    for k in range(n):
        t = k * dt
        w = 2 * np.pi * t / MOTION_PERIOD_S
        offset = DEVICE_RADIUS_M * np.array([np.sin(w), np.cos(w) - 1.0, 0.5 * np.sin(2 * w)])
        twist = Rotation.from_rotvec([0.0, 0.0, DEVICE_TWIST_RAD * np.sin(w)])
        commands.append(
            DeviceCommand(
                position=DEVICE_ORIGIN + offset,
                quaternion=twist.as_quat(),
                engaged=True,
                gripper_closed=gripper_command(t) > 0,
                seq=k,
                client_time_ms=1000.0 * t,
            )
        )
    return commands


# --- timing helpers ---------------------------------------------------------------------------
def ms_per_call(fn: Callable[[Any], object], arguments: Sequence[Any]) -> float:
    """Mean wall time of `fn(a)` over `arguments`, in milliseconds."""
    start = time.perf_counter()
    for argument in arguments:
        fn(argument)
    return (time.perf_counter() - start) / len(arguments) * 1e3


def us_per_call_batches(fn: Callable[[], object], calls: int) -> list[float]:
    """Mean microseconds per call of each batch of `STATE_BATCH` calls."""
    batches = []
    for _ in range(max(1, calls // STATE_BATCH)):
        start = time.perf_counter()
        for _ in range(STATE_BATCH):
            fn()
        batches.append((time.perf_counter() - start) / STATE_BATCH * 1e6)
    return batches


def ms_per_frame(render: Callable[[], object], move: Callable[[int], object], frames: int) -> float:
    """Mean render time over `frames`, moving the arm (untimed) before each frame."""
    total = 0.0
    for k in range(frames):
        move(k)
        start = time.perf_counter()
        render()
        total += time.perf_counter() - start
    return total / frames * 1e3


# --- one task ---------------------------------------------------------------------------------
class TaskBench:
    """All measurements of one task, as phases run in order (`phases`); `close` frees the rest."""

    def __init__(self, task: str, options: BenchOptions) -> None:
        self.spec: TaskSpec = get_task(task)
        self.options = options
        self.config = SimConfig(task=task, robot=options.robot, control_hz=options.control_hz)
        self.result = TaskResult(task, self.spec.backend)
        self.camera = self.spec.default_camera
        self._sim: Simulation | None = None
        self._teleop: Teleoperator | None = None
        self._env: Any = None

    @property
    def has_robosuite(self) -> bool:
        return self.spec.backend == "robosuite"

    def phases(self) -> list[tuple[str, Callable[[], None]]]:
        """(label, action) in the order they must run."""
        sizes = self.options.sizes
        phases: list[tuple[str, Callable[[], None]]] = [
            ("build our sim", self.build_ours),
            ("our sim.step", self.step_ours),
            ("our teleop step (IK)", self.teleop_ours),
        ]
        phases += [(f"our render {size_key(s)}", self._render_ours_at(s)) for s in sizes]
        phases.append(("get/set_state", self.state_ours))
        if self.has_robosuite:
            phases.append(("robosuite env.step", self.robosuite_step))
            phases.append(("robosuite render", self.robosuite_render))
        if self.options.memory:
            phases.append(("memory (subprocess)", self.memory))
        return phases

    # ours
    def build_ours(self) -> None:
        start = time.perf_counter()
        self._sim = make_simulation(self.config)
        self._sim.reset(seed=0)
        self.result.build_s = time.perf_counter() - start
        self._teleop = Teleoperator(self._sim, ControlConfig(controller="ik-velocity"))

    def _ours(self) -> tuple[Simulation, Teleoperator]:
        assert self._sim is not None and self._teleop is not None, "build_ours runs first"
        return self._sim, self._teleop

    def step_ours(self) -> None:
        sim, _ = self._ours()
        actions = joint_velocity_actions(sim.action_spec, sim.control_dt, self.options.steps)
        sim.reset(seed=0)
        for action in actions[:WARMUP_STEPS]:
            sim.step(action)
        for _ in range(self.options.repeats):
            sim.reset(seed=0)
            self.result.step_ms.append(ms_per_call(sim.step, actions))

    def teleop_ours(self) -> None:
        sim, teleop = self._ours()
        commands = device_commands(sim.control_dt, self.options.steps)
        teleop.reset(seed=0)
        for command in commands[:WARMUP_STEPS]:
            teleop.step(command)
        for _ in range(self.options.repeats):
            teleop.reset(seed=0)
            self.result.teleop_ms.append(ms_per_call(teleop.step, commands))

    def _render_ours_at(self, size: tuple[int, int]) -> Callable[[], None]:
        def run() -> None:
            sim, _ = self._ours()
            width, height = size
            frames = self.options.frames
            actions = joint_velocity_actions(sim.action_spec, sim.control_dt, frames)
            sim.reset(seed=0)
            for k in range(WARMUP_FRAMES):
                sim.step(actions[k % frames])
                sim.render(self.camera, width, height)
            values = self.result.render_ms.setdefault(size_key(size), [])
            for _ in range(self.options.repeats):
                sim.reset(seed=0)
                values.append(
                    ms_per_frame(
                        lambda: sim.render(self.camera, width, height),
                        lambda k: sim.step(actions[k]),
                        frames,
                    )
                )

        return run

    def state_ours(self) -> None:
        sim, _ = self._ours()
        sim.reset(seed=0)
        state = sim.get_state()
        self.result.state_size = int(state.size)
        calls = self.options.state_calls
        self.result.get_state_us = us_per_call_batches(sim.get_state, calls)
        self.result.set_state_us = us_per_call_batches(lambda: sim.set_state(state), calls)
        self._close_ours()

    def _close_ours(self) -> None:
        if self._sim is not None:
            self._sim.close()
        self._sim = self._teleop = None
        release_memory()

    # plain robosuite
    def _make_robosuite_env(self, offscreen: bool) -> Any:
        import robosuite
        from robosuite.controllers import load_composite_controller_config

        logging.getLogger("robosuite").setLevel(logging.ERROR)
        return robosuite.make(
            self.spec.env_name,
            robots=self.options.robot,
            controller_configs=load_composite_controller_config(robot=self.options.robot),
            has_renderer=False,
            has_offscreen_renderer=offscreen,
            use_camera_obs=False,
            control_freq=self.options.control_hz,
            ignore_done=True,  # else env.step refuses to run past the default horizon (1000)
            **self.spec.env_kwargs,
        )

    def _robosuite_actions(self, n: int) -> list[np.ndarray]:
        low, _ = self._env.action_spec
        return osc_actions(int(low.shape[0]), 1.0 / self.options.control_hz, n)

    def _restore_robosuite(self, state: np.ndarray) -> None:
        self._env.sim.set_state_from_flattened(state)
        self._env.sim.forward()

    def robosuite_step(self) -> None:
        self._env = self._make_robosuite_env(offscreen=False)
        try:
            self._env.reset()
            initial = np.array(self._env.sim.get_state().flatten())
            actions = self._robosuite_actions(self.options.steps)
            for action in actions[:WARMUP_STEPS]:
                self._env.step(action)
            self.result.robosuite_step_ms = []
            for _ in range(self.options.repeats):
                self._restore_robosuite(initial)
                self.result.robosuite_step_ms.append(ms_per_call(self._env.step, actions))
        finally:
            self._close_env()

    def robosuite_render(self) -> None:
        self._env = self._make_robosuite_env(offscreen=True)
        try:
            env = self._env
            env.reset()
            context = getattr(env.sim, "_render_context_offscreen", None)
            if context is not None:  # our renderers may have left another context current
                context.gl_ctx.make_current()
            initial = np.array(env.sim.get_state().flatten())
            frames = self.options.frames
            actions = self._robosuite_actions(frames)
            self.result.robosuite_render_ms = {}
            for width, height in self.options.sizes:

                def render(width: int = width, height: int = height) -> None:
                    env.sim.render(camera_name=self.camera, width=width, height=height)

                self._restore_robosuite(initial)
                for k in range(WARMUP_FRAMES):
                    env.step(actions[k % frames])
                    render()
                values = self.result.robosuite_render_ms.setdefault(size_key((width, height)), [])
                for _ in range(self.options.repeats):
                    self._restore_robosuite(initial)
                    values.append(ms_per_frame(render, lambda k: env.step(actions[k]), frames))
        finally:
            self._close_env()

    def _close_env(self) -> None:
        if self._env is not None:
            self._env.close()
        self._env = None
        release_memory()

    # memory
    def memory(self) -> None:
        self.result.memory_mib = measure_memory_in_subprocess(
            self.spec.name, self.options.robot, self.camera, self.options.sizes[0]
        )

    def close(self) -> None:
        """Free whatever a failed phase left open."""
        self._close_ours()
        self._close_env()


# --- memory, in a fresh process ---------------------------------------------------------------
def measure_memory_in_subprocess(
    task: str, robot: str, camera: str, size: tuple[int, int]
) -> dict[str, float]:
    """Run this file as a child process (nothing built yet) and read its memory report."""
    command = [
        sys.executable,
        str(Path(__file__).resolve()),
        "memory",
        "--task",
        task,
        "--robot",
        robot,
        "--camera",
        camera,
        "--width",
        str(size[0]),
        "--height",
        str(size[1]),
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=900, check=False)
    for line in reversed(done.stdout.splitlines()):
        if line.startswith(MEMORY_MARKER):
            return json.loads(line.removeprefix(MEMORY_MARKER))
    tail = "\n".join((done.stderr or done.stdout).splitlines()[-15:])
    raise RuntimeError(f"memory probe for {task} failed (exit {done.returncode}):\n{tail}")


def _rss_mib() -> float:
    gc.collect()
    return psutil.Process().memory_info().rss / MIB


def memory_probe(task: str, robot: str, camera: str, width: int, height: int) -> dict[str, float]:
    """RSS once crowdteleop + robosuite are imported, then after each of two simulations is
    built, reset and has rendered one frame (both kept alive)."""
    import robosuite  # noqa: F401  (part of the baseline for every task)

    import crowdteleop.control  # noqa: F401
    import crowdteleop.sim.robosuite_backend  # noqa: F401

    baseline = _rss_mib()
    sims = []
    after = []
    for _ in range(2):
        sim = make_simulation(SimConfig(task=task, robot=robot))
        sim.reset(seed=0)
        sim.render(camera, width, height)
        sims.append(sim)
        after.append(_rss_mib())
    for sim in sims:
        sim.close()
    return {
        "baseline": baseline,
        "after_first": after[0],
        "after_second": after[1],
        "first_sim": after[0] - baseline,
        "second_sim": after[1] - after[0],
    }


# --- machine facts ----------------------------------------------------------------------------
def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _version(package: str) -> str:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "not installed"


def _gl_renderer() -> str:
    """The OpenGL renderer MuJoCo gets under the current MUJOCO_GL (e.g. llvmpipe)."""
    try:
        import mujoco
        from OpenGL import GL

        context = mujoco.GLContext(16, 16)
        context.make_current()
        renderer = GL.glGetString(GL.GL_RENDERER).decode()
        context.free()
        return renderer
    except Exception as exc:  # any GL failure: report it rather than abort the benchmark
        return f"unavailable ({type(exc).__name__})"


def machine_facts() -> dict[str, str]:
    """What the figures depend on, printed above the table."""
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else "?"
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    return {
        "cpu": _cpu_model(),
        "cores": (
            f"{psutil.cpu_count(logical=False)} physical, {psutil.cpu_count()} logical, "
            f"{usable} usable"
        ),
        "memory": f"{psutil.virtual_memory().total / MIB / 1024:.1f} GiB",
        "load average (1, 5, 15 min)": load,
        "MUJOCO_GL": os.environ.get("MUJOCO_GL", "unset"),
        "PYOPENGL_PLATFORM": os.environ.get("PYOPENGL_PLATFORM", "unset"),
        "LP_NUM_THREADS": os.environ.get("LP_NUM_THREADS", "unset"),
        "GL renderer": _gl_renderer(),
        "python": platform.python_version(),
        "mujoco": _version("mujoco"),
        "robosuite": _version("robosuite"),
        "mink": _version("mink"),
        "numpy": _version("numpy"),
    }


def _main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="memory probe for benchmarks/sim.py")
    parser.add_argument("mode", choices=["memory"])
    parser.add_argument("--task", required=True)
    parser.add_argument("--robot", default="Sawyer")
    parser.add_argument("--camera", default="frontview")
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--height", type=int, default=240)
    args = parser.parse_args(argv)
    report = memory_probe(args.task, args.robot, args.camera, args.width, args.height)
    print(MEMORY_MARKER + json.dumps(report), flush=True)


if __name__ == "__main__":
    _main()
