// Input devices of the browser page. Each turns its input into the one device command the
// server takes: a 6-DoF pose in the device's own frame, a clutch and a gripper. Keyboard,
// gamepad and 3D mouse give velocities, integrated here into a virtual hand pose.

import { xrToRobot } from "./xr.js";

const MAX_SPEED = 0.25;   // m/s at full deflection
const MAX_TURN = 1.2;     // rad/s

export function quatMultiply(a, b) {
  const [ax, ay, az, aw] = a, [bx, by, bz, bw] = b;
  return [aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
          aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz];
}

export function quatFromRotationVector([x, y, z]) {
  const angle = Math.hypot(x, y, z);
  if (angle < 1e-9) return [0, 0, 0, 1];
  const s = Math.sin(angle / 2) / angle;
  return [x * s, y * s, z * s, Math.cos(angle / 2)];
}

export class VirtualHand {
  constructor() { this.position = [0, 0, 0]; this.quaternion = [0, 0, 0, 1]; }
  move(velocity, angular, dt) {
    this.position = this.position.map((p, i) => p + velocity[i] * dt);
    const turn = quatFromRotationVector(angular.map((w) => w * dt));
    this.quaternion = quatMultiply(turn, this.quaternion);
  }
}

// Keys: W/S forward/back (x), A/D left/right (y), R/F up/down (z); J/L yaw, I/K pitch, U/O roll;
// G toggles the gripper; C toggles the clutch (on by default: the keyboard is the arm).
export const KEY_LEGEND = [
  ["W / S", "forward / back"], ["A / D", "left / right"], ["R / F", "up / down"],
  ["J / L", "turn left / right"], ["I / K", "tilt"], ["U / O", "roll"],
  ["G", "open / close gripper"], ["C", "clutch on / off"],
];

