"""What makes a demonstration good or poor, measured once when its episode file is written
(off the control loop): the figures COBALT filters its crowd data by (completion time, path
length, jitter, the network, resets) and those LeRobot's users ask for (jerk, idle time).

Each metric is a field of `EpisodeMetrics`, whose description says what it is, in which unit
and why it matters; the functions below compute them from the episode's recorded arrays (the
hand pose of its labels, the device commands, the contacts) and the session's telemetry. A
metric the recording cannot give (an episode recorded without labels has no hand path) is
None, never a made-up number. numpy only: the coordinator imports the model.
"""

from __future__ import annotations

import itertools
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field, model_validator

from crowdteleop.recording.metadata import DEFAULT_CONTROL_HZ
from crowdteleop.vocab import TABLE_CONTACT

IDLE_SPEED_M_S = 0.02  # the device slower than this, the gripper unchanged: nothing is done
SPEED_WINDOW_S = 1.0  # ... over this window, in which a hand's tremor cancels out
IDLE_PAUSE_MIN_S = 0.5  # a shorter stop in between is part of moving, not a pause
CHATTER_WINDOW_S = 1.0  # a gripper change this soon after the previous one is chatter
MIN_STRAIGHT_M = 0.01  # path ratios over a shorter straight line would say nothing
# Paths are measured on the hand's positions averaged over this window: an arm under OSC
# holding a still command near an object trembles a few millimetres at 10 Hz, which over a
# 10 s pause would add a metre of "path"; a person's motion (below ~2 Hz) passes unchanged.
PATH_SMOOTHING_S = 0.2
JOINT_LIMIT_MARGIN = 0.05  # of the joint's range: "near its limit"
SETBACK_MIN_S = 0.5  # a stage gone back to for less is the stage test flickering
SPARC_CUTOFF_HZ = 10.0  # spectral arc length over speeds below this (Balasubramanian 2015)
SPARC_AMPLITUDE_THRESHOLD = 0.05
SPARC_PADDING = 4  # zero padding, as powers of two past the signal's length
TOUCH_GAP_S = 0.25  # a table contact broken for less is the same touch (a finger sliding on it)

Floats = npt.NDArray[np.float64]


