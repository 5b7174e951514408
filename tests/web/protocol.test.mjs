// The page's messages against the real protocol schema (generated from protocol.py for this
// run): every message MessageFactory builds is valid, wrong ones are refused, and the teleop
// server's own parser agrees with the page's validator on all of them.

import assert from "node:assert/strict";
import { describe, test } from "node:test";

import { CLIENT_MESSAGES, MessageFactory, Protocol, ProtocolViolation, channelOf }
  from "../../src/crowdteleop/web/static/protocol.js";
import { realSchema, serverVerdicts } from "./python.mjs";

const schema = realSchema();
const protocol = new Protocol(schema);
const DEVICES = ["phone", "keyboard", "vr", "spacemouse", "gamepad", "bot"];

function built() {
  const f = new MessageFactory("keyboard");
  return {
    pose: f.pose([0.1, -0.2, 0.3], [0, 0, 0, 1], true, false),
    poseWithSeq: f.pose([0, 0, 0], [0, 0, 0.7071, 0.7071], false, true, 41),
    clutch: f.clutch(true),
    gripper: f.gripper(false),
    reset: f.reset(),
    start: f.start(),
    stop: f.stop(),
    skipPractice: f.skipPractice(),
    request: f.request("reset"),
    takeControl: f.takeControl(),
    ping: f.ping(7),
    pong: f.pong({ v: 1, type: "ping", id: 3, server_time_s: 1234.5 }),
    videoStalled: f.videoStatus(true, 1234.4),
    videoResumed: f.videoStatus(false, -3),
    latency: f.latency([12.5, 80, 0], 29.7),
    latencyEmpty: f.latency([], 0),
    latencyCleaned: f.latency([-0.3, NaN, 70_000, ...Array(120).fill(50)], Infinity),
  };
}

// Each a valid message made wrong one way.
function wrong() {
  const f = new MessageFactory("keyboard");
  const pose = f.pose([0.1, 0.2, 0.3], [0, 0, 0, 1], true, false);
  const without = (message, key) => { const copy = { ...message }; delete copy[key]; return copy; };
  const cases = {
    "unknown type": ["events", { v: 1, type: "fly" }],
    "pose on the events channel": ["events", pose],
    "clutch on the control channel": ["control", f.clutch(true)],
    "wrong version": ["control", { ...pose, v: 2 }],
    "extra field": ["control", { ...pose, t: 5 }],
    "old field name t": ["events", { v: 1, type: "ping", id: 1, t: 5 }],
    "string seq": ["control", { ...pose, seq: "1" }],
    "number engaged": ["control", { ...pose, engaged: 1 }],
    "fractional seq": ["control", { ...pose, seq: 1.5 }],
    "negative seq": ["control", { ...pose, seq: -1 }],
    "seq past 2**53": ["control", { ...pose, seq: 2 ** 53 + 2 }],
    "NaN position": ["control", { ...pose, position: [0, NaN, 0] }],
    "infinite time": ["control", { ...pose, client_time_ms: Infinity }],
    "time out of range": ["control", { ...pose, client_time_ms: 1e14 }],
    "short position": ["control", { ...pose, position: [0, 0] }],
    "long quaternion": ["control", { ...pose, quaternion: [0, 0, 0, 1, 0] }],
    "unknown device": ["events", { ...f.takeControl(), device: "toaster" }],
    "latency too large": ["events", { v: 1, type: "latency", samples_ms: [60_001], fps: 30 }],
    "negative latency": ["events", { v: 1, type: "latency", samples_ms: [-1], fps: 30 }],
    "too many samples": ["events", { v: 1, type: "latency", samples_ms: Array(101).fill(1), fps: 30 }],
    "fps too high": ["events", { v: 1, type: "latency", samples_ms: [], fps: 1001 }],
    "pong without server_time_s": ["events", { v: 1, type: "pong", id: 1 }],
    "gripper without closed": ["events", without(f.gripper(true), "closed")],
  };
  for (const key of ["seq", "client_time_ms", "device", "position", "quaternion", "engaged", "gripper"]) {
    cases[`pose without ${key}`] = ["control", without(pose, key)];
  }
  return cases;
}

