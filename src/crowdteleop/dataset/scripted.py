"""Episodes recorded from scripted operators, step by step as the teleop server records them.

The platform's test users: each episode goes through the full control path (scripted operator
-> Teleoperator -> Simulation) and every control step through ``EpisodeRecorder`` with the
metadata the teleop session writes (``recording.metadata.episode_metadata``), so tests and
benchmarks exercise the very files workers produce.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from crowdteleop.control.command import DeviceCommand
from crowdteleop.control.config import ControlConfig
from crowdteleop.control.teleoperator import Teleoperator, TeleopStep
from crowdteleop.recording.episode_file import CommandRecord, StepLabels, StepRecord
from crowdteleop.recording.metadata import EpisodeMetadata, episode_metadata, simulation_facts
from crowdteleop.recording.versions import runtime_versions
from crowdteleop.recording.wal import EpisodeRecorder
from crowdteleop.sim.interface import Simulation
from crowdteleop.vocab import ControllerName, Outcome

if TYPE_CHECKING:  # the operator (scipy) loads with the first episode, as run_episode does
    from crowdteleop.control.scripted.operator import OperatorStyle


@dataclass(frozen=True)
class ScriptedEpisode:
    path: Path | None  # None when not finalized: ``recorder`` then waits for it
    recorder: EpisodeRecorder
    outcome: Outcome
    steps: int
    step_seconds: float  # wall time of the control steps alone (for overhead figures)
    record_seconds: float  # wall time of the appends alone (and of reading the step's labels)
    step_cpu_seconds: float  # CPU time of this thread in the control steps
    record_cpu_seconds: float  # ... and in the appends (a busy machine inflates wall times)


@dataclass(frozen=True)
class ScriptedRig:
    """One task's simulation, its control pipeline and what its episodes' files say."""

    sim: Simulation
    teleop: Teleoperator
    control: ControlConfig
    metadata: EpisodeMetadata


@contextmanager
def scripted_rig(
    task: str = "lift",
    controller: ControllerName = "ik-velocity",
    model_seed: int = 0,
    robot: str = "Sawyer",
) -> Iterator[ScriptedRig]:
    """A rig for one task; closes the simulation."""
    from crowdteleop.sim import SimConfig, make_simulation

    control = ControlConfig(controller=controller)
    config = SimConfig(
        task=task, action_mode=control.action_mode, model_seed=model_seed, robot=robot
    )
    sim = make_simulation(config)
    try:
        metadata = episode_metadata(
            config, control, camera="frontview", model_xml=sim.mjcf_xml(), reset_seed=0
        ).model_copy(update=simulation_facts(sim))
        yield ScriptedRig(sim, Teleoperator(sim, control), control, metadata)
    finally:
        sim.close()


def command_record(command: DeviceCommand, seq: int, wall_s: float, device: str) -> CommandRecord:
    """A scripted operator's command as the teleop server records a device's."""
    return {
        "seq": seq,
        "client_time_ms": 1000.0 * wall_s,
        "engaged": bool(command.engaged),
        "position": np.asarray(command.position).tolist(),
        "quaternion": np.asarray(command.quaternion).tolist(),
        "gripper": float(command.gripper_closed),
        "device": device,
    }


def _start_recording(
    rig: ScriptedRig, directory: Path, episode_id: str, seed: int
) -> EpisodeRecorder:
    """Reset with ``seed`` (as run_episode will) and open the episode's recorder with what
    this reset made: its model (with the bodies it placed: Door's door) and controller state."""
    rig.teleop.reset(seed)
    metadata = rig.metadata.model_copy(
        update={
            "reset_seed": seed,
            "model_xml": rig.sim.mjcf_xml(),
            "controller_state_at_start": [float(v) for v in rig.sim.controller_state()],
        }
    ).to_record()
    return EpisodeRecorder(directory, episode_id, metadata)


def record_scripted_episode(
    rig: ScriptedRig,
    directory: Path,
    episode_id: str,
    seed: int,
    extra_metadata: dict[str, Any] | None = None,
    time_limit_s: float | None = None,
    finalize: bool = True,
    style: OperatorStyle | None = None,
) -> ScriptedEpisode:
    """One scripted episode recorded into ``directory/<episode_id>.hdf5``; with ``finalize``
    False the recorder is left open, as the teleop server hands it to ``store_episode``.
    ``style``: the operator's (``control.scripted.skills.SKILLS``); None, the default one."""
    from crowdteleop.control.scripted import ScriptedOperator, run_episode

    sim, teleop, control = rig.sim, rig.teleop, rig.control
    extra = dict(extra_metadata or {})
    # reset_seed: replaying OSC actions needs the episode's reset (its null-space posture)
    operator = ScriptedOperator(sim, control.mapping, style=style, seed=seed)
    recorder = _start_recording(rig, directory, episode_id, seed)
    step_once = teleop.step
    timing = {"step": 0.0, "record": 0.0, "step_cpu": 0.0, "record_cpu": 0.0}

    def recorded_step(command: DeviceCommand) -> TeleopStep:
        state = sim.get_state()
        label_start, label_cpu = time.perf_counter(), time.thread_time()
        # the subtask label of `state`, read before the step as the teleop session does
        labels = StepLabels.read(sim)
        timing["record"] += time.perf_counter() - label_start
        timing["record_cpu"] += time.thread_time() - label_cpu
        started_wall, started, cpu = time.time(), time.perf_counter(), time.thread_time()
        step = step_once(command)
        duration = time.perf_counter() - started
        timing["step"] += duration
        timing["step_cpu"] += time.thread_time() - cpu
        record_start, record_cpu = time.perf_counter(), time.thread_time()
        recorder.append(
            StepRecord(
                index=recorder.steps,
                state=state,
                action=np.asarray(step.action, dtype=float),
                command=command_record(
                    command, recorder.steps, started_wall, str(extra.get("interface", "scripted"))
                ),
                server_time=started_wall,
                step_duration_s=duration,
                reward=float(step.result.reward),
                success=bool(step.result.success),
                contacts=[vars(c) for c in step.result.contacts],
                labels=labels,
            )
        )
        timing["record"] += time.perf_counter() - record_start
        timing["record_cpu"] += time.thread_time() - record_cpu
        return step

    teleop.step = recorded_step  # type: ignore[method-assign]  # record each step as it runs
    try:
        result = run_episode(teleop, operator, seed, time_limit_s=time_limit_s)
    finally:
        teleop.step = step_once  # type: ignore[method-assign]  # undo the wrapping
    outcome: Outcome = "success" if result.success else "timeout"
    path = (
        recorder.finalize(outcome, {"versions": runtime_versions(), **extra}) if finalize else None
    )
    return ScriptedEpisode(
        path,
        recorder,
        outcome,
        result.steps,
        timing["step"],
        timing["record"],
        timing["step_cpu"],
        timing["record_cpu"],
    )
