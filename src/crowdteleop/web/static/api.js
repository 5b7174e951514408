// The coordinator's HTTP API, as the pages use it. Errors carry the server's message. The
// answers the pages act on (a session's view, a campaign's) are checked against their models'
// JSON Schema, served by the coordinator at /views.json (coord/api/schemas.py, PAGE_VIEWS), as
// the teleop messages are against /protocol.json: a page and a server that drifted apart say so.

import { compile } from "./schema.js";

const CHECKED = [
  [/^\/api\/sessions(\/[^/]+(\/heartbeat)?)?$/, "SessionView"],
  [/^\/api\/campaigns\/[^/]+$/, "CampaignView"],
  [/^\/api\/review\/episodes$/, "ReviewPageView"],
  [/^\/api\/review\/episodes\/[^/]+$/, "ReviewEpisodeDetail"],
  [/^\/api\/review\/episodes\/[^/]+\/(decision|undo)$/, "DecidedView"],
];
let views = null;  // name -> validator, once /views.json is loaded

// The problems of `payload` as the answer of `path` (none for paths not checked).
export async function viewProblems(path, payload) {
  const checked = CHECKED.find(([pattern]) => pattern.test(path.split("?")[0]));
  if (!checked) return [];
  if (!views) {
    const schemas = await (await fetch("/views.json")).json();
    views = Object.fromEntries(Object.entries(schemas).map(([name, schema]) => [name, compile(schema)]));
  }
  return views[checked[1]](payload).map((problem) => `${checked[1]}${problem}`);
}

export class ApiError extends Error {
  constructor(status, code, message) { super(message); this.status = status; this.code = code; }
}

export async function call(path, { method = "GET", token, body } = {}) {
  const headers = { "Content-Type": "application/json" };
  if (token) headers.Authorization = `Bearer ${token}`;
  const response = await fetch(path, { method, headers, body: body && JSON.stringify(body) });
  let payload = null;
  try { payload = await response.json(); } catch { payload = null; }
  if (!response.ok) {
    const code = (payload && payload.error) || "http_error";
    const message = (payload && payload.message) || `request failed (${response.status})`;
    throw new ApiError(response.status, code, message);
  }
  const problems = await viewProblems(path, payload);
  if (problems.length) throw new ApiError(response.status, "view_mismatch", problems.slice(0, 3).join("; "));
  return payload;
}

// The worker's join, kept per browser (localStorage: every tab of it), not per tab: its token
// is how a rejoin proves it is the same browser, so a second tab or a reload gets the same
// session, while another browser with the same study id must take it over explicitly.
export const worker = {
  load() {
    const raw = localStorage.getItem("crowdteleop.worker");
    return raw ? JSON.parse(raw) : null;
  },
  save(joined) { localStorage.setItem("crowdteleop.worker", JSON.stringify(joined)); },
};
