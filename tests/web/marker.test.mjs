// The camera mode's marker (src/crowdteleop/web/static/marker.js): the cells drawn are a marker
// the vendored detector (js-aruco2) finds, and the corners it gives turn back into the phone's
// pose in the worker's frame.

import assert from "node:assert/strict";
import { createRequire } from "node:module";
import { describe, test } from "node:test";

import {
  DEVICE_FROM_BODY, MARKER_DICTIONARY, MARKER_ID, MARKER_SIZE_M, focalPx, homography,
  markerCells, matrixToQuaternion, poseFromCorners,
} from "../../src/crowdteleop/web/static/marker.js";
import { refineCorners } from "../../src/crowdteleop/web/static/corners.js";

const require = createRequire(import.meta.url);
const { AR } = require("../../src/crowdteleop/web/static/vendor/js-aruco2-2.0.0/aruco.js");

const bits = () => new AR.Dictionary(MARKER_DICTIONARY).codeList[MARKER_ID];
const WIDTH = 640, HEIGHT = 480, F = focalPx(WIDTH);

function rotation(axis, degrees) {  // rows of the rotation about x (0), y (1) or z (2)
  const c = Math.cos((degrees * Math.PI) / 180), s = Math.sin((degrees * Math.PI) / 180);
  const [i, j] = [[1, 2], [2, 0], [0, 1]][axis];
  const m = [[1, 0, 0], [0, 1, 0], [0, 0, 1]];
  m[i][i] = c; m[i][j] = -s; m[j][i] = s; m[j][j] = c;
  return m;
}
const mul = (A, B) => A.map((row) => [0, 1, 2].map((j) => row[0] * B[0][j] + row[1] * B[1][j] + row[2] * B[2][j]));
const T = (A) => [0, 1, 2].map((i) => A.map((row) => row[i]));
const apply = (A, v) => A.map((row) => row[0] * v[0] + row[1] * v[1] + row[2] * v[2]);
const angleDeg = (a, b) => (2 * Math.acos(Math.min(1, Math.abs(a.reduce((s, v, i) => s + v * b[i], 0))))) * 180 / Math.PI;

// Where a phone at `positionM` (worker's frame) turned by `bodyInWorld` sees the marker's corners.
function project(positionM, bodyInWorld) {
  const mFromW = [[0, -1, 0], [0, 0, 1], [-1, 0, 0]];  // M <- W
  const dFromB = [[0, -1, 0], [0, 0, 1], [-1, 0, 0]];  // D <- B
  const dFromC = [[1, 0, 0], [0, -1, 0], [0, 0, -1]];  // D <- C
  const mFromC = mul(mul(mul(mFromW, bodyInWorld), T(dFromB)), dFromC);
  const centre = apply(mFromW, positionM), h = MARKER_SIZE_M / 2;
  return [[-h, h], [h, h], [h, -h], [-h, -h]].map(([x, y]) => {
    const p = apply(T(mFromC), [x - centre[0], y - centre[1], -centre[2]]);
    return { x: (F * p[0]) / p[2] + WIDTH / 2, y: (F * p[1]) / p[2] + HEIGHT / 2 };
  });
}

describe("the pose from the marker's corners", () => {
  const views = [
    ["straight on, 40 cm away", [-0.4, 0, 0], rotation(2, 0)],
    ["off to the left and low, turned towards it", [-0.35, 0.08, -0.05], mul(rotation(2, -12), rotation(1, 8))],
    ["close and rolled", [-0.22, -0.03, 0.04], mul(rotation(0, 25), rotation(2, 6))],
  ];
  for (const [name, position, body] of views) {
    test(name, () => {
      const pose = poseFromCorners(project(position, body), { widthPx: WIDTH, heightPx: HEIGHT, focalLengthPx: F });
      pose.position.forEach((v, i) => assert.ok(Math.abs(v - position[i]) < 1e-6, `${pose.position} vs ${position}`));
      assert.ok(angleDeg(pose.quaternion, matrixToQuaternion(body)) < 1e-4);
    });
  }

  test("moving the phone towards the screen is forward, to the right is -y, up is +z", () => {
    const at = (p) => poseFromCorners(project(p, rotation(2, 0)), { widthPx: WIDTH, heightPx: HEIGHT, focalLengthPx: F }).position;
    const [a, b] = [at([-0.4, 0, 0]), at([-0.3, -0.05, 0.02])];
    assert.ok(b[0] - a[0] > 0.099 && b[1] - a[1] < -0.049 && b[2] - a[2] > 0.019);
  });

  test("corners on a line (a marker seen edge-on) give no pose", () => {
    const line = [0, 1, 2, 3].map((i) => ({ x: 100 + 10 * i, y: 200 }));
    assert.equal(poseFromCorners(line, { widthPx: WIDTH, heightPx: HEIGHT, focalLengthPx: F }), null);
  });

  test("the homography maps its four points", () => {
    const from = [[0, 0], [1, 0], [1, 1], [0, 1]], to = [[2, 3], [5, 3.5], [4.5, 7], [1.8, 6]];
    const [h1, h2, h3] = homography(from, to);
    from.forEach(([x, y], i) => {
      const w = h1[2] * x + h2[2] * y + h3[2];
      assert.ok(Math.abs((h1[0] * x + h2[0] * y + h3[0]) / w - to[i][0]) < 1e-9);
      assert.ok(Math.abs((h1[1] * x + h2[1] * y + h3[1]) / w - to[i][1]) < 1e-9);
    });
  });

  test("the device-from-body turn takes the body's forward to the phone's back", () => {
    const [x, y, z, w] = DEVICE_FROM_BODY;  // rotate (1, 0, 0): forward is -z of the device
    const forward = [1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)];
    assert.deepEqual(forward.map((v) => Math.round(v)), [0, 0, -1]);
  });
});

