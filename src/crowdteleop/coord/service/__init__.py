"""The service core: the `Coordinator` and the services the API calls; they own the rules and
the locks, and reach the database and the teleop servers through `db/` and `fleet/`."""
