"""`crowdteleop serve`: the coordination server (registered in crowdteleop/cli.py)."""

from __future__ import annotations

import contextlib
import json
import re
import signal
import socket
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

if TYPE_CHECKING:
    import uvicorn
    from rich.console import Console

    from crowdteleop.coord.service.config import CoordConfig
    from crowdteleop.coord.service.preparing import Preparation

TlsFiles = tuple[Path, Path]

WILDCARD = ("0.0.0.0", "::", "")
LOOPBACK = ("127.0.0.1", "localhost", "::1")


def serve(
    host: Annotated[str, typer.Option(help="address to bind (0.0.0.0: the LAN too)")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="port; 0 picks a free one")] = 8000,
    database_url: Annotated[
        str | None,
        typer.Option(
            help="sqlite:///FILE or postgresql://user@host/db [default: sqlite under data_dir]"
        ),
    ] = None,
    data_dir: Annotated[
        Path | None, typer.Option(help="episodes, logs, database, certificate [default: data]")
    ] = None,
    config: Annotated[
        Path | None,
        typer.Option(help="CoordConfig as JSON/YAML (environment and flags given override it)"),
    ] = None,
    campaign: Annotated[
        Path | None, typer.Option(help="campaign(s) as JSON/YAML (docs/coordination.md)")
    ] = None,
    capacity: Annotated[
        int | None, typer.Option(help="teleop servers at once [default: 2]")
    ] = None,
    admin_token: Annotated[
        str | None, typer.Option(help="admin bearer token [default: random, printed]")
    ] = None,
    https: Annotated[bool, typer.Option(help="serve TLS (self-signed unless --cert)")] = False,
    cert: Annotated[Path | None, typer.Option(help="TLS certificate (PEM)")] = None,
    key: Annotated[Path | None, typer.Option(help="TLS private key (PEM)")] = None,
    public_url: Annotated[
        str | None, typer.Option(help="base URL phones reach us at [default: from host/port]")
    ] = None,
    heartbeat_timeout: Annotated[
        float | None, typer.Option(help="seconds of silence before a session is abandoned")
    ] = None,
    ice_server: Annotated[list[str] | None, typer.Option(help="STUN/TURN URL (repeatable)")] = None,
    print_config: Annotated[
        bool, typer.Option(help="print every setting and where it came from, then exit")
    ] = False,
) -> None:
    """Run the coordination server: workers join, queue, and teleoperate their own robot.

    Settings: defaults < --config file < CROWDTELEOP_<FIELD> variables < flags given."""
    import logging

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s %(message)s")
    logging.getLogger("alembic").setLevel(logging.WARNING)  # a line per plugin, each start
    options = ServeOptions(
        host=host,
        port=port,
        database_url=database_url,
        data_dir=data_dir,
        config=config,
        campaign=campaign,
        capacity=capacity,
        admin_token=admin_token,
        https=https or cert is not None,
        cert=cert,
        key=key,
        public_url=public_url,
        heartbeat_timeout=heartbeat_timeout,
        ice_servers=ice_server or [],
    )
    prepared = _prepared(options, print_config)
    if prepared is not None:
        _serve_until_stopped(*prepared)


def _prepared(
    options: ServeOptions, print_config: bool
) -> tuple[Settings, list[socket.socket], TlsFiles | None] | None:
    """The settings, the bound sockets and the TLS files; None after `--print-config`. Bad
    settings exit 2, saying why."""
    import yaml
    from pydantic import ValidationError
    from rich.console import Console

    try:
        if print_config:
            _print_config(options, Console())
            return None
        return _settings(options)
    except (ValidationError, ValueError, OSError, yaml.YAMLError) as exc:
        Console(stderr=True).print(f"[red]error:[/red] {exc}", markup=True, highlight=False)
        raise typer.Exit(2) from exc


