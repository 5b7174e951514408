// The phone controller: pair with a code, then the phone is a 6-DoF input device. With WebXR
// (Android Chrome + ARCore) the phone's tracked pose, filtered (pose_filter.js), is the device
// pose; without it (iPhones) the rear camera tracks a marker on the worker's screen
// (camera_mode.js); otherwise its orientation sensors give the rotation and the drag pads the
// translation.
// docs/phone.md says which phone gets which mode.

import { call } from "./api.js";
import { cameraSupported } from "./camera.js";
import { cameraOrientation, startCameraMode } from "./camera_mode.js";
import { CLUTCH_TEXT, CLUTCH_WORD } from "./clutch.js";
import { quatMultiply } from "./devices.js";
import { PhonePoseFilter } from "./pose_filter.js";
import { Protocol } from "./protocol.js";
import { TeleopConnection } from "./rtc.js";
import { takePose } from "./tracked_pose.js";
import { XrTracker, arSupported } from "./xr.js";

const $ = (id) => document.getElementById(id);
const SEND_HZ = 30;
const PAD_METRES = 0.4;  // a drag across the whole pad moves the hand this far

// All of the page's state, declared here and sealed so it cannot grow fields by accident.
// Exposed as window.crowdteleop for end-to-end tests (the one global).
class PhoneState {
  constructor() {
    this.protocol = null;  // the loaded Protocol (schema from /protocol.json)
    this.token = null;  // the phone token pairing gave
    this.connection = null;
    this.position = [0, 0, 0];  // metres, the device frame
    this.quaternion = [0, 0, 0, 1];  // x, y, z, w
    this.engaged = false;
    this.gripper = false;
    this.source = "none";  // what moves the hand: "none", "orientation", "xr" or "camera"
    this.haptics = 0;  // haptic events received
    this.xr = null;  // the XrTracker, while AR tracking runs
    this.camera = null;  // the CameraTracker, while camera tracking runs
    this.tracking = "none";  // AR or camera tracking: "none", "starting", "tracking" or "lost"
    this.filter = null;  // the PhonePoseFilter of the AR or camera session
    this.fusion = null;  // camera mode's OrientationFusion
    this.rawPose = null;  // the last tracked pose before filtering (robot-style frame)
    this.stallShown = false;
    this.ready = false;
    this.secure = window.isSecureContext;  // sensors and WebXR need https (or localhost)
    Object.seal(this);
  }
}

const phone = new PhoneState();
window.crowdteleop = phone;

function banner(kind, text) {
  $("banner").className = `banner ${kind} show`;
  $("banner").textContent = text;
}

function axisQuat(axis, degrees) {
  const half = ((degrees || 0) * Math.PI) / 360, s = Math.sin(half);
  const q = [0, 0, 0, Math.cos(half)];
  q[axis] = s;
  return q;
}

// DeviceOrientation angles are intrinsic Z-X'-Y'' (alpha, beta, gamma) in degrees (W3C spec).
export function orientationQuaternion(alpha, beta, gamma) {
  return quatMultiply(quatMultiply(axisQuat(2, alpha), axisQuat(0, beta)), axisQuat(1, gamma));
}

function onOrientation(event) {
  if (phone.source === "xr" || event.alpha === null) return;
  const quaternion = orientationQuaternion(event.alpha, event.beta, event.gamma);
  if (phone.camera) cameraOrientation(phone, quaternion);
  if (phone.source === "camera") return;
  phone.quaternion = quaternion;
  phone.source = "orientation";
  if (!phone.camera) showMode("orientation sensors + drag");
}

function showMode(text) {
  $("motion").textContent = text;
}

// Over plain http on a LAN a browser hides the motion sensors and WebXR without a word; say so,
// and what to do. Pairing and the drag pads still work.
const INSECURE = "This page is not secure (its address starts with http, not https), so your "
  + "phone's motion sensors and AR tracking are switched off: only the drag pads work. Open the "
  + "phone link over HTTPS (the study's organiser starts the server with --https), or scan the "
  + "QR code again.";

