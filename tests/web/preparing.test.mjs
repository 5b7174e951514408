// What the join and teleop pages say while a robot is being prepared (web/static/preparing.js),
// for the coordinator's estimates ({eta_s, total_s}: RobotPreparation in coord/api/schemas.py,
// served with the views at /views.json).

import assert from "node:assert/strict";
import { test } from "node:test";

import { preparingText, progressOf, remainingS, showPreparing } from "../../src/crowdteleop/web/static/preparing.js";
import { compile } from "../../src/crowdteleop/web/static/schema.js";
import { python } from "./python.mjs";

test("an estimate is said in whole seconds, and counts down between answers", () => {
  const estimate = { eta_s: 8.4, total_s: 10 };
  assert.equal(preparingText(estimate), "Preparing your robot… about 8 s");
  assert.equal(preparingText(estimate, 3000, 0), "Preparing your robot… about 5 s");
  assert.equal(remainingS(estimate, 30_000, 0), 1, "never 'now' until the robot is ready");
  assert.equal(preparingText(null), "Preparing your robot…");
  assert.equal(preparingText({ eta_s: 0, total_s: 10 }), "A robot is ready for you.");
});

test("the progress bar fills with the start and hides once a robot is ready", () => {
  assert.deepEqual(progressOf({ eta_s: 8, total_s: 10 }), { value: 2, max: 10 });
  assert.deepEqual(progressOf({ eta_s: 8, total_s: 10 }, 2000, 0), { value: 4, max: 10 });
  assert.deepEqual(progressOf({ eta_s: 12, total_s: 10 }), { value: 0, max: 12 }, "a slow start stretches it");
  assert.equal(progressOf({ eta_s: 0, total_s: 10 }), null);
  assert.equal(progressOf(null), null);
  const bar = { hidden: true, value: 0, max: 1 };
  assert.equal(showPreparing(bar, { eta_s: 5, total_s: 10 }), "Preparing your robot… about 5 s");
  assert.deepEqual(bar, { hidden: false, value: 5, max: 10 });
  showPreparing(bar, null);
  assert.equal(bar.hidden, true);
});

test("the estimates are checked against the views' schema the coordinator serves", () => {
  const source = "import json; from crowdteleop.coord.api.schemas import page_views_schema; print(json.dumps(page_views_schema()))";
  const schemas = JSON.parse(python(["-c", source]));
  const robot = compile({ $defs: schemas.CampaignView.$defs, ...schemas.CampaignView.properties.robot });
  assert.deepEqual(robot({ eta_s: 4.2, total_s: 10 }), []);
  assert.deepEqual(robot(null), [], "null: every slot is held");
  assert.notDeepEqual(robot({ eta_s: -1, total_s: 10 }), []);
  assert.notDeepEqual(robot({ eta_s: 4.2 }), [], "the bar needs the whole start");
});
