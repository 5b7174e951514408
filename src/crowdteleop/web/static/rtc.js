// WebRTC to a teleop server, signalled through the coordinator: the page's half of
// crowdteleop.client.connection (same channels, same messages, same latency matching).

import { FrameMatcher, LatencyTracker } from "./latency.js";
import { MessageFactory, ProtocolViolation } from "./protocol.js";

const LATENCY_REPORT_MS = 1000;
const STALL_CHECK_MS = 100;
const FPS_WINDOW_FRAMES = 60;

export class TeleopConnection extends EventTarget {
  // `protocol` is the loaded Protocol: every message in and out is checked against its schema.
  // iceServers: the coordinator's RTCIceServer objects (urls, and for TURN username and
  // credential); a bare URL string is taken as a server without credentials.
  // iceTransportPolicy: "relay" connects through TURN only.
  constructor({ protocol, offerUrl, authorization, device, iceServers = [], iceTransportPolicy = "all", video = true }) {
    super();
    this.protocol = protocol;
    this.offerUrl = offerUrl;
    this.authorization = authorization;
    this.messages = new MessageFactory(device);
    this.video = video;
    this.pc = new RTCPeerConnection({
      iceServers: iceServers.map((server) => (typeof server === "string" ? { urls: server } : server)),
      iceTransportPolicy,
    });
    this.control = null;
    this.events = null;
    this.latencyTimer = null;
    this.matcher = new FrameMatcher();
    this.latency = new LatencyTracker();  // performance.now() milliseconds
    this.reportedSamples = 0;  // how many of latency.samplesMs went to the server
    this.framesShown = 0;
    this.firstFrameAt = null;  // wall clock (Date.now()) ms of the first frame, for benchmarks
    this.frameTimesMs = [];  // performance.now() of the latest frames, for fps
    this.lastFrameMs = null;  // performance.now() of the latest frame shown
    this.videoStalled = false;
    this.stallTimer = null;
    this.stats = { refusedOutgoing: 0, ignoredIncoming: 0 };  // messages the schema refused
    this.state = { hello: null, status: null, telemetry: null, haptics: 0, saved: [],
                   episodes: [], errors: [] };
  }

  async connect(timeoutMs = 20000, timeline = {}) {
    this.control = this.pc.createDataChannel("control", { ordered: false, maxRetransmits: 0 });
    this.events = this.pc.createDataChannel("events");
    this.events.onmessage = (event) => this.#onMessage(event.data);
    if (this.video) {
      this.pc.addTransceiver("video", { direction: "recvonly" });
      this.pc.ontrack = (event) => this.#emit("track", { stream: event.streams[0] || new MediaStream([event.track]) });
    }
    this.pc.onconnectionstatechange = () => this.#emit("connection", { state: this.pc.connectionState });
    await this.pc.setLocalDescription(await this.pc.createOffer());
    await this.#iceGathered(3000);  // aiortc takes no trickled candidates: send them all at once
    timeline.gathered = Date.now();
    const response = await fetch(this.offerUrl, {
      method: "POST",
      headers: { "Content-Type": "application/json", Authorization: this.authorization },
      body: JSON.stringify({ sdp: this.pc.localDescription.sdp, type: "offer" }),
    });
    const answer = await response.json();
    if (!response.ok) {
      throw new Error(answer.message || `the server refused the connection (${response.status})`);
    }
    timeline.answered = Date.now();
    await this.pc.setRemoteDescription({ sdp: answer.sdp, type: answer.type });
    await new Promise((resolve, reject) => {
      const timer = setTimeout(() => reject(new Error("the robot did not answer in time")), timeoutMs);
      this.addEventListener("hello", () => { clearTimeout(timer); resolve(); }, { once: true });
    });
    timeline.hello = Date.now();
    this.latencyTimer = setInterval(() => this.#reportLatency(), LATENCY_REPORT_MS);
  }

  close() {
    clearInterval(this.latencyTimer);
    clearInterval(this.stallTimer);
    this.pc.close();
  }

  #iceGathered(timeoutMs) {
    if (this.pc.iceGatheringState === "complete") return Promise.resolve();
    return new Promise((resolve) => {
      const done = () => { if (this.pc.iceGatheringState === "complete") resolve(); };
      this.pc.addEventListener("icegatheringstatechange", done);
      setTimeout(resolve, timeoutMs);
    });
  }

  #emit(type, detail) { this.dispatchEvent(new CustomEvent(type, { detail })); }

