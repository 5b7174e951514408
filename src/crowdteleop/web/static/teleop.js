// The worker's teleop page: get a robot (or a place in line), watch it, drive it.

import { call, worker } from "./api.js";
import { CLUTCH_TEXT, CLUTCH_WORD } from "./clutch.js";
import { GamepadDevice, KEY_LEGEND, KeyboardDevice, SpaceMouseDevice, VRControllerDevice } from "./devices.js";
import { watchPractice } from "./practice.js";
import { showPreparing } from "./preparing.js";
import { Protocol } from "./protocol.js";
import { TeleopConnection } from "./rtc.js";
import { XrScreen } from "./xr_screen.js";

const $ = (id) => document.getElementById(id);
const HEARTBEAT_MS = 5000;
const FEEDBACK_WAIT_MS = 10000;  // the last demonstration's feedback, at most this late
const REDIRECT_DELAY_MS = 8000;  // the completion code shown, then on to the study's page
const SEND_HZ = 30;

// All of the page's state, declared here and sealed: a typo'd or new field throws instead of
// quietly growing the object. Exposed as window.crowdteleop for end-to-end tests, benchmarks
// and curious users (the one global).
class TeleopPage {
  constructor() {
    this.protocol = null;  // the loaded Protocol (schema from /protocol.json)
    this.token = null;  // the worker token from the join page
    this.view = null;  // the coordinator's latest view of the session
    this.connection = null;
    this.devices = {};
    this.device = null;  // the input device whose commands this page sends
    this.external = false;  // a script drives through `drive`: the keyboard stays quiet
    this.pairing = null;
    this.xrScreen = null;  // what the VR headset shows (xr_screen.js), while in VR
    this.lastCommand = null;
    this.refusedAtMs = 0;  // performance.now() of the last not_in_control refusal
    this.tookControlAtMs = 0;  // performance.now() of our last take_control
    this.tookControlForScript = false;
    this.ended = false;
    this.pendingFeedback = null;  // a saved success's episode whose feedback has not come yet
    this.ready = false;
    this.readyAt = null;  // the view's ready_at of the robot we are connected to
    this.timeline = { loaded: Date.now() };  // wall-clock ms marks of the way to the first frame
    Object.seal(this);
  }

  // For scripted drivers (tests, demos): commands that enter through this page's data channel
  // exactly as the keyboard's do. The keyboard stays quiet while a script drives.
  drive(position, quaternion, engaged, gripper, seq) {
    this.external = true;
    const driver = this.connection.state.status && this.connection.state.status.controlling_device;
    if (driver && driver !== this.connection.messages.device && !this.tookControlForScript) {
      this.connection.takeControl();
      this.tookControlForScript = true;
    }
    return this.connection.sendPose(position, quaternion, engaged, gripper, seq);
  }
}

const page = new TeleopPage();
window.crowdteleop = page;

function banner(kind, text) {
  const element = $("banner");
  element.className = `banner ${kind} show`;
  element.textContent = text;
}
function clearBanner() { $("banner").className = "banner"; }

// How the last demonstration compares with the study's (the coordinator's judgement,
// docs/quality.md): each figure beside the study's middle, and one tip.
function showFeedback(f) {
  const middle = (value, text) => (value === null || value === undefined ? "" : ` (study: ${text})`);
  $("feedback-time").textContent =
    `${f.time_s.toFixed(1)} s` + middle(f.median_time_s, `${f.median_time_s?.toFixed(1)} s`);
  $("feedback-idle").textContent = f.idle_percent === null || f.idle_percent === undefined
    ? "–"
    : `${Math.round(f.idle_percent)}%` + middle(f.median_idle_percent, `${Math.round(f.median_idle_percent)}%`);
  $("feedback-smooth").textContent = f.smoother_than_percent === null || f.smoother_than_percent === undefined
    ? "–"
    : `smoother than ${Math.round(f.smoother_than_percent)}% of the study`;
  $("feedback-tip").textContent = f.tip;
  $("feedback").hidden = false;
}

