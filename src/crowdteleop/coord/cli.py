"""`crowdteleop serve`: the coordination server (registered in crowdteleop/cli.py)."""

from __future__ import annotations

import contextlib
import socket
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

if TYPE_CHECKING:
    import uvicorn

    from crowdteleop.coord.service.config import CoordConfig

TlsFiles = tuple[Path, Path]

WILDCARD = ("0.0.0.0", "::", "")
LOOPBACK = ("127.0.0.1", "localhost", "::1")


def serve(
    host: Annotated[str, typer.Option(help="address to bind (0.0.0.0: the LAN too)")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="port; 0 picks a free one")] = 8000,
    database_url: Annotated[
        str | None,
        typer.Option(
            help="sqlite:///FILE or postgresql://user@host/db [default: sqlite under --data-dir]"
        ),
    ] = None,
    data_dir: Annotated[Path, typer.Option(help="episodes, logs, database, certificate")] = Path(
        "data"
    ),
    config: Annotated[
        Path | None, typer.Option(help="CoordConfig as JSON/YAML (options override it)")
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
) -> None:
    """Run the coordination server: workers join, queue, and teleoperate their own robot."""
    import asyncio
    import logging
    import secrets

    from pydantic import ValidationError
    from rich.console import Console

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s %(message)s")
    logging.getLogger("alembic").setLevel(logging.WARNING)  # a line per plugin, each start
    err = Console(stderr=True)
    options = ServeOptions(
        host=host,
        port=port,
        database_url=database_url,
        data_dir=data_dir,
        config=config,
        campaign=campaign,
        capacity=capacity,
        admin_token=admin_token or secrets.token_urlsafe(24),
        https=https or cert is not None,
        cert=cert,
        key=key,
        public_url=public_url,
        heartbeat_timeout=heartbeat_timeout,
        ice_servers=ice_server or [],
    )
    try:
        settings, sockets, tls = _settings(options)
    except (ValidationError, ValueError, OSError) as exc:
        err.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(2) from exc
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(_run(settings, sockets, tls, show_token=admin_token is None))


@dataclass
class ServeOptions:
    host: str
    port: int
    database_url: str | None
    data_dir: Path
    config: Path | None
    campaign: Path | None
    capacity: int | None
    admin_token: str
    https: bool
    cert: Path | None
    key: Path | None
    public_url: str | None
    heartbeat_timeout: float | None
    ice_servers: list[str]


def _settings(o: ServeOptions) -> tuple[CoordConfig, list[socket.socket], TlsFiles | None]:
    """The config, the bound listening sockets (public, then internal if any), TLS files."""
    from crowdteleop.coord.db.replicas import default_replica_name
    from crowdteleop.coord.guard.http_limits import listening_socket
    from crowdteleop.coord.guard.tls import local_names
    from crowdteleop.coord.service.campaign import load_campaigns
    from crowdteleop.coord.service.config import CoordConfig

    main = listening_socket(o.host, o.port)
    bound = main.getsockname()[1]
    scheme = "https" if o.https else "http"
    shown = o.host
    if o.host in WILDCARD:
        lan = [n for n in local_names() if n.count(".") == 3 and not n.startswith("127.")]
        shown = lan[0] if lan else "127.0.0.1"
    shown = f"[{shown}]" if ":" in shown else shown
    sockets = [main]
    tls = None
    internal_host = "127.0.0.1" if o.host in WILDCARD + LOOPBACK else shown
    internal = f"http://{internal_host}:{bound}"
    if o.https:
        tls = _tls_files(o)
        # Teleop servers report over plain HTTP on loopback (no certificate to trust).
        side = listening_socket("127.0.0.1", 0)
        internal = f"http://127.0.0.1:{side.getsockname()[1]}"
        sockets.append(side)
    fields: dict[str, Any] = {
        "admin_token": o.admin_token,
        "data_dir": o.data_dir,
        "public_url": o.public_url or f"{scheme}://{shown}:{bound}",
    }
    # A config file may say otherwise (replicas behind a load balancer report through it).
    defaults = {
        "internal_url": internal,
        "replica_name": default_replica_name(bound),
        "database_url": f"sqlite:///{o.data_dir / 'coord.sqlite3'}",
    }
    if o.database_url is not None:
        fields["database_url"] = o.database_url
    if o.campaign is not None:
        fields["campaigns"] = load_campaigns(o.campaign)
    if o.capacity is not None:
        fields["capacity"] = o.capacity
    if o.heartbeat_timeout is not None:
        fields["heartbeat_timeout_s"] = o.heartbeat_timeout
    if o.ice_servers:
        fields["ice_servers"] = o.ice_servers
    if o.config is not None:
        return CoordConfig.from_file(o.config, defaults, **fields), sockets, tls
    return CoordConfig.model_validate({**defaults, **fields}), sockets, tls


def _tls_files(o: ServeOptions) -> TlsFiles:
    """--cert and --key, or a self-signed certificate for every name this machine answers to."""
    from crowdteleop.coord.guard.private import private_dir
    from crowdteleop.coord.guard.tls import local_names, self_signed

    if o.cert is not None and o.key is not None:
        return o.cert, o.key
    if o.cert is not None or o.key is not None:
        raise ValueError("--cert and --key go together")
    names = set(local_names()) | ({o.host} if o.host not in WILDCARD else set())
    private_dir(o.data_dir)  # before its tls/ folder, which would give it usual modes
    return self_signed(o.data_dir / "tls", sorted(names))


async def _run(
    settings: CoordConfig, sockets: list[socket.socket], tls: TlsFiles | None, show_token: bool
) -> None:
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
        base = settings.public_url.rstrip("/")
        print(f"READY {base}", flush=True)
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
