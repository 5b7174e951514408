"""The practice round before a worker's first demonstration: move the hand to a green ball.

A new worker's first minute decides whether they learn the controls; a recorded episode is a
poor place for it (its first seconds would be a person finding out which key does what). So
before the first episode the session shows a target that is only drawn (a `Marker`, no body:
the physics and the recorded state never see it) about 12 cm from the hand. The round ends
when the hand stays within `REACH_M` of it for `HOLD_S`, after `duration_s`, or on a skip; the
scene then resets and the next engaged command starts episode 1. Nothing of it is recorded.

Its clock starts with the first engaged command (the rule that starts an episode), not when the
server starts: a warm spare waits for its worker, and a phone user still reading has not begun
(the keyboard, always engaged, sends its first command as the page connects). One round per
worker: `TeleopSession.assign` starts a new one for the new worker; resets and episodes do not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from crowdteleop.sim.types import Marker
from crowdteleop.teleop.protocol import PracticeStage

# From the hand's start, in the world frame: right, up and a little towards the frontview
# camera, in the open where the ball shows against the wall. 12.3 cm, well inside every arm's
# reach, and clear of the table and the task's objects.
TARGET_OFFSET_M = (0.04, 0.10, 0.06)
TARGET_RADIUS_M = 0.03
# Green and opaque: an opaque marker is drawn with the moving layer of the fast renderer's
# composite; a see-through one would cost a full single pass a frame (~22 vs ~5 ms).
TARGET_RGBA = (0.15, 0.85, 0.25, 1.0)
REACH_M = 0.03  # the hand's centre this close to the ball's centre counts as there
HOLD_S = 0.25  # ... for this long: passing through it on the way is not arriving


@dataclass
class PracticeRound:
    """One worker's practice round; `advance` once per control step (simulation thread)."""

    duration_s: float
    control_dt: float
    stage: PracticeStage = "off"
    reached: bool = False
    target_m: npt.NDArray[np.float64] | None = None  # placed from the hand, per scene
    _steps: int = 0  # control steps since the worker's first engaged command
    _started: bool = False
    _held_steps: int = 0

    @classmethod
    def for_worker(cls, duration_s: float, control_dt: float) -> PracticeRound:
        """A round for a new worker; ``duration_s`` 0 means none (stage ``off``)."""
        return cls(duration_s, control_dt, stage="running" if duration_s > 0 else "off")

    @property
    def running(self) -> bool:
        return self.stage == "running"

    @property
    def left_s(self) -> float:
        """Seconds left; the whole round until the worker first moves."""
        if not self.running:
            return 0.0
        return max(0.0, self.duration_s - self._steps * self.control_dt)

    def place(self, hand_m: npt.NDArray[np.float64]) -> None:
        """Put the target at its offset from the hand (a fresh scene's start)."""
        self.target_m = np.asarray(hand_m, dtype=np.float64) + TARGET_OFFSET_M
        self._held_steps = 0

    def scene_reset(self) -> None:
        """A new scene may start the hand elsewhere: the target follows on the next step."""
        self.target_m = None

    def advance(self, engaged: bool, hand_m: npt.NDArray[np.float64]) -> bool:
        """Count one control step that ended with the hand at ``hand_m``; True if the round
        ended in it (reached or out of time): the caller resets the scene."""
        if not self.running:
            return False
        if self.target_m is None:
            self.place(hand_m)
        self._started = self._started or engaged
        if self._started:
            self._steps += 1
        assert self.target_m is not None
        near = float(np.linalg.norm(np.asarray(hand_m) - self.target_m)) <= REACH_M
        self._held_steps = self._held_steps + 1 if near else 0
        if self._held_steps >= max(1, round(HOLD_S / self.control_dt)):
            self.reached = True
            self.stage = "done"
        elif self._started and self.left_s <= 0:
            self.stage = "done"
        return not self.running

    def skip(self) -> bool:
        """The worker skipped it; True if a round was running (the scene then resets)."""
        if not self.running:
            return False
        self.stage = "done"
        return True

    def markers(self) -> tuple[Marker, ...]:
        """What to draw into the frame: the target while the round runs."""
        if not self.running or self.target_m is None:
            return ()
        x, y, z = (float(v) for v in self.target_m)
        return (Marker((x, y, z), TARGET_RADIUS_M, TARGET_RGBA),)
