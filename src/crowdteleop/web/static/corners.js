// Sub-pixel marker corners. The detector's corners are contour pixels, off by up to a pixel; for
// a marker 60-150 px across that tilts the recovered pose by degrees and, at arm's length, moves
// the phone's position by centimetres. So each side of the marker is re-found where the grey
// level changes fastest across it, a line is fitted to each side, and the corners are where
// neighbouring lines cross (what OpenCV's ArUco module does with its contour refinement).

const SEARCH_PX = 3;  // how far across the detected side the edge is looked for
const SAMPLES = 24;  // points per side
const MARGIN = 0.15;  // of the side, left out at each end: the corner's neighbourhood is round

// The grey level at (x, y), bilinear; null outside the image. Pixel i spans [i, i + 1), so
// its value belongs to i + 0.5.
function grey({ width, height, data }, xPx, yPx) {
  const x = xPx - 0.5, y = yPx - 0.5;
  const x0 = Math.floor(x), y0 = Math.floor(y);
  if (x0 < 0 || y0 < 0 || x0 + 1 >= width || y0 + 1 >= height) return null;
  const fx = x - x0, fy = y - y0, i = y0 * width + x0;
  return (data[i] * (1 - fx) + data[i + 1] * fx) * (1 - fy) + (data[i + width] * (1 - fx) + data[i + width + 1] * fx) * fy;
}

// Where along the normal through `p` the grey level crosses halfway between the dark and the
// light side (sub-pixel, by linear interpolation), or null where there is no clear edge.
function edgeAlong(image, p, normal) {
  const steps = [];
  for (let s = -SEARCH_PX; s <= SEARCH_PX + 1e-9; s += 0.25) {
    const v = grey(image, p[0] + normal[0] * s, p[1] + normal[1] * s);
    if (v === null) return null;
    steps.push([s, v]);
  }
  const values = steps.map(([, v]) => v);
  const low = Math.min(...values), high = Math.max(...values);
  if (high - low < 30) return null;
  const mid = (low + high) / 2;
  let best = null;
  for (let i = 0; i + 1 < steps.length; i += 1) {
    const [s0, v0] = steps[i], [s1, v1] = steps[i + 1];
    if ((v0 - mid) * (v1 - mid) > 0 || v0 === v1) continue;
    const s = s0 + ((mid - v0) / (v1 - v0)) * (s1 - s0);
    if (best === null || Math.abs(s) < Math.abs(best)) best = s;  // the crossing nearest the side
  }
  return best === null ? null : [p[0] + normal[0] * best, p[1] + normal[1] * best];
}

// The total-least-squares line through points: {point, direction}, or null.
function fitLine(points) {
  if (points.length < 4) return null;
  const n = points.length;
  const mx = points.reduce((s, p) => s + p[0], 0) / n, my = points.reduce((s, p) => s + p[1], 0) / n;
  let sxx = 0, sxy = 0, syy = 0;
  for (const [x, y] of points) { sxx += (x - mx) ** 2; sxy += (x - mx) * (y - my); syy += (y - my) ** 2; }
  const angle = 0.5 * Math.atan2(2 * sxy, sxx - syy);
  return { point: [mx, my], direction: [Math.cos(angle), Math.sin(angle)] };
}

function intersect(a, b) {
  const det = a.direction[0] * b.direction[1] - a.direction[1] * b.direction[0];
  if (Math.abs(det) < 1e-6) return null;
  const dx = b.point[0] - a.point[0], dy = b.point[1] - a.point[1];
  const t = (dx * b.direction[1] - dy * b.direction[0]) / det;
  return { x: a.point[0] + t * a.direction[0], y: a.point[1] + t * a.direction[1] };
}

// The corners ([{x, y}], clockwise) refined on the grey image {width, height, data}; a corner
// whose sides cannot be re-found, or that would move more than SEARCH_PX, stays as it was.
export function refineCorners(image, corners) {
  const lines = corners.map((from, i) => {
    const to = corners[(i + 1) % corners.length];
    const length = Math.hypot(to.x - from.x, to.y - from.y);
    if (length < 8) return null;
    const normal = [-(to.y - from.y) / length, (to.x - from.x) / length];
    const points = [];
    for (let k = 0; k < SAMPLES; k += 1) {
      const f = MARGIN + ((1 - 2 * MARGIN) * k) / (SAMPLES - 1);
      const edge = edgeAlong(image, [from.x + f * (to.x - from.x), from.y + f * (to.y - from.y)], normal);
      if (edge) points.push(edge);
    }
    return fitLine(points);
  });
  return corners.map((corner, i) => {
    const before = lines[(i + corners.length - 1) % corners.length], after = lines[i];
    const refined = before && after ? intersect(before, after) : null;
    const moved = refined ? Math.hypot(refined.x - corner.x, refined.y - corner.y) : Infinity;
    return moved <= SEARCH_PX ? refined : corner;
  });
}
