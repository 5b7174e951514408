// Every clutch state the server can send has words on the pages, and no page word names a state
// the server does not have: the list comes from the real protocol schema of this run.

import assert from "node:assert/strict";
import { test } from "node:test";

import { CLUTCH_TEXT, CLUTCH_WORD } from "../../src/crowdteleop/web/static/clutch.js";
import { realSchema } from "./python.mjs";

function states(schema) {
  const server = schema.channels.server;
  const status = Object.values(server.$defs).find((d) => d.title === "TaskStatus");
  return status.properties.clutch.enum;
}

test("each clutch state of the protocol has a sentence and a word", () => {
  const known = states(realSchema());
  assert.ok(known && known.length >= 6, JSON.stringify(known));
  assert.deepEqual(Object.keys(CLUTCH_TEXT).sort(), [...known].sort());
  assert.deepEqual(Object.keys(CLUTCH_WORD).sort(), [...known].sort());
});
