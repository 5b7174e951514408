// What the phone's tracked pose goes through before it is sent (docs/phone.md, "Filtering").
//
// Phone tracking (ARCore/ARKit through WebXR, or the camera-marker mode) jitters by millimetres
// at rest and sometimes jumps by centimetres when it relocalises: the RoboTurk paper's users
// felt both as a shaky or lurching arm. So:
// - a One-Euro filter (Casiez, Roussel & Vogel, CHI 2012) smooths slow motion hard and fast
//   motion little, on position and on orientation;
// - a jump faster than a hand can move is a tracking glitch, not motion: the stroke ends;
// - each clutch stroke may carry the hand at most `maxReachM` from where it began (the
//   workspace limit), so a runaway pose cannot fling the arm across the table;
// - a heading re-centre makes "forward" the direction the phone pointed when it was taken.
// Motion scaling (robot metres per phone metre) is the server's `translation_scale`.

import { quatMultiply } from "./devices.js";

const TWO_PI = 2 * Math.PI;

function smoothing(cutoffHz, dtS) {
  const tau = 1 / (TWO_PI * cutoffHz);
  return 1 / (1 + tau / dtS);
}

// The One-Euro rule: the signal's speed, itself smoothed, raises the cutoff. minCutoffHz: the
// cutoff at rest (lower: smoother, more lag at rest); beta: how fast the cutoff rises with
// speed, per unit of speed (higher: less lag in motion).
class AdaptiveCutoff {
  constructor({ minCutoffHz = 1.0, beta = 0.0, derivativeCutoffHz = 1.0 } = {}) {
    Object.assign(this, { minCutoffHz, beta, derivativeCutoffHz, speed: 0 });
  }
  // The smoothing factor for a step of dtS at this raw speed.
  alpha(rawSpeed, dtS) {
    this.speed += smoothing(this.derivativeCutoffHz, dtS) * (rawSpeed - this.speed);
    return smoothing(this.minCutoffHz + this.beta * Math.abs(this.speed), dtS);
  }
}

// One scalar signal.
export class OneEuroFilter {
  constructor(settings = {}) { this.settings = settings; this.reset(); }
  reset() { this.value = null; this.timeS = null; this.cutoff = new AdaptiveCutoff(this.settings); }
  filter(value, timeS) {
    if (this.value === null) [this.value, this.timeS] = [value, timeS];
    if (!(timeS > this.timeS)) return this.value;
    const dtS = timeS - this.timeS;
    this.value += this.cutoff.alpha((value - this.value) / dtS, dtS) * (value - this.value);
    this.timeS = timeS;
    return this.value;
  }
}

function normalise(q) {
  const n = Math.hypot(...q) || 1;
  return q.map((v) => v / n);
}

export function slerp(a, b, t) {
  let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3];
  const target = dot < 0 ? b.map((v) => -v) : b;  // the short way round
  dot = Math.abs(dot);
  if (dot > 0.9995) return normalise(a.map((v, i) => v + t * (target[i] - v)));
  const angle = Math.acos(Math.min(1, dot)), s = Math.sin(angle);
  const wa = Math.sin((1 - t) * angle) / s, wb = Math.sin(t * angle) / s;
  return normalise(a.map((v, i) => wa * v + wb * target[i]));
}

export function angleBetween(a, b) {
  const dot = Math.abs(a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]);
  return 2 * Math.acos(Math.min(1, dot));
}

// A One-Euro filter on orientation: the cutoff follows the angular speed, and each step is a
// slerp towards the new reading.
export class RotationFilter {
  constructor(settings = {}) { this.settings = settings; this.reset(); }
  reset() { this.value = null; this.timeS = null; this.cutoff = new AdaptiveCutoff(this.settings); }
  filter(quaternion, timeS) {
    const q = normalise(quaternion);
    if (this.value === null) [this.value, this.timeS] = [q, timeS];
    if (!(timeS > this.timeS)) return this.value;
    const dtS = timeS - this.timeS;
    const alpha = this.cutoff.alpha(angleBetween(this.value, q) / dtS, dtS);
    this.value = slerp(this.value, q, alpha);
    this.timeS = timeS;
    return this.value;
  }
}

// Defaults for a hand-held phone, from tests/web/pose_filter.test.mjs at 60 frames/s:
// white jitter at rest drops to about a quarter (position) and a third (rotation); a 0.3 m/s
// sweep lags about 20 ms, a 2 rad/s turn about 17 ms.
export const PHONE_FILTER = {
  position: { minCutoffHz: 1.0, beta: 10, derivativeCutoffHz: 1.0 },  // beta per m/s
  rotation: { minCutoffHz: 1.0, beta: 2, derivativeCutoffHz: 1.0 },  // beta per rad/s
  maxSpeedMps: 4.0,  // a faster jump is a tracking glitch (a hand reaches ~2-3 m/s)
  maxReachM: 0.6,  // per clutch stroke, from where the stroke began
};

