// Where the VR headset's screen goes and what its status panel says (web/static/xr_screen.js),
// and which controller drives (web/static/devices.js).

import assert from "node:assert/strict";
import { test } from "node:test";

import { handsOf, pulseStrength } from "../../src/crowdteleop/web/static/devices.js";
import { SCREEN, ScreenPlacement, facingMatrix, panelMatrix, projectedRect, statusLines, wrap } from "../../src/crowdteleop/web/static/xr_screen.js";

const close = (actual, expected, tolerance = 1e-9) =>
  actual.forEach((v, i) => assert.ok(Math.abs(v - expected[i]) < tolerance, `${actual} != ${expected}`));
const apply = (m, [x, y, z]) => [0, 1, 2].map((r) => m[r] * x + m[4 + r] * y + m[8 + r] * z + m[12 + r]);

test("the screen is placed 1.5 m ahead of the head, level, a little below the eyes", () => {
  const placement = new ScreenPlacement();
  placement.placeInFront([0, 1.6, 0], [0, -0.5, -0.866]);  // looking down: still level ahead
  close(placement.centre, [0, 1.6 - SCREEN.drop, -1.5]);
  placement.placeInFront([1, 1.6, 2], [1, 0, 0]);  // turned right
  close(placement.centre, [2.5, 1.6 - SCREEN.drop, 2]);
  assert.equal(placement.width, 1.2);
});

test("the screen's quad faces the worker: its corners span its width, its normal points back", () => {
  const m = facingMatrix([0, 1.5, -1.5], [0, 1.6, 0], 1.2, 0.9);
  close(apply(m, [-0.5, 0.5, 0]), [-0.6, 1.95, -1.5]);
  close(apply(m, [0.5, -0.5, 0]), [0.6, 1.05, -1.5]);
  close(m.slice(8, 11), [0, 0, 1]);
  const side = facingMatrix([1.5, 1.5, 0], [0, 1.5, 0], 1, 1);  // to the right: faces -x
  close(side.slice(8, 11), [-1, 0, 0]);
  close(apply(side, [0.5, 0, 0]), [1.5, 1.5, 0.5]);  // its right edge is toward +z (behind)
});

test("the panel hangs below the screen, centred", () => {
  const placement = new ScreenPlacement();
  placement.placeInFront([0, 1.6, 0], [0, 0, -1]);
  const panel = panelMatrix(placement, 0.9);
  const top = apply(panel, [0, 0.5, 0]);
  assert.ok(top[1] < placement.centre[1] - 0.45, `${top}`);
  close([top[0], top[2]], [0, -1.5]);
});

test("the other hand's thumbstick pushes, pulls and resizes within limits", () => {
  const placement = new ScreenPlacement();
  placement.placeInFront([0, 0, 0], [0, 0, -1]);
  placement.nudge([0, -1], 0.5);  // stick forward: 0.5 m farther
  close([Math.hypot(...placement.centre)], [Math.hypot(1.5, SCREEN.drop) + 0.5]);
  placement.nudge([0, 1], 100);
  close([Math.hypot(...placement.centre)], [SCREEN.minDistance]);
  placement.nudge([0.05, 0.05], 1);  // inside the dead zone: nothing
  close([Math.hypot(...placement.centre)], [SCREEN.minDistance]);
  placement.nudge([1, 0], 100);
  assert.equal(placement.width, SCREEN.maxWidth);
  placement.nudge([-1, 0], 100);
  assert.equal(placement.width, SCREEN.minWidth);
});

test("holding the other hand's grip drags the screen with the hand, from where it was", () => {
  const placement = new ScreenPlacement();
  placement.placeInFront([0, 1.6, 0], [0, 0, -1]);
  const start = [...placement.centre];
  placement.drag([0.2, 1.2, -0.3], true);
  close(placement.centre, start);  // grabbing does not jump
  placement.drag([0.5, 1.3, -0.3], true);
  close(placement.centre, [start[0] + 0.3, start[1] + 0.1, start[2]]);
  placement.drag([0, 0, 0], false);
  placement.drag([1, 1, 1], true);  // a new grab starts from the screen's place
  close(placement.centre, [start[0] + 0.3, start[1] + 0.1, start[2]]);
});

test("the screen's rectangle in a view: 1.2 m wide at 1.5 m is 40% of a 90-degree view", () => {
  const [near, far] = [0.1, 100];
  const projection = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, (far + near) / (near - far), -1, 0, 0, 2 * far * near / (near - far), 0];
  const identity = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1];
  const model = facingMatrix([0, 0, -1.5], [0, 0, 0], 1.2, 0.9);
  close(projectedRect(projection, identity, model, { width: 1000, height: 1000 }), [300, 350, 700, 650], 1e-6);
});

test("the panel says the task, the demonstrations and the clutch in words", () => {
  assert.deepEqual(statusLines({ task: "Lift the cube.", demosDone: 1, demosRequired: 3, clutch: "driving" }),
    ["Lift the cube.", "Demonstrations 1 / 3", "Moving: the arm follows you."]);
  assert.deepEqual(statusLines({}), ["Connecting…", "Demonstrations –", "Clutch: –"]);
});

test("long lines wrap at words", () => {
  const measure = (text) => text.length * 10;
  assert.deepEqual(wrap("Let go and press again to move", 120, measure), ["Let go and", "press again", "to move"]);
  assert.deepEqual(wrap("unbreakablelongword fits", 50, measure), ["unbreakablelongword", "fits"]);
  assert.deepEqual(wrap("", 50, measure), []);
});

test("the right hand drives when there is one; the other moves the screen", () => {
  const hand = (handedness) => ({ handedness, gripSpace: {}, gamepad: {} });
  const [left, right] = [hand("left"), hand("right")];
  assert.deepEqual(handsOf([left, right]), { driver: right, other: left });
  assert.deepEqual(handsOf([left]), { driver: left, other: null });
  assert.deepEqual(handsOf([{ handedness: "none" }]), { driver: null, other: null });  // no grip, no pad
  assert.equal(pulseStrength(0), 0.3);
  assert.equal(pulseStrength(5), 1);
});
