// What each clutch state (the server's TaskStatus.clutch, crowdteleop/teleop/clutch.py) tells
// the worker: whether the arm follows their device and, if not, what their next press does.
// tests/web/clutch.test.mjs checks these keys against the served schema's list of states.

export const CLUTCH_TEXT = {
  no_driver: "Nobody drives: press a device's hold button or a key to take the arm.",
  released: "Ready: hold to move.",
  driving: "Moving: the arm follows you.",
  waiting_for_pose: "Pressed: waiting for your device's first position.",
  video_stalled: "Stopped: your video froze. Nothing moves until the picture is back.",
  press_again: "Let go and press again to move (the video paused while you held it).",
};

// A short word for status rows.
export const CLUTCH_WORD = {
  no_driver: "nobody", released: "ready", driving: "moving", waiting_for_pose: "waiting",
  video_stalled: "video stopped", press_again: "press again",
};

export function clutchText(state) {
  return CLUTCH_TEXT[state] || "";
}