function formatSeconds(s) {
  if (s === null || s === undefined) return "–";
  const m = Math.floor(s / 60), r = Math.round(s % 60);
  return `${m}:${String(r).padStart(2, "0")}`;
}

function showView(view) {
  page.view = view;
  $("queue").hidden = view.state !== "queued";
  if (view.state === "queued") {
    $("queue-position").textContent = view.queue_position;
    $("queue-eta").textContent = formatSeconds(view.eta_s);
  }
  $("demos").textContent = `${view.demos_done} / ${view.demos_required}${reviewProgress(view)}`;
  $("instruction").textContent = view.instruction;
  const preparing = showPreparing($("preparing"), view.state === "starting" ? view.preparing : null);
  if (view.state === "starting") banner("info", view.notice || preparing);
  else if (view.state === "queued" && view.notice) banner("info", view.notice);
  if (view.completion_code) finish(view);
  else if (view.state === "ended" && !page.ended) {
    page.ended = true;
    const why = { timeout: "Your session's time is up.", abandoned: "Your session expired.",
                  left: "You left the session.", error: "Your robot stopped working. Please reload.",
                  queue_timeout: "The wait was too long; please try again later." };
    banner("error", why[view.ended_reason] || "Your session has ended.");
    if (page.connection) page.connection.close();
  } else if (page.ready && (view.state !== "ready" || view.ready_at !== page.readyAt)) {
    // Our robot's server crashed or hung: the session waits again at its place, its count
    // kept. Drop the dead connection; `robotLoop` connects to the new robot when it is ready.
    page.ready = false;
    if (page.connection) page.connection.close();
    page.connection = null;
    $("connection").textContent = "waiting for a new robot";
    if (view.notice) banner("info", view.notice);
  }
}

// Where the campaign holds the completion code until demonstrations are accepted
// (docs/workers.md): "2 of 3 accepted, 1 awaiting review".
function reviewProgress(view) {
  if (!view.accepted_required) return "";
  const waiting = view.awaiting_review ? `, ${view.awaiting_review} awaiting review` : "";
  return ` · ${view.accepted} of ${view.accepted_required} accepted${waiting}`;
}

function finish(view) {
  if (page.ended) return;
  page.ended = true;
  clearBanner();  // "Demonstration saved" and the like: the completion says it all
  const done = $("done");
  done.className = "banner done show";
  done.innerHTML = "";
  done.append("All demonstrations done, thank you! Your completion code: ");
  const code = document.createElement("strong");
  code.id = "completion-code";
  code.textContent = view.completion_code;
  done.append(code);
  if (view.redirect_url) {
    const link = document.createElement("a");
    link.href = view.redirect_url;
    link.textContent = "Return to Prolific";
    done.append(" ", link);
  }
  done.after($("feedback"));  // how the last demonstration went, read right under the code
  lastFeedback().then(() => {
    if (page.connection) page.connection.close();
    // the robot is gone: no black video, no buttons that do nothing, and no side panels
    // (marker, phone, keys, a status that would go stale): the code and the feedback remain
    $("video").hidden = true;
    document.querySelector(".controls").hidden = true;
    document.querySelector("aside").hidden = true;
    if (view.redirect_url) setTimeout(() => { location.href = view.redirect_url; }, REDIRECT_DELAY_MS);
  });
}

// The last demonstration's feedback comes over the data channel once the coordinator has
// counted it, and the coordinator's view may say "done" a moment before: keep the channel
// open for it, and leave for the study's page only once the worker could read it.
function lastFeedback() {
  const c = page.connection;
  if (page.pendingFeedback === null || !c) return Promise.resolve();
  return new Promise((resolve) => {
    const arrived = () => {
      clearTimeout(timer);
      c.removeEventListener("feedback", arrived);
      resolve();
    };
    const timer = setTimeout(arrived, FEEDBACK_WAIT_MS);
    c.addEventListener("feedback", arrived);
  });
}

