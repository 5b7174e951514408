// The fiducial marker of the phone's camera mode: the teleop page shows it, the phone page finds
// it in its rear camera's image (js-aruco2, vendored) and turns its four corners into the phone's
// 6-DoF pose relative to the screen. Pure math here, so node tests can check it
// (tests/web/marker.test.mjs); docs/phone.md has the frames and the figures.

export const MARKER_DICTIONARY = "ARUCO_MIP_36h12";  // OpenCV's DICT_ARUCO_MIP_36h12, same ids
export const MARKER_ID = 7;
// The black square's side as drawn on the worker's screen at the CSS reference pixel (96 per
// inch). Real screens differ by up to about a third, which scales motion the same way.
export const MARKER_SIZE_M = 0.06;
const CSS_PX_PER_M = 96 / 0.0254;
// A phone's main camera sees about 65 degrees across the image's longer side (portrait frames
// are narrower across); an error here scales distances alike.
export const CAMERA_HFOV_DEG = 65;

// The marker's cells, quiet zone included: rows of booleans, true = white. `bits` is the
// dictionary's code for the id, a string of "0" and "1", row by row (js-aruco2's codeList).
export function markerCells(bits) {
  const inner = Math.round(Math.sqrt(bits.length)), size = inner + 4;
  const cells = [];
  for (let y = 0; y < size; y += 1) {
    const row = [];
    for (let x = 0; x < size; x += 1) {
      const quiet = x === 0 || y === 0 || x === size - 1 || y === size - 1;
      const border = x === 1 || y === 1 || x === size - 2 || y === size - 2;
      row.push(quiet || (!border && bits[(y - 2) * inner + (x - 2)] === "1"));
    }
    cells.push(row);
  }
  return cells;
}

// Draws the marker on a canvas so that its black square is MARKER_SIZE_M at 96 CSS px per inch.
export function drawMarker(canvas, bits) {
  const cells = markerCells(bits), inner = cells.length - 2;
  const cellPx = Math.round((MARKER_SIZE_M * CSS_PX_PER_M) / inner);
  const scale = window.devicePixelRatio || 1;
  canvas.width = canvas.height = cells.length * cellPx * scale;
  canvas.style.width = canvas.style.height = `${cells.length * cellPx}px`;
  const context = canvas.getContext("2d");
  context.scale(scale, scale);
  cells.forEach((row, y) => row.forEach((white, x) => {
    context.fillStyle = white ? "#fff" : "#000";
    context.fillRect(x * cellPx, y * cellPx, cellPx, cellPx);
  }));
}

export function focalPx(longSidePx, hfovDeg = CAMERA_HFOV_DEG) {
  return longSidePx / 2 / Math.tan((hfovDeg * Math.PI) / 360);
}

// Solves A x = b (n x n, partial pivoting); A and b are overwritten.
function solve(A, b) {
  const n = b.length;
  for (let c = 0; c < n; c += 1) {
    let pivot = c;
    for (let r = c + 1; r < n; r += 1) if (Math.abs(A[r][c]) > Math.abs(A[pivot][c])) pivot = r;
    [A[c], A[pivot]] = [A[pivot], A[c]];
    [b[c], b[pivot]] = [b[pivot], b[c]];
    for (let r = c + 1; r < n; r += 1) {
      const f = A[r][c] / A[c][c];
      for (let k = c; k < n; k += 1) A[r][k] -= f * A[c][k];
      b[r] -= f * b[c];
    }
  }
  const x = new Array(n).fill(0);
  for (let r = n - 1; r >= 0; r -= 1) {
    let s = b[r];
    for (let k = r + 1; k < n; k += 1) s -= A[r][k] * x[k];
    x[r] = s / A[r][r];
  }
  return x;
}

// The homography (h33 = 1) taking the four points `from` ([x, y]) to `to`, as columns h1 h2 h3.
export function homography(from, to) {
  const A = [], b = [];
  from.forEach(([x, y], i) => {
    const [u, v] = to[i];
    A.push([x, y, 1, 0, 0, 0, -u * x, -u * y]); b.push(u);
    A.push([0, 0, 0, x, y, 1, -v * x, -v * y]); b.push(v);
  });
  const h = solve(A, b);
  return [[h[0], h[3], h[6]], [h[1], h[4], h[7]], [h[2], h[5], 1]];
}

const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => Math.hypot(...a);
const scaled = (a, s) => a.map((v) => v * s);
const plus = (a, b) => a.map((v, i) => v + b[i]);

