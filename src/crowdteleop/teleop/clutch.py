"""The clutch's state machine: the one place that decides whether the arm follows the device.

A worker holds a clutch (a button, the grip, the keyboard's C) to make the arm follow their
hand. Things happen around that press: the video stops, another device takes over, the scene
resets, the device's tracking is lost. Each ends in a named state (`ClutchState`), sent to every
page in the status so the worker is told why the arm does or does not follow, and from each the
next press either drives or the state says what is in the way.

    no_driver ──device takes control──▶ released ◀──────── let go ─────────┐
                                          │ press (with a pose)            │
                                          ▼                                │
         waiting_for_pose ◀─press, no pose yet── driving ──────────────────┘
                                          │ video stops (any state but no_driver)
                                          ▼
                                    video_stalled ──picture back, held since before──▶ press_again
                                          │ picture back, let go (or pressed anew)        │ let go
                                          ▼                                               ▼
                                  released (or driving) ◀─────────────────────────────────┘

A device taking control always starts `released` (or `video_stalled` while the picture is
frozen): a press left over from before the switch never blocks the new device's first press.
"""

from __future__ import annotations

from dataclasses import dataclass

from crowdteleop.vocab import ClutchState


@dataclass
class Clutch:
    """The clutch of whichever device drives; `engaged` is whether the arm follows it now."""

    state: ClutchState = "no_driver"
    held: bool = False  # the driving device's own clutch, as it last said
    has_pose: bool = False  # the driving device has sent a pose to anchor on
    video_stalled: bool = False  # the worker's picture is frozen
    stale_press: bool = False  # held since before the picture froze: not a press made seeing

    @property
    def engaged(self) -> bool:
        return self.state == "driving"

    def switch(self) -> None:
        """A device took control: it starts with its clutch let go."""
        self.held = self.has_pose = self.stale_press = False
        self.state = "video_stalled" if self.video_stalled else "released"

    def leave(self) -> None:
        """The driving device left: nobody drives."""
        self.held = self.has_pose = self.stale_press = False
        self.state = "no_driver"

    def device(self, held: bool, has_pose: bool) -> None:
        """The driving device says whether its clutch is held (with every pose and press)."""
        if self.state == "no_driver":
            return
        self.held, self.has_pose = held, has_pose
        if not held:
            self.stale_press = False
        if self.video_stalled:
            return  # nothing drives blind; the press is judged when the picture is back
        self._follow()

    def _follow(self) -> None:
        """The state the device's clutch gives when nothing else is in the way."""
        if not self.held:
            self.state = "released"
        elif self.stale_press:
            self.state = "press_again"
        else:
            self.state = "driving" if self.has_pose else "waiting_for_pose"

    def stall(self, stalled: bool) -> None:
        """The worker's picture froze (or is back)."""
        self.video_stalled = stalled
        if self.state == "no_driver":
            return
        if stalled:
            self.stale_press = self.held
            self.state = "video_stalled"
        else:
            self._follow()

    def scene_reset(self) -> None:
        """A fresh scene: the arm stops following until the device's next message anchors it
        again (a held clutch then drives from the new scene)."""
        if self.state in ("driving", "waiting_for_pose"):
            self.state = "released"