  // Checked against the schema first: a message the server would refuse is not sent at all.
  #send(message) {
    let wire;
    try {
      wire = this.protocol.encode(message);
    } catch (error) {
      if (!(error instanceof ProtocolViolation)) throw error;
      this.stats.refusedOutgoing += 1;
      console.error(error.message, message);
      return false;
    }
    const target = wire.channel === "control" ? this.control : this.events;
    if (!target || target.readyState !== "open") return false;
    target.send(wire.data);
    return true;
  }

  sendPose(position, quaternion, engaged, gripper, seq) {
    const message = this.messages.pose(position, quaternion, engaged, gripper, seq);
    if (this.#send(message)) this.latency.commandSent(message.seq, performance.now());
    return message.seq;
  }
  sendClutch(engaged) { return this.#send(this.messages.clutch(engaged)); }
  sendGripper(closed) { return this.#send(this.messages.gripper(closed)); }
  request(type) { return this.#send(this.messages.request(type)); }
  takeControl() { return this.#send(this.messages.takeControl()); }

  // requestVideoFrameCallback hands us each frame as it is presented, with its RTP timestamp.
  watchVideo(videoElement) {
    if (!("requestVideoFrameCallback" in HTMLVideoElement.prototype)) return;
    const onFrame = (nowMs, metadata) => {
      if (this.framesShown === 0) this.firstFrameAt = Date.now();
      if (this.videoStalled) this.#videoStall(false, performance.now() - this.lastFrameMs);
      this.lastFrameMs = performance.now();
      this.framesShown += 1;
      this.frameTimesMs.push(nowMs);
      if (this.frameTimesMs.length > FPS_WINDOW_FRAMES) this.frameTimesMs.shift();
      if (metadata.rtpTimestamp !== undefined) {
        const seq = this.matcher.commandSeqOf(metadata.rtpTimestamp);
        if (seq !== null) this.latency.frameShown(seq, nowMs);
      }
      videoElement.requestVideoFrameCallback(onFrame);
    };
    videoElement.requestVideoFrameCallback(onFrame);
    // The worker must not drive blind: video that stops (a frozen network, a hidden tab)
    // releases the clutch on the server until the device lets go and presses again.
    this.stallTimer = setInterval(() => {
      const limitMs = (this.state.hello && this.state.hello.video_stall_ms) || 1000;
      if (this.lastFrameMs === null || this.videoStalled) return;
      const gapMs = performance.now() - this.lastFrameMs;
      if (gapMs > limitMs) this.#videoStall(true, gapMs);
    }, STALL_CHECK_MS);
  }

  #videoStall(stalled, gapMs) {
    this.videoStalled = stalled;
    this.#send(this.messages.videoStatus(stalled, gapMs));
    this.#emit("videostall", { stalled, gapMs });
  }

  fps() {
    const times = this.frameTimesMs;
    const spanMs = times.length < 2 ? 0 : times[times.length - 1] - times[0];
    return spanMs > 0 ? (1000 * (times.length - 1)) / spanMs : 0;
  }

  latencyMs(quantile = 0.5) {
    const recent = this.latency.samplesMs.slice(-200).sort((a, b) => a - b);
    return recent.length ? recent[Math.min(recent.length - 1, Math.round(quantile * (recent.length - 1)))] : null;
  }

  #reportLatency() {
    const samples = this.latency.samplesMs.slice(this.reportedSamples, this.reportedSamples + 100);
    this.reportedSamples += samples.length;
    this.#send(this.messages.latency(samples, this.fps()));
  }

  #onMessage(raw) {
    let message;
    try {
      message = this.protocol.decode(raw);
    } catch (error) {
      if (!(error instanceof ProtocolViolation)) throw error;
      this.stats.ignoredIncoming += 1;
      console.warn(error.message, raw);
      return;
    }
    const s = this.state;
    switch (message.type) {
      case "hello": s.hello = message; break;
      case "status": s.status = message; break;
      case "telemetry": s.telemetry = message; break;
      case "frame": this.matcher.addTag(message.pts, message.command_seq); return;
      case "haptic": s.haptics += 1; break;
      case "episode": s.episodes.push(message); break;
      case "saved": s.saved.push(message); break;
      case "error": s.errors.push(message); break;
      case "ping": this.#send(this.messages.pong(message)); return;
      default: break;
    }
    this.#emit(message.type, message);
  }
}
