"""A Python client of the teleop server (aiortc), and the scripted bot built on it."""
