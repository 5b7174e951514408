"""What a campaign asks of its workers: tasks, arms, controllers, interfaces, how many demos."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import yaml
from pydantic import AnyHttpUrl, BaseModel, ConfigDict, Field, field_validator, model_validator

from crowdteleop.recording.metadata import RegionName
from crowdteleop.recording.quality import QualityThresholds
from crowdteleop.tasks import ROBOSUITE_ARMS, get_task, task_names
from crowdteleop.vocab import WORKER_DEVICES, ControllerName, WorkerDevice

NAME_PATTERN = r"^[a-z0-9][a-z0-9_-]{0,63}$"


def _default_controllers() -> list[ControllerName]:
    return ["ik-velocity"]


class Region(BaseModel):
    """One place serving a campaign: a coordinator with its own cluster, at its public URL."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: RegionName
    url: AnyHttpUrl = Field(description="its coordinator's public URL (its join page is `/`)")

    @property
    def origin(self) -> str:
        """scheme://host[:port], as a browser's Origin and a CSP source name it."""
        port = f":{self.url.port}" if self.url.port not in (None, 80, 443) else ""
        return f"{self.url.scheme}://{self.url.host}{port}"


class ReviewPolicy(BaseModel):
    """How a campaign's demonstrations are accepted: by reviewers on /review, and where the
    score is clear by the score itself (docs/review.md)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    accepted_required: int = Field(
        0,
        ge=0,
        le=1000,
        description="accepted demonstrations a worker needs before their completion code; "
        "0: the code comes after `demos_required` successes, reviewed or not",
    )
    auto_accept_score: float | None = Field(
        None,
        ge=0,
        le=100,
        description="a successful, unflagged demonstration scoring at least this is "
        "accepted automatically; None: only reviewers accept",
    )
    auto_reject_score: float | None = Field(
        None,
        ge=0,
        le=100,
        description="a demonstration scoring below this is rejected automatically; None: "
        "only reviewers reject",
    )

    @model_validator(mode="after")
    def _reject_below_accept(self) -> ReviewPolicy:
        low, high = self.auto_reject_score, self.auto_accept_score
        if low is not None and high is not None and low >= high:
            raise ValueError(f"auto_reject_score ({low}) must be below auto_accept_score ({high})")
        return self


class CampaignConfig(BaseModel):
    """One data-collection campaign; sessions are assigned round-robin over its lists."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field("default", pattern=NAME_PATTERN)
    title: str = Field("Teach a robot arm", max_length=200)
    instructions: str = Field(
        "Move the robot arm with your phone (or the keyboard) and complete the task shown. "
        "Hold the clutch button to move, release it to reposition your hand.",
        max_length=10_000,
    )
    tasks: list[str] = Field(default_factory=lambda: ["lift"], min_length=1)
    robots: list[str] = Field(default_factory=lambda: ["Sawyer"], min_length=1)
    controllers: list[ControllerName] = Field(default_factory=_default_controllers, min_length=1)
    interfaces: list[WorkerDevice] = Field(
        default_factory=lambda: list(WORKER_DEVICES), min_length=1
    )
    demos_required: int = Field(3, ge=1, le=1000)
    practice_s: float = Field(
        20.0,
        ge=0,
        le=600,
        description="a practice round before each worker's first demonstration: reach a green "
        "ball, nothing recorded, skippable (teleop/practice.py); 0: none",
    )
    time_limit_s: float = Field(1800.0, gt=0, le=24 * 3600, description="per session")
    quality: QualityThresholds = Field(
        default_factory=QualityThresholds,
        description="when a demonstration is flagged, and why (docs/quality.md)",
    )
    review: ReviewPolicy = Field(
        default_factory=ReviewPolicy,
        description="when demonstrations count as accepted, and how many a worker needs",
    )
    capacity: int | None = Field(
        None, ge=1, description="unused here: the server-wide capacity applies (CoordConfig)"
    )
    allow_anonymous: bool = Field(
        True,
        description="take join links without Prolific or MTurk ids; false: refuse them (403)",
    )
    prolific_completion_code: str | None = Field(
        None,
        pattern=r"^[A-Za-z0-9]{4,32}$",
        description="the study's code on Prolific; a random code per session when unset",
    )

    regions: list[Region] = Field(
        default_factory=list,
        max_length=16,
        description="the regions serving this campaign (the coordinator's own `region` among "
        "them): the join page measures the worker's round trip to each and sends them to the "
        "nearest with a free robot (docs/deploy.md); empty: this coordinator alone",
    )

    @field_validator("regions")
    @classmethod
    def _distinct_regions(cls, regions: list[Region]) -> list[Region]:
        names = [region.name for region in regions]
        if len(set(names)) != len(names):
            raise ValueError(f"region names must be unique, got {names}")
        return regions

    @field_validator("tasks")
    @classmethod
    def _known_tasks(cls, tasks: list[str]) -> list[str]:
        known = task_names()
        unknown = [task for task in tasks if task not in known]
        if unknown:
            raise ValueError(f"unknown task(s) {unknown}; known: {sorted(known)}")
        return tasks

    @model_validator(mode="after")
    def _robots_fit_tasks(self) -> CampaignConfig:
        """Every (task, robot) pair `assignment` hands out must build: a robosuite task takes
        a single-arm robosuite robot, and a task that names its robots takes only those."""
        pairs = {self.assignment(i)[:2] for i in range(math.lcm(len(self.tasks), len(self.robots)))}
        for task_name, robot in sorted(pairs):
            task = get_task(task_name)
            if task.backend == "robosuite" and robot not in ROBOSUITE_ARMS:
                raise ValueError(
                    f"robot {robot!r} is not a single-arm robosuite robot "
                    f"({', '.join(ROBOSUITE_ARMS)}); task {task_name!r} needs one"
                )
            if task.robots and robot not in task.robots:
                raise ValueError(
                    f"robot {robot!r} does not fit task {task_name!r}: it takes "
                    f"{', '.join(task.robots)} (sessions pair tasks and robots in turn)"
                )
        return self

    def assignment(self, index: int) -> tuple[str, str, str]:
        """(task, robot, controller) for the campaign's `index`-th session."""
        return (
            self.tasks[index % len(self.tasks)],
            self.robots[index % len(self.robots)],
            self.controllers[index % len(self.controllers)],
        )


def read_structured(path: Path) -> Any:
    """JSON or YAML, by extension (YAML is a superset of JSON, so anything else is YAML)."""
    text = path.read_text()
    if path.suffix == ".json":
        return json.loads(text)
    return yaml.safe_load(text)


def load_campaigns(path: Path) -> list[CampaignConfig]:
    """A file holding one campaign (a mapping) or several (a list, or {campaigns: [...]})."""
    data = read_structured(path)
    if isinstance(data, dict) and "campaigns" in data:
        data = data["campaigns"]
    items = data if isinstance(data, list) else [data]
    campaigns = [CampaignConfig.model_validate(item) for item in items]
    names = [c.name for c in campaigns]
    if len(set(names)) != len(names):
        raise ValueError(f"campaign names must be unique, got {names}")
    return campaigns