class EpisodeMetrics(BaseModel):
    """One episode's quality figures (None: the recording cannot give it)."""

    model_config = ConfigDict(extra="ignore")  # metrics added later are read by older code

    completion_time_s: float = Field(
        description="seconds from the first step to the last (s): slow demonstrations teach "
        "slow, hesitant policies"
    )
    idle_start_s: float | None = Field(
        None, description="seconds before the hand first moves (s): time spent finding bearings"
    )
    idle_end_s: float | None = Field(
        None, description="seconds after the hand last moves (s): a policy learns to stall"
    )
    idle_between_s: float | None = Field(
        None,
        description=f"seconds of pauses of {IDLE_PAUSE_MIN_S} s or more between the first "
        "and the last move (s): a policy cannot tell when to resume",
    )
    idle_fraction: float | None = Field(
        None, description="idle time (start, end and pauses) over the completion time (0-1)"
    )
    longest_pause_s: float | None = Field(
        None, description="the longest pause between the first and the last move (s)"
    )
    longest_pause_stage: str | None = Field(
        None, description="the task stage halfway through the longest pause (e.g. 'grasp')"
    )
    path_length_m: float | None = Field(
        None,
        description="the distance the hand travelled (m), its positions averaged over 0.2 s: an "
        "arm under OSC holding still near an object trembles a few millimetres at 10 Hz, which "
        "over a 10 s pause would add a metre",
    )
    path_ratio: float | None = Field(
        None,
        description="path length over the straight lines through the hand's waypoints: its "
        "start, where each stage of the task began, its end (1 or more): detours and "
        "back-and-forth make it grow",
    )
    jerk_rms_m_s3: float | None = Field(
        None,
        description="root mean square of the hand's jerk, the third derivative of its "
        "position (m/s^3): tremor and jolts, which policies imitate",
    )
    angular_jerk_rms_rad_s3: float | None = Field(
        None, description="the same of the hand's orientation (rad/s^3)"
    )
    sparc: float | None = Field(
        None,
        description="spectral arc length of the hand's speed (no unit, <= 0; closer to 0 is "
        "smoother): a smoothness measure independent of the movement's length and duration",
    )
    setbacks: int | None = Field(
        None,
        description=f"times the task went back to a stage it had left, for {SETBACK_MIN_S} s "
        "or more (count): a dropped or lost object, a grasp that slipped",
    )
    first_setback: str | None = Field(
        None,
        description="the first of them, 'from -> to at seconds' (e.g. 'grasped -> reach at 6.2 s')",
    )
    clutch_reanchors: int | None = Field(
        None,
        description="times the worker let go of the clutch and took it again (count): each is "
        "a pause and a re-aim",
    )
    gripper_changes: int | None = Field(
        None, description="times the gripper command opened or closed (count)"
    )
    gripper_chatter: int | None = Field(
        None,
        description=f"gripper changes within {CHATTER_WINDOW_S} s of the previous one "
        "(count): hesitant grasps that policies copy",
    )
    table_contacts: int | None = Field(
        None,
        description="times the arm touched the table (count; contacts less than "
        f"{TOUCH_GAP_S} s apart are one touch): pressing into the table strains the arm and "
        "shoves the objects, and a policy learns to scrape",
    )
    table_contact_s: float | None = Field(
        None, description="seconds the arm spent touching the table (s)"
    )
    joint_limit_fraction: float | None = Field(
        None,
        description=f"share of steps with an arm joint within {JOINT_LIMIT_MARGIN:.0%} of its "
        "range from a limit (0-1): awkward postures the controller fights",
    )
    resets_before: int | None = Field(
        None,
        description="episodes the worker reset or failed in this session since their last "
        "success (count): how hard this one came",
    )
    latency_p50_ms: float | None = Field(
        None, description="median control-to-photon latency while recording (ms)"
    )
    latency_p95_ms: float | None = Field(
        None, description="95th percentile of that latency (ms): lag makes people overshoot"
    )
    rtt_jitter_ms: float | None = Field(
        None, description="mean change between successive round-trip times (ms)"
    )
    loss_fraction: float | None = Field(None, description="video packets lost (0-1)")
    video_stalls: int | None = Field(
        None, description="times the worker's video stopped during the episode (count)"
    )

    @model_validator(mode="before")
    @classmethod
    def _finite(cls, values: Any) -> Any:
        """A metric of a recording with NaN in it is unknown (None), not NaN: the report to
        the coordinator and its database take finite numbers only."""
        if not isinstance(values, dict):
            return values
        return {
            k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in values.items()
        }


class RecordedLabels(Protocol):
    """An episode's labels (`recording.episode_file.EpisodeLabels`) as the metrics read them."""

    @property
    def hand_pose(self) -> Floats: ...

    @property
    def stage(self) -> list[str]: ...


class RecordedEpisode(Protocol):
    """An episode's arrays (`recording.episode_file.EpisodeData`) as the metrics read them."""

    @property
    def labels(self) -> RecordedLabels | None: ...

    @property
    def commands(self) -> Sequence[Mapping[str, Any]]: ...

    @property
    def states(self) -> Floats: ...

    @property
    def contacts(self) -> Sequence[Sequence[Mapping[str, Any]]]: ...


@dataclass(frozen=True)
class MotionInputs:
    """What the metrics read of an episode: per step (N of them, `dt_s` apart) the hand's
    pose and stage, the commands' clutch, gripper and device position, and the state; and the
    arm's joints (where in the state, their limits) and whether the arm touched the table,
    when the recording says."""

    dt_s: float
    hand_pose: Floats | None  # (N, 7) x y z qx qy qz qw, or None without labels
    stages: Sequence[str] | None
    engaged: Sequence[bool]
    gripper_closed: Sequence[bool]
    states: Floats
    command_positions: Floats | None = None  # (N, 3) the device's, metres
    arm_state_index: Sequence[int] | None = None
    arm_limits_rad: Floats | None = None  # (J, 2)
    on_table: Sequence[bool] | None = None  # per step: the arm touching the table


