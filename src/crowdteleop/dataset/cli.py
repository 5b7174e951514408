"""``crowdteleop dataset build | replay | stats | export`` (heavy imports inside the commands,
so ``crowdteleop --help`` stays fast)."""

from __future__ import annotations

import json
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

import typer
from rich.console import Console
from rich.table import Table

from crowdteleop.errors import CrowdteleopError

if TYPE_CHECKING:
    from crowdteleop.dataset.generation.run import GenerationReport

app = typer.Typer(
    help="Build, replay, summarize and export demonstration datasets.", no_args_is_help=True
)
console = Console(soft_wrap=True)
errors = Console(stderr=True, soft_wrap=True)


@contextmanager
def clear_errors() -> Iterator[None]:
    """Our errors (and pydantic's) as one red line and exit code 2, not a traceback (the
    offline commands share it: `dataset`, `learn`)."""
    from pydantic import ValidationError

    try:
        yield
    except (CrowdteleopError, ValidationError, OSError) as error:
        errors.print(f"[red]error:[/red] {error}", soft_wrap=True)
        raise typer.Exit(2) from error


def progress_columns(*extra: Any) -> tuple[Any, ...]:
    """The commands' progress bar: what, bar, done / total, time left, then ``extra``."""
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn

    return (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        *extra,
    )


@contextmanager
def _progress(description: str) -> Iterator[Callable[[int, int], None]]:
    from rich.progress import Progress

    with Progress(*progress_columns(), console=console, transient=False) as bar:
        job = bar.add_task(description, total=None)

        def update(done: int, total: int) -> None:
            bar.update(job, completed=done, total=total)

        yield update


def _local_sources(sources: list[str], endpoint: str | None, work: Path) -> list[Path]:
    """Directories and files as given; ``s3://bucket/prefix`` downloaded into ``work``."""
    from crowdteleop.recording.review import is_review_name
    from crowdteleop.recording.s3 import S3Config, S3Storage

    paths = []
    for source in sources:
        if not source.startswith("s3://"):
            paths.append(Path(source))
            continue
        bucket, _, prefix = source[len("s3://") :].partition("/")
        store = S3Storage(S3Config(bucket=bucket, endpoint_url=endpoint))
        store.check()
        keys = [
            key
            for key in store.list(prefix)
            if key.endswith(".hdf5") or is_review_name(key)  # decisions lie beside episodes
        ]
        for key in keys:
            target = work / bucket / key
            store.get(store.uri(key), target)
            if key.endswith(".hdf5"):
                paths.append(target)
    return paths


@app.command()
def build(
    sources: Annotated[list[str], typer.Argument(help="episode dirs/files or s3://bucket/prefix")],
    output: Annotated[Path, typer.Option(help="dataset file to write")] = Path("demo.hdf5"),
    task: Annotated[str | None, typer.Option(help="only this task's episodes")] = None,
    include_failed: Annotated[bool, typer.Option(help="keep unsuccessful episodes too")] = False,
    fastest: Annotated[list[int] | None, typer.Option(help="fastest_N filter key(s)")] = None,
    valid_fraction: Annotated[float, typer.Option(help="share of demos in mask/valid")] = 0.1,
    seed: Annotated[int, typer.Option(help="seed of the train/valid split")] = 0,
    drift_tolerance: Annotated[
        float, typer.Option(help="flag demos whose action replay drifts more (<0: no check)")
    ] = 1e-6,
    skip_bad: Annotated[bool, typer.Option(help="leave unreadable episodes out")] = False,
    overwrite: Annotated[bool, typer.Option(help="replace an existing output")] = False,
    s3_endpoint: Annotated[str | None, typer.Option(help="endpoint of s3:// sources")] = None,
    obs: Annotated[
        list[str] | None,
        typer.Option(
            help="observations to compute from the states: low-dim (robosuite's keys, the "
            "default), rgb:CAMERA:WxH (e.g. rgb:agentview:84x84), or none; repeat or "
            "comma-separate"
        ),
    ] = None,
    filter_: Annotated[
        list[str] | None,
        typer.Option(
            "--filter",
            help="keep only: accepted (by a reviewer, docs/review.md), not-rejected, "
            "unflagged, score>=N; repeat to combine",
        ),
    ] = None,
) -> None:
    """Assemble episode files into a robomimic-compatible demo.hdf5."""
    from crowdteleop.dataset.build import BuildOptions, build_dataset
    from crowdteleop.dataset.observations import LOW_DIM, parse_obs
    from crowdteleop.dataset.selection import parse_filter

    with clear_errors(), tempfile.TemporaryDirectory() as work:
        wanted = parse_obs(obs or [LOW_DIM])
        filters = [parse_filter(text) for text in filter_ or []]
        paths = _local_sources(sources, s3_endpoint, Path(work))
        with _progress("checking and assembling") as progress:
            options = BuildOptions(
                include_failed=include_failed,
                task=task,
                fastest=fastest or (),
                valid_fraction=valid_fraction,
                seed=seed,
                skip_bad=skip_bad,
                drift_tolerance=None if drift_tolerance < 0 else drift_tolerance,
                obs=wanted,
                filters=filters,
            )
            report = build_dataset(paths, output, options, overwrite=overwrite, progress=progress)
    for path, why in report.skipped:
        errors.print(f"[yellow]skipped[/yellow] {path}: {why}")
    for name in report.flagged:
        errors.print(f"[yellow]flagged[/yellow] {name}: action replay diverges beyond tolerance")
    left_out = f", {report.filtered_out} left out by --filter" if filter_ else ""
    console.print(
        f"{output}: {len(report.demos)} demos, {sum(d.steps for d in report.demos)} steps, "
        f"{len(report.flagged)} flagged{left_out}, built in {report.seconds:.1f} s"
    )


