// The teleop message protocol, shared with the server: the server publishes its JSON Schema at
// /protocol.json (generated from crowdteleop/teleop/protocol.py); `loadProtocol` checks that the
// schema knows every message this file builds, so server and page cannot drift apart silently.

export const PROTOCOL_VERSION = 1;

export const CLIENT_MESSAGES = {
  control: ["pose"],
  events: ["clutch", "gripper", "reset", "start", "stop", "take_control", "ping", "pong", "latency"],
};

function typesIn(schema) {
  const types = new Set();
  for (const def of Object.values(schema.$defs || {})) {
    const tag = def.properties && def.properties.type;
    if (tag && tag.const) types.add(tag.const);
  }
  const own = schema.properties && schema.properties.type;
  if (own && own.const) types.add(own.const);
  return types;
}

export async function loadProtocol(base = "") {
  const response = await fetch(`${base}/protocol.json`);
  if (!response.ok) throw new Error(`protocol schema unavailable (${response.status})`);
  const schema = await response.json();
  if (schema.version !== PROTOCOL_VERSION) {
    throw new Error(`server speaks protocol ${schema.version}, this page ${PROTOCOL_VERSION}`);
  }
  for (const [channel, types] of Object.entries(CLIENT_MESSAGES)) {
    const known = typesIn(schema.channels[channel]);
    for (const type of types) {
      if (!known.has(type)) throw new Error(`protocol mismatch: ${channel}/${type} unknown`);
    }
  }
  return schema;
}

// One sequence counter per device: the server keeps the newest message of the controlling
// device and drops older ones, across both channels.
export class MessageFactory {
  constructor(device) {
    this.device = device;
    this.seq = 0;
  }
  next(seq) {
    this.seq = seq === undefined ? this.seq + 1 : Math.max(seq, this.seq + 1);
    return this.seq;
  }
  pose(position, quaternion, engaged, gripper, seq) {
    return {
      v: PROTOCOL_VERSION, type: "pose", seq: this.next(seq), t: Date.now(), device: this.device,
      position: position.map(Number), quaternion: quaternion.map(Number),
      engaged: Boolean(engaged), gripper: Boolean(gripper),
    };
  }
  clutch(engaged) {
    return { v: PROTOCOL_VERSION, type: "clutch", seq: this.next(), t: Date.now(),
             device: this.device, engaged: Boolean(engaged) };
  }
  gripper(closed) {
    return { v: PROTOCOL_VERSION, type: "gripper", seq: this.next(), t: Date.now(),
             device: this.device, closed: Boolean(closed) };
  }
  request(type) {
    return { v: PROTOCOL_VERSION, type };
  }
  takeControl() {
    return { v: PROTOCOL_VERSION, type: "take_control", device: this.device };
  }
}
