// What the teleop page says of the practice round (web/static/practice.js), for the statuses
// the server sends (checked against the real schema, so the fields are the server's).

import assert from "node:assert/strict";
import { test } from "node:test";

import { practiceText } from "../../src/crowdteleop/web/static/practice.js";
import { Protocol } from "../../src/crowdteleop/web/static/protocol.js";
import { realSchema } from "./python.mjs";

const protocol = new Protocol(realSchema());
const base = { v: 1, type: "status", episode: 0, state: "ready", elapsed_s: 0, time_limit_s: 60, success: false,
               stage: "", message: "", completed: 0, total: 0, controlling_device: "keyboard", successes: 0,
               end_effector: [0, 0, 1] };
const status = (fields) => protocol.decode(JSON.stringify({ ...base, ...fields }));

test("while practising: not recorded, where to go, whole seconds left", () => {
  assert.equal(practiceText(status({ practice: "running", practice_left_s: 13.2 })),
    "Practice (not recorded): move the hand to the green ball — 14 s left");
  assert.equal(practiceText(status({ practice: "running", practice_left_s: 20 })),
    "Practice (not recorded): move the hand to the green ball — 20 s left");
});

test("once done, until demonstration 1 starts: what the next move does", () => {
  assert.equal(practiceText(status({ practice: "done" })),
    "Practice done: the next time you move, demonstration 1 starts");
  assert.equal(practiceText(status({ practice: "done", practice_reached: true })),
    "You reached it. Practice done: the next time you move, demonstration 1 starts");
  assert.equal(practiceText(status({ practice: "done", episode: 1, state: "running" })), null);
});

test("nothing to say without a practice round (or from a server that has none)", () => {
  assert.equal(practiceText(status({ practice: "off" })), null);
  assert.equal(practiceText(status({})), null);
  assert.equal(practiceText(null), null);
});
