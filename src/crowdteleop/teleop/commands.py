"""Which device drives the arm, and its latest command (latest wins, stale ones dropped)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from crowdteleop.control.command import DeviceCommand
from crowdteleop.recording.episode_file import CommandRecord
from crowdteleop.teleop.clutch import Clutch
from crowdteleop.teleop.protocol import ClutchEvent, GripperEvent, PoseCommand
from crowdteleop.vocab import DeviceKind


@dataclass(frozen=True)
class Driver:
    """The (peer, device) pair driving the arm. Switching is explicit: `take_control`.

    Not to be confused with the control law (`crowdteleop.control.teleoperator.ControlLaw`)."""

    peer_id: str
    device: DeviceKind


class NotInControlError(Exception):
    """A command came from a device that does not drive the arm."""


@dataclass
class CommandBoard:
    """Holds the controlling device's latest state.

    Pose messages travel unordered and unreliable, clutch and gripper events reliable: all carry
    one per-device sequence number, so whichever arrives last in sequence order wins and an old
    pose can never undo a newer clutch release.
    """

    driver: Driver | None = None
    position: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    quaternion: npt.NDArray[np.float64] = field(
        default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0])
    )
    clutch: Clutch = field(default_factory=Clutch)
    gripper_closed: bool = False
    last_seq: int = -1
    last_client_time_ms: float = 0.0
    has_pose: bool = False
    # Set when control changes hands; the next `command` shows the clutch released once.
    release_pending: bool = False

    @property
    def engaged(self) -> bool:
        """Whether the arm follows the device now (`clutch.py` says when)."""
        return self.clutch.engaged

    @property
    def video_stalled(self) -> bool:
        return self.clutch.video_stalled

    def take_control(self, peer_id: str, device: DeviceKind) -> bool:
        """Make (peer, device) the driver; returns whether anything changed."""
        new = Driver(peer_id, device)
        if new == self.driver:
            return False
        self.driver = new
        self.clutch.switch()  # a new device starts with the clutch released
        self.last_seq = -1
        self.has_pose = False
        # ... and the control loop must see that release: the new device's first engaged pose
        # may arrive before the next step, and a mapper that never saw the clutch let go would
        # keep the old device's anchor and pull the hand to where the old anchor puts it.
        self.release_pending = True
        return True

    def release(self, peer_id: str) -> bool:
        """The peer left: nobody drives until a device takes control."""
        if self.driver is None or self.driver.peer_id != peer_id:
            return False
        self.driver = None
        self.clutch.leave()
        self.last_seq = -1
        self.has_pose = False
        return True

    def set_video_stalled(self, stalled: bool) -> bool:
        """The worker's page saw its video stop (or resume); returns whether that changed."""
        if stalled == self.clutch.video_stalled:
            return False
        self.clutch.stall(stalled)
        return True

    def release_clutch(self) -> None:
        """After a reset the arm stops following until the device's next message: a clutch
        anchored in the last episode would pull the new scene to a stale device pose."""
        self.clutch.scene_reset()

    def _check(self, peer_id: str, device: DeviceKind, seq: int) -> bool:
        """False for stale messages; raises NotInControlError for other devices."""
        if self.driver is None:
            self.take_control(peer_id, device)
        if self.driver != Driver(peer_id, device):
            raise NotInControlError(
                f"{device} on this connection does not drive the arm "
                f"({self.driver.device if self.driver else 'nobody'} does); "
                "send take_control to switch"
            )
        if seq <= self.last_seq:
            return False
        self.last_seq = seq
        return True

    def apply_pose(self, peer_id: str, message: PoseCommand) -> bool:
        if not self._check(peer_id, message.device, message.seq):
            return False
        self.position = np.array(message.position, dtype=float)
        self.quaternion = np.array(message.quaternion, dtype=float)
        self.has_pose = True
        self.clutch.device(message.engaged, has_pose=True)
        self.gripper_closed = message.gripper
        self.last_client_time_ms = message.client_time_ms
        return True

    def apply_event(self, peer_id: str, message: ClutchEvent | GripperEvent) -> bool:
        if not self._check(peer_id, message.device, message.seq):
            return False
        if isinstance(message, ClutchEvent):
            # Engaging needs a pose to anchor on; a clutch press before any pose waits for one.
            self.clutch.device(message.engaged, self.has_pose)
        else:
            self.gripper_closed = message.closed
        self.last_client_time_ms = message.client_time_ms
        return True

    def command(self) -> DeviceCommand:
        """The command for this control step (call once per step)."""
        engaged = self.engaged and not self.release_pending
        self.release_pending = False
        return DeviceCommand(
            position=self.position,
            quaternion=self.quaternion,
            engaged=engaged,
            gripper_closed=self.gripper_closed,
            seq=max(self.last_seq, 0),
            client_time_ms=self.last_client_time_ms,
        )

    def raw_command(self) -> CommandRecord:
        """What the recorder stores for this step: the device's latest state as sent."""
        return {
            "seq": self.last_seq,
            "client_time_ms": self.last_client_time_ms,
            "device": self.driver.device if self.driver else None,
            "position": self.position.tolist(),
            "quaternion": self.quaternion.tolist(),
            "engaged": self.engaged,
            "gripper": self.gripper_closed,
        }
