// Control-to-photon latency, the browser's copy of crowdteleop/client/latency.py (same rules,
// same test vectors: tests/fixtures/latency_vectors.json). No browser API in here, so node's
// test runner can import it.
//
// The server tags every frame it publishes with its RTP-clock pts and the last command the
// frame reflects. The browser sees pts plus an offset it cannot know (the sender adds a random
// origin); frame times come from the wall clock, so the gaps between them are irregular: the
// one offset under which earlier decoded frames also land on tagged pts is the right one.

export const MAX_TAGS = 600;  // 30 s of frames at 20 fps
export const RTP_MODULO = 2 ** 32;
export const CANDIDATES = 60;  // a decoded frame is one of the last few seconds' frames
const RECENT_FRAMES = 8;
const MAX_PENDING_COMMANDS = 2000;

const rtp = (x) => ((x % RTP_MODULO) + RTP_MODULO) % RTP_MODULO;

export class FrameMatcher {
  constructor() {
    this.tags = new Map();  // pts -> command seq, oldest first
    this.offset = null;
    this.recent = [];  // RTP timestamps of the latest frames not explained by `offset`
  }

  addTag(pts, commandSeq) {
    this.tags.set(pts, commandSeq);
    while (this.tags.size > MAX_TAGS) this.tags.delete(this.tags.keys().next().value);
  }

  // The command a decoded frame reflects, or null while the offset is unknown.
  commandSeqOf(rtpTimestamp) {
    if (this.offset !== null) {
      const pts = rtp(rtpTimestamp - this.offset);
      if (this.tags.has(pts)) return this.tags.get(pts);
    }
    this.recent.push(rtpTimestamp);
    if (this.recent.length > RECENT_FRAMES) this.recent.shift();
    const offset = this.#findOffset();
    if (offset === null) return null;
    this.offset = offset;
    const seq = this.tags.get(rtp(rtpTimestamp - offset));
    return seq === undefined ? null : seq;
  }

  // Three frames must agree: with frame gaps jittering by tens of RTP ticks, a wrong offset
  // that lands two earlier frames on tags by chance is vanishingly rare.
  #findOffset() {
    if (this.recent.length < 3) return null;
    const newest = this.recent[this.recent.length - 1], earlier = this.recent.slice(0, -1);
    const candidates = [...this.tags.keys()].slice(-CANDIDATES).reverse();
    for (const pts of candidates) {
      const offset = rtp(newest - pts);
      const hits = earlier.filter((r) => this.tags.has(rtp(r - offset))).length;
      if (hits >= 2) return offset;
    }
    return null;
  }
}

// Send times by command seq; each command's latency is the time to the first frame showing it.
// Times are milliseconds of one clock (performance.now() in the page).
export class LatencyTracker {
  constructor() {
    this.sentAtMs = new Map();  // seq -> when sent, oldest first
    this.samplesMs = [];
    this.shownUpTo = -1;  // the newest command seq a shown frame covered
  }

  commandSent(seq, atMs) {
    this.sentAtMs.set(seq, atMs);
    while (this.sentAtMs.size > MAX_PENDING_COMMANDS) this.sentAtMs.delete(this.sentAtMs.keys().next().value);
  }

  // The latencies (ms) this frame completes: every pending command up to `commandSeq`.
  frameShown(commandSeq, atMs) {
    const found = [];
    if (commandSeq <= this.shownUpTo) return found;
    for (const [seq, sentAtMs] of [...this.sentAtMs]) {
      if (seq > this.shownUpTo && seq <= commandSeq) {
        found.push(atMs - sentAtMs);
        this.sentAtMs.delete(seq);
      }
    }
    this.shownUpTo = commandSeq;
    this.samplesMs.push(...found);
    return found;
  }
}