def _serve_until_stopped(
    settings: Settings, sockets: list[socket.socket], tls: TlsFiles | None
) -> None:
    """Serve until SIGTERM or Ctrl-C (exit 0); a server that could not start exits 3."""
    import asyncio

    from rich.console import Console

    # SIGTERM (`systemctl stop`) stops as Ctrl-C does: uvicorn's graceful shutdown, then the
    # signal it raises again ends here as KeyboardInterrupt: exit 0, not a death by signal.
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    started = True
    try:
        with contextlib.suppress(KeyboardInterrupt):
            started = asyncio.run(
                _run(settings.config, sockets, tls, show_token=settings.token_made_up)
            )
    except SystemExit as exc:  # uvicorn's, when the app's startup (its lifespan) failed
        started = exc.code in (0, None)
    if not started:
        Console(stderr=True).print("[red]error:[/red] the coordinator did not start (see above)")
        raise typer.Exit(3)


@dataclass
class ServeOptions:
    """`serve`'s command line; None (or empty) where a flag was not given, so that it
    overrides nothing."""

    host: str = "127.0.0.1"
    port: int = 8000
    database_url: str | None = None
    data_dir: Path | None = None
    config: Path | None = None
    campaign: Path | None = None
    capacity: int | None = None
    admin_token: str | None = None
    https: bool = False
    cert: Path | None = None
    key: Path | None = None
    public_url: str | None = None
    heartbeat_timeout: float | None = None
    ice_servers: list[str] = field(default_factory=list)

    @property
    def scheme(self) -> str:
        return "https" if self.https else "http"


# The CoordConfig fields that a flag sets, and the flag.
FLAGS = {
    "database_url": "--database-url",
    "data_dir": "--data-dir",
    "campaigns": "--campaign",
    "capacity": "--capacity",
    "admin_token": "--admin-token",
    "public_url": "--public-url",
    "heartbeat_timeout_s": "--heartbeat-timeout",
    "ice_servers": "--ice-server",
}
RANDOM_TOKEN = "default (random, printed at start)"


@dataclass(frozen=True)
class Layers:
    """The fields that the config file, the environment and the flags given set, merged in
    that order (a later layer wins), and where each one's value came from."""

    values: dict[str, Any]
    origins: dict[str, str]

    @property
    def loopback_reports(self) -> bool:
        """Whether teleop servers report to this process's loopback address: not when a
        layer names internal_url, nor when they run on a Ray cluster (other machines)."""
        return "internal_url" not in self.values and self.values.get("ray") is None

    @property
    def data_dir(self) -> Path:
        """The effective data_dir: the derived defaults and the certificate go under it."""
        from crowdteleop.coord.service.config import CoordConfig

        return Path(self.values.get("data_dir", CoordConfig.model_fields["data_dir"].default))


@dataclass(frozen=True)
class Settings:
    """The settings `serve` runs with, and where each field's value came from."""

    config: CoordConfig
    origins: dict[str, str]

    @property
    def token_made_up(self) -> bool:
        """No layer gave an admin token: the random one is printed at start."""
        return self.origins["admin_token"] == RANDOM_TOKEN


def given_settings(o: ServeOptions) -> Layers:
    """The fields set by the --config file, then CROWDTELEOP_<FIELD> variables, then flags."""
    from crowdteleop.coord.service.config import ENV_PREFIX, environment_settings, file_settings

    in_file = file_settings(o.config) if o.config is not None else {}
    in_environment = environment_settings()
    in_flags = _flag_fields(o)
    origins = {name: f"file {o.config}" for name in in_file}
    origins |= {name: f"environment {ENV_PREFIX}{name.upper()}" for name in in_environment}
    origins |= {name: f"flag {FLAGS[name]}" for name in in_flags}
    return Layers({**in_file, **in_environment, **in_flags}, origins)


def _flag_fields(o: ServeOptions) -> dict[str, Any]:
    """The CoordConfig fields the command line sets: a flag not given sets nothing."""
    from crowdteleop.coord.service.campaign import load_campaigns

    fields = {
        "database_url": o.database_url,
        "data_dir": o.data_dir,
        "campaigns": load_campaigns(o.campaign) if o.campaign is not None else None,
        "capacity": o.capacity,
        "admin_token": o.admin_token,
        "public_url": o.public_url,
        "heartbeat_timeout_s": o.heartbeat_timeout,
        "ice_servers": o.ice_servers or None,
    }
    return {name: value for name, value in fields.items() if value is not None}


