// The phone controller: pair with a code, then the phone is a 6-DoF input device. With WebXR
// (Android Chrome + ARCore) the phone's tracked pose is the device pose; otherwise its
// orientation sensors give the rotation and the drag pads the translation.

import { call } from "./api.js";
import { quatMultiply } from "./devices.js";
import { Protocol } from "./protocol.js";
import { TeleopConnection } from "./rtc.js";

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
    this.source = "none";  // what moves the hand: "none", "orientation" or "xr"
    this.haptics = 0;  // haptic events received
    this.xr = null;  // the WebXR session, while AR tracking runs
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
  phone.quaternion = orientationQuaternion(event.alpha, event.beta, event.gamma);
  phone.source = "orientation";
  $("motion").textContent = "orientation sensors + drag";
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

async function enableXR() {
  if (!phone.secure) return;  // WebXR exists only in a secure context
  if (!navigator.xr || !(await navigator.xr.isSessionSupported("immersive-ar").catch(() => false))) return;
  $("start-ar").hidden = false;
  $("start-ar").onclick = async () => {
    try {
      const session = await navigator.xr.requestSession("immersive-ar", { requiredFeatures: ["local"] });
      const gl = document.createElement("canvas").getContext("webgl", { xrCompatible: true });
      session.updateRenderState({ baseLayer: new XRWebGLLayer(session, gl) });
      const space = await session.requestReferenceSpace("local");
      const frame = (time, xrFrame) => {
        const pose = xrFrame.getViewerPose(space);
        if (pose) {  // WebXR is y-up, -z forward; the robot frame is z-up, x forward
          const { position: p, orientation: q } = pose.transform;
          phone.position = [-p.z, -p.x, p.y];
          phone.quaternion = [-q.z, -q.x, q.y, q.w];
          phone.source = "xr";
          $("motion").textContent = "6-DoF (AR tracking)";
        }
        session.requestAnimationFrame(frame);
      };
      session.requestAnimationFrame(frame);
      phone.xr = session;
    } catch (error) { banner("error", `AR tracking unavailable: ${error.message}`); }
  };
}

function dragPad(element, apply) {
  let last = null;
  element.addEventListener("pointerdown", (e) => {
    last = [e.clientX, e.clientY];
    try { element.setPointerCapture(e.pointerId); } catch { /* synthetic pointers have none */ }
  });
  element.addEventListener("pointermove", (e) => {
    if (!last || phone.source === "xr") return;
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
  const press = (engaged) => {
    if (phone.engaged === engaged) return;
    const driver = c.state.status && c.state.status.controlling_device;
    if (engaged && driver !== "phone") c.takeControl();  // holding the clutch asks to drive
    phone.engaged = engaged;
    clutch.classList.toggle("held", engaged);
    c.sendClutch(engaged);
  };
  clutch.addEventListener("pointerdown", (e) => { e.preventDefault(); press(true); });
  for (const type of ["pointerup", "pointercancel", "pointerleave"]) clutch.addEventListener(type, () => press(false));
  $("gripper").onclick = () => {
    phone.gripper = !phone.gripper;
    $("gripper").textContent = phone.gripper ? "Open gripper" : "Close gripper";
    c.sendGripper(phone.gripper);
  };
  c.addEventListener("haptic", ({ detail }) => {
    phone.haptics += 1;
    $("haptics").textContent = phone.haptics;
    if (navigator.vibrate) navigator.vibrate(Math.round(20 + 60 * detail.intensity));
  });
  c.addEventListener("status", ({ detail }) => {
    $("driver").textContent = detail.controlling_device || "nobody";
    if (detail.video_stalled) {
      phone.stallShown = true;
      banner("error", "The video on your computer stopped, so the robot holds still. When it is "
        + "back, let go of the hold button and press it again.");
    } else if (phone.stallShown || detail.controlling_device === "phone") {
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