def episode_metrics(
    motion: MotionInputs, telemetry: Mapping[str, Any], resets_before: int | None = None
) -> EpisodeMetrics:
    """Every metric of one episode."""
    steps = len(motion.states)
    return EpisodeMetrics(
        completion_time_s=round(steps * motion.dt_s, 3),
        **_hand_metrics(motion),
        clutch_reanchors=clutch_reanchors(motion.engaged) if motion.engaged else None,
        **_gripper_metrics(motion),
        **table_metrics(motion.on_table, motion.dt_s),
        joint_limit_fraction=joint_limit_fraction(motion),
        resets_before=resets_before,
        **network_metrics(telemetry),
    )


def _hand_metrics(motion: MotionInputs) -> dict[str, Any]:
    pose = motion.hand_pose
    if pose is None or len(pose) < 4:
        return {}
    positions, dt = pose[:, :3], motion.dt_s
    # Idle is the worker's: their device held still (an arm under OSC keeps trembling a few
    # millimetres on a still command), or the hand where no device positions were recorded.
    device = motion.command_positions
    still_source = device if device is not None and len(device) == len(pose) else positions
    moving = moving_steps(still_source, motion.gripper_closed, dt)
    return {
        **setback_metrics(motion.stages, dt),
        **idle_metrics(moving, dt, motion.stages),
        **_path_metrics(smoothed(positions, round(PATH_SMOOTHING_S / dt)), motion.stages),
        "jerk_rms_m_s3": round(jerk_rms(positions, dt), 4),
        "angular_jerk_rms_rad_s3": round(jerk_rms(angular_path(pose[:, 3:]), dt), 4),
        "sparc": sparc(np.linalg.norm(np.diff(positions, axis=0), axis=1) / dt, 1 / dt),
    }


def _path_metrics(positions: Floats, stages: Sequence[str] | None) -> dict[str, Any]:
    return {
        "path_length_m": round(path_length_m(positions), 4),
        "path_ratio": path_ratio(positions, stages),
    }


def smoothed(path: Floats, window: int) -> Floats:
    """(N, D) `path` averaged over `window` steps centred on each (ends held): a moving
    average, so an oscillation whose period divides the window vanishes."""
    if window <= 1 or len(path) < window:
        return path
    before = window // 2
    padded = np.concatenate(
        [np.repeat(path[:1], before, 0), path, np.repeat(path[-1:], window - 1 - before, 0)]
    )
    sums: Floats = np.cumsum(np.concatenate([np.zeros((1, path.shape[1])), padded]), axis=0)
    averaged: Floats = (sums[window:] - sums[:-window]) / window
    return averaged


def _gripper_metrics(motion: MotionInputs) -> dict[str, Any]:
    if not motion.gripper_closed:
        return {}
    changes = np.flatnonzero(np.diff(np.asarray(motion.gripper_closed, dtype=np.int8)))
    gaps_s = np.diff(changes) * motion.dt_s
    return {
        "gripper_changes": int(changes.size),
        "gripper_chatter": int(np.count_nonzero(gaps_s < CHATTER_WINDOW_S)),
    }


def moving_steps(positions: Floats, gripper_closed: Sequence[bool], dt_s: float) -> Any:
    """(N,) bool: the steps in which the device (or hand) went faster than `IDLE_SPEED_M_S`
    over the `SPEED_WINDOW_S` around it, or the gripper command changed. Over a window, a
    trembling hand held in the air nets nothing: tremor is not moving."""
    n = len(positions)
    half = max(1, round(SPEED_WINDOW_S / dt_s / 2))
    index = np.arange(n)
    low, high = np.maximum(index - half, 0), np.minimum(index + half, n - 1)
    span_s = np.maximum(high - low, 1) * dt_s
    speed = np.linalg.norm(positions[high] - positions[low], axis=1) / span_s
    moving = speed > IDLE_SPEED_M_S
    if len(gripper_closed) == n:
        closed = np.asarray(gripper_closed, dtype=np.int8)
        moving[1:] |= np.diff(closed) != 0
    return moving


