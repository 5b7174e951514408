"""The one device-agnostic command every input device (phone, VR, keyboard, 3D mouse) sends."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from crowdteleop.errors import InvalidCommandError

IDENTITY_QUATERNION = np.array([0.0, 0.0, 0.0, 1.0])


@dataclass(frozen=True)
class DeviceCommand:
    """A 6-DoF device pose in the device's own frame, plus the buttons a worker presses.

    position: metres; quaternion: (x, y, z, w), normalized on construction. ``engaged`` is the
    clutch: the arm follows the device only while it is held. ``seq`` orders commands from one
    device and ``client_time_ms`` is the client's clock (milliseconds); both go into recordings.
    """

    position: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    quaternion: npt.NDArray[np.float64] = field(default_factory=lambda: IDENTITY_QUATERNION.copy())
    engaged: bool = False
    gripper_closed: bool = False
    reset: bool = False
    seq: int = 0
    client_time_ms: float = 0.0

    def __post_init__(self) -> None:
        position = np.asarray(self.position, dtype=float)
        quaternion = np.asarray(self.quaternion, dtype=float)
        if position.shape != (3,) or quaternion.shape != (4,):
            raise InvalidCommandError(
                f"pose needs a 3-vector and a 4-quaternion, got shapes {position.shape} "
                f"and {quaternion.shape}"
            )
        if not (np.all(np.isfinite(position)) and np.all(np.isfinite(quaternion))):
            raise InvalidCommandError("pose contains NaN or infinity")
        norm = float(np.linalg.norm(quaternion))
        if norm < 1e-6:
            raise InvalidCommandError("quaternion has zero length")
        object.__setattr__(self, "position", position)
        object.__setattr__(self, "quaternion", quaternion / norm)
