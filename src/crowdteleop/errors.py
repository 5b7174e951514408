"""Errors of our own, each with a message that tells the user what to do."""


class CrowdteleopError(Exception):
    """Base class of every error crowdteleop raises on purpose."""


class ConfigError(CrowdteleopError, ValueError):
    """A configuration names something that does not exist or is out of range."""


class UnknownTaskError(ConfigError):
    pass


class UnknownRobotError(ConfigError):
    pass


class UnknownCameraError(ConfigError):
    pass


class InvalidResolutionError(ConfigError):
    pass


class InvalidActionError(CrowdteleopError, ValueError):
    """An action has the wrong shape or holds NaN / inf."""


class InvalidStateError(CrowdteleopError, ValueError):
    """A state vector does not belong to this simulation."""


class RenderBackendError(CrowdteleopError, RuntimeError):
    """No offscreen OpenGL backend works on this machine."""


class InvalidCommandError(CrowdteleopError, ValueError):
    """A device command holds NaN / inf, a zero quaternion or a wrong shape."""
