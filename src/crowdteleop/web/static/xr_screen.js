// What the worker sees in the VR headset: the live video on a screen 1.5 m ahead, 1.2 m wide,
// and below it a status panel (the task, the demonstrations done, the clutch in words). Plain
// WebGL1: one shader, one textured quad drawn twice per view (screen, then panel).
//
// The other hand (not the one that drives the arm) moves the screen: hold its grip to drag the
// screen along with the hand; its thumbstick pushes the screen away or pulls it nearer (up /
// down) and makes it larger or smaller (right / left). The screen always faces the worker.

import { CLUTCH_TEXT } from "./clutch.js";

export const SCREEN = { distance: 1.5, width: 1.2, drop: 0.15,  // m ahead, m wide, m below the eyes
                        minWidth: 0.4, maxWidth: 4, minDistance: 0.5, maxDistance: 5,
                        pushSpeed: 1.0, growRate: 1.0 };  // m/s and e-folds/s at full stick
const PANEL = { widthOfScreen: 0.75, gap: 0.05, pixels: [768, 256], margin: 24, lineHeight: 46 };
const DEAD_ZONE = 0.15;
const BACKGROUND = [0.08, 0.08, 0.1, 1];

// --- where the screen is: pure math, tested in tests/web/xr_screen.test.mjs ----------------

const sub = (a, b) => a.map((v, i) => v - b[i]);
const add = (a, b) => a.map((v, i) => v + b[i]);
const scale = (a, s) => a.map((v) => v * s);
const clamp = (v, lo, hi) => Math.min(hi, Math.max(lo, v));

// The screen's centre, its width and the point it faces (the worker's head when placed).
export class ScreenPlacement {
  constructor() { this.centre = null; this.width = SCREEN.width; this.viewer = [0, 0, 0]; this.grab = null; }
  get placed() { return this.centre !== null; }

  // In front of the head, level: `forward` is the head's -z axis in the scene.
  placeInFront(head, forward) {
    const level = Math.hypot(forward[0], forward[2]) > 1e-6 ? [forward[0], 0, forward[2]] : [0, 0, -1];
    const ahead = scale(level, SCREEN.distance / Math.hypot(...level));
    this.viewer = [...head];
    this.centre = add(add(head, ahead), [0, -SCREEN.drop, 0]);
  }

  // The other hand's thumbstick, axes -1..1 (y < 0 is pushed forward), for dt seconds.
  nudge([x, y], dt) {
    const dx = Math.abs(x) < DEAD_ZONE ? 0 : x, dy = Math.abs(y) < DEAD_ZONE ? 0 : y;
    this.width = clamp(this.width * Math.exp(dx * SCREEN.growRate * dt), SCREEN.minWidth, SCREEN.maxWidth);
    if (!dy) return;
    const away = sub(this.centre, this.viewer);
    const distance = Math.hypot(...away);
    const wanted = clamp(distance - dy * SCREEN.pushSpeed * dt, SCREEN.minDistance, SCREEN.maxDistance);
    this.centre = add(this.viewer, scale(away, wanted / distance));
  }

  // The other hand's grip: held, the screen keeps its offset from the hand.
  drag(hand, held) {
    if (!held) { this.grab = null; return; }
    if (!this.grab) this.grab = sub(this.centre, hand);
    this.centre = add(hand, this.grab);
  }
}

// A quad's model matrix (column-major, WebGL's order): the unit square [-0.5, 0.5]^2 scaled to
// width x height at `centre`, turned about the vertical to face `viewer`.
export function facingMatrix(centre, viewer, width, height) {
  let [nx, nz] = [viewer[0] - centre[0], viewer[2] - centre[2]];
  const length = Math.hypot(nx, nz);
  [nx, nz] = length > 1e-6 ? [nx / length, nz / length] : [0, 1];
  return [nz * width, 0, -nx * width, 0,  0, height, 0, 0,  nx, 0, nz, 0,  ...centre, 1];
}

// The status panel's matrix: centred below the screen's quad.
export function panelMatrix(placement, screenHeight) {
  const width = placement.width * PANEL.widthOfScreen;
  const height = width * PANEL.pixels[1] / PANEL.pixels[0];
  const below = [0, -(screenHeight / 2 + PANEL.gap + height / 2), 0];
  return facingMatrix(add(placement.centre, below), placement.viewer, width, height);
}

