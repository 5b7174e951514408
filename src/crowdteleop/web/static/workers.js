// The workers page: each worker's figures and reputation in a sortable table, one worker's
// demonstrations with their score, flags and review decision, and blocking (docs/workers.md).

import { call } from "./api.js";

const $ = (id) => document.getElementById(id);
const REFRESH_MS = 10000;
const percent = (x) => (x === null || x === undefined ? "–" : `${Math.round(x * 100)}%`);
const number = (x) => (x === null || x === undefined ? "–" : String(Number.isInteger(x) ? x : x.toFixed(1)));
const flagCount = (w) => Object.values(w.stats.flags).reduce((a, b) => a + b, 0);

// [label, value for sorting, text shown]
const COLUMNS = [
  ["worker", (w) => w.worker_id, (w) => w.worker_id],
  ["source", (w) => w.source, (w) => w.source],
  ["study id", (w) => w.external_id ?? "", (w) => w.external_id ?? "–"],
  ["reputation", (w) => w.reputation, (w) => w.reputation.toFixed(1)],
  ["demos", (w) => w.stats.demonstrations, (w) => number(w.stats.demonstrations)],
  ["success", (w) => w.stats.success_rate, (w) => percent(w.stats.success_rate)],
  ["median score", (w) => w.stats.median_score, (w) => number(w.stats.median_score)],
  ["accepted", (w) => w.stats.accepted, (w) => number(w.stats.accepted)],
  ["rejected", (w) => w.stats.rejected, (w) => number(w.stats.rejected)],
  ["awaiting", (w) => w.stats.undecided, (w) => number(w.stats.undecided)],
  ["acceptance", (w) => w.stats.acceptance_rate, (w) => percent(w.stats.acceptance_rate)],
  ["flags", flagCount, (w) => number(flagCount(w))],
  ["s per demo", (w) => w.stats.median_time_s, (w) => number(w.stats.median_time_s)],
  ["blocked", (w) => w.blocked_at ?? 0, (w) => (w.blocked_at ? "blocked" : "")],
];

const state = { token: null, workers: [], sort: 3, descending: true, chosen: null };

// Built with textContent, never markup: ids and reasons come from the crowd.
function cells(tag, values) {
  const tr = document.createElement("tr");
  for (const value of values) {
    const cell = document.createElement(tag);
    cell.textContent = value;
    tr.append(cell);
  }
  return tr;
}

function compare(a, b) {
  const [, key] = COLUMNS[state.sort];
  const [x, y] = [key(a), key(b)];
  if (x === y) return 0;
  if (x === null || x === undefined) return 1; // unknown figures last, either way
  if (y === null || y === undefined) return -1;
  const order = x < y ? -1 : 1;
  return state.descending ? -order : order;
}

function header() {
  const tr = cells("th", COLUMNS.map(([label]) => label));
  [...tr.children].forEach((th, index) => {
    th.dataset.column = String(index);
    if (index === state.sort) th.setAttribute("aria-sort", state.descending ? "descending" : "ascending");
    th.addEventListener("click", () => {
      state.descending = index === state.sort ? !state.descending : index >= 3;
      state.sort = index;
      drawTable();
    });
  });
  return tr;
}

function drawTable() {
  const head = document.createElement("thead");
  head.append(header());
  const body = document.createElement("tbody");
  for (const w of [...state.workers].sort(compare)) {
    const tr = cells("td", COLUMNS.map(([, , text]) => text(w)));
    tr.dataset.worker = w.worker_id;
    if (w.blocked_at) tr.classList.add("blocked");
    if (w.worker_id === state.chosen) tr.classList.add("chosen");
    tr.addEventListener("click", () => openWorker(w.worker_id));
    body.append(tr);
  }
  $("workers").replaceChildren(head, body);
  $("count").textContent = `${state.workers.length} workers`;
}

async function refresh() {
  state.workers = await call("/api/admin/workers", { token: state.token });
  drawTable();
}

function drawDetail(w) {
  $("detail").hidden = false;
  $("detail-title").textContent = `${w.worker_id} (${w.source}${w.external_id ? ` ${w.external_id}` : ""})`;
  $("detail-status").textContent = w.blocked_at
    ? `blocked ${new Date(w.blocked_at * 1000).toLocaleString()}${w.blocked_reason ? `: ${w.blocked_reason}` : ""}`
    : `reputation ${number(w.reputation)}`;
  const s = w.stats;
  const flags = Object.entries(s.flags).map(([metric, n]) => `${metric} ×${n}`).join(", ") || "none";
  const figures = [["episodes", number(s.episodes)], ["demonstrations", number(s.demonstrations)],
    ["success rate", percent(s.success_rate)], ["median score", number(s.median_score)],
    ["accepted / rejected / awaiting", `${s.accepted} / ${s.rejected} / ${s.undecided}`],
    ["acceptance rate", percent(s.acceptance_rate)], ["flags", flags],
    ["median time per demonstration", s.median_time_s === null ? "–" : `${number(s.median_time_s)} s`]];
  $("detail-stats").replaceChildren(...figures.flatMap(([k, v]) => {
    const [a, b] = [document.createElement("span"), document.createElement("span")];
    a.className = "muted";
    a.textContent = k;
    b.textContent = v;
    return [a, b];
  }));
  $("block").hidden = Boolean(w.blocked_at);
  $("block-reason").hidden = Boolean(w.blocked_at);
  $("unblock").hidden = !w.blocked_at;
  const rows = w.episodes.map((e) => {
    const tr = cells("td", [e.episode_id, String(e.number), e.outcome, number(e.duration_s), number(e.score),
      (e.flags || []).map((f) => f.reason).join("; ") || "–", e.decision || "undecided"]);
    if (e.decision) tr.lastChild.className = e.decision;
    return tr;
  });
  $("episodes").replaceChildren(cells("th", ["episode", "#", "outcome", "s", "score", "flags", "decision"]), ...rows);
}

async function openWorker(id) {
  state.chosen = id;
  drawTable();
  const worker = await call(`/api/admin/workers/${encodeURIComponent(id)}`, { token: state.token });
  // Two rows clicked quickly: the first answer, arriving last, must not show one worker while
  // Block acts on the other.
  if (state.chosen === id) drawDetail(worker);
}

async function setBlocked(blocked) {
  const id = state.chosen;
  const path = `/api/admin/workers/${encodeURIComponent(id)}/${blocked ? "block" : "unblock"}`;
  const body = blocked ? { reason: $("block-reason").value } : undefined;
  drawDetail(await call(path, { method: "POST", token: state.token, body }));
  $("block-reason").value = "";
  await refresh();
}

function showError(error) {
  $("banner").className = "banner error show";
  $("banner").textContent = error.status === 401 ? "Wrong admin token." : error.message;
}

async function open(token) {
  state.token = token;
  try {
    await refresh();
  } catch (error) {
    showError(error);
    return;
  }
  $("banner").className = "banner";
  sessionStorage.setItem("crowdteleop.admin", token);
  $("login").hidden = true;
  $("workers-view").hidden = false;
  setInterval(() => refresh().catch(() => {}), REFRESH_MS);
}

$("login").addEventListener("submit", (e) => { e.preventDefault(); open($("token").value); });
$("block-form").addEventListener("submit", (e) => { e.preventDefault(); setBlocked(true).catch(showError); });
$("unblock").addEventListener("click", () => setBlocked(false).catch(showError));
const saved = sessionStorage.getItem("crowdteleop.admin");
if (saved) open(saved);