async function heartbeat() {
  if (!page.view || page.view.state === "ended") return;
  try {
    const kind = page.device ? page.device.kind : undefined;
    showView(await call(`/api/sessions/${page.view.session_id}/heartbeat`, {
      method: "POST", token: page.token, body: kind ? { interface: kind } : {} }));
  } catch (error) {
    if (error.code === "taken_over" && !page.ended) {
      page.ended = true;
      banner("error", error.message);
      if (page.connection) page.connection.close();
      $("connection").textContent = "closed";
      $("pair-code").textContent = "–";  // its phones were unpaired with it
      $("qr").removeAttribute("src");
      return;
    }
    banner("error", `Lost contact with the server: ${error.message}`);
  }
}

async function waitUntilReady() {
  while (page.view.state === "queued" || page.view.state === "starting") {
    // A warm spare is handed over in well under a second: look often while starting.
    await new Promise((resolve) => setTimeout(resolve, page.view.state === "starting" ? 200 : 1000));
    await heartbeat();
  }
}

async function pairPhone() {
  try {
    const pairing = await call(`/api/sessions/${page.view.session_id}/pairing`, { method: "POST", token: page.token });
    page.pairing = pairing;
    $("pair-code").textContent = pairing.code;
    $("phone-link").textContent = new URL(pairing.phone_url).origin + "/phone";
    $("qr").src = `/qr.svg?text=${encodeURIComponent(pairing.phone_url)}`;
    setTimeout(pairPhone, Math.max(5, pairing.expires_s - 10) * 1000);
  } catch (error) {
    if (!page.ended) $("pair-code").textContent = "–";
  }
}

function useDevice(device) {
  page.device = device;
  page.connection.messages.device = device.kind;
  page.connection.takeControl();
}

function controlLoop() {
  let last = performance.now();
  setInterval(() => {
    const now = performance.now(), dt = (now - last) / 1000;
    last = now;
    if (!page.device || page.external || !page.connection) return;
    const command = page.device.update(dt);
    if (!command) return;
    letGoWhenIdle(command);
    const key = JSON.stringify(command);
    const busy = page.device.active === undefined || page.device.active;
    if (busy || key !== page.lastCommand) {
      const driver = page.connection.state.status && page.connection.state.status.controlling_device;
      // Another device drives, or the same kind on another connection (a tab left open, or
      // one reloaded before the server noticed the old one gone): the server refused our last
      // command. Pressing keys is asking to drive.
      const refused = page.refusedAtMs > page.tookControlAtMs;
      const otherDevice = driver && driver !== page.device.kind;
      if (busy && (otherDevice || refused) && now - page.tookControlAtMs > 1000) {
        page.connection.takeControl();
        page.tookControlAtMs = now;
      }
      page.connection.sendPose(command.position, command.quaternion, command.engaged, command.gripper);
      page.lastCommand = key;
    }
  }, 1000 / SEND_HZ);
}

// A keyboard or 3D mouse has no button held down: its clutch is on until C (or the right
// button) turns it off. When the server asks for a fresh press (the video paused while it
// drove), an idle keyboard lets go for it, so the next key drives.
function letGoWhenIdle(command) {
  const status = page.connection.state.status;
  const toggled = page.device.kind === "keyboard" || page.device.kind === "spacemouse";
  if (status && status.clutch === "press_again" && toggled && !page.device.active) command.engaged = false;
}

// The clutch's state in the status row, and a banner while it waits for the worker.
function showClutch(status) {
  $("clutch-state").textContent = CLUTCH_WORD[status.clutch] || "–";
  $("clutch-state").title = CLUTCH_TEXT[status.clutch] || "";
  const waiting = status.clutch === "press_again" && page.device && page.device.kind !== "keyboard";
  if (waiting) banner("info", CLUTCH_TEXT.press_again);
  else if ($("banner").textContent === CLUTCH_TEXT.press_again) clearBanner();
}