const transform = (m, v) => [0, 1, 2, 3].map((r) => m[r] * v[0] + m[4 + r] * v[1] + m[8 + r] * v[2] + m[12 + r] * v[3]);

// Where a quad lands in a view, in the viewport's pixels from its bottom left:
// [left, bottom, right, top]. Matrices column-major, as WebXR gives them.
export function projectedRect(projection, viewInverse, model, { width, height }) {
  const corners = [[-0.5, -0.5], [0.5, -0.5], [-0.5, 0.5], [0.5, 0.5]].map(([x, y]) => {
    const clip = transform(projection, transform(viewInverse, transform(model, [x, y, 0, 1])));
    return [(clip[0] / clip[3] + 1) / 2 * width, (clip[1] / clip[3] + 1) / 2 * height];
  });
  const xs = corners.map((c) => c[0]), ys = corners.map((c) => c[1]);
  return [Math.min(...xs), Math.min(...ys), Math.max(...xs), Math.max(...ys)];
}

// The panel's words. info: { task, demosDone, demosRequired, clutch } (any may be missing).
export function statusLines({ task, demosDone, demosRequired, clutch } = {}) {
  const demos = demosRequired ? `${demosDone ?? 0} / ${demosRequired}` : "–";
  return [task || "Connecting…", `Demonstrations ${demos}`, CLUTCH_TEXT[clutch] || "Clutch: –"];
}

// `text` in lines no wider than `width`, as `measure(text)` measures them (words kept whole).
export function wrap(text, width, measure) {
  const lines = [];
  for (const word of text.split(/\s+/).filter(Boolean)) {
    const last = lines.length ? `${lines[lines.length - 1]} ${word}` : null;
    if (last !== null && measure(last) <= width) lines[lines.length - 1] = last;
    else lines.push(word);
  }
  return lines;
}

// --- drawing -------------------------------------------------------------------------------

const VERTEX = `
attribute vec2 corner;
uniform mat4 projection, view, model;
varying vec2 uv;
void main() {
  uv = vec2(corner.x + 0.5, 0.5 - corner.y);
  gl_Position = projection * view * model * vec4(corner, 0.0, 1.0);
}`;
const FRAGMENT = `
precision mediump float;
uniform sampler2D picture;
varying vec2 uv;
void main() { gl_FragColor = texture2D(picture, uv); }`;

function compile(gl, type, source) {
  const shader = gl.createShader(type);
  gl.shaderSource(shader, source);
  gl.compileShader(shader);
  if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(shader));
  return shader;
}

function program(gl) {
  const linked = gl.createProgram();
  gl.attachShader(linked, compile(gl, gl.VERTEX_SHADER, VERTEX));
  gl.attachShader(linked, compile(gl, gl.FRAGMENT_SHADER, FRAGMENT));
  gl.linkProgram(linked);
  if (!gl.getProgramParameter(linked, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(linked));
  return linked;
}

function texture(gl) {
  const made = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, made);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, 1, 1, 0, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array([0, 0, 0, 255]));
  for (const [key, value] of [[gl.TEXTURE_MIN_FILTER, gl.LINEAR], [gl.TEXTURE_MAG_FILTER, gl.LINEAR],
    [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE], [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE]]) {
    gl.texParameteri(gl.TEXTURE_2D, key, value);
  }
  return made;
}

function drawPanel(canvas, lines) {
  const context = canvas.getContext("2d");
  const [w, h] = PANEL.pixels, { margin, lineHeight } = PANEL;
  context.fillStyle = "#1c2230";
  context.fillRect(0, 0, w, h);
  context.fillStyle = "#ffffff";
  let y = margin + 30;
  lines.forEach((line, i) => {
    context.font = i === 0 ? "bold 34px sans-serif" : "32px sans-serif";
    for (const part of wrap(line, w - 2 * margin, (t) => context.measureText(t).width)) {
      context.fillText(part, margin, y);
      y += lineHeight;
    }
  });
}

// The headset's scene. `video`: the page's <video>; `status`: () => the statusLines info.
export class XrScreen {
  constructor(video, status) {
    this.video = video;
    this.status = status;
    this.placement = new ScreenPlacement();
    this.gl = null;
    this.frames = 0;  // frames drawn, for tests
    this.panelCanvas = document.createElement("canvas");
    [this.panelCanvas.width, this.panelCanvas.height] = PANEL.pixels;
    this.panelText = "";
    this.sampling = [];  // resolve functions waiting for the next frame's pixels
  }

