"""The coordination server: workers join, queue for a slot, get a dedicated teleop server."""
