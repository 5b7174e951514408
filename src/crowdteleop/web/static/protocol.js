// The teleop message protocol, shared with the server. The server publishes its JSON Schema at
// /protocol.json (generated from crowdteleop/teleop/protocol.py). Every message a page sends is
// built by MessageFactory and checked against that schema by Protocol.encode before it leaves;
// every message the server sends is checked by Protocol.decode before the page acts on it. So
// server and page cannot drift apart silently: a mismatch shows up as a refused message here.

import { compile } from "./schema.js";

export const PROTOCOL_VERSION = 1;

export const CLIENT_MESSAGES = {
  control: ["pose"],
  events: ["clutch", "gripper", "reset", "start", "stop", "skip_practice", "take_control", "ping", "pong",
           "latency", "video"],
};

// LatencyReport's bounds in protocol.py: the factory keeps reports inside them.
const MAX_LATENCY_SAMPLES = 100;
const MAX_LATENCY_MS = 60_000;
const MAX_FPS = 1000;

export function channelOf(type) {
  return CLIENT_MESSAGES.control.includes(type) ? "control" : "events";
}

// A message the schema refuses; `problems` lists what is wrong ("/path: why").
export class ProtocolViolation extends Error {
  constructor(what, problems) {
    super(`${what}: ${problems.slice(0, 3).join("; ")}`);
    this.problems = problems;
  }
}

function typesIn(schema) {
  const types = new Set();
  for (const def of [schema, ...Object.values(schema.$defs || {})]) {
    const tag = def.properties && def.properties.type;
    if (tag && tag.const) types.add(tag.const);
  }
  return types;
}

export class Protocol {
  constructor(schema) {
    if (schema.version !== PROTOCOL_VERSION) {
      throw new Error(`server speaks protocol ${schema.version}, this page ${PROTOCOL_VERSION}`);
    }
    for (const [channel, types] of Object.entries(CLIENT_MESSAGES)) {
      const known = typesIn(schema.channels[channel]);
      for (const type of types) {
        if (!known.has(type)) throw new Error(`protocol mismatch: ${channel}/${type} unknown`);
      }
    }
    this.schema = schema;
    this.validators = {};
    for (const [channel, channelSchema] of Object.entries(schema.channels)) {
      this.validators[channel] = compile(channelSchema);
    }
  }

  static async load(base = "") {
    const response = await fetch(`${base}/protocol.json`);
    if (!response.ok) throw new Error(`protocol schema unavailable (${response.status})`);
    return new Protocol(await response.json());
  }

  // What is wrong with `message` on `channel` ("control", "events" or "server"); [] if nothing.
  problems(channel, message) {
    const validate = this.validators[channel];
    return validate ? validate(message) : [`no channel ${channel} in the schema`];
  }

  // The wire form of an outgoing message and its channel; throws ProtocolViolation instead of
  // sending something the server would refuse.
  encode(message) {
    const channel = channelOf(message && message.type);
    const problems = this.problems(channel, message);
    if (problems.length) throw new ProtocolViolation(`refusing to send ${message && message.type}`, problems);
    return { channel, data: JSON.stringify(message) };
  }

  // A server message, parsed and checked; throws ProtocolViolation if it is not one.
  decode(raw) {
    let message;
    try { message = JSON.parse(raw); } catch (error) {
      throw new ProtocolViolation("ignoring a server message", [`not JSON: ${error.message}`]);
    }
    const problems = this.problems("server", message);
    if (problems.length) throw new ProtocolViolation(`ignoring server ${message && message.type}`, problems);
    return message;
  }
}

// The one place outgoing messages are built. One sequence counter per device: the server keeps
// the newest message of the controlling device and drops older ones, across both channels.
export class MessageFactory {
  constructor(device, clockMs = () => Date.now()) {
    this.device = device;
    this.seq = 0;
    this.clockMs = clockMs;  // client_time_ms: wall clock, milliseconds
  }
  next(seq) {
    this.seq = seq === undefined ? this.seq + 1 : Math.max(seq, this.seq + 1);
    return this.seq;
  }
  #stamped(type) {
    return { v: PROTOCOL_VERSION, type, seq: this.next(), client_time_ms: this.clockMs(), device: this.device };
  }
  pose(position, quaternion, engaged, gripper, seq) {
    return {
      v: PROTOCOL_VERSION, type: "pose", seq: this.next(seq), client_time_ms: this.clockMs(), device: this.device,
      position: position.map(Number), quaternion: quaternion.map(Number),
      engaged: Boolean(engaged), gripper: Boolean(gripper),
    };
  }
  clutch(engaged) { return { ...this.#stamped("clutch"), engaged: Boolean(engaged) }; }
  gripper(closed) { return { ...this.#stamped("gripper"), closed: Boolean(closed) }; }
  request(type) { return { v: PROTOCOL_VERSION, type }; }  // "reset", "start", "stop", "skip_practice"
  reset() { return this.request("reset"); }
  start() { return this.request("start"); }
  stop() { return this.request("stop"); }
  skipPractice() { return this.request("skip_practice"); }
  takeControl() { return { v: PROTOCOL_VERSION, type: "take_control", device: this.device }; }
  ping(id) { return { v: PROTOCOL_VERSION, type: "ping", id, client_time_ms: this.clockMs() }; }
  // The answer to the server's ping echoes its id and clock, stamped with ours: the server
  // learns how far our clock is from its own, and so how old each pose is when it arrives.
  pong(serverPing) {
    return { v: PROTOCOL_VERSION, type: "pong", id: serverPing.id, server_time_s: serverPing.server_time_s,
             client_time_ms: this.clockMs() };
  }
  // Our video stopped (no new frame for the hello's video_stall_ms) or came back.
  videoStatus(stalled, gapMs) {
    return { v: PROTOCOL_VERSION, type: "video", stalled: Boolean(stalled), gap_ms: Math.max(0, Math.round(gapMs)) };
  }
  // A sample over a minute is a stalled tab, not a latency: left out. Negative ones are clock
  // granularity: zero.
  latency(samplesMs, fps) {
    const samples = samplesMs.filter((x) => Number.isFinite(x) && x <= MAX_LATENCY_MS)
      .slice(0, MAX_LATENCY_SAMPLES).map((x) => Math.max(0, x));
    const rate = Number.isFinite(fps) ? Math.min(Math.max(fps, 0), MAX_FPS) : 0;
    return { v: PROTOCOL_VERSION, type: "latency", samples_ms: samples, fps: rate };
  }
}