@app.command()
def generate(
    source: Annotated[Path, typer.Argument(help="labelled dataset (from `dataset build`)")],
    num: Annotated[int, typer.Option(help="successful demonstrations to generate")] = 100,
    output: Annotated[
        Path, typer.Option(help="folder: episodes, attempts.jsonl, demo.hdf5")
    ] = Path("generated"),
    workers: Annotated[int, typer.Option(help="local processes running attempts")] = 1,
    ray: Annotated[
        str | None,
        typer.Option(help="run attempts on Ray actors: a cluster address, 'auto' or 'local'"),
    ] = None,
    strategy: Annotated[
        str, typer.Option(help="source per attempt: nearest (object pose) or random")
    ] = "nearest",
    per_subtask: Annotated[bool, typer.Option(help="choose a source per subtask")] = False,
    action_noise: Annotated[
        float, typer.Option(min=0.0, max=1.0, help="std of noise on executed arm actions")
    ] = 0.0,
    robosuite_step: Annotated[
        bool,
        typer.Option(help="execute on robosuite's own step (~6x slower): its very physics"),
    ] = False,
    seed: Annotated[int, typer.Option(help="attempt i is scene seed+i")] = 1_000_000,
    max_attempts: Annotated[
        int | None, typer.Option(help="stop after this many attempts (default 20 x --num)")
    ] = None,
    build_dataset: Annotated[
        bool, typer.Option("--build/--no-build", help="build OUT/demo.hdf5 at the end")
    ] = True,
) -> None:
    """New demonstrations from labelled ones, MimicGen's way: each source's subtask segments
    moved with their objects into new scenes, executed, and kept where the task succeeds
    (docs/generation.md). Started again on the same OUT, it resumes."""
    from rich.progress import Progress, TextColumn

    from crowdteleop.dataset.generation.attempt import Settings
    from crowdteleop.dataset.generation.run import GenerateOptions
    from crowdteleop.dataset.generation.run import generate as run_generation

    with clear_errors():
        if strategy not in ("nearest", "random"):
            raise typer.BadParameter("--strategy is nearest or random")
        options = GenerateOptions(
            num=num,
            workers=workers,
            ray_address=ray,
            seed=seed,
            max_attempts=max_attempts,
            settings=Settings(
                strategy=strategy,  # type: ignore[arg-type]
                per_subtask=per_subtask,
                action_noise=action_noise,
                robosuite_step=robosuite_step,
            ),
            build=build_dataset,
        )
        columns = progress_columns(TextColumn("{task.fields[attempts]} attempts"))
        with Progress(*columns, console=console) as bar:
            job = bar.add_task("generating", total=num, attempts=0)

            def update(successes: int, wanted: int, attempts: int) -> None:
                bar.update(job, completed=min(successes, wanted), total=wanted, attempts=attempts)

            report = run_generation(source, output, options, update)
    _print_generation(report)
    if report.successes < num:
        errors.print(f"[yellow]only {report.successes} of {num} generated[/yellow]")
        raise typer.Exit(1)


