// The phone's pose filter (src/crowdteleop/web/static/pose_filter.js): less jitter at rest, little
// lag in motion, glitches and runaway strokes stopped, and a heading re-centre.

import assert from "node:assert/strict";
import { describe, test } from "node:test";

import { quatMultiply } from "../../src/crowdteleop/web/static/devices.js";
import {
  OneEuroFilter, OrientationFusion, PHONE_FILTER, PhonePoseFilter, RotationFilter, angleBetween, headingOf,
  rotateVector, yawQuaternion,
} from "../../src/crowdteleop/web/static/pose_filter.js";

const DT_S = 1 / 60;  // a WebXR frame

function gaussian(seed) {  // a seeded normal sampler (LCG + Box-Muller): runs are repeatable
  let state = seed;
  const uniform = () => ((state = (state * 1664525 + 1013904223) % 4294967296) + 1) / 4294967297;
  return () => Math.sqrt(-2 * Math.log(uniform())) * Math.cos(2 * Math.PI * uniform());
}

const rms = (values) => Math.sqrt(values.reduce((sum, v) => sum + v * v, 0) / values.length);

describe("OneEuroFilter with the phone's position settings", () => {
  test("cuts white millimetre jitter at rest to under 30 %", () => {
    const noise = gaussian(1), filter = new OneEuroFilter(PHONE_FILTER.position);
    const raw = [], out = [];
    for (let i = 0; i < 600; i += 1) {
      const reading = 0.002 * noise();
      raw.push(reading);
      out.push(filter.filter(reading, i * DT_S));
    }
    assert.ok(rms(out.slice(60)) < 0.3 * rms(raw), `${rms(out.slice(60))} vs ${rms(raw)}`);
  });

  test("follows a 0.3 m/s sweep with under 30 ms of lag", () => {
    const filter = new OneEuroFilter(PHONE_FILTER.position);
    let lagS = 0;
    for (let i = 0; i < 120; i += 1) {
      const truth = 0.3 * i * DT_S;
      lagS = (truth - filter.filter(truth, i * DT_S)) / 0.3;
    }
    assert.ok(lagS > 0 && lagS < 0.03, `lag ${lagS} s`);
  });
});

describe("RotationFilter", () => {
  test("cuts orientation jitter to under 40 % and lags a 2 rad/s turn under 30 ms", () => {
    const noise = gaussian(2), filter = new RotationFilter(PHONE_FILTER.rotation);
    const rawErrors = [], errors = [];
    for (let i = 0; i < 300; i += 1) {
      const truth = yawQuaternion(0.3);
      const reading = yawQuaternion(0.3 + 0.01 * noise());
      rawErrors.push(angleBetween(reading, truth));
      errors.push(angleBetween(filter.filter(reading, i * DT_S), truth));
    }
    assert.ok(rms(errors.slice(60)) < 0.4 * rms(rawErrors));
    let lagRad = 0;
    for (let i = 300; i < 360; i += 1) {
      const truth = yawQuaternion(0.3 + 2 * (i - 299) * DT_S);
      lagRad = angleBetween(filter.filter(truth, i * DT_S), truth);
    }
    assert.ok(lagRad < 2 * 0.03, `lag ${lagRad} rad at 2 rad/s`);
  });
});

describe("PhonePoseFilter", () => {
  const still = [0, 0, 0, 1];

  test("a jump faster than a hand is a glitch: the output stays put", () => {
    const filter = new PhonePoseFilter();
    for (let i = 0; i < 30; i += 1) filter.update([0.001 * i, 0, 0], still, i * DT_S);
    const before = filter.output.position;
    const out = filter.update([0.25, 0, 0], still, 30 * DT_S);  // 22 cm in one frame
    assert.equal(out.glitch, true);
    assert.deepEqual(out.position, before);
    assert.equal(filter.update([0.251, 0, 0], still, 31 * DT_S).glitch, false, "then on");
  });

  test("a stroke carries the hand at most maxReachM from where it began", () => {
    const filter = new PhonePoseFilter();
    filter.update([0, 0, 0], still, 0);
    filter.beginStroke();
    let out;
    for (let i = 1; i < 400; i += 1) out = filter.update([0.5 * i * DT_S, 0, 0], still, i * DT_S);
    assert.equal(out.limited, true);
    assert.ok(Math.abs(out.position[0] - PHONE_FILTER.maxReachM) < 1e-9, `${out.position}`);
    filter.endStroke();
    out = filter.update([0.5 * 400 * DT_S, 0, 0], still, 400 * DT_S);
    assert.equal(out.limited, false, "between strokes the phone may be anywhere");
  });

  test("re-centring makes the phone's heading forward", () => {
    const filter = new PhonePoseFilter();
    const facingLeft = yawQuaternion(Math.PI / 2);
    filter.recentreHeading(facingLeft);
    let out;
    for (let i = 0; i < 120; i += 1) {  // carried 10 cm along where it points (world +y)
      out = filter.update([0, 0.1 * Math.min(1, i / 60), 0], facingLeft, i * DT_S);
    }
    assert.ok(Math.abs(out.position[0] - 0.1) < 0.002 && Math.abs(out.position[1]) < 0.002,
      `${out.position}`);
    assert.ok(Math.abs(headingOf(out.quaternion)) < 1e-3);
  });
});

test("headingOf reads back yawQuaternion and rotateVector turns x to y by a quarter turn", () => {
  for (const yaw of [-2.5, -1, 0, 0.7, 3]) assert.ok(Math.abs(headingOf(yawQuaternion(yaw)) - yaw) < 1e-9);
  const [x, y, z] = rotateVector(yawQuaternion(Math.PI / 2), [1, 0, 0]);
  assert.ok(Math.abs(x) < 1e-12 && Math.abs(y - 1) < 1e-12 && Math.abs(z) < 1e-12);
});

describe("camera mode's orientation fusion", () => {
  const turn = (axis, radians) => { const q = [0, 0, 0, Math.cos(radians / 2)]; q[axis] = Math.sin(radians / 2); return q; };
  const worldOffset = turn(2, 1.2);  // the sensors' world (north) is turned from the screen's

  test("without sensors it passes the marker's rotation through", () => {
    const fusion = new OrientationFusion();
    assert.deepEqual(fusion.camera(turn(1, 0.3), 0), turn(1, 0.3));
  });

  test("with sensors it finds their world's offset and keeps the marker's jitter out", () => {
    const fusion = new OrientationFusion(), noise = gaussian(7), errors = [], raw = [];
    for (let i = 0; i < 300; i += 1) {
      const nowMs = (i * 1000) / 30, body = turn(0, 0.2 + 0.3 * Math.sin(i / 40));
      fusion.sensor(body, nowMs);  // the body in the sensors' world
      const jitter = turn(1, 0.03 * noise());  // ~1.7 degrees of marker noise
      const seen = quatMultiply(jitter, quatMultiply(worldOffset, body));
      const out = fusion.camera(seen, nowMs);
      if (i > 150) { errors.push(angleBetween(out, quatMultiply(worldOffset, body))); raw.push(angleBetween(seen, quatMultiply(worldOffset, body))); }
    }
    assert.ok(rms(errors) < rms(raw) / 3, `fused ${rms(errors)} rad vs marker ${rms(raw)} rad`);
  });

  test("stale sensors (over half a second) are not used", () => {
    const fusion = new OrientationFusion();
    fusion.sensor(turn(0, 1), 0);
    assert.deepEqual(fusion.camera(turn(1, 0.3), 600), turn(1, 0.3));
  });
});
