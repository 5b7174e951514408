"""``crowdteleop dataset generate SRC --num N --output OUT``: attempts in new scenes until N
succeed, on local processes or Ray actors; resumable.

``OUT/`` holds ``episodes/gen-<attempt>.hdf5`` (each success, an episode file like a worker's,
its provenance in the metadata), ``attempts.jsonl`` (one line per attempt: its scene seed,
outcome, why it failed, the source segments it used) and ``demo.hdf5``, the dataset built from
the first N successes in attempt order (the same whatever the number of workers). Attempt ``i``
is scene ``seed + i``: an interrupted run started again skips the attempts its log holds, and an
episode whose file was written but not logged is logged, not generated again.
"""

from __future__ import annotations

import json
import os
import time
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from crowdteleop.dataset.files import DatasetError
from crowdteleop.dataset.generation.attempt import Attempt, Settings
from crowdteleop.dataset.generation.segments import common_subtasks
from crowdteleop.dataset.generation.sources import Sources, read_sources
from crowdteleop.dataset.generation.worker import (
    GenerationWorker,
    run_pool_attempt,
    start_pool_worker,
)
from crowdteleop.dataset.replay import recorded_env_args
from crowdteleop.recording.episode_file import StepRecord
from crowdteleop.recording.versions import runtime_versions
from crowdteleop.recording.wal import EpisodeRecorder
from crowdteleop.recording.wal_codec import WAL_SUFFIX

LOG = "attempts.jsonl"
EPISODES = "episodes"
DATASET = "demo.hdf5"
DEFAULT_SEED = 1_000_000  # scene seeds far from the ones recordings and evaluations use


@dataclass(frozen=True)
class GenerateOptions:
    num: int
    workers: int = 1
    ray_address: str | None = None  # "auto", an address, or "local": Ray actors instead
    seed: int = DEFAULT_SEED
    max_attempts: int | None = None  # default: 20 per demonstration asked for
    settings: Settings = field(default_factory=Settings)
    build: bool = True


@dataclass
class GenerationReport:
    output: Path
    sources: int
    left_out: list[str]
    subtasks: list[str]
    attempts: int = 0
    successes: int = 0
    reasons: Counter[str] = field(default_factory=Counter)
    # per source demo (the first segment's): attempts made from it, and how many succeeded
    by_source: dict[str, tuple[int, int]] = field(default_factory=dict)
    resumed: int = 0
    seconds: float = 0.0
    dataset: Path | None = None

    @property
    def success_rate(self) -> float:
        return self.successes / self.attempts if self.attempts else 0.0


def _logged(output: Path) -> dict[int, dict[str, Any]]:
    """The attempts an earlier run logged (a torn last line, from a crash, is ignored)."""
    log = output / LOG
    done: dict[int, dict[str, Any]] = {}
    if not log.exists():
        return done
    for line in log.read_text().splitlines():
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            continue
        done[int(entry["attempt"])] = entry
    return done


def episode_id(index: int) -> str:
    return f"gen-{index:07d}"


