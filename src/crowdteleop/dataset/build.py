"""``crowdteleop dataset build``: episode files -> one robomimic-style ``demo.hdf5``.

Layout (robosuite's demo.hdf5 as extended by robomimic; docs/dataset.md): ``data`` attrs
``env_args`` (JSON) and ``total``; ``data/demo_<k>`` (k from 1, oldest first) with ``states``,
``actions``, ``rewards``, ``dones``, ``obs/`` and ``next_obs/`` (robosuite's observation keys,
``--obs``), ``actions_abs`` (absolute end-effector targets), ``controller_states`` and attrs
``model_file``, ``num_samples``, plus our metadata as attributes; ``mask/<filter key>``
lists of demo names: ``train`` / ``valid`` (90/10, seeded), ``interface_<x>``,
``worker_<x>``, ``network_<x>``, ``region_<x>``, ``fastest_<N>``, ``replay_ok``,
``quality_top_50`` / ``quality_bottom_50`` / ``quality_unflagged`` (dataset/quality.py).

Every input is read and checked before anything is written, and the output appears under its
name only when whole (temporary file, fsync, rename): a bad input leaves an existing dataset
exactly as it was.
"""

from __future__ import annotations

import json
import os
import random
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from crowdteleop.dataset.absolute import AbsoluteTargets
from crowdteleop.dataset.env_meta import dataset_env_args
from crowdteleop.dataset.files import DATASET_FORMAT, DatasetError, DemoSummary
from crowdteleop.dataset.generation.labels import (
    stack_labels,
    targets_in_world,
    write_datagen_info,
)
from crowdteleop.dataset.observations import (
    LOW_DIM,
    ObsSpec,
    observe_demo,
    parse_obs,
    write_demo_pass,
)
from crowdteleop.dataset.quality import DemoQuality, dataset_quality, quality_masks
from crowdteleop.dataset.selection import DemoFilter, review_attrs, review_masks, reviews_of
from crowdteleop.dataset.summary import summarize
from crowdteleop.provenance.controllers import ArmController
from crowdteleop.provenance.env_args import EnvArgs
from crowdteleop.recording.episode_file import DEMO, CorruptEpisodeError, Episode, read_episode
from crowdteleop.recording.metadata import EpisodeMetadata
from crowdteleop.recording.storage import fsync_directory
from crowdteleop.recording.versions import SCHEMA_VERSION, runtime_versions

COPIED = (
    "states",
    "actions",
    "rewards",
    "dones",
    "success",
    "server_time",
    "step_duration_s",
    "contacts",
    "commands",
)
DEFAULT_DRIFT_TOLERANCE = 1e-6  # max |state error| of action replay in the recording simulator


DEFAULT_OBS = parse_obs([LOW_DIM])


@dataclass(frozen=True)
class BuildOptions:
    """What goes into a dataset and how it is checked (``crowdteleop dataset build``'s flags)."""

    include_failed: bool = False  # keep unsuccessful episodes too
    task: str | None = None  # only this task's episodes
    fastest: Sequence[int] = ()  # a ``fastest_<N>`` filter key for each N
    valid_fraction: float = 0.1  # share of demos in ``mask/valid``
    seed: int = 0  # of the train/valid split
    skip_bad: bool = False  # leave unreadable episodes out (said why) instead of stopping
    # max action-replay state error before a demo is flagged (not dropped); None: no replay
    drift_tolerance: float | None = DEFAULT_DRIFT_TOLERANCE
    obs: ObsSpec = DEFAULT_OBS  # observations computed from the states
    # keep only the episodes every filter keeps (review decisions, flags, score: selection.py)
    filters: Sequence[DemoFilter] = ()


@dataclass
class Work:
    """Progress over the build's passes, in demo-steps."""

    progress: Callable[[int, int], None] | None
    total: int
    done: int = 0

    def add(self, steps: int) -> None:
        self.done += steps
        if self.progress is not None:
            self.progress(min(self.done, self.total), self.total)


