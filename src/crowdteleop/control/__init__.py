"""Teleoperation control: device command -> clutch and frame mapping -> controller -> action.

Importing this package loads no simulator: `crowdteleop.control.config` is read by processes
that never step a robot. The pipeline itself is `crowdteleop.control.teleoperator.Teleoperator`.
"""
