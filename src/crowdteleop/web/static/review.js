// The reviewer page (docs/review.md): a grid of episodes with filters and sorts; a click plays
// the episode (rendered from its recorded states by the coordinator), seekable, at 1x to 4x;
// accept (a), reject with a reason (r), undo (u), next and previous (j, k). Each decision is
// made against the decision count this page saw, so a reviewer who was quicker is reported
// ("decided by bob meanwhile") instead of overwritten. Answers are checked against the served
// JSON Schema of their views (api.js).

import { viewProblems } from "./api.js";

const $ = (id) => document.getElementById(id);
const PAGE = 48;
const number = (x) => (x === null || x === undefined ? "–" : String(Number.isInteger(x) ? x : x.toFixed(1)));

// `loads` numbers the grid's requests: filters changed quickly send several, and an older
// answer arriving last must not draw over the newer one.
const state = { token: null, reviewer: null, episodes: [], total: 0, chosen: null, loads: 0 };

class RequestError extends Error {
  constructor(status, payload) {
    super((payload && payload.message) || `request failed (${status})`);
    this.status = status;
    this.payload = payload;
  }
}

async function request(path, { method = "GET", body } = {}) {
  const headers = { "Content-Type": "application/json", Authorization: `Bearer ${state.token}` };
  const response = await fetch(path, { method, headers, body: body && JSON.stringify(body) });
  let payload = null;
  try { payload = await response.json(); } catch { payload = null; }
  if (!response.ok) throw new RequestError(response.status, payload);
  // Checked against the served JSON Schema (/views.json): a page and a server that drifted
  // apart say so instead of acting on what they misread.
  const problems = await viewProblems(path, payload);
  if (problems.length) throw new RequestError(response.status, { message: problems.slice(0, 3).join("; ") });
  return payload;
}

function say(text, kind = "info") {
  $("banner").className = `banner ${kind} show`;
  $("banner").textContent = text;
}

function quiet() { $("banner").className = "banner"; }

function showError(error) {
  if (error.status === 401) say("Wrong or missing token: a reviewer's token or the admin token.", "error");
  else say(error.message, "error");
}

// --- the grid -------------------------------------------------------------------------------

function query(offset) {
  const params = new URLSearchParams();
  for (const [name, value] of new FormData($("filters"))) if (String(value).trim()) params.set(name, String(value).trim());
  params.set("limit", String(PAGE));
  params.set("offset", String(offset));
  return params.toString();
}

function badge(decision) {
  const span = document.createElement("span");
  span.className = `badge ${decision || "undecided"}`;
  span.textContent = decision || "undecided";
  return span;
}

function text(tag, value, className) {
  const element = document.createElement(tag);
  element.textContent = value;
  if (className) element.className = className;
  return element;
}

// Built with textContent, never markup: ids and reasons come from the crowd.
function card(episode) {
  const div = document.createElement("div");
  div.className = "card";
  div.tabIndex = 0;
  div.dataset.episode = episode.episode_id;
  if (episode.episode_id === state.chosen) div.classList.add("chosen");
  const img = document.createElement("img");
  img.loading = "lazy";
  img.alt = "";
  img.src = episode.thumbnail_url;
  img.addEventListener("error", () => img.classList.add("missing"));
  const flags = (episode.flags || []).map((f) => f.reason).join("; ");
  div.append(img, text("div", `${episode.task} · ${episode.worker_id}`, "card-title"),
    text("div", `score ${number(episode.score)} · ${episode.outcome} · ${number(episode.duration_s)} s`, "muted small"),
    text("div", flags, "flags small"), badge(episode.decision));
  div.addEventListener("click", () => choose(episode.episode_id));
  return div;
}

function drawGrid() {
  $("grid").replaceChildren(...state.episodes.map(card));
  $("count").textContent = `${state.total} episode${state.total === 1 ? "" : "s"}`;
  $("more").hidden = state.episodes.length >= state.total;
}

async function load(more = false) {
  const mine = ++state.loads;
  const page = await request(`/api/review/episodes?${query(more ? state.episodes.length : 0)}`);
  if (mine !== state.loads) return;
  state.episodes = more ? [...state.episodes, ...page.episodes] : page.episodes;
  state.total = page.total;
  drawGrid();
}

function reload() { load().then(quiet, showError); }

// --- one episode ----------------------------------------------------------------------------

function current() { return state.detail && state.detail.episode_id === state.chosen ? state.detail : null; }

function drawDetail(episode) {
  state.detail = episode;
  const index = state.episodes.findIndex((e) => e.episode_id === episode.episode_id);
  if (index >= 0) state.episodes[index] = { ...state.episodes[index], ...episode };
  drawGrid();
  $("title").replaceChildren(text("span", `${episode.episode_id} `), badge(episode.decision));
  const flags = (episode.flags || []).map((f) => f.reason).join("; ") || "none";
  const facts = [["task", episode.task], ["worker", episode.worker_id], ["outcome", episode.outcome],
    ["score", number(episode.score)], ["duration", `${number(episode.duration_s)} s`], ["flags", flags],
    ["recorded", new Date(episode.created_at * 1000).toLocaleString()]];
  $("facts").replaceChildren(...facts.flatMap(([k, v]) => [text("span", k, "muted"), text("span", v)]));
  $("history").replaceChildren(...episode.history.map((h) => {
    const what = h.decision ? h.decision : "undecided (undone)";
    const li = text("li", `${what} by ${h.reviewer}${h.automatic ? " (automatic)" : ""} · ${new Date(h.at * 1000).toLocaleString()}`);
    li.dataset.decision = h.decision || "";
    if (h.reason) li.append(text("span", ` · ${h.reason}`, "muted"));
    return li;
  }));
}