function showStatus() {
  const c = page.connection;
  c.addEventListener("status", ({ detail: s }) => {
    $("timer").textContent = `${formatSeconds(s.elapsed_s)} / ${formatSeconds(s.time_limit_s)}`;
    $("stage").textContent = s.message || s.stage || "–";
    $("driver").textContent = s.controlling_device || "nobody";
    showClutch(s);
    // The QR code has done its job: the phone camera's marker moves up into view.
    document.body.classList.toggle("phone-drives", s.controlling_device === "phone");
  });
  c.addEventListener("videostall", ({ detail }) => {
    if (detail.stalled) {
      banner("error", "Your video stopped, so the robot stopped: nothing you do moves it until "
        + "the picture is back. Then let go of the clutch and press it again.");
    } else clearBanner();
  });
  c.addEventListener("haptic", ({ detail }) => {
    if (page.device === page.devices.vr) page.devices.vr.pulse(detail.intensity);
  });
  c.addEventListener("feedback", ({ detail }) => {
    page.pendingFeedback = null;
    showFeedback(detail);
  });
  c.addEventListener("saved", ({ detail }) => {
    if (detail.outcome === "success") {
      page.pendingFeedback = detail.episode;
      if (!page.ended) banner("info", "Demonstration saved. Thank you!");
    }
    heartbeat();
  });
  c.addEventListener("error", ({ detail }) => {
    if (detail.code === "not_in_control") {  // not the worker's fault: their keys take over
      page.refusedAtMs = performance.now();
      return;
    }
    banner("error", detail.message);
  });
  c.addEventListener("connection", ({ detail }) => {
    $("connection").textContent = detail.state;
    if (["failed", "disconnected"].includes(detail.state) && !page.ended && c === page.connection) {
      banner("error", "Disconnected from your robot. Check your network; reload to reconnect.");
    }
  });
}

function statusTicker() {
  setInterval(() => {
    const c = page.connection;
    if (!c) return;
    const fps = c.fps(), latency = c.latencyMs(0.5);
    $("fps").textContent = `${fps.toFixed(0)} fps`;
    $("latency").textContent = latency === null ? "–" : `${latency.toFixed(0)} ms`;
    // Judged on the round trip, not the frame rate: a still scene sends few frames on purpose.
    const rtt = c.state.telemetry ? c.state.telemetry.rtt_ms : null;
    const connected = c.pc.connectionState === "connected";
    const quality = !connected ? "bad" : rtt !== null && rtt > 150 ? "fair" : "good";
    $("quality").className = `dot ${quality}`;
  }, 1000);
}

// The headset shows the video, the task, the demonstrations and the clutch (xr_screen.js);
// leaving VR hands the arm back to the keyboard.
async function enterVr() {
  const vr = page.devices.vr;
  page.xrScreen = new XrScreen($("video"), vrStatus);
  $("use-vr").disabled = true;
  try {
    await vr.open(page.xrScreen, leftVr);
    useDevice(vr);
  } catch (error) {
    banner("error", `VR: ${error.message}`);
    $("use-vr").disabled = false;
  }
}

function leftVr() {
  page.xrScreen = null;
  $("use-vr").disabled = false;
  if (page.device === page.devices.vr) useDevice(page.devices.keyboard);
  banner("info", "You left VR: the keyboard drives again (or press Drive in VR).");
}

function vrStatus() {
  const view = page.view || {}, status = page.connection && page.connection.state.status;
  return { task: view.instruction, demosDone: view.demos_done, demosRequired: view.demos_required,
           clutch: status && status.clutch };
}

