// The join / consent page: the study's ids come from the link; agreeing gets a worker token.

import { call, worker } from "./api.js";
import { showPreparing } from "./preparing.js";
import { RTTS_PARAM, chooseRegion, decodeRoundTrips, joinUrlAt, measure, roundTrips } from "./region.js";

const $ = (id) => document.getElementById(id);

const minutes = (s) => Math.max(1, Math.round(s / 60));
const LOOK_AGAIN_MS = 2000;  // how often the page asks again while a robot is being prepared

// Whether a robot is ready for a worker who starts now, or how long until one is (a warm
// spare starting, or a start after the click); all busy: the queue says the wait. Asked again
// until one is ready, counting down in between.
function showRobot(c, askedMs) {
  const text = showPreparing($("preparing"), c.robot, Date.now(), askedMs);
  $("robot").textContent = c.robot ? text : "All robots are busy: after Start you will see your place in line.";
}

async function watchRobot(name, campaign) {
  let c = campaign, askedMs = Date.now();
  const tick = setInterval(() => showRobot(c, askedMs), 250);
  while (c && c.robot && c.robot.eta_s > 0) {
    await new Promise((resolve) => setTimeout(resolve, LOOK_AGAIN_MS));
    try { c = await call(`/api/campaigns/${encodeURIComponent(name)}`); askedMs = Date.now(); }
    catch { break; }
  }
  showRobot(c, askedMs);
  clearInterval(tick);
}

// What the study asks, before anyone agrees: the task, how many demonstrations, how long.
// Returns the campaign (null when the link names none here).
async function showCampaign(name) {
  try {
    const c = await call(`/api/campaigns/${encodeURIComponent(name)}`);
    $("title").textContent = c.title;
    $("instructions").textContent = `${c.instructions} Read the consent below, then start.`;
    $("required").textContent = String(c.demos_required);
    $("duration").textContent = c.typical_session_s
      ? `, usually about ${minutes(c.typical_session_s)} min (at most ${minutes(c.time_limit_s)} min)`
      : `, at most ${minutes(c.time_limit_s)} min`;
    return c;
  } catch (error) {
    if (error.code === "unknown_campaign") {
      $("banner").className = "banner error show";
      $("banner").textContent = "This study link names no study here: please check the link.";
    }
    return null;
  }
}

// A campaign served from several regions: time each, and go to the nearest with a free robot
// unless that is here. Returns the round trips to record (null without regions, undefined when
// leaving); a link that carries them was sent here by another region's page, so it stays.
async function placeWorker(campaign, carried) {
  if (!campaign || campaign.regions.length < 2) return null;
  if (carried !== undefined) return decodeRoundTrips(carried);
  const text = $("instructions").textContent;
  $("instructions").textContent = "Finding the nearest server…";
  const measured = await Promise.all(campaign.regions.map((region) => measure(region)));
  const chosen = chooseRegion(measured);
  const rtts = roundTrips(measured);
  if (chosen && chosen.name !== campaign.region) {
    location.replace(joinUrlAt(chosen, location.search, rtts));
    return undefined;
  }
  $("instructions").textContent = text;
  return rtts;
}

async function main() {
  const params = Object.fromEntries(new URLSearchParams(location.search));
  const campaign = params.campaign || null;
  const carried = params[RTTS_PARAM];
  delete params.campaign;
  delete params[RTTS_PARAM];
  let placed = false; // Start waits for the region's choice (at once without regions)
  const allow = () => { $("agree").disabled = !placed || !$("consent").checked; };
  $("consent").onchange = allow;
  $("instructions").textContent = "Read the consent below, then start.";
  const shown = await showCampaign(campaign || "default");
  const rtts = await placeWorker(shown, carried);
  if (rtts === undefined) return;
  if (shown) watchRobot(campaign || "default", shown);
  placed = true;
  allow();
  // The token this tab was given before proves a rejoin is the same browser; another browser
  // with the same study id is refused while the session is live, unless it takes over.
  const earlier = worker.load();
  const join = async (takeOver) => {
    $("agree").disabled = true;
    $("take-over").hidden = true;
    try {
      const body = { params, campaign, take_over: takeOver };
      if (earlier && earlier.worker_token) body.worker_token = earlier.worker_token;
      if (rtts) body.region_rtts_ms = rtts;
      const joined = await call("/api/join", { method: "POST", body });
      worker.save(joined);
      location.assign("/teleop");
    } catch (error) {
      $("banner").className = "banner error show";
      $("banner").textContent = error.message;
      $("agree").disabled = false;
      if (error.code === "in_use") $("take-over").hidden = false;
    }
  };
  $("agree").onclick = () => join(false);
  $("take-over").onclick = () => join(true);
}

main();