export function yawQuaternion(radians) {
  return [0, 0, Math.sin(radians / 2), Math.cos(radians / 2)];
}

export function rotateVector(q, v) {
  const [x, y, z] = quatMultiply(quatMultiply(q, [...v, 0]), [-q[0], -q[1], -q[2], q[3]]);
  return [x, y, z];
}

// The heading (about the robot frame's z, up) of a pose's forward axis (+x).
export function headingOf(quaternion) {
  const [fx, fy] = rotateVector(quaternion, [1, 0, 0]);
  return Math.atan2(fy, fx);
}

// Tracked poses (robot-style frame: z up, x forward) in, the pose to send out.
export class PhonePoseFilter {
  constructor(settings = PHONE_FILTER) {
    this.settings = settings;
    this.position = [0, 1, 2].map(() => new OneEuroFilter(settings.position));
    this.rotation = new RotationFilter(settings.rotation);
    this.recentre = [0, 0, 0, 1];  // undoes the heading the phone had when re-centred
    this.last = null;  // the last raw reading: { position, timeS }
    this.strokeStart = null;  // the filtered position when the clutch went down
    this.output = { position: [0, 0, 0], quaternion: [0, 0, 0, 1] };
  }
  reset() {
    this.position.forEach((f) => f.reset());
    this.rotation.reset();
    this.last = null;
  }
  // Make the current heading "forward"; the filters start afresh from the next reading.
  recentreHeading(quaternion) {
    this.recentre = yawQuaternion(-headingOf(quaternion));
    this.reset();
  }
  beginStroke() { this.strokeStart = [...this.output.position]; }
  endStroke() { this.strokeStart = null; }
  // Returns { position, quaternion, glitch, limited }; on a glitch the output stays put.
  update(position, quaternion, timeS) {
    const turned = rotateVector(this.recentre, position);
    const q = quatMultiply(this.recentre, quaternion);
    if (this.last && timeS > this.last.timeS) {
      const dtS = timeS - this.last.timeS;
      const jump = Math.hypot(...turned.map((v, i) => v - this.last.position[i]));
      if (jump / dtS > this.settings.maxSpeedMps && jump > 0.02) {
        this.reset();
        this.last = { position: turned, timeS };
        return { ...this.output, glitch: true, limited: false };
      }
    }
    this.last = { position: turned, timeS };
    let filtered = turned.map((v, i) => this.position[i].filter(v, timeS));
    let limited = false;
    if (this.strokeStart) {
      const offset = filtered.map((v, i) => v - this.strokeStart[i]);
      const reach = Math.hypot(...offset);
      if (reach > this.settings.maxReachM) {
        const scale = this.settings.maxReachM / reach;
        filtered = offset.map((v, i) => this.strokeStart[i] + v * scale);
        limited = true;
      }
    }
    this.output = { position: filtered, quaternion: this.rotation.filter(q, timeS) };
    return { ...this.output, glitch: false, limited };
  }
}

const inverse = ([x, y, z, w]) => [-x, -y, -z, w];

// Camera mode's rotation: the orientation sensors turn smoothly at 60 Hz and drift slowly; the
// marker's rotation does not drift but jitters. The output is the sensors' rotation carried
// into the marker's frame by an offset that follows the marker's rotation slowly (a
// complementary filter). Both inputs are the phone's body frame, in their own world frames.
export class OrientationFusion {
  constructor({ gain = 0.05, staleMs = 500 } = {}) {
    Object.assign(this, { gain, staleMs, offset: null, sensorQ: null, sensorAtMs: -Infinity });
  }

  sensor(bodyQ, nowMs) {
    this.sensorQ = bodyQ;
    this.sensorAtMs = nowMs;
  }

  // The rotation to use for a marker rotation seen at nowMs: the fused one while the sensors
  // are fresh, else the marker's own.
  camera(bodyQ, nowMs) {
    if (!this.sensorQ || nowMs - this.sensorAtMs > this.staleMs) {
      this.offset = null;
      return bodyQ;
    }
    const target = quatMultiply(bodyQ, inverse(this.sensorQ));
    this.offset = this.offset ? slerp(this.offset, target, this.gain) : target;
    const fused = quatMultiply(this.offset, this.sensorQ), n = Math.hypot(...fused);
    return fused.map((v) => v / n);
  }
}