@dataclass
class BuildReport:
    output: Path
    demos: list[DemoSummary] = field(default_factory=list)
    skipped: list[tuple[str, str]] = field(default_factory=list)  # (input, why)
    flagged: list[str] = field(default_factory=list)  # demos whose action replay diverged
    filtered_out: int = 0  # episodes the --filter options left out
    seconds: float = 0.0


def read_inputs(
    paths: Sequence[Path], skip_bad: bool = False
) -> tuple[list[tuple[Path, Episode]], list[tuple[str, str]]]:
    """Every episode file read and checked; a bad one raises (or is skipped, said why)."""
    episodes, skipped = [], []
    for path in paths:
        try:
            episode = read_episode(path)
            if episode.model_xml is None or episode.env_args is None:
                raise CorruptEpisodeError(f"{path} has no model_file or env_args to replay it")
            if episode.steps == 0:
                raise CorruptEpisodeError(f"{path} holds no steps")
        except CorruptEpisodeError as error:
            if not skip_bad:
                raise DatasetError(
                    f"{error} (nothing was written; --skip-bad leaves it out)"
                ) from error
            skipped.append((str(path), str(error)))
            continue
        episodes.append((path, episode))
    return episodes, skipped


def episode_files(sources: Sequence[Path]) -> list[Path]:
    """``*.hdf5`` under each source directory (recursively), or the source file itself."""
    files: list[Path] = []
    for source in sources:
        source = Path(source)
        if source.is_dir():
            files.extend(sorted(p for p in source.rglob("*.hdf5") if not p.name.startswith(".")))
        elif source.is_file():
            files.append(source)
        else:
            raise DatasetError(f"{source} does not exist")
    return files