// Rows of a 3x3 rotation matrix -> quaternion [x, y, z, w].
export function matrixToQuaternion(m) {
  const [[a, b, c], [d, e, f], [g, h, i]] = m;
  const t = a + e + i;
  let q;
  if (t > 0) {
    const s = 2 * Math.sqrt(1 + t);
    q = [(h - f) / s, (c - g) / s, (d - b) / s, s / 4];
  } else if (a > e && a > i) {
    const s = 2 * Math.sqrt(1 + a - e - i);
    q = [s / 4, (b + d) / s, (c + g) / s, (h - f) / s];
  } else if (e > i) {
    const s = 2 * Math.sqrt(1 + e - a - i);
    q = [(b + d) / s, s / 4, (f + h) / s, (c - g) / s];
  } else {
    const s = 2 * Math.sqrt(1 + i - a - e);
    q = [(c + g) / s, (f + h) / s, s / 4, (d - b) / s];
  }
  const n = norm(q);
  return q.map((v) => v / n);
}

const multiply = (A, B) => A.map((row) => [0, 1, 2].map((j) => row[0] * B[0][j] + row[1] * B[1][j] + row[2] * B[2][j]));
const transpose = (A) => [0, 1, 2].map((i) => A.map((row) => row[i]));

// Frames (docs/phone.md). Marker M: x right on the screen, y up, z out of it towards the worker.
// Camera C (OpenCV's): x right in the image, y down, z along the view. Phone D (the W3C device
// frame): x right, y up, z out of the phone's screen; the rear camera looks along -z. The
// worker's frame W and the phone's body frame B are the robot's: x forward (into the screen),
// y left, z up. Held upright and facing the screen, the phone's B equals W.
const W_FROM_M = [[0, 0, -1], [-1, 0, 0], [0, 1, 0]];
const C_TO_D = [[1, 0, 0], [0, -1, 0], [0, 0, -1]];  // D <- C
const B_TO_D = [[0, -1, 0], [0, 0, 1], [-1, 0, 0]];  // D <- B
export const DEVICE_FROM_BODY = matrixToQuaternion(B_TO_D);

// The phone's pose in the worker's frame from the marker's corners in the image (pixels,
// clockwise from the marker's top-left as js-aruco2 gives them), or null for a degenerate view.
// {position: [x, y, z] metres, quaternion: [x, y, z, w] of B in W, distanceM}.
export function poseFromCorners(corners, { widthPx, heightPx, focalLengthPx, sizeM = MARKER_SIZE_M }) {
  const h = sizeM / 2;
  const plane = [[-h, h], [h, h], [h, -h], [-h, -h]];
  const image = corners.map(({ x, y }) => [(x - widthPx / 2) / focalLengthPx, (y - heightPx / 2) / focalLengthPx]);
  const [h1, h2, h3] = homography(plane, image);
  let lambda = 2 / (norm(h1) + norm(h2));
  if (h3[2] < 0) lambda = -lambda;  // the marker is in front of the camera
  const r1 = scaled(h1, lambda), r2 = scaled(h2, lambda), t = scaled(h3, lambda);
  // The closest rotation to [r1 r2 r1xr2], split evenly between r1 and r2 (Zhang's trick).
  const a = plus(r1, r2), b = cross(r1, r2);
  if (norm(a) < 1e-9 || norm(b) < 1e-9 || !t.every(Number.isFinite)) return null;
  const c = cross(a, b);
  const an = scaled(a, 1 / norm(a)), cn = scaled(c, 1 / norm(c));
  const x = scaled(plus(an, cn), Math.SQRT1_2), y = scaled(plus(an, scaled(cn, -1)), Math.SQRT1_2);
  const R = transpose([x, y, cross(x, y)]);  // C <- M (columns: the marker's axes in C)
  const Rt = transpose(R);
  const centre = scaled([0, 1, 2].map((i) => Rt[i][0] * t[0] + Rt[i][1] * t[1] + Rt[i][2] * t[2]), -1);
  const position = [0, 1, 2].map((i) => W_FROM_M[i].reduce((s, v, j) => s + v * centre[j], 0));
  // W <- B = (W <- M)(M <- C)(C <- D)(D <- B)
  const rotation = multiply(multiply(multiply(W_FROM_M, Rt), transpose(C_TO_D)), B_TO_D);
  return { position, quaternion: matrixToQuaternion(rotation), distanceM: norm(t) };
}
