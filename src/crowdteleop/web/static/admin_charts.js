// The admin page's charts (uPlot, vendored): demonstrations per hour, queue length and wait,
// live sessions, latency, and the demonstrations' quality scores, from GET /api/admin/charts.
// Each chart is built once and given new data on each refresh; it follows its box's width.

import uPlot from "./vendor/uplot-1.6.32/uPlot.esm.js";

const COLOURS = { accent: "#4cc38a", blue: "#4ca3c3", warn: "#f0b429", bad: "#ef5350", grey: "#6b7a88" };
const AXIS = { stroke: "#9aa7b2", grid: { stroke: "#2c353f", width: 1 }, ticks: { stroke: "#2c353f", width: 1 } };
const COUNTS = [1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000, 10000];
const HEIGHT = { wide: 210, narrow: 180 };

// Zero at the bottom, a little room at the top; 1 when there is nothing to show yet.
const fromZero = (u, min, max) => [0, max > 0 ? max * 1.15 : 1];

const line = (label, stroke, extra = {}) => ({ label, stroke, width: 2, spanGaps: false, points: { show: true, size: 5, fill: stroke }, ...extra });
const bars = (label, fill, size) => ({ label, fill, stroke: fill, width: 0, paths: uPlot.paths.bars({ size: [size], align: 0 }), points: { show: false } });

// What each chart draws: its series and the y axis's label (units in it), its data from a response.
const SPECS = {
  "chart-demos": {
    y: "episodes per hour",
    counts: true,
    series: [bars("episodes", COLOURS.grey, 0.8), bars("successful", COLOURS.accent, 0.5)],
    data: (c) => [c.bins.map((b) => b.episodes), c.bins.map((b) => b.successes)],
    empty: (c) => (c.bins.some((b) => b.episodes) ? "" : "No episodes yet in these hours."),
  },
  "chart-queue": {
    y: "workers waiting",
    series: [line("mean waiting", COLOURS.blue), line("most at once", COLOURS.warn, { dash: [5, 4] })],
    data: (c) => [c.bins.map((b) => b.queue_length_mean), c.bins.map((b) => b.queue_length_max)],
    empty: (c) => (c.bins.some((b) => b.queue_length_max) ? "" : "Nobody had to wait."),
  },
  "chart-wait": {
    y: "wait (s)",
    series: [line("median wait (s)", COLOURS.blue), line("longest wait (s)", COLOURS.bad, { dash: [5, 4] })],
    data: (c) => [c.bins.map((b) => b.queue_wait_s_median), c.bins.map((b) => b.queue_wait_s_max)],
    empty: (c) => (c.bins.some((b) => b.queue_wait_s_max !== null) ? "" : "No one left the queue in these hours."),
  },
  "chart-live": {
    y: "sessions",
    series: [line("mean live", COLOURS.accent), line("most at once", COLOURS.warn, { dash: [5, 4] })],
    data: (c) => [c.bins.map((b) => b.live_sessions_mean), c.bins.map((b) => b.live_sessions_max)],
    empty: (c) => (c.bins.some((b) => b.live_sessions_max) ? "" : "No sessions in these hours."),
  },
  "chart-latency": {
    y: "latency (ms)",
    series: [line("p50 (ms)", COLOURS.accent), line("p95 (ms)", COLOURS.bad)],
    data: (c) => [c.bins.map((b) => b.latency_p50_ms), c.bins.map((b) => b.latency_p95_ms)],
    empty: (c) => (c.bins.some((b) => b.latency_p50_ms !== null) ? "" : "No latency measured in these hours."),
  },
  "chart-scores": {
    y: "demonstrations",
    x: "quality score (0-100)",
    counts: true,
    series: [bars("demonstrations", COLOURS.blue, 0.85)],
    data: (c) => [c.scores.map((s) => s.demonstrations)],
    xs: (c) => c.scores.map((s) => (s.score_from + s.score_to) / 2),
    empty: (c) => (c.scores.some((s) => s.demonstrations) ? note(c) : "No scored demonstrations in these hours."),
  },
};

const note = (c) => (c.unscored ? `${c.unscored} more without a score (reported unmeasured).` : "");

function options(spec, width, narrow, window) {
  const time = !spec.xs;
  return {
    width,
    height: narrow ? HEIGHT.narrow : HEIGHT.wide,
    legend: { live: false },
    cursor: { drag: { x: false, y: false }, points: { size: 6 } },
    scales: {
      x: time ? { time: true, range: () => window() } : { time: false, range: [0, 100] },
      y: { range: fromZero },
    },
    axes: [
      // A time axis's values take two lines (hour, then the date where it changes).
      { ...AXIS, label: spec.x ?? "time (local)", labelSize: 18, size: time ? 50 : 32, space: narrow ? 60 : 70 },
      { ...AXIS, label: spec.y, labelSize: 18, size: 44, ...(spec.counts ? { incrs: COUNTS } : {}) },
    ],
    series: [{ label: spec.x ?? "time" }, ...spec.series],
  };
}

export class AdminCharts {
  constructor(root) {
    this.plots = new Map();
    this.window = [0, 1];
    this.root = root;
    new ResizeObserver(() => this.resize()).observe(root);
  }

  // Draw a GET /api/admin/charts answer.
  update(charts) {
    // Each bin's value sits at its middle; the time axis spans the bins' edges.
    const half = charts.bin_s / 2;
    const first = charts.bins[0].start_s;
    this.window = [first, charts.bins[charts.bins.length - 1].start_s + charts.bin_s];
    const middles = charts.bins.map((b) => b.start_s + half);
    for (const [id, spec] of Object.entries(SPECS)) {
      const figure = this.root.querySelector(`#${id}`);
      const data = [spec.xs ? spec.xs(charts) : middles, ...spec.data(charts)];
      let plot = this.plots.get(id);
      if (!plot) {
        const { width, narrow } = this.size(figure);
        plot = new uPlot(options(spec, width, narrow, () => this.window), data, figure);
        // The axes' labels are drawn on the canvas: say them to screen readers too.
        plot.ctx.canvas.setAttribute("role", "img");
        plot.ctx.canvas.setAttribute("aria-label", `${spec.y} against ${spec.x ?? "time (local)"}`);
        const empty = document.createElement("p");
        empty.className = "empty";
        figure.append(empty);
        this.plots.set(id, plot);
      } else {
        plot.setData(data);
      }
      figure.querySelector(".empty").textContent = spec.empty(charts);
    }
  }

  size(figure) {
    const width = Math.max(200, Math.floor(figure.clientWidth - 12));
    return { width, narrow: width < 420 };
  }

  resize() {
    for (const [id, plot] of this.plots) {
      const { width, narrow } = this.size(this.root.querySelector(`#${id}`));
      if (Math.abs(plot.width - width) > 2) plot.setSize({ width, height: narrow ? HEIGHT.narrow : HEIGHT.wide });
    }
  }
}