async function enableOrientation() {
  if (!phone.secure) {
    banner("error", INSECURE);
    $("motion").textContent = "drag pads only (not https)";
    return;
  }
  const needsPermission = typeof DeviceOrientationEvent !== "undefined"
    && typeof DeviceOrientationEvent.requestPermission === "function";
  if (needsPermission) {  // iOS asks the user, and only from a tap
    $("motion-permission").hidden = false;
    $("motion-permission").onclick = async () => {
      let answer;
      try {
        answer = await DeviceOrientationEvent.requestPermission();
      } catch (error) {  // e.g. not from a tap, or an insecure page
        banner("error", `Motion sensors could not be turned on (${error.message}). Tap the button again, or use the drag pads.`);
        return;
      }
      if (answer === "granted") {
        window.addEventListener("deviceorientation", onOrientation);
        $("motion-permission").hidden = true;
      } else banner("error", "Motion sensors were not allowed: the phone can only move, not turn, the hand.");
    };
  } else {
    window.addEventListener("deviceorientation", onOrientation);
  }
}

// Why this phone got the mode it got, in a line (docs/phone.md has the table).
async function modeReason() {
  if (!phone.secure) return "The page is not on https, so the browser keeps the motion sensors off.";
  if (await arSupported()) return "This phone can track itself in 3D: tap \"Track phone in 3D\" for full 6-DoF.";
  if (cameraSupported()) return "No AR tracking in this browser (as on iPhones): tap \"Track the marker\" and point the back camera at your computer's screen for full 6-DoF.";
  if (!navigator.xr) return "This browser has no WebXR (as on iPhones): the phone turns the hand, the pads move it.";
  return "This phone has no AR tracking (on Android: install Google Play Services for AR): the phone turns the hand, the pads move it.";
}

// Camera tracking is offered where AR tracking is not: the phone needs a camera and https.
async function enableCamera() {
  if (await arSupported() || !cameraSupported()) return;
  $("start-camera").hidden = false;
  $("start-camera").onclick = () => startCameraMode({ phone, setClutch, banner, showMode });
}

async function enableXR() {
  if (!(await arSupported())) return;
  $("start-ar").hidden = false;
  $("start-ar").onclick = startXR;
  $("recentre").onclick = () => {
    if (!phone.filter || !phone.rawPose) return;
    setClutch(false);  // the frame turns: the next stroke starts from here
    phone.filter.recentreHeading(phone.rawPose.quaternion);
    banner("info", "Re-centred: forward is where the phone points now.");
  };
}

const AR_STARTING = "AR tracking is still starting: move the phone slowly over a well-lit, "
  + "textured surface until it says 6-DoF, then press the hold button.";

const TRACKING_LOST = "The phone lost track of where it is, so the robot holds still. Point "
  + "the camera at a well-lit, textured surface (not a blank wall), then let go of the hold "
  + "button and press it again.";

