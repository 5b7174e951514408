// The practice round before a worker's first demonstration (crowdteleop/teleop/practice.py):
// the server draws a green ball near the hand and says in each status how long the round has
// left; nothing of it is recorded. This module words it and wires the "Skip practice" button.
// `practiceText` is pure, so node tests check the wording (tests/web/practice.test.mjs).

// What the page says for a status, or null when there is nothing to say about practice.
export function practiceText(status) {
  if (!status || !status.practice || status.practice === "off") return null;
  if (status.practice === "running") {
    const left = Math.max(0, Math.ceil(status.practice_left_s));
    return `Practice (not recorded): move the hand to the green ball — ${left} s left`;
  }
  // Done: said until the first demonstration starts (episode 1 starts on the next move).
  if (status.episode > 0 || status.state !== "ready") return null;
  const praise = status.practice_reached ? "You reached it. " : "";
  return `${praise}Practice done: the next time you move, demonstration 1 starts`;
}

// Show `box` (with the text in `text`) while there is something to say; the button skips.
export function watchPractice(connection, box, text, skip) {
  skip.onclick = () => connection.request("skip_practice");
  connection.addEventListener("status", ({ detail }) => {
    const words = practiceText(detail);
    box.hidden = words === null;
    if (words !== null && text.textContent !== words) text.textContent = words;
    skip.hidden = detail.practice !== "running";
  });
}
