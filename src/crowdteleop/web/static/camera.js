// The phone's camera tracking (any phone with a rear camera, iPhones included): the teleop page
// shows a marker, this finds it in each camera frame (js-aruco2, vendored, loaded as a classic
// script: window.AR), refines its corners and turns them into the phone's 6-DoF pose relative
// to the screen (marker.js).

import { refineCorners } from "./corners.js";
import { MARKER_DICTIONARY, MARKER_ID, focalPx, poseFromCorners } from "./marker.js";

const LOST_AFTER_MS = 300;  // no marker for this long: tracking is lost
const MAX_WIDTH_PX = 640;  // frames are searched at this width at most (detection cost ~ pixels)
const WINDOW = 60;  // frames the rate and timing figures cover

export function cameraSupported() {
  return window.isSecureContext && Boolean(navigator.mediaDevices && navigator.mediaDevices.getUserMedia)
    && typeof window.AR !== "undefined";
}

// Rate and timing of the last WINDOW frames, for the page and for tests (docs/phone.md).
class TrackingFigures {
  constructor() { this.frames = []; }

  add(atMs, detectMs, latencyMs, found) {
    this.frames.push({ atMs, detectMs, latencyMs, found });
    if (this.frames.length > WINDOW) this.frames.shift();
  }

  summary() {
    const f = this.frames, median = (xs) => [...xs].sort((a, b) => a - b)[Math.floor(xs.length / 2)];
    if (f.length < 2) return null;
    const spanS = (f[f.length - 1].atMs - f[0].atMs) / 1000;
    return {
      framesPerS: (f.length - 1) / spanS,
      posesPerS: (f.filter((x) => x.found).length - 1) / spanS,
      detectMs: median(f.map((x) => x.detectMs)),
      latencyMs: median(f.map((x) => x.latencyMs)),
    };
  }
}

// One camera session. handlers: pose({position, quaternion, distanceM}, timeS), trackingLost(),
// trackingBack(), ended(reason).
export class CameraTracker {
  constructor(video, handlers) {
    this.video = video;
    this.handlers = handlers;
    this.stream = null;
    this.detector = null;
    this.canvas = document.createElement("canvas");
    this.context = this.canvas.getContext("2d", { willReadFrequently: true });
    this.tracking = false;
    this.lastSeenMs = -Infinity;
    this.watchdog = null;
    this.figures = new TrackingFigures();
  }

  async start() {
    this.stream = await navigator.mediaDevices.getUserMedia({
      audio: false,
      video: { facingMode: { ideal: "environment" }, width: { ideal: 640 }, height: { ideal: 480 } },
    });
    this.detector = new window.AR.Detector({ dictionaryName: MARKER_DICTIONARY });
    this.video.srcObject = this.stream;
    this.video.muted = true;
    this.video.playsInline = true;
    await this.video.play();
    for (const track of this.stream.getVideoTracks()) {
      track.addEventListener("ended", () => this.#end("ended"));  // e.g. revoked, or taken
    }
    this.watchdog = setInterval(() => {
      if (this.tracking && performance.now() - this.lastSeenMs > LOST_AFTER_MS) {
        this.tracking = false;
        this.handlers.trackingLost();
      }
    }, 50);
    this.#schedule();
  }

  stop() { this.#end("stopped"); }

  #end(reason) {
    if (!this.stream) return;
    for (const track of this.stream.getTracks()) track.stop();
    this.stream = null;
    clearInterval(this.watchdog);
    this.tracking = false;
    this.video.srcObject = null;
    this.handlers.ended(reason);
  }

  #schedule() {
    if (!this.stream) return;
    if (this.video.requestVideoFrameCallback) {
      this.video.requestVideoFrameCallback((now, metadata) => this.#frame(metadata));
    } else {
      requestAnimationFrame(() => this.#frame({}));
    }
  }

  // One camera frame: find the marker, and if it is there, the pose.
  #frame(metadata) {
    if (!this.stream) return;
    this.#schedule();
    const width = this.video.videoWidth, height = this.video.videoHeight;
    if (!width || !height) return;
    const scale = Math.min(1, MAX_WIDTH_PX / width);
    const w = Math.round(width * scale), h = Math.round(height * scale);
    if (this.canvas.width !== w) this.canvas.width = w;
    if (this.canvas.height !== h) this.canvas.height = h;
    const startMs = performance.now();
    this.context.drawImage(this.video, 0, 0, w, h);
    const image = this.context.getImageData(0, 0, w, h);
    const marker = this.detector.detect(image).find((m) => m.id === MARKER_ID);
    const pose = marker
      ? poseFromCorners(refineCorners(this.detector.grey, marker.corners), { widthPx: w, heightPx: h, focalLengthPx: focalPx(Math.max(w, h)) })
      : null;
    const nowMs = performance.now();
    const capturedMs = metadata.captureTime ?? metadata.presentationTime ?? startMs;
    this.figures.add(nowMs, nowMs - startMs, nowMs - capturedMs, Boolean(pose));
    if (!pose) return;
    this.lastSeenMs = nowMs;
    if (!this.tracking) {
      this.tracking = true;
      this.handlers.trackingBack();
    }
    this.handlers.pose(pose, nowMs / 1000);
  }
}
