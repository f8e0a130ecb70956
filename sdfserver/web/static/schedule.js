// The dissertation's benchmark mode (§3.5): a brush every 200 ms at a random position and size,
// from a seed. The same generator and draw order as sdfserver/bench/schedule.py (a test runs
// both with node), so the page and `sdfserver bench` make the same schedule from the same seed.

export const EDIT_INTERVAL_MS = 200;
export const DEFAULT_SEED = 2025;

// mulberry32: 32-bit integer steps, one division by 2^32 (exact in a double).
export function mulberry32(seed) {
  let state = seed >>> 0;
  return function uniform() {
    state = (state + 0x6d2b79f5) >>> 0;
    let t = state;
    t = Math.imul(t ^ (t >>> 15), t | 1) >>> 0;
    t = (t ^ ((t + (Math.imul(t ^ (t >>> 7), t | 61) >>> 0)) >>> 0)) >>> 0;
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
  };
}

export function maxRadiusVox(size) {
  return Math.max(2, Math.min(...size) / 16);
}

export function nextBrush(uniform, size) {
  const center = size.map((s) => uniform() * s);
  const radius = 1 + uniform() * (maxRadiusVox(size) - 1);
  const place = uniform() >= 0.5;
  const colour = place ? 1 + Math.floor(uniform() * 255) : 0;
  return { op: "sphere", center, radius, colour };
}

export function schedule(seed, size, count) {
  const uniform = mulberry32(seed);
  return Array.from({ length: count }, () => nextBrush(uniform, size));
}
