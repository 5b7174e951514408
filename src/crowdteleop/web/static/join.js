// The join / consent page: the study's ids come from the link; agreeing gets a worker token.

import { call, worker } from "./api.js";

const $ = (id) => document.getElementById(id);

async function main() {
  const params = Object.fromEntries(new URLSearchParams(location.search));
  const campaign = params.campaign || null;
  delete params.campaign;
  $("consent").onchange = () => { $("agree").disabled = !$("consent").checked; };
  $("instructions").textContent = "Read the consent below, then start.";
  $("agree").onclick = async () => {
    $("agree").disabled = true;
    try {
      const joined = await call("/api/join", { method: "POST", body: { params, campaign } });
      worker.save(joined);
      location.assign("/teleop");
    } catch (error) {
      $("banner").className = "banner error show";
      $("banner").textContent = error.message;
      $("agree").disabled = false;
    }
  };
}

main();