def idle_metrics(moving: Any, dt_s: float, stages: Sequence[str] | None) -> dict[str, Any]:
    """Idle at the start, at the end and in pauses between, in seconds and as one fraction;
    the longest pause and the stage it began in."""
    steps = len(moving)
    indices = np.flatnonzero(moving)
    if indices.size == 0:
        return {
            "idle_start_s": steps * dt_s,
            "idle_end_s": 0.0,
            "idle_between_s": 0.0,
            "idle_fraction": 1.0,
            "longest_pause_s": 0.0,
        }
    first, last = int(indices[0]), int(indices[-1])
    pauses = _pauses(moving[first : last + 1], dt_s)
    between_s = sum(length for _, length in pauses) * dt_s
    start_s, end_s = first * dt_s, (steps - 1 - last) * dt_s
    longest = max(pauses, key=lambda pause: pause[1], default=None)
    stage = None
    if longest is not None and stages is not None and len(stages) == steps:
        stage = stages[first + longest[0] + longest[1] // 2] or None  # where most of it was
    return {
        "idle_start_s": round(start_s, 3),
        "idle_end_s": round(end_s, 3),
        "idle_between_s": round(between_s, 3),
        "idle_fraction": round((start_s + end_s + between_s) / (steps * dt_s), 4),
        "longest_pause_s": round(longest[1] * dt_s, 3) if longest else 0.0,
        "longest_pause_stage": stage,
    }


def _pauses(moving: Any, dt_s: float) -> list[tuple[int, int]]:
    """(start, length) of each run of still steps at least `IDLE_PAUSE_MIN_S` long."""
    still = np.concatenate([[0], (~moving).astype(np.int8), [0]])
    edges = np.diff(still)
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    minimum = int(np.ceil(IDLE_PAUSE_MIN_S / dt_s))
    return [(int(s), int(e - s)) for s, e in zip(starts, ends, strict=True) if e - s >= minimum]


def setback_metrics(stages: Sequence[str] | None, dt_s: float) -> dict[str, Any]:
    """Returns to a stage already left ("grasped" -> "reach": the object was dropped) that
    last `SETBACK_MIN_S` or more; the first one, said as a person would."""
    if not stages:
        return {}
    runs: list[tuple[str, int, int]] = []  # (stage, first step, length)
    for index, stage in enumerate(stages):
        if runs and runs[-1][0] == stage:
            runs[-1] = (stage, runs[-1][1], runs[-1][2] + 1)
        else:
            runs.append((stage, index, 1))
    minimum = int(np.ceil(SETBACK_MIN_S / dt_s))
    kept = [run for run in runs if run[2] >= minimum or run is runs[0]]
    order: dict[str, int] = {}  # each stage's place in the task: where it first appeared
    for stage, _, _ in kept:
        order.setdefault(stage, len(order))
    setbacks = [
        f"{previous[0]} -> {stage} at {start * dt_s:.1f} s"
        for previous, (stage, start, _) in itertools.pairwise(kept)
        if order[stage] < order[previous[0]]
    ]
    return {"setbacks": len(setbacks), "first_setback": setbacks[0] if setbacks else None}


def path_length_m(positions: Floats) -> float:
    return float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum())


def path_ratio(positions: Floats, stages: Sequence[str] | None = None) -> float | None:
    """Path length over the straight lines between the hand's waypoints: where it began,
    where each stage of the task began (the grasp, the lift...) and where it ended. 1 for the
    straightest; None when those lines are too short to say (the hand hardly went anywhere)."""
    marks = [0, len(positions) - 1]
    if stages is not None and len(stages) == len(positions):
        marks += [i for i in range(1, len(stages)) if stages[i] != stages[i - 1]]
    waypoints = positions[sorted(set(marks))]
    straight = float(np.linalg.norm(np.diff(waypoints, axis=0), axis=1).sum())
    if straight < MIN_STRAIGHT_M:
        return None
    return round(path_length_m(positions) / straight, 4)