describe("MessageFactory", () => {
  test("every message it builds is valid on its channel", () => {
    for (const [name, message] of Object.entries(built())) {
      assert.deepEqual(protocol.problems(channelOf(message.type), message), [], name);
    }
  });
  test("it builds every message type a page may send", () => {
    const types = new Set(Object.values(built()).map((message) => message.type));
    assert.deepEqual([...types].sort(), Object.values(CLIENT_MESSAGES).flat().sort());
  });
  test("every device kind is valid", () => {
    for (const device of DEVICES) {
      const f = new MessageFactory(device);
      for (const message of [f.pose([0, 0, 0], [0, 0, 0, 1], true, true), f.clutch(false), f.takeControl()]) {
        assert.deepEqual(protocol.problems(channelOf(message.type), message), [], device);
      }
    }
  });
  test("one sequence counter across pose, clutch and gripper; a given seq only moves it up", () => {
    const f = new MessageFactory("phone", () => 1_700_000_000_000);
    assert.deepEqual([f.pose([0, 0, 0], [0, 0, 0, 1], 1, 0).seq, f.clutch(1).seq, f.gripper(0).seq], [1, 2, 3]);
    assert.equal(f.pose([0, 0, 0], [0, 0, 0, 1], 1, 0, 10).seq, 10);
    assert.equal(f.pose([0, 0, 0], [0, 0, 0, 1], 1, 0, 5).seq, 11);
    assert.equal(f.clutch(true).client_time_ms, 1_700_000_000_000);
  });
  test("pong echoes the server ping's id and server_time_s, stamped with our clock", () => {
    const pong = new MessageFactory("vr", () => 1_700_000_000_500).pong({ v: 1, type: "ping", id: 9, server_time_s: 55.25 });
    assert.deepEqual(pong, { v: 1, type: "pong", id: 9, server_time_s: 55.25, client_time_ms: 1_700_000_000_500 });
  });
  test("a video status says stalled or not, with a whole, non-negative gap", () => {
    assert.deepEqual(built().videoStalled, { v: 1, type: "video", stalled: true, gap_ms: 1234 });
    assert.equal(built().videoResumed.gap_ms, 0);
  });
  test("a latency report is kept inside the schema's bounds", () => {
    const report = built().latencyCleaned;
    assert.equal(report.samples_ms.length, 100);
    assert.equal(report.samples_ms[0], 0);
    assert.ok(report.samples_ms.every(Number.isFinite));
    assert.equal(report.fps, 0);
  });
});

describe("Protocol", () => {
  test("refuses each wrong message", () => {
    for (const [name, [channel, message]] of Object.entries(wrong())) {
      assert.ok(protocol.problems(channel, message).length > 0, `accepted: ${name}`);
    }
  });
  test("the teleop server's parser agrees with the page on every message", () => {
    const good = Object.values(built()).map((message) => [channelOf(message.type), message]);
    const bad = Object.values(wrong());  // NaN and Infinity reach the server as null: still wrong
    const verdicts = serverVerdicts([...good, ...bad]);
    const verdict = ([channel, message]) => (protocol.problems(channel, message).length ? "refused" : "ok");
    const page = [...good, ...bad].map(verdict);
    const names = [...Object.keys(built()), ...Object.keys(wrong())];
    verdicts.forEach((verdict, i) => {
      assert.equal(verdict === "ok" ? "ok" : "refused", page[i], `${names[i]}: server says ${verdict}`);
    });
  });
  test("encode gives the channel and the JSON, or throws instead of sending", () => {
    const pose = new MessageFactory("keyboard").pose([0, 0, 0], [0, 0, 0, 1], true, false);
    const wire = protocol.encode(pose);
    assert.equal(wire.channel, "control");
    assert.deepEqual(JSON.parse(wire.data), pose);
    assert.equal(protocol.encode({ v: 1, type: "stop" }).channel, "events");
    assert.throws(() => protocol.encode({ ...pose, position: [NaN, 0, 0] }),
      (error) => error instanceof ProtocolViolation && /position\/0/.test(error.problems[0]));
    assert.throws(() => protocol.encode({ v: 1, type: "fly" }), ProtocolViolation);
  });
  test("refuses a schema of another version or one that lacks a message the page sends", () => {
    assert.throws(() => new Protocol({ ...schema, version: 2 }), /protocol 2/);
    const { control } = schema.channels;
    const renamed = { ...control, properties: { ...control.properties, type: { const: "posed" } } };
    assert.throws(() => new Protocol({ ...schema, channels: { ...schema.channels, control: renamed } }),
      /control\/pose unknown/);
  });
});

