"""Pictures and timings of the fast renderer against robosuite's own picture.

    .venv/bin/python benchmarks/render_pictures.py                 # pictures + timings
    .venv/bin/python benchmarks/render_pictures.py --no-timing     # pictures only
    .venv/bin/python benchmarks/render_pictures.py --tasks lift --runs 7 --json out/render.json

Pictures: ``docs/rendering/<task>.png``, three panels at 320x240 - robosuite's default picture
(a plain `mujoco.Renderer` on the physics model, collision geoms hidden: what robosuite's camera
shows) | ours | the absolute difference times 4 - after reset and a few joint-velocity steps;
``<task>-robot-960x720.png``: the same, cropped to the robot at 960x720 (``--detail`` tasks).

Timings: wall-clock ms per frame (median of ``--frames`` frames per run, median of ``--runs``
runs), frontview. Between two timed frames the arm moves to another recorded state (untimed),
so no frame is served from the idle cache. The reference renderer is timed the same way.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import statistics
import time
from pathlib import Path

import numpy as np
import psutil
from PIL import Image, ImageDraw

# crowdteleop's import chooses MUJOCO_GL; it comes before anything that imports mujoco.
from crowdteleop.sim import SimConfig, make_simulation
from crowdteleop.sim.rendering import CameraRenderer

ROOT = Path(__file__).resolve().parent.parent
TASKS = ("lift", "pick-place-can", "nut-assembly-round")
SIZES = ((320, 240), (480, 360))
CAMERA = "frontview"
AMPLIFY = 4
LABEL_HEIGHT = 16
DETAIL_SIZE = (960, 720)


def arm_action(sim, index: int) -> np.ndarray:
    """Joint velocities on sinusoids (phases spread over the joints), gripper closing."""
    action = np.zeros(sim.action_spec.size)
    action[:-1] = 0.6 * np.sin(0.3 * index + np.arange(sim.action_spec.size - 1))
    action[-1] = 1.0
    return action


def difference(ours: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    diff = np.abs(ours.astype(np.int16) - reference.astype(np.int16))
    differs = diff.max(axis=2) > 0
    return {
        "mad": float(diff.mean()),
        "mad_differing": float(diff[differs].mean()) if differs.any() else 0.0,
        "differing_fraction": float(differs.mean()),
    }


def side_by_side(reference: np.ndarray, ours: np.ndarray, title: str) -> Image.Image:
    diff = np.abs(ours.astype(np.int16) - reference.astype(np.int16)) * AMPLIFY
    panels = [reference, ours, np.clip(diff, 0, 255).astype(np.uint8)]
    labels = ["robosuite default", "ours (fastrender)", f"|difference| x{AMPLIFY}"]
    height, width = reference.shape[:2]
    canvas = Image.new("RGB", (3 * width, height + LABEL_HEIGHT), "white")
    draw = ImageDraw.Draw(canvas)
    for index, (panel, label) in enumerate(zip(panels, labels, strict=True)):
        canvas.paste(Image.fromarray(panel), (index * width, LABEL_HEIGHT))
        draw.text((index * width + 4, 2), label if index else f"{label} - {title}", fill="black")
    return canvas


def pictures(task: str, out_dir: Path, steps: int, detail: bool) -> dict[str, float]:
    sim = make_simulation(SimConfig(task=task))
    reference = CameraRenderer(sim._model, hidden_geom_groups=(0,))
    try:
        sim.reset(seed=0)
        for index in range(steps):
            sim.step(arm_action(sim, index))
        width, height = SIZES[0]
        ours = sim.render(CAMERA, width, height)
        theirs = reference.render(sim._data, CAMERA, width, height)
        figures = difference(ours, theirs)
        title = f"{task}, MAD {figures['mad']:.2f}"
        side_by_side(theirs, ours, title).save(out_dir / f"{task}.png")
        if detail:  # the robot at 960x720, where simplified meshes would show first
            width, height = DETAIL_SIZE
            rows, columns = slice(0, int(0.62 * height)), slice(int(0.33 * width), int(0.7 * width))
            ours = sim.render(CAMERA, width, height)[rows, columns]
            theirs = reference.render(sim._data, CAMERA, width, height)[rows, columns]
            title = f"{task} {width}x{height}, robot"
            side_by_side(theirs, ours, title).save(out_dir / f"{task}-robot-{width}x{height}.png")
        return figures
    finally:
        reference.close()
        sim.close()


def timings(task: str, runs: int, frames: int) -> dict[str, object]:
    sim = make_simulation(SimConfig(task=task))
    reference = CameraRenderer(sim._model, hidden_geom_groups=(0,))
    try:
        sim.reset(seed=0)
        states = []
        for index in range(frames):
            sim.step(arm_action(sim, index))
            states.append(sim.get_state())
        renderer = sim._renderer
        result: dict[str, object] = {
            "triangles_drawn_per_frame": int(_moving_triangles(renderer)),
            "triangles_render_model": int(renderer.render_model.mesh_facenum.sum()),
            "triangles_physics_model": int(sim._model.mesh_facenum.sum()),
        }
        for width, height in SIZES:
            for name, render in (
                ("ours", lambda w, h: sim.render(CAMERA, w, h)),
                ("robosuite", lambda w, h: reference.render(sim._data, CAMERA, w, h)),
            ):
                render(width, height)  # warm-up: buffers, background
                per_run = []
                for _ in range(runs):
                    times = []
                    for state in states:
                        sim.set_state(state)
                        start = time.perf_counter()
                        render(width, height)
                        times.append(time.perf_counter() - start)
                    per_run.append(1e3 * statistics.median(times))
                result[f"{name}_{width}x{height}_ms"] = statistics.median(per_run)
                result[f"{name}_{width}x{height}_runs_ms"] = per_run
        sim.set_state(states[-1])
        sim.render(CAMERA, *SIZES[0])
        start, calls = time.perf_counter(), 200
        for _ in range(calls):
            sim.render(CAMERA, *SIZES[0])  # nothing moved: the cached frame
        result["idle_us"] = 1e6 * (time.perf_counter() - start) / calls
        return result
    finally:
        reference.close()
        sim.close()


def _moving_triangles(renderer) -> int:
    """Mesh triangles in the per-frame (moving) layer of the render model."""
    from crowdteleop.sim.fastrender.layers import MOVING

    model = renderer.render_model
    moving = (model.geom_group == MOVING) & (model.geom_type == 7)  # 7: mjGEOM_MESH
    return int(model.mesh_facenum[model.geom_dataid[moving]].sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "rendering")
    parser.add_argument("--steps", type=int, default=12, help="control steps before the picture")
    parser.add_argument("--timing", action=argparse.BooleanOptionalAction, default=True)
    parser.add_argument(
        "--detail", default="lift", help="tasks that also get a 960x720 crop of the robot"
    )
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    report: dict[str, object] = {
        "load_average_at_start": os.getloadavg(),
        "cpu_count": psutil.cpu_count(),
        "MUJOCO_GL": os.environ.get("MUJOCO_GL"),
        "LP_NUM_THREADS": os.environ.get("LP_NUM_THREADS"),
        "tasks": {},
    }
    for task in args.tasks.split(","):
        detail = task in args.detail.split(",")
        entry: dict[str, object] = {"picture_320x240": pictures(task, args.out, args.steps, detail)}
        gc.collect()
        if args.timing:
            entry.update(timings(task, args.runs, args.frames))
        report["tasks"][task] = entry  # type: ignore[index]
        print(task, json.dumps(entry, default=float))
    if args.timing:
        print("\n| task | ours 320x240 | robosuite 320x240 | ours 480x360 | robosuite 480x360 |")
        print("|---|---|---|---|---|")
        for task, entry in report["tasks"].items():  # type: ignore[union-attr]
            cells = [
                f"{entry[f'{who}_{w}x{h}_ms']:.1f} ms"
                for w, h in SIZES
                for who in ("ours", "robosuite")
            ]
            print(f"| {task} | " + " | ".join(cells) + " |")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2, default=float))


if __name__ == "__main__":
    main()
