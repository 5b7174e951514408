// The coordinator's HTTP API, as the pages use it. Errors carry the server's message.

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
