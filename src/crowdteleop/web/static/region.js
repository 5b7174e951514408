// Regions: a campaign served from several places sends each worker to the nearest one with a
// free robot. Every region's coordinator answers GET /api/ping (any origin may ask); the join
// page times a few of them per region, all regions at once, and goes where `chooseRegion` says.

export const PINGS = 4; // the first opens the connection (DNS, TCP, TLS): only the rest are timed
export const PING_TIMEOUT_MS = 2000;
export const RTTS_PARAM = "region_rtts"; // how the round trips travel to the chosen region

const median = (values) => {
  const sorted = [...values].sort((a, b) => a - b);
  const middle = Math.floor(sorted.length / 2);
  return sorted.length % 2 ? sorted[middle] : (sorted[middle - 1] + sorted[middle]) / 2;
};

// How long the browser's network stack waited for a ping's answer (request sent to first byte,
// from Resource Timing; the ping allows it with Timing-Allow-Origin), or null where it does not
// say. Timed by the page instead, a busy main thread (a page still loading its modules, video
// being decoded) adds its own delay to the promise and the page measures itself, not distance.
export function networkTiming(url, since) {
  const entries = globalThis.performance?.getEntriesByName?.(url, "resource") ?? [];
  const entry = entries.at(-1);
  if (!entry || entry.startTime < since || !(entry.requestStart > 0) || !(entry.responseStart > 0)) {
    return null;
  }
  return entry.responseStart - entry.requestStart;
}

// One region's round trip (median of the timed pings, ms) and how free it is; `error` instead
// when it cannot be reached in time or answers something else.
export async function measure(region, { pings = PINGS, timeoutMs = PING_TIMEOUT_MS,
                                        fetchImpl = fetch, now = () => performance.now(),
                                        timing = networkTiming } = {}) {
  const url = new URL("/api/ping", region.url).href;
  const times = [];
  let last = null;
  for (let i = 0; i < pings; i++) {
    const abort = new AbortController();
    const timer = setTimeout(() => abort.abort(), timeoutMs);
    try {
      const start = now();
      const response = await fetchImpl(url, { cache: "no-store", mode: "cors", signal: abort.signal });
      last = await response.json();
      if (i > 0 || pings === 1) times.push(timing(url, start) ?? now() - start);
      if (!response.ok) return { ...region, error: `HTTP ${response.status}` };
    } catch (error) {
      return { ...region, error: error.name === "AbortError" ? "timed out" : String(error.message || error) };
    } finally {
      clearTimeout(timer);
    }
  }
  return { ...region, rtt_ms: Math.round(median(times) * 10) / 10,
           free_slots: last.free_slots, queued: last.queued, capacity: last.capacity };
}

// The nearest region with a robot free for a new worker (more free than waiting); when none
// has one, the shortest wait per robot, the nearer on a tie; null when none answered.
export function chooseRegion(measured) {
  const reachable = measured.filter((m) => Number.isFinite(m.rtt_ms));
  if (!reachable.length) return null;
  const nearer = (a, b) => a.rtt_ms - b.rtt_ms;
  const free = reachable.filter((m) => m.free_slots > m.queued).sort(nearer);
  if (free.length) return free[0];
  const wait = (m) => (m.queued - m.free_slots + 1) / Math.max(1, m.capacity);
  return [...reachable].sort((a, b) => wait(a) - wait(b) || nearer(a, b))[0];
}

// {name: rtt_ms} of the regions that answered: what the join records.
export const roundTrips = (measured) =>
  Object.fromEntries(measured.filter((m) => Number.isFinite(m.rtt_ms)).map((m) => [m.name, m.rtt_ms]));

// The round trips as one query parameter ("near:12.3,far:181") and back; anything malformed
// in a hand-edited link is dropped, not trusted (the server checks names and ranges again).
export const encodeRoundTrips = (rtts) =>
  Object.entries(rtts).map(([name, ms]) => `${name}:${ms}`).join(",");

export function decodeRoundTrips(text) {
  const rtts = {};
  for (const part of (text || "").split(",").slice(0, 16)) {
    const [name, value] = part.split(":");
    const ms = Number(value);
    if (/^[a-z0-9][a-z0-9_-]{0,31}$/.test(name || "") && Number.isFinite(ms) && ms >= 0 && ms <= 60000) {
      rtts[name] = ms;
    }
  }
  return rtts;
}

// The chosen region's join page, with this link's parameters and the round trips measured.
export function joinUrlAt(region, search, rtts) {
  const params = new URLSearchParams(search);
  params.set(RTTS_PARAM, encodeRoundTrips(rtts));
  return `${new URL("/join", region.url).href}?${params}`;
}