export class KeyboardDevice {
  constructor(target = window) {
    this.kind = "keyboard";
    this.hand = new VirtualHand();
    this.down = new Set();
    this.engaged = true;
    this.gripper = false;
    target.addEventListener("keydown", (e) => this.#key(e, true));
    target.addEventListener("keyup", (e) => this.#key(e, false));
  }
  #key(event, pressed) {
    if (event.target && ["INPUT", "TEXTAREA"].includes(event.target.tagName)) return;
    const key = event.key.toLowerCase();
    if (pressed && !event.repeat && key === "g") this.gripper = !this.gripper;
    if (pressed && !event.repeat && key === "c") this.engaged = !this.engaged;
    if (pressed) this.down.add(key); else this.down.delete(key);
  }
  get active() { return this.down.size > 0; }
  update(dt) {
    const axis = (plus, minus) => (this.down.has(plus) ? 1 : 0) - (this.down.has(minus) ? 1 : 0);
    const velocity = [axis("w", "s"), axis("a", "d"), axis("r", "f")].map((v) => v * MAX_SPEED);
    const angular = [axis("u", "o"), axis("i", "k"), axis("j", "l")].map((v) => v * MAX_TURN);
    this.hand.move(velocity, angular, dt);
    return { ...this.pose(), engaged: this.engaged, gripper: this.gripper };
  }
  pose() { return { position: this.hand.position, quaternion: this.hand.quaternion }; }
}

// Any gamepad (Gamepad API): left stick x/y, right stick z/yaw; A = gripper, right bumper = clutch.
export class GamepadDevice {
  constructor() { this.kind = "gamepad"; this.hand = new VirtualHand(); this.gripper = false;
                  this.lastA = false; }
  get connected() { return [...(navigator.getGamepads ? navigator.getGamepads() : [])].some(Boolean); }
  update(dt) {
    const pad = [...navigator.getGamepads()].find(Boolean);
    if (!pad) return null;
    const dead = (v) => (Math.abs(v) < 0.12 ? 0 : v);
    const [lx, ly, rx, ry] = pad.axes.map(dead);
    const a = pad.buttons[0] && pad.buttons[0].pressed;
    if (a && !this.lastA) this.gripper = !this.gripper;
    this.lastA = a;
    const engaged = Boolean(pad.buttons[5] && pad.buttons[5].pressed);
    this.hand.move([-ly * MAX_SPEED, -lx * MAX_SPEED, -ry * MAX_SPEED], [0, 0, -rx * MAX_TURN], dt);
    return { position: this.hand.position, quaternion: this.hand.quaternion, engaged, gripper: this.gripper };
  }
}

// 3Dconnexion SpaceMouse over WebHID: report 1 = translation, 2 = rotation (int16 x3, +-350),
// 3 = buttons (left = gripper toggle, right = clutch while held).
export class SpaceMouseDevice {
  constructor() {
    this.kind = "spacemouse"; this.hand = new VirtualHand(); this.device = null;
    this.translation = [0, 0, 0];  // x, y, z deflection, -1..1
    this.rotation = [0, 0, 0];  // about x, y, z, -1..1
    this.gripper = false; this.engaged = true;
  }
  static get supported() { return "hid" in navigator; }
  async open() {
    const [device] = await navigator.hid.requestDevice({ filters: [{ vendorId: 0x256f }, { vendorId: 0x046d }] });
    if (!device) throw new Error("no 3D mouse chosen");
    await device.open();
    device.addEventListener("inputreport", (event) => this.#report(event));
    this.device = device;
  }
  #report({ reportId, data }) {
    const read = () => [0, 2, 4].map((o) => data.getInt16(o, true) / 350);
    if (reportId === 1) this.translation = read();
    else if (reportId === 2) this.rotation = read();
    else if (reportId === 3) {
      const buttons = data.getUint8(0);
      if (buttons & 1) this.gripper = !this.gripper;
      this.engaged = !(buttons & 2);
    }
  }
  update(dt) {
    if (!this.device) return null;
    const [x, y, z] = this.translation;
    this.hand.move([-y * MAX_SPEED, -x * MAX_SPEED, -z * MAX_SPEED], this.rotation.map((v) => -v * MAX_TURN), dt);
    return { position: this.hand.position, quaternion: this.hand.quaternion,
             engaged: this.engaged, gripper: this.gripper };
  }
}

export const HAPTIC_MS = 60;

// A contact's intensity (0..1, the server's) as a pulse strength: the lightest touch is felt.
export const pulseStrength = (intensity) => 0.3 + 0.7 * Math.min(1, Math.max(0, intensity));

// The controllers of an XR session: the right one drives when there is one; the other one
// (if any) moves the headset's screen.
export function handsOf(inputSources) {
  const hands = [...inputSources].filter((s) => s.gripSpace && s.gamepad);
  const driver = hands.find((s) => s.handedness === "right") || hands[0] || null;
  return { driver, other: hands.find((s) => s !== driver) || null };
}

// A VR controller (WebXR immersive-vr): the driving hand's grip pose is the device pose;
// trigger (buttons[0]) = gripper (held), grip (buttons[1]) = clutch (held). `open(scene,
// onEnd)`: `scene` (xr_screen.js's XrScreen) draws what the headset shows and hears the other
// hand; `onEnd` is called when the session ends (the worker left VR).
export class VRControllerDevice {
  constructor() { this.kind = "vr"; this.session = null; this.latest = null; this.driver = null; }
  static async supported() {
    return Boolean(navigator.xr) && (await navigator.xr.isSessionSupported("immersive-vr"));
  }
  async open(scene = null, onEnd = () => {}) {
    const session = await navigator.xr.requestSession("immersive-vr");
    this.session = session;
    session.addEventListener("end", () => {
      this.session = null; this.latest = null; this.driver = null;
      onEnd();
    });
    let layer, space;
    try {
      const gl = document.createElement("canvas").getContext("webgl", { xrCompatible: true });
      layer = new XRWebGLLayer(session, gl);
      session.updateRenderState({ baseLayer: layer });
      scene?.attach(gl);
      space = await session.requestReferenceSpace("local");
    } catch (error) {
      await session.end().catch(() => {});
      throw error;
    }
    this.#run(session, layer, space, scene);
  }
  #run(session, layer, space, scene) {
    let lastMs = null;
    const frame = (timeMs, xrFrame) => {
      if (this.session !== session) return;
      session.requestAnimationFrame(frame);
      const { driver, other } = handsOf(session.inputSources);
      this.#drive(xrFrame, space, driver);
      const viewer = xrFrame.getViewerPose(space);
      const dt = (timeMs - (lastMs ?? timeMs)) / 1000;
      lastMs = timeMs;
      if (scene && viewer) scene.draw(viewer, layer, otherHand(xrFrame, space, other), dt);
    };
    session.requestAnimationFrame(frame);
  }
  #drive(xrFrame, space, source) {
    this.driver = source;
    const pose = source && xrFrame.getPose(source.gripSpace, space);
    if (!pose) return;
    this.latest = { ...xrToRobot(pose.transform),
                    gripper: source.gamepad.buttons[0]?.pressed || false,
                    engaged: source.gamepad.buttons[1]?.pressed || false };
  }
  // A haptic pulse on the driving controller, where it has an actuator.
  pulse(intensity, ms = HAPTIC_MS) {
    const gamepad = this.driver?.gamepad;
    const actuator = gamepad?.hapticActuators?.[0];
    if (actuator?.pulse) return actuator.pulse(pulseStrength(intensity), ms);
    return gamepad?.vibrationActuator?.playEffect?.("dual-rumble",
      { duration: ms, strongMagnitude: pulseStrength(intensity) });
  }
  update() { return this.latest; }
}

// The non-driving hand as the screen hears it: where it is, its grip, its thumbstick.
function otherHand(xrFrame, space, source) {
  const pose = source && xrFrame.getPose(source.gripSpace, space);
  if (!pose) return null;
  const { x, y, z } = pose.transform.position;
  const axes = source.gamepad.axes;
  return { position: [x, y, z], squeeze: source.gamepad.buttons[1]?.pressed || false,
           stick: [axes[2] ?? 0, axes[3] ?? 0] };
}
