// The join / consent page: the study's ids come from the link; agreeing gets a worker token.

import { call, worker } from "./api.js";

const $ = (id) => document.getElementById(id);

const minutes = (s) => Math.max(1, Math.round(s / 60));

// What the study asks, before anyone agrees: the task, how many demonstrations, how long.
async function showCampaign(name) {
  try {
    const c = await call(`/api/campaigns/${encodeURIComponent(name)}`);
    $("title").textContent = c.title;
    $("instructions").textContent = `${c.instructions} Read the consent below, then start.`;
    $("required").textContent = String(c.demos_required);
    $("duration").textContent = c.typical_session_s
      ? `, usually about ${minutes(c.typical_session_s)} min (at most ${minutes(c.time_limit_s)} min)`
      : `, at most ${minutes(c.time_limit_s)} min`;
  } catch (error) {
    if (error.code === "unknown_campaign") {
      $("banner").className = "banner error show";
      $("banner").textContent = "This study link names no study here: please check the link.";
    }
  }
}

async function main() {
  const params = Object.fromEntries(new URLSearchParams(location.search));
  const campaign = params.campaign || null;
  delete params.campaign;
  $("consent").onchange = () => { $("agree").disabled = !$("consent").checked; };
  $("instructions").textContent = "Read the consent below, then start.";
  showCampaign(campaign || "default");
  // The token this tab was given before proves a rejoin is the same browser; another browser
  // with the same study id is refused while the session is live, unless it takes over.
  const earlier = worker.load();
  const join = async (takeOver) => {
    $("agree").disabled = true;
    $("take-over").hidden = true;
    try {
      const body = { params, campaign, take_over: takeOver };
      if (earlier && earlier.worker_token) body.worker_token = earlier.worker_token;
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
