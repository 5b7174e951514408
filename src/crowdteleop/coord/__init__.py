"""The coordination server: workers join, queue for a slot, get a dedicated teleop server.

- `api/`: the HTTP API and the pages: routers, their schemas and views, FastAPI dependencies.
- `service/`: the service core: the `Coordinator` (sessions from queued to ended, the slots,
  and the background sweeps it owns), the services the API calls, the settings.
- `fleet/`: the teleop servers: launchers (local processes, Ray), the pool's slots, warm
  spares, the cluster's room, TURN credentials, the servers' HTTP API as the coordinator calls it.
- `db/`: the database: engine and migrations, tables, stores, replicas and the admission lock.
- `guard/`: what protects it: rate and HTTP limits, security headers, client addresses, join
  identities, TLS, tokens and private files, and the error answers.

`app.py` builds the app from these; `cli.py` is `crowdteleop serve`.
"""
