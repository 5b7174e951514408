// The admin page: live sessions, the queue, teleop servers, demonstration figures, and the
// charts of the last 24 hours (admin_charts.js).

import { AdminCharts } from "./admin_charts.js";
import { call } from "./api.js";

const CHARTS_EVERY_MS = 30000; // the charts' bins are hours: a refresh each half minute is plenty

const $ = (id) => document.getElementById(id);

// Built with textContent, never markup: worker ids and campaign names come from the crowd.
function row(cells, tag = "td") {
  const tr = document.createElement("tr");
  for (const value of cells) {
    const cell = document.createElement(tag);
    cell.textContent = value;
    tr.append(cell);
  }
  return tr;
}

function table(element, rows, columns) {
  const text = (value) => (typeof value === "number" ? String(Number.isInteger(value) ? value : value.toFixed(1)) : String(value ?? "–"));
  const lines = [row(columns.map(([, label]) => label), "th")];
  for (const item of rows) lines.push(row(columns.map(([key]) => text(item[key]))));
  if (!rows.length) {
    const empty = row(["none"]);
    empty.firstChild.colSpan = columns.length;
    empty.firstChild.className = "muted";
    lines.push(empty);
  }
  element.replaceChildren(...lines);
}

async function refresh(token) {
  const o = await call("/api/admin/overview", { token });
  $("totals").textContent = Object.entries(o.totals || {}).map(([k, v]) => `${k}: ${v}`).join(" · ")
    + ` · capacity ${o.capacity}`;
  const session = [["session_id", "session"], ["worker_id", "worker"], ["campaign", "campaign"],
    ["state", "state"], ["task", "task"], ["controller", "controller"], ["interface", "interface"],
    ["demos_done", "done"], ["demos_required", "required"], ["rtt_ms", "round trip ms"]];
  table($("sessions"), o.sessions, session);
  table($("queue"), o.queue, [["queue_position", "position"], ...session]);
  table($("servers"), o.teleop_servers, [["session_id", "session"], ["url", "url"], ["pid", "pid"], ["alive", "alive"]]);
  const summary = [["key", ""], ["successes", "successes"], ["episodes", "episodes"], ["mean_s", "mean s"],
    ["median_s", "median s"], ["min_s", "min s"], ["max_s", "max s"]];
  table($("per-worker"), o.completion_time_per_worker, summary);
  table($("per-interface"), o.completion_time_per_interface, summary);
  const refusals = Object.entries(o.refusals || {}).map(([reason, count]) => ({ reason, count }));
  table($("refusals"), refusals, [["reason", "refused by"], ["count", "since start"]]);
  $("restarts").textContent = `${o.restarts} sessions given a new teleop server since start`;
}

async function refreshCharts(token, charts) {
  charts.update(await call("/api/admin/charts?hours=24", { token }));
  $("charts-note").textContent = "";
}

async function open(token) {
  try {
    await refresh(token);
  } catch (error) {
    $("banner").className = "banner error show";
    $("banner").textContent = error.status === 401 ? "Wrong admin token." : error.message;
    return;
  }
  sessionStorage.setItem("crowdteleop.admin", token);
  $("login").hidden = true;
  $("overview").hidden = false;
  setInterval(() => refresh(token).catch(() => {}), 2000);
  // Drawn once the overview is shown: the charts take their boxes' widths.
  const charts = new AdminCharts($("overview"));
  const drawCharts = () => refreshCharts(token, charts).catch((error) => {
    $("charts-note").textContent = `(could not load: ${error.message})`;
  });
  await drawCharts();
  setInterval(drawCharts, CHARTS_EVERY_MS);
}

$("login").addEventListener("submit", (e) => { e.preventDefault(); open($("token").value); });
const saved = sessionStorage.getItem("crowdteleop.admin");
if (saved) open(saved);
