// What the join and teleop pages say while a robot (its teleop server) is being prepared:
// "Preparing your robot… about N s" and a progress bar, from the coordinator's estimate
// (`preparing` of the session, `robot` of the campaign: {eta_s, total_s}; its measured start
// times). Between two answers the page counts down by itself.

// The sentence for an estimate (null: none, as a session not starting has).
export function preparingText(estimate, nowMs = 0, sinceMs = 0) {
  if (!estimate) return "Preparing your robot…";
  const left = remainingS(estimate, nowMs, sinceMs);
  if (estimate.eta_s <= 0) return "A robot is ready for you.";
  return `Preparing your robot… about ${Math.max(1, Math.round(left))} s`;
}

// Seconds left of `estimate`, given `sinceMs - nowMs` ms passed since it came (at least 1 s
// while it is not ready: an estimate is never "now" until the robot is).
export function remainingS(estimate, nowMs = 0, sinceMs = 0) {
  if (!estimate || estimate.eta_s <= 0) return 0;
  return Math.max(1, estimate.eta_s - Math.max(0, nowMs - sinceMs) / 1000);
}

// The progress bar's value and maximum, in seconds of the start (null: hide the bar).
export function progressOf(estimate, nowMs = 0, sinceMs = 0) {
  if (!estimate || estimate.eta_s <= 0 || !(estimate.total_s > 0)) return null;
  const total = Math.max(estimate.total_s, estimate.eta_s);
  return { value: total - remainingS(estimate, nowMs, sinceMs), max: total };
}

// Shows `estimate` in a <progress> (hidden without one) and returns the sentence for it.
export function showPreparing(bar, estimate, nowMs = 0, sinceMs = 0) {
  const progress = progressOf(estimate, nowMs, sinceMs);
  bar.hidden = progress === null;
  if (progress) { bar.max = progress.max; bar.value = progress.value; }
  return preparingText(estimate, nowMs, sinceMs);
}