def jerk_rms(path: Floats, dt_s: float) -> float:
    """Root mean square of the third finite difference of a (N, D) path over dt^3."""
    if len(path) < 4:
        return 0.0
    jerk = np.diff(path, n=3, axis=0) / dt_s**3
    return float(np.sqrt(np.mean(np.sum(jerk**2, axis=1))))


def angular_path(quaternions: Floats) -> Floats:
    """(N, 3) the orientation as a rotation vector accumulated step by step from the first
    (x y z w quaternions), so its derivatives are angular velocity, acceleration and jerk."""
    q = quaternions / np.linalg.norm(quaternions, axis=1, keepdims=True)
    previous, current = q[:-1], q[1:]
    # relative rotation previous^-1 * current, as a rotation vector
    w = np.sum(previous * current, axis=1)
    sign = np.where(w < 0, -1.0, 1.0)
    pw, pv = previous[:, 3:], -previous[:, :3]
    cw, cv = current[:, 3:], current[:, :3]
    vector = pw * cv + cw * pv + np.cross(pv, cv)
    vector *= sign[:, None]
    norm = np.linalg.norm(vector, axis=1)
    angle = 2 * np.arctan2(norm, np.abs(w))
    scale = np.where(norm > 1e-12, angle / np.maximum(norm, 1e-12), 2.0)
    steps = vector * scale[:, None]
    return np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])


def sparc(speed: Floats, sample_hz: float) -> float | None:
    """Spectral arc length (Balasubramanian et al. 2015) of a speed profile: the length of
    its normalised magnitude spectrum up to `SPARC_CUTOFF_HZ`, cut where it stays below
    `SPARC_AMPLITUDE_THRESHOLD`; negative, closer to 0 for a smoother movement."""
    if len(speed) < 4 or not np.any(speed > 0):
        return None
    size = int(2 ** (np.ceil(np.log2(len(speed))) + SPARC_PADDING))
    frequencies = np.fft.rfftfreq(size, 1 / sample_hz)
    magnitude = np.abs(np.fft.rfft(speed, size))
    magnitude /= magnitude.max()
    band = frequencies <= SPARC_CUTOFF_HZ
    frequencies, magnitude = frequencies[band], magnitude[band]
    above = np.flatnonzero(magnitude >= SPARC_AMPLITUDE_THRESHOLD)
    end = int(above[-1]) + 1 if above.size else len(magnitude)
    frequencies, magnitude = frequencies[:end], magnitude[:end]
    span = frequencies[-1] - frequencies[0] if end > 1 else 1.0
    arc = -np.sum(np.sqrt((np.diff(frequencies) / span) ** 2 + np.diff(magnitude) ** 2))
    return round(float(arc), 4)


def clutch_reanchors(engaged: Sequence[bool]) -> int:
    """Times the clutch was taken again after a release (the first take is no re-anchor)."""
    held = np.asarray(engaged, dtype=np.int8)
    takes = int(np.count_nonzero(np.diff(held) == 1)) + int(held[0] == 1)
    return max(0, takes - 1)


def table_metrics(on_table: Sequence[bool] | None, dt_s: float) -> dict[str, Any]:
    """Touches of the table (gaps shorter than `TOUCH_GAP_S` joined) and the time in contact."""
    if on_table is None or not len(on_table):
        return {}
    touching = np.asarray(on_table, dtype=bool)
    steps = np.flatnonzero(touching)
    gaps = np.diff(steps) - 1  # steps without contact between two with it
    touches = int(len(steps) > 0) + int(np.count_nonzero(gaps * dt_s >= TOUCH_GAP_S))
    return {"table_contacts": touches, "table_contact_s": round(len(steps) * dt_s, 3)}


def joint_limit_fraction(motion: MotionInputs) -> float | None:
    if motion.arm_state_index is None or motion.arm_limits_rad is None:
        return None
    joints = motion.states[:, list(motion.arm_state_index)]
    low, high = motion.arm_limits_rad[:, 0], motion.arm_limits_rad[:, 1]
    limited = high > low  # a joint without a range has no limit to come near
    margin = (high - low) * JOINT_LIMIT_MARGIN
    near = ((joints - low < margin) | (high - joints < margin)) & limited
    return round(float(np.mean(np.any(near, axis=1))), 4)


