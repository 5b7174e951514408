// WebRTC to a teleop server, signalled through the coordinator: the page's half of
// crowdteleop.client.connection (same channels, same messages, same latency matching).

import { MessageFactory } from "./protocol.js";

const RTP_MODULO = 2 ** 32;

// Frames are tagged by the server with their RTP-clock pts and the last command they show; the
// browser sees pts plus an unknown offset, found as the one under which frames land on tags.
export class FrameMatcher {
  constructor() { this.tags = new Map(); this.offset = null; this.recent = []; }
  addTag(pts, commandSeq) {
    this.tags.set(pts, commandSeq);
    if (this.tags.size > 600) this.tags.delete(this.tags.keys().next().value);
  }
  commandSeqOf(rtp) {
    const mod = (x) => ((x % RTP_MODULO) + RTP_MODULO) % RTP_MODULO;
    if (this.offset !== null && this.tags.has(mod(rtp - this.offset))) {
      return this.tags.get(mod(rtp - this.offset));
    }
    this.recent.push(rtp);
    if (this.recent.length > 8) this.recent.shift();
    if (this.recent.length < 3) return null;
    const candidates = [...this.tags.keys()].slice(-60).reverse();
    for (const pts of candidates) {
      const offset = mod(rtp - pts);
      const hits = this.recent.slice(0, -1).filter((r) => this.tags.has(mod(r - offset))).length;
      if (hits >= 2) { this.offset = offset; return this.tags.get(pts); }
    }
    return null;
  }
}

export class TeleopConnection extends EventTarget {
  constructor({ offerUrl, authorization, device, iceServers = [], video = true }) {
    super();
    this.offerUrl = offerUrl;
    this.authorization = authorization;
    this.messages = new MessageFactory(device);
    this.video = video;
    this.pc = new RTCPeerConnection({ iceServers: iceServers.map((urls) => ({ urls })) });
    this.matcher = new FrameMatcher();
    this.sentAt = new Map();
    this.shownUpTo = 0;
    this.latencies = [];
    this.reported = 0;
    this.framesShown = 0;
    this.frameTimes = [];
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
    this.latencyTimer = setInterval(() => this.#reportLatency(), 1000);
  }

  close() {
    clearInterval(this.latencyTimer);
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

  #send(channel, message) {
    const target = channel === "control" ? this.control : this.events;
    if (!target || target.readyState !== "open") return false;
    target.send(JSON.stringify(message));
    return true;
  }

  sendPose(position, quaternion, engaged, gripper, seq) {
    const message = this.messages.pose(position, quaternion, engaged, gripper, seq);
    this.sentAt.set(message.seq, performance.now());
    if (this.sentAt.size > 2000) this.sentAt.delete(this.sentAt.keys().next().value);
    this.#send("control", message);
    return message.seq;
  }
  sendClutch(engaged) { return this.#send("events", this.messages.clutch(engaged)); }
  sendGripper(closed) { return this.#send("events", this.messages.gripper(closed)); }
  request(type) { return this.#send("events", this.messages.request(type)); }
  takeControl() { return this.#send("events", this.messages.takeControl()); }

  // requestVideoFrameCallback hands us each frame as it is presented, with its RTP timestamp.
  watchVideo(videoElement) {
    if (!("requestVideoFrameCallback" in HTMLVideoElement.prototype)) return;
    const onFrame = (now, metadata) => {
      if (this.framesShown === 0) this.firstFrameAt = Date.now();  // wall clock, for benchmarks
      this.framesShown += 1;
      this.frameTimes.push(now);
      if (this.frameTimes.length > 60) this.frameTimes.shift();
      if (metadata.rtpTimestamp !== undefined) {
        const seq = this.matcher.commandSeqOf(metadata.rtpTimestamp);
        if (seq !== null && seq > this.shownUpTo) {
          for (const [sent, at] of this.sentAt) {
            if (sent > this.shownUpTo && sent <= seq) {
              this.latencies.push(now - at);
              this.sentAt.delete(sent);
            }
          }
          this.shownUpTo = seq;
        }
      }
      videoElement.requestVideoFrameCallback(onFrame);
    };
    videoElement.requestVideoFrameCallback(onFrame);
  }

  fps() {
    const t = this.frameTimes;
    return t.length < 2 ? 0 : (1000 * (t.length - 1)) / (t[t.length - 1] - t[0]);
  }

  latencyMs(quantile = 0.5) {
    const recent = this.latencies.slice(-200).sort((a, b) => a - b);
    return recent.length ? recent[Math.min(recent.length - 1, Math.round(quantile * (recent.length - 1)))] : null;
  }

  #reportLatency() {
    const samples = this.latencies.slice(this.reported, this.reported + 100).map((x) => Math.max(0, x));
    this.reported += samples.length;
    this.#send("events", { v: 1, type: "latency", samples_ms: samples, fps: this.fps() });
  }

  #onMessage(raw) {
    let message;
    try { message = JSON.parse(raw); } catch { return; }
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
      case "ping": this.#send("events", { v: 1, type: "pong", id: message.id, t: message.t }); return;
      default: break;
    }
    this.#emit(message.type, message);
  }
}
