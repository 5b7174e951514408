"""Teleoperation control: device command -> clutch and frame mapping -> controller -> action."""

from crowdteleop.control.command import DeviceCommand
from crowdteleop.control.config import ControlConfig, MappingConfig
from crowdteleop.control.mapping import ClutchMapper
from crowdteleop.control.teleoperator import Teleoperator, make_controller

__all__ = [
    "ClutchMapper",
    "ControlConfig",
    "DeviceCommand",
    "MappingConfig",
    "Teleoperator",
    "make_controller",
]