def network_metrics(telemetry: Mapping[str, Any]) -> dict[str, Any]:
    """The network figures the teleop server measured while the episode was recorded (none
    for an episode recorded without a worker's link, such as a scripted one)."""
    names = ("latency_p50_ms", "latency_p95_ms", "rtt_jitter_ms", "loss_fraction")
    found: dict[str, Any] = {n: float(telemetry[n]) for n in names if n in telemetry}
    for name in ("latency_p50_ms", "latency_p95_ms"):  # 0: no client reported any (unknown)
        if found.get(name, 1.0) <= 0:
            del found[name]
    if "episode_video_stalls" in telemetry:
        found["video_stalls"] = int(telemetry["episode_video_stalls"])
    return found


def motion_of(episode: RecordedEpisode, metadata: Mapping[str, Any]) -> MotionInputs:
    """An episode's arrays as the metrics read them (`metadata`: the episode's, with the
    `control_hz` and `arm_joints` its writer recorded)."""
    labels = episode.labels
    commands = episode.commands
    arm = metadata.get("arm_joints") or {}
    return MotionInputs(
        dt_s=1.0 / float(metadata.get("control_hz") or DEFAULT_CONTROL_HZ),
        hand_pose=labels.hand_pose if labels is not None else None,
        stages=labels.stage if labels is not None else None,
        engaged=[bool(c.get("engaged")) for c in commands] if _has(commands, "engaged") else [],
        gripper_closed=[_closed(c.get("gripper")) for c in commands]
        if _has(commands, "gripper")
        else [],
        states=episode.states,
        command_positions=_command_positions(commands),
        arm_state_index=arm.get("state_index"),
        arm_limits_rad=np.asarray(arm["limits_rad"], dtype=float) if arm else None,
        on_table=_on_table(episode.contacts, metadata),
    )


def measure(episode: RecordedEpisode, metadata: Mapping[str, Any]) -> EpisodeMetrics:
    """The metrics of an episode about to be written (`metadata`: what it will carry, with
    the session's `telemetry` and `resets_before` where a teleop server recorded it)."""
    telemetry = metadata.get("telemetry")
    resets = metadata.get("resets_before")
    return episode_metrics(
        motion_of(episode, metadata),
        telemetry if isinstance(telemetry, Mapping) else {},
        resets if isinstance(resets, int) else None,
    )


def _command_positions(commands: Sequence[Mapping[str, Any]]) -> Floats | None:
    """The device positions, (N, 3); None unless every command carries three numbers."""
    if not _has(commands, "position"):
        return None
    try:
        positions = np.asarray([c["position"] for c in commands], dtype=float)
    except (TypeError, ValueError):
        return None
    return positions if positions.shape == (len(commands), 3) else None


def _on_table(
    contacts: Sequence[Sequence[Mapping[str, Any]]], metadata: Mapping[str, Any]
) -> list[bool] | None:
    """Per step, any contact with the table; None for a recording whose contacts could not
    name it (recorded before the table's were, or a scene without one)."""
    if TABLE_CONTACT not in (metadata.get("contact_objects") or ()):
        return None
    return [any(c.get("object") == TABLE_CONTACT for c in step) for step in contacts]


def _has(commands: Sequence[Mapping[str, Any]], key: str) -> bool:
    return bool(commands) and all(key in c for c in commands)


def _closed(gripper: Any) -> bool:
    """A device sends the gripper as a bool, the scripted rig as a closed fraction."""
    if isinstance(gripper, bool):
        return gripper
    return isinstance(gripper, int | float) and bool(np.isfinite(gripper)) and gripper >= 0.5


