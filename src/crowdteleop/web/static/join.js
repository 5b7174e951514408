// The join / consent page: the study's ids come from the link; agreeing gets a worker token.

import { call, worker } from "./api.js";

const $ = (id) => document.getElementById(id);

async function main() {
  const params = Object.fromEntries(new URLSearchParams(location.search));
  const campaign = params.campaign || null;
  delete params.campaign;
  $("consent").onchange = () => { $("agree").disabled = !$("consent").checked; };
  $("instructions").textContent = "Read the consent below, then start.";
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
