"""`crowdteleop node`: a machine joins the Ray cluster that runs teleop servers, in one command.

`node start` installs nothing. It checks what a node needs (crowdteleop's Python packages,
offscreen rendering through the system's GL libraries, the address the workers' browsers will
reach, a writable work folder), says how to fix what is missing, and only then runs `ray start`
with the node's `teleop` slots and its address (docs/deploy.md, "A Ray cluster").
"""

from __future__ import annotations

import importlib.util
import json
import os
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import psutil
import typer
from rich.console import Console
from rich.table import Table

from crowdteleop.coord.fleet.ray_launcher import HOST_VARIABLE, TELEOP_RESOURCE
from crowdteleop.coord.guard.tls import local_names

app = typer.Typer(help="Join this machine to the Ray cluster that runs teleop servers.")

# What one live session costs (benchmarks/README.md, docs/deploy.md "Sizing"): ~0.18 of a core
# while driving, ~0.8 GiB resident. Four to a core and 1 GiB each leaves room for Ray itself.
SESSIONS_PER_CPU = 4
GIB_PER_SESSION = 1.0
GCS_PORT = 6379
PACKAGES = {
    "ray": "pip install 'crowdteleop[cluster]'",
    "mujoco": "pip install crowdteleop (in the same venv as on the coordinator)",
    "aiortc": "pip install crowdteleop",
    "av": "pip install crowdteleop",
}
RENDER_PROBE = (
    "from crowdteleop.gl import choose_gl_backend; backend = choose_gl_backend(); import mujoco; "
    'm = mujoco.MjModel.from_xml_string(\'<mujoco><worldbody><geom size=".1"/></worldbody>'
    "</mujoco>'); r = mujoco.Renderer(m, 32, 32); r.update_scene(mujoco.MjData(m)); "
    "r.render(); print(backend)"
)


@dataclass(frozen=True)
class Check:
    """One thing a node needs: whether it has it, what was found, how to fix it."""

    name: str
    ok: bool
    found: str
    fix: str = ""


def package_checks() -> list[Check]:
    found = {name: importlib.util.find_spec(name) is not None for name in PACKAGES}
    return [
        Check(f"python package {name}", ok, "installed" if ok else "missing", PACKAGES[name])
        for name, ok in found.items()
    ]


def render_check() -> Check:
    """A tiny offscreen MuJoCo render in a child process (a missing GL library can crash)."""
    try:
        done = subprocess.run(
            [sys.executable, "-c", RENDER_PROBE], capture_output=True, text=True, timeout=60
        )
    except subprocess.TimeoutExpired:
        return Check("offscreen rendering", False, "timed out after 60 s", _GL_FIX)
    if done.returncode == 0:
        return Check("offscreen rendering", True, f"MUJOCO_GL={done.stdout.strip()}")
    last = (done.stderr.strip().splitlines() or ["failed"])[-1][:160]
    return Check("offscreen rendering", False, last, _GL_FIX)


_GL_FIX = "apt-get install libosmesa6 libegl1 libgl1 libglib2.0-0 (scripts/system-deps.sh)"


def address_check(ip: str) -> Check:
    if ip in local_names():
        return Check("address", True, f"{ip} is this machine's")
    return Check("address", False, f"{ip} is not an address of this machine", "--ip ADDRESS")


def folder_check(folder: Path) -> Check:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / ".crowdteleop-write-check"
        probe.write_text("ok")
        probe.unlink()
    except OSError as exc:
        return Check("work folder", False, str(exc), "--work-dir FOLDER (writable)")
    return Check("work folder", True, str(folder))


def node_checks(ip: str, work_dir: Path) -> list[Check]:
    return [*package_checks(), render_check(), address_check(ip), folder_check(work_dir)]


def default_slots() -> tuple[int, str]:
    """As many sessions as the node's cores and memory hold (see SESSIONS_PER_CPU)."""
    cpus = os.cpu_count() or 1
    memory_gib = psutil.virtual_memory().available / 2**30
    slots = max(1, min(cpus * SESSIONS_PER_CPU, int(memory_gib / GIB_PER_SESSION)))
    return slots, f"{cpus} cores x {SESSIONS_PER_CPU}, {memory_gib:.0f} GiB free at 1 GiB each"


def ray_start_command(head_address: str | None, slots: int, ip: str, cpus: int | None) -> list[str]:
    """`ray start` for a head (no address) or a node joining `head_address`."""
    ray = shutil.which("ray") or str(Path(sys.executable).with_name("ray"))
    command = [ray, "start", f"--node-ip-address={ip}"]
    if head_address is None:
        # crowdteleop[cluster] installs Ray without its dashboard (ray[default]).
        command += ["--head", f"--port={GCS_PORT}", "--include-dashboard=false"]
    else:
        command += [f"--address={head_address}"]
    command += [f"--resources={json.dumps({TELEOP_RESOURCE: slots})}"]
    if cpus is not None:
        command += [f"--num-cpus={cpus}"]
    return command


def show(console: Console, checks: list[Check]) -> bool:
    table = Table("check", "", "found", "fix")
    for check in checks:
        mark = "[green]ok[/green]" if check.ok else "[red]missing[/red]"
        table.add_row(check.name, mark, check.found, "" if check.ok else check.fix)
    console.print(table)
    return all(check.ok for check in checks)


Ip = Annotated[
    str,
    typer.Option(
        help="this node's address on the cluster's network: Ray announces it, and workers' "
        "browsers and the coordinator reach its teleop servers there"
    ),
]
WorkDir = Annotated[
    Path, typer.Option(help="the node's work folder (the coordinator's ray.node_work_dir)")
]


@app.command()
def check(ip: Ip, work_dir: WorkDir = Path("/tmp/crowdteleop-ray")) -> None:
    """Check what a node needs, install nothing; exit 1 if something is missing."""
    if not show(Console(), node_checks(ip, work_dir)):
        raise typer.Exit(1)


@app.command()
def start(
    ip: Ip,
    address: Annotated[
        str | None, typer.Option(help="the head's HOST:PORT; without it, this node is the head")
    ] = None,
    slots: Annotated[
        int | None, typer.Option(min=1, help="teleop sessions this node holds [default: sized]")
    ] = None,
    cpus: Annotated[int | None, typer.Option(help="CPUs Ray may use [default: all]")] = None,
    work_dir: WorkDir = Path("/tmp/crowdteleop-ray"),
    dry_run: Annotated[bool, typer.Option(help="check and print `ray start`, run nothing")] = False,
) -> None:
    """Check this machine, then join it to the cluster (`ray start`) with its teleop slots."""
    console = Console()
    if not show(console, node_checks(ip, work_dir)):
        console.print("[red]not started:[/red] fix what is missing above (nothing was installed)")
        raise typer.Exit(1)
    if slots is None:
        slots, why = default_slots()
        console.print(f"teleop slots: {slots} ({why}); --slots to choose")
    command = ray_start_command(address, slots, ip, cpus)
    console.print("$ " + shlex.join(command), soft_wrap=True)
    if dry_run:
        return
    env = {"RAY_USAGE_STATS_ENABLED": "0", **os.environ, HOST_VARIABLE: ip}
    done = subprocess.run(command, env=env, check=False)
    if done.returncode != 0:
        raise typer.Exit(done.returncode)
    role = "head" if address is None else f"node of {address}"
    console.print(f"[green]joined[/green] as the {role}, {slots} teleop slots at {ip}")
