// The browser's latency matcher against the vectors the Python client's tests also run
// (tests/client/test_latency_vectors.py): both must report the same command for every frame.

import assert from "node:assert/strict";
import { readFileSync } from "node:fs";
import { describe, test } from "node:test";

import { FrameMatcher, LatencyTracker } from "../../src/crowdteleop/web/static/latency.js";

const vectors = JSON.parse(readFileSync(new URL("../fixtures/latency_vectors.json", import.meta.url), "utf8"));

describe("FrameMatcher", () => {
  for (const { name, steps } of vectors.matcher) {
    test(name, () => {
      const matcher = new FrameMatcher();
      const found = [], expected = [];
      for (const step of steps) {
        if (step.tag) matcher.addTag(...step.tag);
        else if (step.tags) for (const [pts, seq] of step.tags) matcher.addTag(pts, seq);
        else { found.push(matcher.commandSeqOf(step.frame)); expected.push(step.seq); }
      }
      assert.deepEqual(found, expected);
    });
  }
});

const close = (actual, expected) => {
  assert.equal(actual.length, expected.length, `${actual} vs ${expected}`);
  actual.forEach((x, i) => assert.ok(Math.abs(x - expected[i]) < 1e-6, `${actual} vs ${expected}`));
};

describe("LatencyTracker", () => {
  for (const { name, steps } of vectors.tracker) {
    test(name, () => {
      const tracker = new LatencyTracker();
      const every = [];
      for (const step of steps) {
        if (step.sent !== undefined) tracker.commandSent(step.sent, step.at_ms);
        else {
          close(tracker.frameShown(step.shown, step.at_ms), step.samples_ms);
          every.push(...step.samples_ms);
        }
      }
      close(tracker.samplesMs, every);
    });
  }
});
