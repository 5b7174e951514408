// The project's Python, for JS tests that need the real thing: the protocol schema generated
// from crowdteleop/teleop/protocol.py for this run (never a copy kept in the repo), and the
// server's own parser as a second opinion on messages.

import { execFileSync } from "node:child_process";
import { fileURLToPath } from "node:url";

export const ROOT = fileURLToPath(new URL("../../", import.meta.url));
const PYTHON = process.env.CROWDTELEOP_PYTHON || `${ROOT}.venv/bin/python`;

export function python(args, input) {
  return execFileSync(PYTHON, args, { cwd: ROOT, encoding: "utf8", input, stdio: ["pipe", "pipe", "inherit"] });
}

export function realSchema() {
  return JSON.parse(python(["-m", "crowdteleop", "protocol-schema"]));
}

const SERVER_VERDICT = `
import json, sys
from crowdteleop.teleop.protocol import ProtocolError, parse_inbound
for line in sys.stdin:
    channel, raw = json.loads(line)
    try:
        parse_inbound(channel, raw, 1 << 20)
        print("ok")
    except ProtocolError as error:
        print(error.code)
`;

// What the teleop server says to each [channel, message]: "ok" or its error code.
export function serverVerdicts(pairs) {
  const lines = pairs.map(([channel, message]) => JSON.stringify([channel, JSON.stringify(message)]));
  return python(["-c", SERVER_VERDICT], lines.join("\n") + "\n").trim().split("\n");
}