  attach(gl) {
    this.gl = gl;
    this.program = program(gl);
    this.quad = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, this.quad);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-0.5, -0.5, 0.5, -0.5, -0.5, 0.5, 0.5, 0.5]), gl.STATIC_DRAW);
    this.videoTexture = texture(gl);
    this.panelTexture = texture(gl);
    this.panelText = "";
  }

  // One XR frame: `viewerPose` (XRViewerPose), `layer` (XRWebGLLayer), `other`: the other
  // hand's { position, squeeze, stick } or null, `dt` in seconds.
  draw(viewerPose, layer, other, dt) {
    this.#move(viewerPose, other, dt);
    const gl = this.gl;
    gl.bindFramebuffer(gl.FRAMEBUFFER, layer.framebuffer);
    gl.clearColor(...BACKGROUND);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    this.#upload();
    const screenHeight = this.placement.width * this.#aspect();
    const screen = facingMatrix(this.placement.centre, this.placement.viewer, this.placement.width, screenHeight);
    const panel = panelMatrix(this.placement, screenHeight);
    for (const view of viewerPose.views) {
      const { x, y, width, height } = layer.getViewport(view);
      gl.viewport(x, y, width, height);
      this.#quad(view, screen, this.videoTexture);
      this.#quad(view, panel, this.panelTexture);
    }
    this.frames += 1;
    this.#answerSamples(layer, viewerPose.views[0], screen);
  }

  #move(viewerPose, other, dt) {
    if (!this.placement.placed) {
      const { position: p, orientation: q } = viewerPose.transform;
      // the head's -z axis, rotated by its orientation
      const forward = [-2 * (q.x * q.z + q.w * q.y), -2 * (q.y * q.z - q.w * q.x), -(1 - 2 * (q.x * q.x + q.y * q.y))];
      this.placement.placeInFront([p.x, p.y, p.z], forward);
    }
    if (!other) return;
    this.placement.drag(other.position, other.squeeze);
    if (!other.squeeze) this.placement.nudge(other.stick, dt);
  }

  #aspect() {
    const { videoWidth: w, videoHeight: h } = this.video;
    return w && h ? h / w : 3 / 4;
  }

  #upload() {
    const gl = this.gl;
    if (this.video.readyState >= 2) {
      gl.bindTexture(gl.TEXTURE_2D, this.videoTexture);
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, this.video);
    }
    const lines = statusLines(this.status());
    const text = lines.join("\n");
    if (text === this.panelText) return;
    this.panelText = text;
    drawPanel(this.panelCanvas, lines);
    gl.bindTexture(gl.TEXTURE_2D, this.panelTexture);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, this.panelCanvas);
  }

  #quad(view, model, picture) {
    const gl = this.gl, p = this.program;
    gl.useProgram(p);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.quad);
    const corner = gl.getAttribLocation(p, "corner");
    gl.enableVertexAttribArray(corner);
    gl.vertexAttribPointer(corner, 2, gl.FLOAT, false, 0, 0);
    gl.uniformMatrix4fv(gl.getUniformLocation(p, "projection"), false, view.projectionMatrix);
    gl.uniformMatrix4fv(gl.getUniformLocation(p, "view"), false, view.transform.inverse.matrix);
    gl.uniformMatrix4fv(gl.getUniformLocation(p, "model"), false, new Float32Array(model));
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, picture);
    gl.uniform1i(gl.getUniformLocation(p, "picture"), 0);
    gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
  }

  // For tests and screenshots: the first view's pixels as the next frame draws them,
  // { width, height, rgba (rows bottom-up, as WebGL reads them), screen (projectedRect) }.
  sample() { return new Promise((resolve) => this.sampling.push(resolve)); }

  #answerSamples(layer, view, screen) {
    if (!this.sampling.length) return;
    const gl = this.gl;
    const viewport = layer.getViewport(view);
    const { x, y, width, height } = viewport;
    const rgba = new Uint8Array(width * height * 4);
    gl.readPixels(x, y, width, height, gl.RGBA, gl.UNSIGNED_BYTE, rgba);
    const rect = projectedRect(view.projectionMatrix, view.transform.inverse.matrix, screen, viewport);
    for (const resolve of this.sampling.splice(0)) resolve({ width, height, rgba, screen: rect });
  }
}
