// Benchmark mode: the dissertation's §3.5 scenario in the page. A brush every 200 ms from the
// seeded schedule (schedule.js, the same as `sdfserver bench`'s), the camera orbiting the world so
// frames keep coming, and two frame rates (§3.5.1): over all frames, and over the frames that
// arrived while an edit's recompute was in flight (from posting it until a frame shows its version).
import { EDIT_INTERVAL_MS, mulberry32, nextBrush } from "./schedule.js";

export class Benchmark {
  // host: { edit(edits) -> the version it became, lookAt(position, target), viewChanged(), size(), stats }
  constructor(host) {
    this.host = host;
    this.running = false;
  }

  start(seed) {
    const size = this.host.size();
    this.seed = seed;
    this.uniform = mulberry32(seed);
    this.size = size;
    this.running = true;
    this.startedAt = performance.now();
    this.nextEditAt = this.startedAt;
    this.frames = 0;
    this.recomputeFrames = 0;
    this.recomputeMs = 0;
    this.inFlight = [];  // versions posted and not yet seen in a frame; null while the POST is out
    this.inFlightSince = null;
    this.edits = 0;
    this.failed = 0;
    this.publish();
  }

  stop() {
    this.running = false;
    this.closeInterval(performance.now());
    this.publish();
  }

  closeInterval(now) {
    if (this.inFlightSince !== null && this.inFlight.length === 0) {
      this.recomputeMs += now - this.inFlightSince;
      this.inFlightSince = null;
    }
  }

  async postEdit(now) {
    const brush = nextBrush(this.uniform, this.size);
    const slot = { version: null };
    this.inFlight.push(slot);
    if (this.inFlightSince === null) this.inFlightSince = now;
    try {
      slot.version = await this.host.edit([brush]);
      this.edits++;
    } catch {
      this.failed++;
      this.inFlight.splice(this.inFlight.indexOf(slot), 1);
      this.closeInterval(performance.now());
    }
  }

  // Every animation frame: move the camera, post the edits that are due.
  tick(now) {
    if (!this.running) return;
    const [sx, sy, sz] = this.size;
    const angle = (now - this.startedAt) * 0.0003;
    const r = 0.9 * Math.max(sx, sz);
    this.host.lookAt([sx / 2 + r * Math.sin(angle), sy * 0.7, sz / 2 + r * Math.cos(angle)],
      [sx / 2, sy / 8, sz / 2]);
    this.host.viewChanged();
    while (now >= this.nextEditAt) {
      this.postEdit(now);
      this.nextEditAt += EDIT_INTERVAL_MS;
    }
    this.publish();
  }

  onFrame(version) {
    if (!this.running) return;
    const now = performance.now();
    this.frames++;
    if (this.inFlight.length) {
      this.recomputeFrames++;
      this.inFlight = this.inFlight.filter((slot) => slot.version === null || slot.version > version);
      this.closeInterval(now);
    }
  }

  fps() {
    const now = performance.now();
    const elapsed = (now - this.startedAt) / 1000;
    const open = this.inFlightSince !== null ? now - this.inFlightSince : 0;
    const recomputeS = (this.recomputeMs + open) / 1000;
    return {
      overall: elapsed > 0 ? this.frames / elapsed : 0,
      recompute: recomputeS > 0 ? this.recomputeFrames / recomputeS : 0,
    };
  }

  publish() {
    const { overall, recompute } = this.running || this.frames ? this.fps() : { overall: 0, recompute: 0 };
    Object.assign(this.host.stats, {
      running: this.running, seed: this.seed ?? null, frames: this.frames ?? 0, edits: this.edits ?? 0,
      recomputeFrames: this.recomputeFrames ?? 0, fpsOverall: overall, fpsRecompute: recompute,
    });
    const el = (id) => document.getElementById(id);
    el("bench-fps").textContent = overall.toFixed(1);
    el("bench-fps-recompute").textContent = recompute.toFixed(1);
    el("bench-edits").textContent = String(this.edits ?? 0);
  }
}