def effective_settings(
    o: ServeOptions, layers: Layers, port: int, report_port: int | None = None
) -> Settings:
    """The layers over defaults derived from their effective values and the listening `port`
    (`report_port`: the loopback listener teleop servers report to under TLS)."""
    from pydantic import ValidationError

    from crowdteleop.coord.service.config import CoordConfig

    derived = _derived(o, layers, port, report_port)
    origins = {name: "default" for name in CoordConfig.model_fields}
    origins |= {name: origin for name, (_, origin) in derived.items()} | layers.origins
    values = {name: value for name, (value, _) in derived.items()} | layers.values
    try:
        return Settings(CoordConfig.model_validate(values), origins)
    except ValidationError as exc:
        named = sorted({str(error["loc"][0]) for error in exc.errors() if error["loc"]})
        given = [f"{name} from {layers.origins[name]}" for name in named if name in layers.origins]
        raise ValueError(f"{exc}\n({'; '.join(given)})" if given else str(exc)) from exc


def _derived(
    o: ServeOptions, layers: Layers, port: int, report_port: int | None
) -> dict[str, tuple[Any, str]]:
    """Defaults that follow from other settings, each with its origin, for the fields that
    no layer sets."""
    import secrets

    from crowdteleop.coord.db.replicas import default_replica_name

    shown = _shown_host(o.host)
    local = "127.0.0.1" if o.host in WILDCARD + LOOPBACK else shown
    internal = f"http://{local}:{port}"
    if report_port is not None:  # TLS: a plain-HTTP listener on loopback
        internal = f"http://127.0.0.1:{report_port}"
    database = f"sqlite:///{layers.data_dir / 'coord.sqlite3'}"
    derived = {
        "database_url": (database, "default (under data_dir)"),
        "public_url": (f"{o.scheme}://{shown}:{port}", "default (from --host, --port)"),
        "admin_token": (secrets.token_urlsafe(24), RANDOM_TOKEN),
        "replica_name": (default_replica_name(port), "default (host name:port)"),
        # On a Ray cluster teleop servers run on other machines: no loopback, so they report
        # through public_url (CoordConfig.report_base_url).
        "internal_url": (internal, "default (this process's own address)")
        if layers.loopback_reports
        else (None, "default (none with ray: public_url)"),
    }
    return {name: value for name, value in derived.items() if name not in layers.values}


def _settings(o: ServeOptions) -> tuple[Settings, list[socket.socket], TlsFiles | None]:
    """The settings, the bound listening sockets (public, then internal if any), TLS files."""
    from crowdteleop.coord.guard.http_limits import listening_socket

    layers = given_settings(o)  # a bad file or variable is named before anything is bound
    main = listening_socket(o.host, o.port)
    sockets = [main]
    tls = report_port = None
    if o.https:
        tls = _tls_files(o, layers.data_dir)
        if layers.loopback_reports:
            # Teleop servers report over plain HTTP on loopback (no certificate to trust).
            side = listening_socket("127.0.0.1", 0)
            report_port = side.getsockname()[1]
            sockets.append(side)
    settings = effective_settings(o, layers, main.getsockname()[1], report_port)
    return settings, sockets, tls


def _shown_host(host: str) -> str:
    """The host name in URLs: a wildcard address shows as this machine's first LAN address."""
    from crowdteleop.coord.guard.tls import local_names

    shown = host
    if host in WILDCARD:
        lan = [n for n in local_names() if n.count(".") == 3 and not n.startswith("127.")]
        shown = lan[0] if lan else "127.0.0.1"
    return f"[{shown}]" if ":" in shown else shown