def _print_generation(report: GenerationReport) -> None:
    """Why attempts failed, which sources generalize, and the run's totals."""
    for why in report.left_out:
        errors.print(f"[yellow]left out[/yellow] {why}")
    table = Table(title=f"{report.successes} of {report.attempts} attempts succeeded")
    table.add_column("why attempts failed")
    table.add_column("attempts", justify="right")
    for reason, count in report.reasons.most_common():
        table.add_row(reason, str(count))
    console.print(table if report.reasons else table.title)
    sources = Table(title="which sources generalize", show_edge=False)
    for column in ("source demo", "attempts", "succeeded"):
        sources.add_column(column, justify="left" if column == "source demo" else "right")
    for name, (tried, kept) in report.by_source.items():
        sources.add_row(name, str(tried), f"{kept / tried:.0%}")
    console.print(sources)
    console.print(
        f"{report.sources} sources, subtasks {' -> '.join(report.subtasks)}; success rate "
        f"{report.success_rate:.0%}; {report.resumed} attempts resumed from an earlier run; "
        f"{report.seconds:.0f} s" + (f"; dataset {report.dataset}" if report.dataset else "")
    )


@app.command()
def check(
    path: Annotated[Path, typer.Argument(help="dataset built by `dataset build`")],
    demos: Annotated[int, typer.Option(help="demos to replay in plain robosuite")] = 3,
) -> None:
    """Will robosuite, robomimic and LeRobot users' code accept this dataset? One verdict per
    check: rebuild from env_info, state replay, action replay, absolute actions, obs keys."""
    from crowdteleop.dataset.check import check_dataset

    with clear_errors(), _progress("checking") as progress:
        results = check_dataset(path, demos, progress)
    table = Table("check", "verdict", title=str(path))
    table.add_column("detail", overflow="fold")  # names and paths whole, never cut with "..."
    colour = {"pass": "green", "fail": "red", "skip": "yellow"}
    for result in results:
        table.add_row(result.name, f"[{colour[result.verdict]}]{result.verdict}[/]", result.detail)
    console.print(table)
    if any(r.verdict == "fail" for r in results):
        raise typer.Exit(1)


@app.command()
def replay(
    path: Annotated[Path, typer.Argument(help="dataset or episode file")],
    demo: Annotated[
        str | None, typer.Option(help="demo name, e.g. demo_3 (default: first)")
    ] = None,
    camera: Annotated[str | None, typer.Option(help="camera (default: the worker's)")] = None,
    width: Annotated[int, typer.Option(help="video width (even)")] = 320,
    height: Annotated[int, typer.Option(help="video height (even)")] = 240,
    output: Annotated[Path, typer.Option(help="MP4 to write")] = Path("out/replay.mp4"),
    robosuite: Annotated[
        bool, typer.Option(help="also step the actions in plain robosuite (from env_args)")
    ] = False,
) -> None:
    """Re-simulate a demo from its states into an MP4; check state replay, measure drift."""
    from crowdteleop.dataset.replay import ReplayChecker, load_demo

    with clear_errors(), ReplayChecker() as checker:
        loaded = load_demo(path, demo)
        with _progress(f"replaying {loaded.name}") as progress:
            result = checker.replay(loaded, camera, width, height, output, progress)
        plain = checker.robosuite_drift(loaded) if robosuite else None
    verdict = "[green]exact[/green]" if result.state_exact else "[red]NOT exact[/red]"
    one_step = "exact" if result.step_exact else f"max state error {result.max_step_error:.3g}"
    console.print(
        f"{loaded.name}: state replay {verdict} ({result.frames} frames -> {output}); "
        f"each action from its recorded state: {one_step}; "
        f"action replay drift: max {result.drift.max_state_error:.3g}, "
        f"final {result.drift.final_state_error:.3g}"
    )
    if plain is not None:
        console.print(
            f"plain robosuite: hand drift per step median {plain.per_step_median_m * 1e3:.2f} mm, "
            f"max {plain.per_step_max_m * 1e3:.2f} mm; open loop max "
            f"{plain.open_loop_max_m * 1e3:.1f} mm, final {plain.open_loop_final_m * 1e3:.1f} mm"
        )
    if not result.state_exact:
        raise typer.Exit(1)