describe("the marker drawn is the one the detector finds", () => {
  test("its cells have a white quiet zone, a black border and the id's 36 bits", () => {
    const cells = markerCells(bits());
    assert.equal(cells.length, 10);
    assert.ok(cells[0].every(Boolean) && cells[9].every(Boolean), "quiet zone");
    assert.ok(cells[1].slice(1, 9).every((c) => !c) && cells[8].slice(1, 9).every((c) => !c), "border");
    assert.equal(cells.slice(2, 8).map((row) => row.slice(2, 8).map(Number).join("")).join(""), bits());
  });

  test("js-aruco2 finds it, with its id, at its corners", () => {
    const cell = 12, cells = markerCells(bits()), offset = 100;
    const width = 400, height = 300, data = new Uint8ClampedArray(width * height * 4).fill(255);
    cells.forEach((row, cy) => row.forEach((white, cx) => {
      for (let y = 0; y < cell; y += 1) for (let x = 0; x < cell; x += 1) {
        const i = ((offset + cy * cell + y) * width + offset + cx * cell + x) * 4;
        data[i] = data[i + 1] = data[i + 2] = white ? 255 : 0;
      }
    }));
    const found = new AR.Detector({ dictionaryName: MARKER_DICTIONARY }).detect({ width, height, data });
    const marker = found.find((m) => m.id === MARKER_ID);
    assert.ok(marker, `found ${found.map((m) => m.id)}`);
    const [tl, , br] = marker.corners;  // clockwise from the marker's top-left
    assert.ok(Math.abs(tl.x - (offset + cell)) <= 1.5 && Math.abs(tl.y - (offset + cell)) <= 1.5, JSON.stringify(tl));
    assert.ok(Math.abs(br.x - (offset + 9 * cell)) <= 1.5 && Math.abs(br.y - (offset + 9 * cell)) <= 1.5, JSON.stringify(br));
  });
});

// The marker as a camera sees it from `position` turned by `body`: each pixel averages 4 x 4
// samples of the cells (a camera integrates over its pixels), on a mid-grey background.
function render(position, body) {
  const corners = project(position, body), cells = markerCells(bits()), n = cells.length;
  // image -> cell coordinates (0..n across the whole marker, quiet zone included)
  const [h1, h2, h3] = homography(corners.map(({ x, y }) => [x, y]), [[1, 1], [n - 1, 1], [n - 1, n - 1], [1, n - 1]]);
  const data = new Uint8ClampedArray(WIDTH * HEIGHT * 4);
  for (let y = 0; y < HEIGHT; y += 1) for (let x = 0; x < WIDTH; x += 1) {
    let sum = 0;
    for (let sy = 0; sy < 4; sy += 1) for (let sx = 0; sx < 4; sx += 1) {
      const u = x + (sx + 0.5) / 4, v = y + (sy + 0.5) / 4;
      const w = h1[2] * u + h2[2] * v + h3[2];
      const cx = Math.floor((h1[0] * u + h2[0] * v + h3[0]) / w), cy = Math.floor((h1[1] * u + h2[1] * v + h3[1]) / w);
      sum += cx >= 0 && cy >= 0 && cx < n && cy < n ? (cells[cy][cx] ? 235 : 20) : 128;
    }
    const i = (y * WIDTH + x) * 4;
    data[i] = data[i + 1] = data[i + 2] = sum / 16;
    data[i + 3] = 255;
  }
  return { image: { width: WIDTH, height: HEIGHT, data }, corners };
}

describe("sub-pixel corners", () => {
  const views = [
    ["straight on, 40 cm away", [-0.4, 0, 0], rotation(2, 0)],
    ["askew", [-0.33, 0.06, -0.04], mul(rotation(2, -15), rotation(1, 10))],
  ];
  for (const [name, position, body] of views) {
    test(`bring the pose to within 1 cm and 1.5 degrees: ${name}`, () => {
      const { image, corners: truth } = render(position, body);
      const detector = new AR.Detector({ dictionaryName: MARKER_DICTIONARY });
      const marker = detector.detect(image).find((m) => m.id === MARKER_ID);
      assert.ok(marker, "detected");
      const refined = refineCorners(detector.grey, marker.corners);
      const err = (cs) => Math.max(...cs.map((c, i) => Math.hypot(c.x - truth[i].x, c.y - truth[i].y)));
      assert.ok(err(refined) < 0.25, `refined corners off by ${err(refined)} px (detector: ${err(marker.corners)})`);
      const pose = poseFromCorners(refined, { widthPx: WIDTH, heightPx: HEIGHT, focalLengthPx: F });
      const offM = Math.hypot(...pose.position.map((v, i) => v - position[i]));
      assert.ok(offM < 0.01, `position off by ${offM} m`);
      assert.ok(angleDeg(pose.quaternion, matrixToQuaternion(body)) < 1.5);
    });
  }
});