def _tls_files(o: ServeOptions, data_dir: Path) -> TlsFiles:
    """--cert and --key, or a self-signed certificate for every name this machine answers to."""
    from crowdteleop.coord.guard.private import private_dir
    from crowdteleop.coord.guard.tls import local_names, self_signed

    if o.cert is not None and o.key is not None:
        return o.cert, o.key
    if o.cert is not None or o.key is not None:
        raise ValueError("--cert and --key go together")
    names = set(local_names()) | ({o.host} if o.host not in WILDCARD else set())
    private_dir(data_dir)  # before its tls/ folder, which would give it usual modes
    return self_signed(data_dir / "tls", sorted(names))


# Fields named like these hold secrets (admin_token, turn.secret, ice_servers[].credential).
SECRET_NAME = re.compile(r"secret|password|token|credential", re.IGNORECASE)
URL_PASSWORD = re.compile(r"(://[^/:@\s]+:)[^/@\s]+@")  # postgresql://user:PASSWORD@host


def _print_config(o: ServeOptions, console: Console) -> None:
    """Every CoordConfig field's effective value and origin, secrets masked; nothing bound:
    the URLs show the configured port (0: one picked at start)."""
    from rich import box
    from rich.console import Console
    from rich.table import Table
    from rich.text import Text

    layers = given_settings(o)
    settings = effective_settings(o, layers, o.port, 0 if o.https else None)
    table = Table("setting", "from", box=box.SIMPLE_HEAD)
    table.add_column("value", overflow="fold")  # a URL or a path whole, over several lines
    for name, value in settings.config.model_dump(mode="json").items():
        table.add_row(name, settings.origins[name], Text(_shown_value(_masked(name, value))))
    if not console.is_terminal:  # piped: whole values, a line each, for grep and tests
        console = Console(width=10_000)
    console.print(f"listening on {o.host}:{o.port} (--host, --port)", highlight=False)
    console.print(table)


def _masked(name: str, value: Any) -> Any:
    """`value` with its secrets replaced: fields named like one, and passwords in URLs."""
    if SECRET_NAME.search(name):
        return value if value is None else "***"
    if isinstance(value, dict):
        return {key: _masked(key, item) for key, item in value.items()}
    if isinstance(value, list):
        return [_masked(name, item) for item in value]
    if isinstance(value, str):
        return URL_PASSWORD.sub(r"\1***@", value)
    return value


def _shown_value(value: Any) -> str:
    if isinstance(value, str):
        return value
    return json.dumps(value)


async def _run(
    settings: CoordConfig, sockets: list[socket.socket], tls: TlsFiles | None, show_token: bool
) -> bool:
    """Serve until stopped; whether the server started at all (its lifespan may refuse)."""
    import asyncio

    import uvicorn

    from crowdteleop.coord.app import create_app
    from crowdteleop.coord.guard.http_limits import uvicorn_options

    app = create_app(settings)
    certificate, key = (str(tls[0]), str(tls[1])) if tls else (None, None)
    limits = uvicorn_options(settings)
    main = uvicorn.Server(
        uvicorn.Config(
            app, log_level="warning", ssl_certfile=certificate, ssl_keyfile=key, **limits
        )
    )
    servers = [main.serve(sockets=[sockets[0]])]
    side = None
    if len(sockets) > 1:
        side = _QuietServer(uvicorn.Config(app, lifespan="off", log_level="warning", **limits))
        servers.append(side.serve(sockets=[sockets[1]]))

    async def announce() -> None:
        while not main.started:
            if main.should_exit:
                return
            await asyncio.sleep(0.05)
        first_robot = await _first_robot(app.state.coordinator.preparation, settings, main)
        if main.should_exit:
            return
        base = settings.public_url.rstrip("/")
        print(f"READY {base}", flush=True)
        print(f"  first robot: {first_robot}", flush=True)
        print(f"  join link:  {base}/join", flush=True)
        print(f"  admin page: {base}/admin", flush=True)
        if show_token:
            print(f"  admin token: {settings.admin_token}", flush=True)
        print(f"  database:   {settings.database_url}", flush=True)
        if tls:
            print(f"  TLS certificate: {tls[0]} (phones must accept it once)", flush=True)

    async def main_then_side() -> None:
        try:
            await servers[0]
        finally:
            if side is not None:
                side.should_exit = True

    await asyncio.gather(main_then_side(), *servers[1:], announce())
    return bool(main.started)