describe("server messages", () => {
  const samples = {
    hello: { v: 1, type: "hello", session_id: "s1", peer_id: "p1", role: "worker", task: "lift",
             instruction: "Lift it.", fps: 20, width: 640, height: 480, controlling_device: null },
    status: { v: 1, type: "status", episode: 2, state: "running", elapsed_s: 3.5, time_limit_s: 600, success: false,
              stage: "reach", message: "", completed: 0, total: 1, controlling_device: "keyboard", successes: 0,
              end_effector: [0.1, 0.2, 0.9] },
    frame: { v: 1, type: "frame", pts: 90000, command_seq: 12, server_time_s: 1712345678.25 },
    ping: { v: 1, type: "ping", id: 4, server_time_s: 812.5 },
    pong: { v: 1, type: "pong", id: 7, client_time_ms: 1712345678123 },
    error: { v: 1, type: "error", code: "not_in_control", message: "another device drives", channel: "control" },
    haptic: { v: 1, type: "haptic", intensity: 0.4, robot_part: "gripper", object: "cube" },
    episode: { v: 1, type: "episode", episode: 1, outcome: "success", steps: 230, successes: 1 },
    saved: { v: 1, type: "saved", episode: 1, outcome: "success", uri: "file:///data/ep1.hdf5" },
    feedback: { v: 1, type: "feedback", episode: 1, score: 61.5, time_s: 12.4, median_time_s: 14, idle_percent: 12,
                median_idle_percent: 18.5, smoother_than_percent: 55, tip: "Well done: keep going like this." },
    telemetry: { v: 1, type: "telemetry", loop_hz: 20, jitter_ms: 0.4, overruns: 0, frames_sent: 100, fps: 20,
                 bitrate_kbps: 300, rtt_ms: 12, errors: { invalid: 1 } },
  };
  test("the page knows a sample of every server message but the admin-only one", () => {
    const mapping = schema.channels.server.discriminator.mapping;
    assert.deepEqual(Object.keys(mapping).filter((type) => type !== "privileged").sort(), Object.keys(samples).sort());
  });
  test("decode accepts each of them", () => {
    for (const [name, message] of Object.entries(samples)) {
      assert.deepEqual(protocol.decode(JSON.stringify(message)), message, name);
    }
  });
  test("decode accepts feedback before the study has a middle to compare with", () => {
    const first = { ...samples.feedback, score: null, median_time_s: null, median_idle_percent: null,
                    smoother_than_percent: null };
    assert.deepEqual(protocol.decode(JSON.stringify(first)), first);
    assert.throws(() => protocol.decode(JSON.stringify({ ...samples.feedback, tip: 3 })), ProtocolViolation);
  });
  test("decode accepts a status in a practice round", () => {
    const status = { ...samples.status, episode: 0, state: "ready", practice: "running", practice_left_s: 14.2,
                     practice_reached: false };
    assert.deepEqual(protocol.decode(JSON.stringify(status)), status);
    assert.throws(() => protocol.decode(JSON.stringify({ ...status, practice: "rehearsal" })), ProtocolViolation);
  });
  test("decode refuses what is not a server message", () => {
    const bad = [
      "not json",
      JSON.stringify({ v: 1, type: "teleport" }),
      JSON.stringify({ ...samples.frame, pts: undefined }),
      JSON.stringify({ ...samples.frame, t: 1 }),
      JSON.stringify({ ...samples.ping, server_time_s: "soon" }),
      JSON.stringify({ ...samples.status, state: "dancing" }),
      JSON.stringify({ ...samples.hello, controlling_device: "toaster" }),
      JSON.stringify({ ...samples.haptic, intensity: 2 }),
      JSON.stringify([samples.hello]),
      "null",
    ];
    for (const raw of bad) assert.throws(() => protocol.decode(raw), ProtocolViolation, raw);
  });
});