async function startXR() {
  const filter = new PhonePoseFilter();
  let recentred = false;
  // The overlay is the whole page: the banner must show in AR too.
  const tracker = new XrTracker($("phone-ui"), {
    pose: (pose, timeS) => {
      if (!recentred) { filter.recentreHeading(pose.quaternion); recentred = true; }
      takePose({ phone, setClutch, banner }, filter, pose, timeS);
    },
    trackingLost: () => {
      phone.tracking = "lost";
      setClutch(false);
      $("motion").textContent = "6-DoF: tracking lost";
      banner("error", TRACKING_LOST);
    },
    trackingBack: () => {
      const wasLost = phone.tracking === "lost";
      phone.tracking = "tracking";
      phone.source = "xr";
      filter.reset();
      $("motion").textContent = "6-DoF (AR tracking)";
      if (wasLost) banner("info", "Tracking is back: press the hold button to move.");
    },
    // A touch on the screen that is not a control: hold anywhere to move.
    selectStart: () => setClutch(true),
    selectEnd: () => setClutch(false),
    reset: () => {  // the system moved the origin (e.g. its own re-centre)
      setClutch(false);
      filter.reset();
    },
    ended: (reason) => {
      setClutch(false);
      phone.xr = null;
      phone.filter = null;
      phone.tracking = "none";
      phone.source = "none";
      $("start-ar").hidden = false;
      $("recentre").hidden = true;
      document.body.classList.remove("xr");
      $("pad").textContent = "drag to move";
      $("motion").textContent = "orientation sensors + drag";
      banner("error", reason === "hidden"
        ? "AR tracking stopped when the page was hidden. Tap \"Track phone in 3D\" to start again."
        : "AR tracking ended. Tap \"Track phone in 3D\" to start again, or use the drag pads.");
    },
  });
  phone.tracking = "starting";
  try {
    await tracker.start();
  } catch (error) {
    phone.tracking = "none";
    banner("error", `AR tracking unavailable: ${error.message}. The drag pads still work.`);
    return;
  }
  phone.xr = tracker;
  phone.filter = filter;
  $("start-ar").hidden = true;
  $("recentre").hidden = false;
  document.body.classList.add("xr");
  $("pad").textContent = "touch and hold anywhere here to move";
  $("motion").textContent = "6-DoF: starting";
}

// Holding the clutch moves the hand; it asks to drive if another device does. Refused while
// AR tracking is not tracking: the pose would be stale.
function setClutch(engaged) {
  const c = phone.connection;
  if (!c || phone.engaged === engaged) return;
  if (engaged && phone.xr && phone.tracking !== "tracking") {  // say why nothing moves
    banner("error", phone.tracking === "starting" ? AR_STARTING : TRACKING_LOST);
    return;
  }
  const driver = c.state.status && c.state.status.controlling_device;
  if (engaged && driver !== "phone") c.takeControl();
  phone.engaged = engaged;
  $("clutch").classList.toggle("held", engaged);
  if (phone.filter) {
    if (engaged) phone.filter.beginStroke(); else phone.filter.endStroke();
  }
  c.sendClutch(engaged);
}

// A haptic event: a vibration where the phone has one (not iOS), else a flash and a click.
let audio = null;
function buzz(intensity) {
  if (navigator.vibrate) { navigator.vibrate(Math.round(20 + 60 * intensity)); return; }
  document.body.classList.add("buzz");
  setTimeout(() => document.body.classList.remove("buzz"), 120);
  try {
    audio ??= new AudioContext();
    const tone = audio.createOscillator(), gain = audio.createGain();
    gain.gain.value = 0.05 + 0.2 * intensity;
    tone.frequency.value = 180;
    tone.connect(gain).connect(audio.destination);
    tone.start();
    tone.stop(audio.currentTime + 0.05);
  } catch { /* no audio: the flash is enough */ }
}

function dragPad(element, apply) {
  let last = null;
  element.addEventListener("pointerdown", (e) => {
    last = [e.clientX, e.clientY];
    try { element.setPointerCapture(e.pointerId); } catch { /* synthetic pointers have none */ }
  });
  element.addEventListener("pointermove", (e) => {
    if (!last || phone.source === "xr" || phone.source === "camera") return;
    const scale = PAD_METRES / element.clientWidth;
    apply((e.clientX - last[0]) * scale, (e.clientY - last[1]) * scale);
    last = [e.clientX, e.clientY];
  });
  const end = () => { last = null; };
  element.addEventListener("pointerup", end);
  element.addEventListener("pointercancel", end);
}