async function choose(id) {
  state.chosen = id;
  $("reject-form").hidden = true;
  $("player").hidden = false;
  const episode = await request(`/api/review/episodes/${encodeURIComponent(id)}`);
  if (state.chosen !== id) return; // j pressed twice: the first answer came after the second choice
  drawDetail(episode);
  $("video-status").textContent = "rendering the episode from its recorded states…";
  const video = $("video");
  video.src = episode.video_url;
  video.playbackRate = 1;
  video.play().catch(() => {});
  document.querySelector(`.card[data-episode="${CSS.escape(id)}"]`)?.scrollIntoView({ block: "nearest" });
}

function step(by) {
  if (!state.episodes.length) return;
  const index = state.episodes.findIndex((e) => e.episode_id === state.chosen);
  const next = Math.min(state.episodes.length - 1, Math.max(0, index < 0 ? 0 : index + by));
  choose(state.episodes[next].episode_id).catch(showError);
}

async function decide(path, body) {
  const episode = current();
  if (!episode) return;
  try {
    const decided = await request(`/api/review/episodes/${encodeURIComponent(episode.episode_id)}/${path}`,
      { method: "POST", body: { ...body, expected_seq: episode.review_seq } });
    drawDetail(decided.episode);
    say(`${decided.episode.episode_id}: ${decided.decision.decision || "undecided"}`, "done");
  } catch (error) {
    if (error.status === 409 && error.payload && error.payload.episode) {
      drawDetail(error.payload.episode);
      say(error.message, "error");  // "decided by bob (rejected) meanwhile: ..."
    } else {
      showError(error);
    }
  }
}

function askReason() {
  $("reject-form").hidden = false;
  $("reason").value = "";
  $("reason").focus();
}

// --- the player -----------------------------------------------------------------------------

function bindPlayer() {
  const video = $("video");
  video.addEventListener("loadeddata", () => { $("video-status").textContent = ""; });
  video.addEventListener("error", () => {
    if (!video.getAttribute("src")) return;
    fetch(video.src).then((r) => r.json()).then((p) => { $("video-status").textContent = p.message; })
      .catch(() => { $("video-status").textContent = "the video could not be played"; });
  });
  video.addEventListener("timeupdate", () => {
    if (video.duration) $("seek").value = String(Math.round((video.currentTime / video.duration) * 1000));
    $("time").textContent = `${video.currentTime.toFixed(1)} / ${number(video.duration || 0)} s`;
  });
  video.addEventListener("play", () => { $("play").textContent = "Pause"; });
  video.addEventListener("pause", () => { $("play").textContent = "Play"; });
  $("seek").addEventListener("input", () => {
    if (video.duration) video.currentTime = (Number($("seek").value) / 1000) * video.duration;
  });
  $("play").addEventListener("click", togglePlay);
  for (const button of document.querySelectorAll(".rate")) {
    button.addEventListener("click", () => setRate(Number(button.dataset.rate)));
  }
}

function togglePlay() {
  const video = $("video");
  if (video.paused) video.play().catch(() => {}); else video.pause();
}

function setRate(rate) {
  $("video").playbackRate = rate;
  for (const button of document.querySelectorAll(".rate")) {
    button.classList.toggle("on", Number(button.dataset.rate) === rate);
  }
}

// --- keys -----------------------------------------------------------------------------------

const KEYS = {
  a: () => decide("decision", { decision: "accepted", reason: "" }),
  r: askReason,
  u: () => decide("undo", {}),
  j: () => step(1),
  k: () => step(-1),
  " ": togglePlay,
};

function onKey(event) {
  const typing = event.target instanceof HTMLInputElement || event.target instanceof HTMLSelectElement;
  if (event.key === "Escape") { $("reason").blur(); $("reject-form").hidden = true; return; }
  if (typing || event.ctrlKey || event.metaKey || event.altKey || $("review-view").hidden) return;
  const action = KEYS[event.key];
  if (!action || (event.key !== "j" && event.key !== "k" && !current())) return;
  event.preventDefault();
  action();
}

// --- start ----------------------------------------------------------------------------------

async function open(token) {
  state.token = token;
  try {
    state.reviewer = (await request("/api/review/me")).reviewer;
    await load();
  } catch (error) {
    showError(error);
    return;
  }
  quiet();
  sessionStorage.setItem("crowdteleop.review", token);
  $("who").textContent = `reviewing as ${state.reviewer}`;
  $("login").hidden = true;
  $("review-view").hidden = false;
}

let typingTimer = null;
$("filters").addEventListener("change", reload);
$("filters").addEventListener("input", (event) => {
  if (!(event.target instanceof HTMLInputElement)) return;
  clearTimeout(typingTimer);
  typingTimer = setTimeout(reload, 400);
});
$("filters").addEventListener("submit", (e) => { e.preventDefault(); reload(); });
$("more").addEventListener("click", () => load(true).catch(showError));
$("accept").addEventListener("click", KEYS.a);
$("reject").addEventListener("click", askReason);
$("undo").addEventListener("click", KEYS.u);
$("reject-form").addEventListener("submit", (e) => {
  e.preventDefault();
  $("reason").blur();  // the keys are the page's again
  $("reject-form").hidden = true;
  decide("decision", { decision: "rejected", reason: $("reason").value });
});
$("login").addEventListener("submit", (e) => { e.preventDefault(); open($("token").value); });
document.addEventListener("keydown", onKey);
bindPlayer();
const saved = sessionStorage.getItem("crowdteleop.review");
if (saved) open(saved);
