// The teleop page's marker for the phone's camera mode (marker.js, docs/phone.md): drawn from
// the vendored js-aruco2 dictionary the phone detects with, so the two cannot disagree.

import { MARKER_DICTIONARY, MARKER_ID, drawMarker } from "./marker.js";

const canvas = document.getElementById("marker");
if (canvas && window.AR) {
  drawMarker(canvas, new window.AR.Dictionary(MARKER_DICTIONARY).codeList[MARKER_ID]);
}
