"""The teleop servers: how they start (locally or on Ray), the slots they hold, warm spares,
TURN credentials, and what the coordinator asks of them over HTTP."""
