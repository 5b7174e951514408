"""What every recorded episode says about how it was made: one model for its writers (the
teleop server, the scripted rig) and its readers (the dataset tools), and `episode_metadata`,
the one way both writers fill it in.

Stored as JSON in the episode file (``crowdteleop.recording.episode_file``); campaigns may add
keys of their own (``campaign``, ``network_condition``, ``interface``...), kept as extras.
Fields have defaults so files recorded before a field existed still read. ``env_args`` and the
controller it names are typed by ``crowdteleop.provenance``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated, Any, Protocol

from pydantic import BaseModel, ConfigDict, Field, StringConstraints

from crowdteleop.provenance.env_args import EnvArgs, SimSettings
from crowdteleop.recording.versions import runtime_versions
from crowdteleop.vocab import ActionMode, ControllerName

DEFAULT_CONTROL_HZ = 20.0
REGION_NAME_PATTERN = r"^[a-z0-9][a-z0-9_-]{0,31}$"
RegionName = Annotated[str, StringConstraints(pattern=REGION_NAME_PATTERN)]
RoundTripMs = Annotated[float, Field(ge=0, le=60_000, allow_inf_nan=False)]


class RegionChoice(BaseModel):
    """Where a worker was sent among a campaign's regions (each a coordinator with its own
    cluster), and the round trips their join page measured to each, which decided it: the
    paper's Oregon-vs-China comparison, kept with every episode."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    region: RegionName = Field(description="the region whose teleop server recorded this")
    rtts_ms: dict[RegionName, RoundTripMs] = Field(
        default_factory=dict,
        max_length=16,
        description="the worker's measured round trip to each region it could reach",
    )


class ArmJoints(BaseModel):
    """Where the arm's joint positions sit in each recorded state, and their limits: what the
    quality metrics (`recording/quality.py`) read postures from without the simulator."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    state_index: list[int] = Field(description="index of each joint's position in a state")
    limits_rad: list[tuple[float, float]] = Field(description="each joint's (low, high)")

    @classmethod
    def of(cls, state_index: Sequence[int], limits_rad: Any) -> ArmJoints:
        """From a simulation's `KinematicModel` (`state_index`, `joint_position_limits`)."""
        return cls(
            state_index=[int(i) for i in state_index],
            limits_rad=[(float(low), float(high)) for low, high in limits_rad],
        )


class ArmKinematics(Protocol):
    """A simulation's `KinematicModel`, as far as `arm_joints_of` reads it."""

    @property
    def state_index(self) -> tuple[int, ...]: ...

    @property
    def joint_position_limits(self) -> Any: ...


class KnowsKinematics(Protocol):
    def kinematics(self) -> ArmKinematics: ...


class RecordedSimulation(KnowsKinematics, Protocol):
    """A simulation, as far as the episode metadata records facts of it."""

    @property
    def contact_objects(self) -> tuple[str, ...]: ...


def arm_joints_of(sim: KnowsKinematics) -> ArmJoints | None:
    """The simulation's arm joints, as the episode metadata records them (None: a backend
    that does not say where they are in its state)."""
    kinematics = sim.kinematics()
    if not kinematics.state_index:
        return None
    return ArmJoints.of(kinematics.state_index, kinematics.joint_position_limits)


def simulation_facts(sim: RecordedSimulation) -> dict[str, Any]:
    """What an episode's metadata records of the simulation it ran in (an update for
    `EpisodeMetadata.model_copy`): where its arm joints are, what its contacts can name."""
    return {"arm_joints": arm_joints_of(sim), "contact_objects": list(sim.contact_objects)}


class EpisodeMetadata(BaseModel):
    model_config = ConfigDict(extra="allow")

    session_id: str | None = Field(None, description="none for episodes made outside sessions")
    worker_id: str | None = None
    task: str = "unknown"
    robot: str = "Sawyer"
    controller: ControllerName | None = None
    action_mode: ActionMode | None = None
    control_hz: float = Field(DEFAULT_CONTROL_HZ, gt=0)
    camera: str = "frontview"
    sim_config: dict[str, Any] = Field(default_factory=dict)
    control_config: dict[str, Any] = Field(default_factory=dict)
    model_xml: str = Field("", repr=False)
    reset_seed: int | None = Field(None, description="the reset that began the episode")
    env_args: EnvArgs | None = None
    episode: int | None = Field(None, description="1-based number within its session")
    interface: str | None = Field(None, description="the device the worker used, if known")
    region: RegionChoice | None = Field(None, description="none where a campaign has no regions")
    controller_state_at_start: list[float] | None = Field(
        None,
        description="the simulation's controller state (robosuite's ramped finger command) "
        "before the first step: with the states and actions it restores every step exactly",
    )
    arm_joints: ArmJoints | None = Field(
        None, description="the arm's joints in the states (recordings since issue 29)"
    )
    contact_objects: list[str] | None = Field(
        None,
        description="what the steps' contacts can name as touched: the task's objects and "
        "'table' (recordings since the table's were recorded; before, a table touch was not)",
    )

    def to_record(self) -> dict[str, Any]:
        """The JSON-ready dict the recorder stores (unset optional fields left out)."""
        return self.model_dump(mode="json", exclude_none=True)


class RecordedSim(SimSettings, Protocol):
    """A simulation's config as an episode records it (``crowdteleop.sim.config.SimConfig``:
    recording sits below ``sim`` and reads it through this protocol)."""

    def model_dump(self, *, mode: str) -> dict[str, Any]: ...


class RecordedControl(Protocol):
    """The control config as an episode records it
    (``crowdteleop.control.config.ControlConfig``)."""

    @property
    def controller(self) -> ControllerName: ...
    def model_dump(self, *, mode: str) -> dict[str, Any]: ...


def episode_metadata(
    sim: RecordedSim,
    control: RecordedControl,
    camera: str,
    model_xml: str,
    reset_seed: int,
    session_id: str | None = None,
    worker_id: str | None = None,
    region: RegionChoice | None = None,
) -> EpisodeMetadata:
    """How an episode on this simulation is made: written by the teleop session and the
    scripted rig alike, so tests and benchmarks record the very files workers produce."""
    return EpisodeMetadata(
        session_id=session_id,
        worker_id=worker_id,
        region=region,
        task=sim.task,
        robot=sim.robot,
        controller=control.controller,
        action_mode=sim.action_mode,
        control_hz=sim.control_hz,
        camera=camera,
        sim_config=sim.model_dump(mode="json"),
        control_config=control.model_dump(mode="json"),
        model_xml=model_xml,
        reset_seed=reset_seed,
        env_args=EnvArgs.of(sim, robosuite_version()),
    )


def robosuite_version() -> str:
    """The robosuite this process runs (robomimic's ``env_version``)."""
    return runtime_versions().get("robosuite", "unknown")
