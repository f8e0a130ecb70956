// The starting scene of a new world: a floor and a few shapes (sdfserver/render/scene.py).
const GRASS = 0b010_101_00, STONE = 0b100_100_10, RED = 0b111_001_00, BLUE = 0b001_010_11,
  YELLOW = 0b111_110_00, WHITE = 0xff;

export function demoScene([sx, sy, sz]) {
  const floor = Math.max(1, Math.floor(sy / 16));
  const u = Math.max(2, Math.floor(Math.min(sx, sz) / 8));
  const cx = Math.floor(sx / 2), cz = Math.floor(sz / 2);
  const thin = Math.max(1, Math.floor(u / 2));
  return [
    { op: "box", min: [0, 0, 0], max: [sx, floor, sz], colour: GRASS },
    { op: "sphere", center: [cx, floor + 1.5 * u, cz], radius: 1.5 * u, colour: RED },
    { op: "box", min: [cx - 3 * u, floor, cz - 3 * u], max: [cx - u, floor + 2 * u, cz - u], colour: BLUE },
    { op: "box", min: [cx + 2 * u, floor, cz - 3 * u], max: [cx + 2 * u + thin, floor + 4 * u, cz - 3 * u + thin], colour: STONE },
    { op: "sphere", center: [cx + 2 * u, floor + u, cz + 2 * u], radius: u, colour: YELLOW },
    { op: "box", min: [cx - 3 * u, floor, cz + 2 * u], max: [cx - 2 * u, floor + 3 * u, cz + 3 * u], colour: WHITE },
  ];
}