async def _first_robot(preparation: Preparation, settings: CoordConfig, main: Any) -> str:
    """Wait (while `main` serves) for the first warm spare, so READY means the first worker
    gets a robot at once; what to say of the first robot."""
    import asyncio

    typical = preparation.typical_start_s()
    if settings.ray is not None:  # a restart takes its sessions back at once; a spare may
        # wait for a slot of the cluster's (or another replica's spare serves)
        return f"about {typical:.0f} s unless a warm spare is up (Ray: started in the background)"
    if settings.spare_servers != 0:
        print(f"warming the first robot (a start takes about {typical:.0f} s)…", flush=True)
    waiting = asyncio.create_task(preparation.first_robot(settings.teleop_start_timeout_s))
    while not waiting.done() and not main.should_exit:
        await asyncio.sleep(0.05)
    if not waiting.done():
        waiting.cancel()
    waited = None
    with contextlib.suppress(asyncio.CancelledError, Exception):
        waited = await waiting
    if waited is not None:
        return f"warm, ready at once (it took {waited:.1f} s)"
    why = "spare_servers is 0" if settings.spare_servers == 0 else "no warm spare is ready"
    return f"about {typical:.0f} s after the first worker joins ({why})"


class _QuietServer:
    """A second listener (plain HTTP on loopback) that leaves signals to the main server."""

    def __init__(self, config: uvicorn.Config) -> None:
        import uvicorn

        class Server(uvicorn.Server):
            @contextlib.contextmanager
            def capture_signals(self) -> Iterator[None]:
                yield

        self._server = Server(config)

    @property
    def should_exit(self) -> bool:
        return self._server.should_exit

    @should_exit.setter
    def should_exit(self, value: bool) -> None:
        self._server.should_exit = value

    async def serve(self, sockets: list[socket.socket]) -> None:
        await self._server.serve(sockets=sockets)


REVIEW_HELP = "Files from the review decisions: bonus payments for the study platforms."
review_app = typer.Typer(help=REVIEW_HELP, no_args_is_help=True)


@review_app.command("bonus")
def review_bonus(
    db: Annotated[str, typer.Option("--db", help="the coordinator's database URL")],
    campaign: Annotated[str, typer.Option(help="the campaign whose demonstrations count")],
    platform: Annotated[
        str, typer.Option("--format", help="prolific (bulk bonus lines) or mturk (CSV)")
    ] = "prolific",
    per_accepted: Annotated[
        float, typer.Option(min=0.01, help="the bonus per accepted demonstration")
    ] = 0.10,
    output: Annotated[
        Path | None, typer.Option("-o", "--output", help="the file to write; stdout without")
    ] = None,
) -> None:
    """A bonus file from the campaign's accepted demonstrations, in the form Prolific's bulk
    bonus takes (`<participant id>,<amount>` lines) or MTurk's (WorkerId, AssignmentId,
    BonusAmount, Reason); docs/workers.md."""
    import asyncio

    from crowdteleop.coord.db.engine import make_engine, make_sessionmaker
    from crowdteleop.coord.db.worker_stats import WorkerStatsStore
    from crowdteleop.coord.service.bonus import BonusFormat, bonus_file

    if platform not in ("prolific", "mturk"):
        raise typer.BadParameter("prolific or mturk", param_hint="--format")
    chosen: BonusFormat = "mturk" if platform == "mturk" else "prolific"

    async def build() -> str:
        engine = make_engine(db)
        try:
            stats = WorkerStatsStore(make_sessionmaker(engine))
            return await bonus_file(stats, campaign, chosen, per_accepted)
        finally:
            await engine.dispose()

    text = asyncio.run(build())
    if output is None:
        typer.echo(text, nl=False)
    else:
        output.write_text(text, encoding="utf-8")
        typer.echo(f"{len(text.splitlines())} lines written to {output}", err=True)