@app.command()
def score(
    dataset: Annotated[Path, typer.Argument(help="dataset with low-dim obs (dataset build)")],
    k: Annotated[int, typer.Option(help="neighbours of the KSG estimator")] = 5,
    samples_per_demo: Annotated[int, typer.Option(help="steps taken from each demo")] = 64,
    dims: Annotated[int, typer.Option(help="principal components kept per side")] = 8,
) -> None:
    """Score every demo by its share of the state-action mutual information (DemInf-style,
    no rollouts; docs/quality.md): attributes deminf_score, masks deminf_top_50/bottom_50."""
    from crowdteleop.dataset.files import open_dataset
    from crowdteleop.dataset.score import ScoreConfig, score_dataset

    with clear_errors():
        open_dataset(dataset).close()  # ours, readable: else a clear error
        config = ScoreConfig(k=k, samples_per_demo=samples_per_demo, dims=dims)
        with _progress("reading demos") as progress:
            result = score_dataset(dataset, config, progress)
    ranked = sorted(zip(result.scores, result.names, strict=True), reverse=True)
    console.print(
        f"{dataset}: {len(result.names)} demos scored from {result.samples} samples in "
        f"{result.seconds:.1f} s; best {ranked[0][1]} ({ranked[0][0]:.2f} nats), worst "
        f"{ranked[-1][1]} ({ranked[-1][0]:.2f}); masks deminf_top_50, deminf_bottom_50"
    )


@app.command()
def stats(
    sources: Annotated[list[Path], typer.Argument(help="dataset file(s) or episode dirs")],
    output: Annotated[Path, typer.Option(help="directory for stats.json/.md and PNGs")] = Path(
        "out/stats"
    ),
    bins: Annotated[int, typer.Option(help="histogram bins")] = 10,
) -> None:
    """Counts, hours, success rates, completion times and KS tests, as the paper's tables."""
    from crowdteleop.dataset.build import episode_files, read_inputs
    from crowdteleop.dataset.files import dataset_demos
    from crowdteleop.dataset.stats import markdown, write_report
    from crowdteleop.dataset.summary import summarize

    with clear_errors():
        demos = []
        for source in sources:
            if source.is_file() and _is_dataset(source):
                demos += dataset_demos(source)
            else:
                episodes, _ = read_inputs(episode_files([source]))
                demos += [summarize(path.stem, ep) for path, ep in episodes]
        if not demos:
            raise CrowdteleopError("no demonstrations found")
        report = write_report(demos, output, bins)
    console.print(markdown(report), markup=False, highlight=False)
    console.print(f"written: {output}/stats.json, stats.md, {len(report['plots'])} plots")


def _is_dataset(path: Path) -> bool:
    import h5py

    try:
        with h5py.File(path, "r") as file:
            return bool(file.attrs.get("format") == "crowdteleop-dataset")
    except OSError:
        return False


@app.command()
def export(
    dataset: Annotated[Path, typer.Argument(help="dataset built by `dataset build`")],
    format: Annotated[
        Literal["robomimic", "lerobot"], typer.Option(help="output format")
    ] = "robomimic",
    output: Annotated[Path, typer.Option(help="file (robomimic) or directory (lerobot)")] = Path(
        "out/export"
    ),
    camera: Annotated[list[str] | None, typer.Option(help="camera(s) to render")] = None,
    width: Annotated[int, typer.Option(help="image width")] = 84,
    height: Annotated[int, typer.Option(help="image height")] = 84,
) -> None:
    """Re-render image observations from the states into robomimic or LeRobot v3 layout."""
    from crowdteleop.dataset.export import export_robomimic
    from crowdteleop.dataset.lerobot import export_lerobot

    cameras = camera or ["agentview"]
    with clear_errors(), _progress(f"rendering {', '.join(cameras)}") as progress:
        writer = export_robomimic if format == "robomimic" else export_lerobot
        written = writer(dataset, output, cameras, width, height, progress)
    console.print(f"{format} export: {written}")
    console.print(json.dumps({"cameras": cameras, "resolution": [width, height]}))
