// How the join page picks a region (web/static/region.js): timed pings, the nearest region
// with a free robot, and the round trips carried to the chosen region's page.

import assert from "node:assert/strict";
import { test } from "node:test";

import {
  chooseRegion, decodeRoundTrips, encodeRoundTrips, joinUrlAt, measure, networkTiming, roundTrips,
} from "../../src/crowdteleop/web/static/region.js";

const region = (name, rtt_ms, free_slots, queued = 0, capacity = 2) =>
  ({ name, url: `https://${name}.example.org`, rtt_ms, free_slots, queued, capacity });

test("the nearest region with a free robot wins", () => {
  const chosen = chooseRegion([region("oregon", 25, 1), region("china", 180, 2)]);
  assert.equal(chosen.name, "oregon");
});

test("a nearer region whose robots are all taken (or promised to its queue) is passed over", () => {
  assert.equal(chooseRegion([region("oregon", 25, 0), region("china", 180, 1)]).name, "china");
  assert.equal(chooseRegion([region("oregon", 25, 1, 1), region("china", 180, 1)]).name, "china");
});

test("when no region has a free robot: the shortest wait per robot, the nearer on a tie", () => {
  const busy = [region("oregon", 25, 0, 6, 2), region("china", 180, 0, 1, 2)];
  assert.equal(chooseRegion(busy).name, "china");
  assert.equal(chooseRegion([region("a", 90, 0, 1), region("b", 30, 0, 1)]).name, "b");
});

test("regions that did not answer are left out; none answering: no choice (stay)", () => {
  const down = { name: "china", url: "https://china.example.org", error: "timed out" };
  assert.equal(chooseRegion([down, region("oregon", 300, 1)]).name, "oregon");
  assert.equal(chooseRegion([down]), null);
  assert.deepEqual(roundTrips([down, region("oregon", 300, 1)]), { oregon: 300 });
});

test("measure times every ping but the first (it opens the connection) and takes the median", async () => {
  let clock = 0;
  const durations = [500, 40, 60, 50]; // ms: a slow first (connection set-up), then three
  let call = 0;
  const fetchImpl = async (url, options) => {
    assert.equal(url, "https://oregon.example.org/api/ping");
    assert.equal(options.cache, "no-store");
    clock += durations[call++];
    return { ok: true, json: async () => ({ region: "oregon", capacity: 2, free_slots: 1, queued: 0 }) };
  };
  const measured = await measure({ name: "oregon", url: "https://oregon.example.org" },
                                 { fetchImpl, now: () => clock });
  assert.equal(call, 4);
  assert.equal(measured.rtt_ms, 50);
  assert.equal(measured.free_slots, 1);
});

test("a region that fails or times out is reported as such, not timed", async () => {
  const refused = async () => { throw new TypeError("Failed to fetch"); };
  const failed = await measure({ name: "x", url: "https://x.example.org" }, { fetchImpl: refused });
  assert.equal(failed.error, "Failed to fetch");
  assert.equal(failed.rtt_ms, undefined);
  const hanging = (_url, { signal }) => new Promise((_resolve, reject) => {
    signal.addEventListener("abort", () => reject(Object.assign(new Error("aborted"), { name: "AbortError" })));
  });
  const slow = await measure({ name: "y", url: "https://y.example.org" }, { fetchImpl: hanging, timeoutMs: 20 });
  assert.equal(slow.error, "timed out");
});

test("round trips travel in one parameter; malformed parts of a hand-edited link are dropped", () => {
  const rtts = { oregon: 25.4, china: 181 };
  assert.deepEqual(decodeRoundTrips(encodeRoundTrips(rtts)), rtts);
  assert.deepEqual(decodeRoundTrips("oregon:25,BAD:1,china:NaN,x:-4,y:1e9,z:7"), { oregon: 25, z: 7 });
  assert.deepEqual(decodeRoundTrips(undefined), {});
});

test("the chosen region's join page keeps the link's study ids and adds the round trips", () => {
  const url = new URL(joinUrlAt({ name: "china", url: "https://china.example.org:8443" },
                                "?PROLIFIC_PID=p1&STUDY_ID=s&campaign=pilot", { oregon: 180, china: 20 }));
  assert.equal(url.origin + url.pathname, "https://china.example.org:8443/join");
  assert.equal(url.searchParams.get("PROLIFIC_PID"), "p1");
  assert.equal(url.searchParams.get("campaign"), "pilot");
  assert.equal(url.searchParams.get("region_rtts"), "oregon:180,china:20");
});

test("the network's own timing of a ping is preferred to the page's clock", async () => {
  let clock = 0;
  const fetchImpl = async () => {
    clock += 45; // a busy page resolves the promise late
    return { ok: true, json: async () => ({ region: "near", capacity: 1, free_slots: 1, queued: 0 }) };
  };
  const timing = (url, since) => {
    assert.equal(url, "https://near.example.org/api/ping");
    assert.equal(typeof since, "number");
    return 5; // request sent to first byte, as Resource Timing reports it
  };
  const measured = await measure({ name: "near", url: "https://near.example.org" },
                                 { fetchImpl, now: () => clock, timing });
  assert.equal(measured.rtt_ms, 5);
});

test("without a timing entry (no Resource Timing, or none allowed) the page's clock is used", () => {
  assert.equal(networkTiming("https://nowhere.example.org/api/ping", 0), null);
});