class _Log:
    """``attempts.jsonl``, appended and fsync'd one line per attempt."""

    def __init__(self, path: Path) -> None:
        self._file = open(path, "a", encoding="utf-8")  # noqa: SIM115  # closed by close()

    def write(self, entry: dict[str, Any]) -> None:
        self._file.write(json.dumps(entry) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> None:
        self._file.close()


def _entry(attempt: Attempt) -> dict[str, Any]:
    return {
        "attempt": attempt.index,
        "seed": attempt.seed,
        "success": attempt.success,
        "reason": attempt.reason,
        "failed_subtask": attempt.failed_subtask,
        "steps": attempt.steps,
        "seconds": round(attempt.seconds, 3),
        "sources": attempt.chosen,
        "worker": attempt.worker,
        "episode": f"{EPISODES}/{episode_id(attempt.index)}.hdf5" if attempt.success else None,
    }


def write_episode(attempt: Attempt, directory: Path, sources: Sources) -> Path:
    """A successful attempt as an episode file: the source's metadata with this scene's reset,
    model and provenance (``generated``)."""
    name = episode_id(attempt.index)
    (directory / f"{name}{WAL_SUFFIX}").unlink(missing_ok=True)  # a crash's leftover
    metadata = sources.metadata.model_copy(
        update={
            "reset_seed": attempt.seed,
            "model_xml": attempt.model_xml,
            "sim_config": attempt.sim_config,
            "controller_state_at_start": attempt.controller_state_at_start,
            "env_args": recorded_env_args(sources.first),  # a dataset keeps them once, not per demo
            "session_id": None,
            "worker_id": "generated",
            "interface": "generated",
            "episode": None,
        }
    ).to_record()
    recorder = EpisodeRecorder(directory, name, metadata)
    now = time.time()
    for i in range(attempt.steps):
        recorder.append(
            StepRecord(
                index=i,
                state=attempt.states[i],
                action=attempt.actions[i],
                command={"seq": i, "device": "generated"},
                server_time=now + i * 0.05,
                step_duration_s=attempt.durations_s[i],
                reward=attempt.rewards[i],
                success=attempt.successes[i],
                contacts=attempt.contacts[i],
                labels=attempt.labels[i],
            )
        )
    provenance = {
        "generated": True,
        "generation": {
            "source_dataset": str(sources.path),
            "attempt": attempt.index,
            "scene_seed": attempt.seed,
            "segments": attempt.chosen,
        },
    }
    return recorder.finalize("success", {"versions": runtime_versions(), **provenance})


Progress = Callable[[int, int, int], None]  # (successes, asked for, attempts)


def generate(
    source: Path, output: Path, options: GenerateOptions, progress: Progress | None = None
) -> GenerationReport:
    """Generate until ``options.num`` attempts succeeded (or ``max_attempts`` ran), then build
    ``OUT/demo.hdf5`` from the first ``num`` successes."""
    if options.num < 1:
        raise DatasetError(f"--num must be at least 1, got {options.num}")
    if options.workers < 1:
        raise DatasetError(f"--workers must be at least 1, got {options.workers}")
    started = time.perf_counter()
    sources = read_sources(source)
    subtasks, kept, left_out = common_subtasks(sources.demos)
    output = Path(output)
    (output / EPISODES).mkdir(parents=True, exist_ok=True)
    report = GenerationReport(output, len(kept), left_out, [str(s) for s in subtasks])
    done = _recover(_logged(output), output / EPISODES, output / LOG)
    report.resumed = len(done)
    limit = options.max_attempts or 20 * options.num
    ledger = _Ledger(output, sources, done, [i for i in range(limit) if i not in done])
    ledger.progress, ledger.wanted = progress, options.num
    try:
        ledger.show()
        if not ledger.enough():
            _dispatch(source, options, iter(ledger.order), ledger.record, ledger.enough)
    finally:
        ledger.close()
    _summarize(report, done)
    chosen = _first_successes(done, options.num)
    if options.build and chosen:
        report.dataset = _build(output, [output / entry["episode"] for entry in chosen])
    report.seconds = time.perf_counter() - started
    return report


class _Ledger:
    """Writes finished attempts in attempt order (workers finish out of order): episodes, then
    their log lines, so the files and the dataset are the same whichever worker ran what."""

    def __init__(
        self, output: Path, sources: Sources, done: dict[int, dict[str, Any]], order: list[int]
    ) -> None:
        self._episodes, self._sources, self.done, self.order = (
            output / EPISODES,
            sources,
            done,
            order,
        )
        self._log = _Log(output / LOG)
        self._waiting: dict[int, Attempt] = {}
        self._next = 0  # position in order of the next attempt to write
        self.progress: Progress | None = None
        self.wanted = 0

    def record(self, attempt: Attempt) -> None:
        self._waiting[attempt.index] = attempt
        while self._next < len(self.order) and self.order[self._next] in self._waiting:
            self._write(self._waiting.pop(self.order[self._next]))
            self._next += 1

    def _write(self, attempt: Attempt) -> None:
        if attempt.success:
            write_episode(attempt, self._episodes, self._sources)
        entry = _entry(attempt)
        self._log.write(entry)
        self.done[attempt.index] = entry
        self.show()

    def enough(self) -> bool:
        return _successes(self.done) >= self.wanted

    def show(self) -> None:
        if self.progress is not None:
            self.progress(_successes(self.done), self.wanted, len(self.done))

    def close(self) -> None:
        self._log.close()


def _successes(done: dict[int, dict[str, Any]]) -> int:
    return sum(1 for entry in done.values() if entry["success"])


def _first_successes(done: dict[int, dict[str, Any]], num: int) -> list[dict[str, Any]]:
    return [done[i] for i in sorted(done) if done[i]["success"]][:num]


def _summarize(report: GenerationReport, done: dict[int, dict[str, Any]]) -> None:
    report.attempts = len(done)
    report.successes = _successes(done)
    report.reasons = Counter(entry["reason"] for entry in done.values() if not entry["success"])
    tried: Counter[str] = Counter()
    kept: Counter[str] = Counter()
    for entry in done.values():
        if entry.get("sources"):  # a recovered entry has only its episode
            tried[entry["sources"][0]["demo"]] += 1
            kept[entry["sources"][0]["demo"]] += bool(entry["success"])
    order = sorted(tried, key=lambda name: int(name.rsplit("_", 1)[-1]))
    report.by_source = {name: (tried[name], kept[name]) for name in order}


def _recover(
    done: dict[int, dict[str, Any]], episodes: Path, log_path: Path
) -> dict[int, dict[str, Any]]:
    """Episodes written but not logged (a crash between the two) are logged, not redone."""
    log = _Log(log_path)
    try:
        for path in sorted(episodes.glob("gen-*.hdf5")):
            index = int(path.stem.split("-")[1])
            if index not in done:
                entry = {
                    "attempt": index,
                    "success": True,
                    "reason": "",
                    "recovered": True,
                    "episode": f"{EPISODES}/{path.name}",
                }
                log.write(entry)
                done[index] = entry
    finally:
        log.close()
    return done


def _dispatch(
    source: Path,
    options: GenerateOptions,
    pending: Iterator[int],
    record: Callable[[Attempt], None],
    enough: Callable[[], bool],
) -> None:
    """Run attempts in order until enough succeeded: in this process (one worker), in a pool of
    processes, or on Ray actors."""
    if options.ray_address is not None:
        from crowdteleop.dataset.generation.ray_workers import run_on_ray

        run_on_ray(
            source,
            options.ray_address,
            options.workers,
            options.settings,
            options.seed,
            pending,
            record,
            enough,
        )
        return
    if options.workers == 1:
        worker = GenerationWorker(source, options.settings)
        for index in pending:
            record(worker.attempt(index, options.seed + index))
            if enough():
                return
        return
    _run_pool(source, options, pending, record, enough)


def _run_pool(
    source: Path,
    options: GenerateOptions,
    pending: Iterator[int],
    record: Callable[[Attempt], None],
    enough: Callable[[], bool],
) -> None:
    """Attempts on ``options.workers`` processes, two queued per process."""
    context = get_context("spawn")  # a forked MuJoCo/OpenGL state is not safe to share
    with ProcessPoolExecutor(
        options.workers,
        mp_context=context,
        initializer=start_pool_worker,
        initargs=(source, options.settings),
    ) as pool:
        running: set[Future[Attempt]] = set()
        while True:
            while len(running) < 2 * options.workers and not enough():
                index = next(pending, None)
                if index is None:
                    break
                running.add(pool.submit(run_pool_attempt, index, options.seed + index))
            if not running:
                return
            finished, running = wait(running, return_when=FIRST_COMPLETED)
            for future in finished:
                record(future.result())
            if enough():
                for future in running:  # already started: their results are kept too
                    record(future.result())
                return


def _build(output: Path, episodes: list[Path]) -> Path:
    """``OUT/demo.hdf5`` from the chosen episodes (replayed, observed and labelled as
    ``dataset build`` does every dataset)."""
    from crowdteleop.dataset.build import BuildOptions, build_dataset

    target = output / DATASET
    build_dataset(episodes, target, BuildOptions(drift_tolerance=None), overwrite=True)
    return target