function wireControls() {
  const c = phone.connection;
  dragPad($("pad"), (dx, dy) => { phone.position[0] -= dy; phone.position[1] -= dx; });
  dragPad($("lift"), (dx, dy) => { phone.position[2] -= dy; });
  const clutch = $("clutch");
  clutch.addEventListener("pointerdown", (e) => { e.preventDefault(); setClutch(true); });
  for (const type of ["pointerup", "pointercancel", "pointerleave"]) clutch.addEventListener(type, () => setClutch(false));
  document.addEventListener("visibilitychange", () => {
    if (document.visibilityState === "hidden") setClutch(false);  // a call, the lock button
  });
  $("gripper").onclick = () => {
    phone.gripper = !phone.gripper;
    $("gripper").textContent = phone.gripper ? "Open gripper" : "Close gripper";
    c.sendGripper(phone.gripper);
  };
  c.addEventListener("haptic", ({ detail }) => {
    phone.haptics += 1;
    $("haptics").textContent = phone.haptics;
    buzz(detail.intensity);
  });
  c.addEventListener("status", ({ detail }) => {
    $("driver").textContent = detail.controlling_device || "nobody";
    $("clutch-state").textContent = CLUTCH_WORD[detail.clutch] || "–";
    const mine = detail.controlling_device === "phone";
    if (mine && detail.clutch === "press_again") banner("info", CLUTCH_TEXT.press_again);
    else if ($("banner").textContent === CLUTCH_TEXT.press_again) $("banner").className = "banner";
    if (detail.video_stalled) {
      phone.stallShown = true;
      banner("error", "The video on your computer stopped, so the robot holds still. When it is "
        + "back, let go of the hold button and press it again.");
    } else if (phone.stallShown || (detail.controlling_device === "phone" && phone.tracking !== "lost")) {
      phone.stallShown = false;
      $("banner").className = "banner";
    }
  });
  c.addEventListener("connection", ({ detail }) => {
    $("connection").textContent = detail.state;
    $("quality").className = `dot ${detail.state === "connected" ? "good" : "bad"}`;
    if (["failed", "disconnected"].includes(detail.state)) banner("error", "Disconnected. Reload this page and pair again.");
  });
  c.addEventListener("error", ({ detail }) => banner("error", detail.message));
  setInterval(() => {
    // Stream only while this phone drives (or is being pressed into driving): another device
    // may hold the arm, and switching is the clutch press's explicit take_control.
    const driver = c.state.status && c.state.status.controlling_device;
    if (phone.engaged || driver === "phone") {
      c.sendPose(phone.position, phone.quaternion, phone.engaged, phone.gripper);
    }
  }, 1000 / SEND_HZ);
}

async function pair(code, key) {
  // The QR link's key proves the code was scanned, not guessed: never rate limited.
  const paired = await call("/api/pair", { method: "POST", body: key ? { code, key } : { code } });
  phone.token = paired.phone_token;
  const session = await call("/api/phone/session", { token: phone.token });
  if (session.state !== "ready") throw new Error("your robot is not ready yet: try again in a moment");
  const connection = new TeleopConnection({
    protocol: phone.protocol, offerUrl: "/api/phone/offer", authorization: `Bearer ${phone.token}`,
    device: "phone", iceServers: session.ice_servers, iceTransportPolicy: session.ice_transport_policy,
    video: false,
  });
  phone.connection = connection;
  await connection.connect();
  $("pair-form").hidden = true;
  $("controller").hidden = false;
  $("connection").textContent = "connected";
  $("quality").className = "dot good";
  wireControls();
  await enableOrientation();
  await enableXR();
  await enableCamera();
  $("motion-why").textContent = await modeReason();
  phone.ready = true;
}

async function main() {
  if (!("RTCPeerConnection" in window)) { banner("error", "This browser has no WebRTC: use Chrome or Safari."); return; }
  try { phone.protocol = await Protocol.load(); } catch (error) { banner("error", error.message); return; }
  if (!phone.secure) banner("error", INSECURE);
  const submit = async (code, key) => {
    try { await pair(code, key); }
    catch (error) { banner("error", error.status === 404 ? "That code is wrong or has expired: get a new one on your computer." : error.message); }
  };
  $("pair-form").addEventListener("submit", (e) => { e.preventDefault(); submit($("code").value); });
  const query = new URLSearchParams(location.search);
  const code = query.get("code");
  if (code) { $("code").value = code; submit(code, query.get("key")); }
}

main();