def build_dataset(
    sources: Sequence[Path],
    output: Path,
    options: BuildOptions | None = None,
    *,
    overwrite: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> BuildReport:
    """Assemble episode files into one dataset file, as ``options`` say (``BuildOptions()``:
    successful episodes, low-dim observations, demos whose action replay drifts past 1e-6
    flagged); ``overwrite`` replaces an existing ``output``."""
    options = options or BuildOptions()
    drift_tolerance = options.drift_tolerance
    started = time.perf_counter()
    output = Path(output)
    if output.exists() and not overwrite:
        raise DatasetError(f"{output} exists; pass --overwrite to replace it")
    episodes, skipped = read_inputs(episode_files(sources), options.skip_bad)
    chosen = [
        (path, ep)
        for path, ep in episodes
        if (options.include_failed or ep.outcome == "success")
        and (options.task is None or ep.metadata.get("task") == options.task)
    ]
    if not chosen:
        which = "" if options.include_failed else "successful "
        raise DatasetError(f"no {which}episodes to build from")
    chosen.sort(key=lambda pair: (pair[1].created_at, pair[1].episode_id))
    kept = _filtered(chosen, options.filters)
    if not kept:
        raise DatasetError(
            f"none of the {len(chosen)} episodes passes --filter "
            + " --filter ".join(f.text for f in options.filters)
        )
    filtered_out, chosen = len(chosen) - len(kept), kept
    # read_inputs refused episodes without env_args
    envs = {EnvArgs.model_validate(ep.env_args).env_name for _, ep in chosen}
    if len(envs) > 1:
        raise DatasetError(
            f"episodes of several environments ({', '.join(sorted(envs))}): a robomimic "
            "dataset holds one; build one per task with --task"
        )
    report = BuildReport(output=output, skipped=skipped, filtered_out=filtered_out)
    drifts: list[float | None] = [None] * len(chosen)
    steps = sum(ep.steps for _, ep in chosen)
    work = Work(progress, steps * (2 if drift_tolerance is not None else 1))
    if drift_tolerance is not None:
        from crowdteleop.dataset.replay import ReplayChecker

        with ReplayChecker() as checker:
            for i, (_, episode) in enumerate(chosen):
                drifts[i] = checker.action_drift(episode).max_state_error
                work.add(episode.steps)
    report.demos = [summarize(f"demo_{i + 1}", ep, drifts[i]) for i, (_, ep) in enumerate(chosen)]
    report.flagged = [
        d.name
        for d in report.demos
        if d.drift is not None and drift_tolerance is not None and not d.drift <= drift_tolerance
    ]
    tmp = output.with_name(f".{output.name}.{os.getpid()}.tmp")
    output.parent.mkdir(parents=True, exist_ok=True)
    try:
        with h5py.File(tmp, "w") as file:
            _write(file, chosen, report, options, work)
        with open(tmp, "rb") as handle:
            os.fsync(handle.fileno())
        os.replace(tmp, output)
    finally:
        tmp.unlink(missing_ok=True)
    fsync_directory(output.parent)
    report.seconds = time.perf_counter() - started
    return report


def _write(
    file: h5py.File,
    chosen: list[tuple[Path, Episode]],
    report: BuildReport,
    options: BuildOptions,
    work: Work,
) -> None:
    from crowdteleop.dataset.replay import ReplayChecker, demo_of_episode

    first = demo_of_episode(chosen[0][1])
    env_args = dataset_env_args(first, options.obs)
    drift_tolerance = options.drift_tolerance
    versions = runtime_versions()
    now = time.localtime()
    file.attrs.update(format=DATASET_FORMAT, schema_version=SCHEMA_VERSION)
    data = file.create_group("data")
    data.attrs.update(
        env_args=json.dumps(env_args.model_dump(mode="json")),
        total=sum(ep.steps for _, ep in chosen),
        date=time.strftime("%m-%d-%Y", now),
        time=time.strftime("%H:%M:%S", now),
        repository_version=versions.get("robosuite", "unknown"),
        env=env_args.env_name,
        env_info=json.dumps(env_args.env_info()),
        schema_version=SCHEMA_VERSION,
        platform_version=versions.get("crowdteleop", "unknown"),
        built_with=json.dumps(versions),
        built_at=time.time(),
        drift_tolerance=-1.0 if drift_tolerance is None else drift_tolerance,
    )
    if env_args.controller is not None:
        data.attrs["actions_abs_controller_configs"] = json.dumps(
            env_args.controller.absolute().to_robosuite()
        )
    qualities = dataset_quality([episode for _, episode in chosen])
    checker = ReplayChecker()
    try:
        _write_demos(data, chosen, report, checker, work, options.obs, env_args.arm)
    finally:
        checker.close()
    for demo, quality in zip(report.demos, qualities, strict=True):
        data[demo.name].attrs.update(quality_attrs(quality))
    _write_masks(
        file, report.demos, report.flagged, options.fastest, options.valid_fraction, options.seed
    )
    reviews = reviews_of([path for path, _ in chosen])
    for demo, review in zip(report.demos, reviews, strict=True):
        data[demo.name].attrs.update(review_attrs(review))
    names = [demo.name for demo in report.demos]
    masks = quality_masks(names, qualities) | review_masks(names, reviews)
    for key, members in masks.items():
        file["mask"].create_dataset(key, data=np.array(members, dtype="S"))


def _filtered(
    chosen: list[tuple[Path, Episode]], filters: Sequence[DemoFilter]
) -> list[tuple[Path, Episode]]:
    """The episodes every filter keeps (scores among all of `chosen`)."""
    if not filters:
        return chosen
    reviews = reviews_of([path for path, _ in chosen])
    qualities = dataset_quality([episode for _, episode in chosen])
    return [
        pair
        for pair, review, quality in zip(chosen, reviews, qualities, strict=True)
        if all(f.keeps(review, quality) for f in filters)
    ]


def _write_demos(
    data: h5py.Group,
    chosen: list[tuple[Path, Episode]],
    report: BuildReport,
    checker: Any,
    work: Work,
    obs: ObsSpec,
    arm: ArmController | None,
) -> None:
    """Each demo's group; with ``arm`` (the recorded arm controller), its ``actions_abs``."""
    from crowdteleop.dataset.replay import demo_of_episode

    for (path, episode), demo in zip(chosen, report.demos, strict=True):
        with h5py.File(path, "r") as source:
            for name in COPIED:
                if name in source[DEMO]:
                    source.copy(source[DEMO][name], data, name=f"{demo.name}/{name}")
        group = data[demo.name]
        info = EpisodeMetadata.model_validate(episode.metadata)
        recorded_versions = episode.metadata.get("versions") or {}
        group.attrs.update(
            num_samples=episode.steps,
            model_file=episode.model_xml or "",
            episode_id=episode.episode_id,
            outcome=episode.outcome,
            recovered=episode.recovered,
            task=demo.task,
            robot=info.robot,
            controller=info.controller or "",
            interface=demo.interface,
            worker=demo.worker,
            campaign=demo.campaign,
            network_condition=demo.network,
            region=demo.region,
            telemetry=json.dumps(episode.metadata.get("telemetry") or {}),
            completion_time_s=demo.completion_s,
            created_at=episode.created_at,
            platform_version=str(recorded_versions.get("crowdteleop", "unknown")),
            simulator_versions=json.dumps(
                {k: recorded_versions.get(k, "unknown") for k in ("robosuite", "mujoco")}
            ),
            schema_version=SCHEMA_VERSION,
            source=str(path),
            metadata=json.dumps(episode.metadata),
            action_replay_drift=-1.0 if demo.drift is None else demo.drift,
            action_replay_flagged=demo.name in report.flagged,
        )
        replayable = demo_of_episode(episode)
        computed = observe_demo(checker, replayable, obs, lambda: work.add(1))
        absolute, targets_world = None, None
        if arm is not None:
            sim = checker.simulation(replayable)
            targets = AbsoluteTargets(sim.kinematics(), arm)
            absolute = targets.of(replayable.states, replayable.actions)
            targets_world = targets_in_world(targets.base_frame(replayable.states[0]), absolute)
        write_demo_pass(group, computed, absolute)
        # recorded at collection where the recording has them, else computed from its states
        labels = episode.labels if episode.labels is not None else stack_labels(computed.labels)
        write_datagen_info(group, labels, replayable.actions, targets_world)


def quality_attrs(quality: DemoQuality) -> dict[str, Any]:
    """A demo's quality as attributes: `quality` (the metrics, JSON), `quality_score` (-1:
    none), `quality_flags` (JSON list of {metric, reason})."""
    return {
        "quality": quality.metrics.model_dump_json(exclude_none=True),
        "quality_score": -1.0 if quality.score is None else quality.score,
        "quality_flags": json.dumps([flag.model_dump() for flag in quality.flags]),
    }


def _write_masks(
    file: h5py.File,
    demos: list[DemoSummary],
    flagged: list[str],
    fastest: Sequence[int],
    valid_fraction: float,
    seed: int,
) -> None:
    names = [d.name for d in demos]
    shuffled = names[:]
    random.Random(seed).shuffle(shuffled)
    n_valid = round(len(names) * valid_fraction)
    if valid_fraction > 0 and len(names) >= 2:
        n_valid = max(1, n_valid)
    masks: dict[str, list[str]] = {
        "train": sorted(shuffled[n_valid:], key=names.index),
        "valid": sorted(shuffled[:n_valid], key=names.index),
        "replay_ok": [n for n in names if n not in flagged],
    }
    for label, attribute in (
        ("interface", "interface"),
        ("worker", "worker"),
        ("network", "network"),
        ("region", "region"),
    ):
        for demo in demos:
            masks.setdefault(f"{label}_{_safe(getattr(demo, attribute))}", []).append(demo.name)
    by_time = sorted(demos, key=lambda d: (d.completion_s, d.name))
    for n in fastest:
        masks[f"fastest_{n}"] = sorted((d.name for d in by_time[:n]), key=names.index)
    group = file.create_group("mask")
    for key, members in masks.items():
        group.create_dataset(key, data=np.array(members, dtype="S"))


def _safe(value: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in value) or "unknown"