class QualityThresholds(BaseModel):
    """Past these a demonstration is flagged, with a reason a person can read: a campaign's
    `quality` setting (each may be changed; the defaults suit the built-in tasks at 20 Hz)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    longest_pause_s: float = Field(5.0, gt=0, description="a pause longer than this")
    idle_start_s: float = Field(10.0, gt=0, description="longer before the first move")
    path_ratio: float = Field(2.0, gt=1, description="a path longer than this many straight")
    gripper_chatter: int = Field(2, ge=1, description="this many quick gripper reversals")
    setbacks: int = Field(1, ge=1, description="this many returns to an earlier stage")
    clutch_reanchors: int = Field(8, ge=1, description="this many clutch re-anchors")
    table_contact_s: float = Field(0.3, gt=0, description="longer than this touching the table")
    joint_limit_fraction: float = Field(0.25, gt=0, le=1, description="this share near a limit")
    latency_p95_ms: float = Field(400.0, gt=0, description="a slower link than this")
    video_stalls: int = Field(1, ge=1, description="this many video stalls")


class QualityFlag(BaseModel):
    """Why a demonstration stands out: the metric, and a sentence for the reviewer."""

    metric: str
    reason: str


def _flag_reason(metrics: EpisodeMetrics, name: str, value: float) -> str:
    stage = metrics.longest_pause_stage
    reasons = {
        "longest_pause_s": f"idle {value:.0f} s" + (f" in the '{stage}' stage" if stage else ""),
        "idle_start_s": f"{value:.0f} s before the hand first moved",
        "path_ratio": f"a detour: the hand travelled {value:.1f} times the straight path",
        "gripper_chatter": f"a hesitant grasp: the gripper changed {metrics.gripper_changes} "
        f"times, {value:.0f} of them within {CHATTER_WINDOW_S:.0f} s of the last",
        "setbacks": f"went back a stage ({metrics.first_setback}): dropped or lost the object",
        "clutch_reanchors": f"let go of the clutch and took it again {value:.0f} times",
        "table_contact_s": f"pressed into the table: {_times(metrics.table_contacts)}, "
        f"{value:.1f} s in all",
        "joint_limit_fraction": f"{value:.0%} of the time with a joint near its limit",
        "latency_p95_ms": f"a slow link: 1 frame in 20 took over {value:.0f} ms",
        "video_stalls": f"the video stalled {value:.0f} times",
    }
    return reasons[name]


def _times(count: int | None) -> str:
    return "once" if count == 1 else f"{count} times"


def quality_flags(metrics: EpisodeMetrics, thresholds: QualityThresholds) -> list[QualityFlag]:
    """The metrics past their thresholds (at or past, for counts), each with its reason."""
    flags = []
    for name, limit in thresholds.model_dump().items():
        value = getattr(metrics, name)
        if value is None:
            continue
        past = value >= limit if isinstance(limit, int) else value > limit
        if past:
            flags.append(QualityFlag(metric=name, reason=_flag_reason(metrics, name, value)))
    return flags


# The composite score's metrics, and which way is better (+1: higher, -1: lower).
SCORED_METRICS: dict[str, int] = {
    "completion_time_s": -1,
    "idle_fraction": -1,
    "path_ratio": -1,
    "jerk_rms_m_s3": -1,
    "sparc": 1,
    "gripper_chatter": -1,
    "setbacks": -1,
    "clutch_reanchors": -1,
}


def better_than(value: float, ordered: Sequence[float], direction: int) -> float:
    """The share (0-1) of the ascending `ordered` values that `value` is better than, ties
    counting half: a percentile rank."""
    below = int(np.searchsorted(ordered, value, side="left"))
    above = len(ordered) - int(np.searchsorted(ordered, value, side="right"))
    ties = len(ordered) - below - above
    return ((below if direction > 0 else above) + 0.5 * ties) / len(ordered)


def quality_score(
    metrics: EpisodeMetrics, distributions: Mapping[str, Sequence[float]]
) -> float | None:
    """0-100: the mean, over `SCORED_METRICS`, of the percentile of this episode among
    `distributions` (each metric's values over the campaign's successful episodes of the
    task, ascending). None without any metric to compare."""
    ranks = [
        better_than(value, distributions[name], direction)
        for name, direction in SCORED_METRICS.items()
        if (value := getattr(metrics, name)) is not None and distributions.get(name)
    ]
    return round(100 * statistics.fmean(ranks), 1) if ranks else None