function wireButtons() {
  $("start").onclick = () => page.connection && page.connection.request("start");
  $("reset").onclick = () => page.connection && page.connection.request("reset");
  $("use-keyboard").onclick = () => useDevice(page.devices.keyboard);
  $("use-gamepad").onclick = () => useDevice(page.devices.gamepad);
  $("use-spacemouse").onclick = async () => {
    try { await page.devices.spacemouse.open(); useDevice(page.devices.spacemouse); }
    catch (error) { banner("error", `3D mouse: ${error.message}`); }
  };
  $("use-vr").onclick = enterVr;
  for (const id of ["start", "reset", "use-keyboard", "use-gamepad", "use-spacemouse", "use-vr"]) $(id).disabled = false;
  $("use-spacemouse").hidden = !SpaceMouseDevice.supported;
  window.addEventListener("gamepadconnected", () => { $("use-gamepad").hidden = false; });
  VRControllerDevice.supported().then((ok) => { $("use-vr").hidden = !ok; }).catch(() => {});
}

async function main() {
  const joined = worker.load();
  if (!joined) { location.replace(`/join${location.search}`); return; }
  page.token = joined.worker_token;
  $("legend").innerHTML = KEY_LEGEND.map(([k, what]) => `<kbd>${k}</kbd><span>${what}</span>`).join("");
  if (!("RTCPeerConnection" in window)) {
    banner("error", "This browser cannot show live video (no WebRTC). Please use a current Chrome, Firefox or Safari.");
    return;
  }
  try {
    page.protocol = await Protocol.load();
    showView(await call("/api/sessions", { method: "POST", token: page.token }));
    page.timeline.session = Date.now();
  } catch (error) {
    banner("error", error.status === 401 ? "Your link has expired: please open the study link again." : error.message);
    return;
  }
  setInterval(heartbeat, HEARTBEAT_MS);
  window.addEventListener("pagehide", () => {
    if (page.view && page.view.state !== "ended") {
      navigator.sendBeacon(`/api/sessions/${page.view.session_id}/leave?token=${encodeURIComponent(page.token)}`);
    }
  });
  await robotLoop();
}

// Connect to the session's robot; if its server is replaced (crash, hang, coordinator restart)
// wait for the new one and connect again. Devices and buttons are wired once.
async function robotLoop() {
  let wired = false;
  while (!page.ended) {
    await waitUntilReady();
    if (page.view.state !== "ready") return;
    if (!(await connectRobot())) return;
    if (!wired) {
      page.devices = { keyboard: new KeyboardDevice(), gamepad: new GamepadDevice(),
                       spacemouse: new SpaceMouseDevice(), vr: new VRControllerDevice() };
      page.device = page.devices.keyboard;
      wireButtons();
      controlLoop();
      statusTicker();
      pairPhone();
      wired = true;
      clearBanner();
    } else {
      page.connection.messages.device = page.device.kind;
      banner("info", "You are connected to a new robot. Your saved demonstrations still count.");
    }
    page.ready = true;
    while (page.ready && !page.ended) await new Promise((resolve) => setTimeout(resolve, 500));
  }
}

async function connectRobot() {
  page.timeline.ready = Date.now();
  clearBanner();
  const connection = new TeleopConnection({
    protocol: page.protocol, offerUrl: `/api/sessions/${page.view.session_id}/offer`,
    authorization: `Bearer ${page.token}`, device: "keyboard", iceServers: page.view.ice_servers,
    iceTransportPolicy: page.view.ice_transport_policy,
  });
  page.connection = connection;
  connection.addEventListener("track", ({ detail }) => { $("video").srcObject = detail.stream; });
  connection.watchVideo($("video"));
  showStatus();
  watchPractice(connection, $("practice"), $("practice-text"), $("skip-practice"));
  try {
    await connection.connect(20000, page.timeline);
  } catch (error) {
    banner("error", `Could not connect to your robot: ${error.message}`);
    return false;
  }
  $("title").textContent = `Your robot: ${connection.state.hello.task}`;
  page.readyAt = page.view.ready_at;
  return true;
}

main();
