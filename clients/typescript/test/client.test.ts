/** The HTTP calls against a real server: worlds, edits and reads checked against a reference,
 * every query kind, frames, files and the error classes. */

import assert from "node:assert/strict";
import { after, before, describe, test } from "node:test";

import {
  Client, InvalidEdit, InvalidInput, NotFound, ServerError, box, colours, distances, eraseBox, sphere, voxels, type Vec3,
} from "sdfclient";

import { TestServer } from "./server.js";

let server: TestServer;
let client: Client;

before(async () => {
  server = await TestServer.start();
  client = new Client(server.url);
});

after(async () => {
  await server?.stop();
});

/** A small deterministic generator (mulberry32): the seed is printed by a failing assertion. */
function random(seed: number): () => number {
  return () => {
    seed = (seed + 0x6d2b79f5) | 0;
    let t = Math.imul(seed ^ (seed >>> 15), 1 | seed);
    t = (t + Math.imul(t ^ (t >>> 7), 61 | t)) ^ t;
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
  };
}

/** The capped taxicab distance to the nearest solid, by breadth-first search from every solid
 * (z, y, x order); all `cap` where there is none within it. */
function taxicab(solid: Uint8Array, [nx, ny, nz]: Vec3, cap: number): Uint8Array {
  const out = new Uint8Array(solid.length).fill(cap);
  let frontier: number[] = [];
  solid.forEach((v, i) => {
    if (v) {
      out[i] = 0;
      frontier.push(i);
    }
  });
  for (let d = 1; d < cap && frontier.length > 0; d++) {
    const next: number[] = [];
    for (const i of frontier) {
      const x = i % nx, y = Math.floor(i / nx) % ny, z = Math.floor(i / (nx * ny));
      const around = [[x - 1, y, z], [x + 1, y, z], [x, y - 1, z], [x, y + 1, z], [x, y, z - 1], [x, y, z + 1]];
      for (const [a, b, c] of around) {
        if (a < 0 || b < 0 || c < 0 || a >= nx || b >= ny || c >= nz) continue;
        const j = (c * ny + b) * nx + a;
        if (out[j] > d) {
          out[j] = d;
          next.push(j);
        }
      }
    }
    frontier = next;
  }
  return out;
}

describe("worlds", () => {
  test("create with every field option, list, describe, update, delete", async () => {
    const palette: Vec3[] = Array.from({ length: 255 }, (_, i) => [i, 255 - i, 7]);
    const world = await client.createWorld([32, 16, 32], {
      chunkSize: 16, maxDistance: 12, algorithm: "exact", metric: "euclidean", signed: true,
      voxelSize: 0.25, origin: [-4, 0, -4], palette,
    });
    try {
      assert.match(world.id, /^[0-9a-f]{12}$/);
      assert.deepEqual(world.size, [32, 16, 32]);
      assert.equal(world.maxDistance, 12);
      assert.equal(world.metric, "euclidean");
      assert.equal(world.signed, true);
      assert.equal(world.voxelSize, 0.25);
      assert.deepEqual(world.origin, [-4, 0, -4]);
      assert.deepEqual(world.palette?.[3], [3, 252, 7]);
      assert.equal(world.storage, "dense");
      assert.ok((await client.listWorlds()).some((w) => w.id === world.id));
      assert.deepEqual((await client.getWorld(world.id)).origin, [-4, 0, -4]);

      const updated = await client.updateWorld(world.id, { voxelSize: 1, origin: [0, 0, 0], maxDistance: 8 });
      assert.equal(updated.voxelSize, 1);
      assert.equal(updated.maxDistance, 8);
      assert.equal(updated.metric, "euclidean");
    } finally {
      await client.deleteWorld(world.id);
    }
    await assert.rejects(client.getWorld(world.id), NotFound);
  });

  test("a focus, set and removed; a sparse generated terrain", async () => {
    const focused = await client.createWorld([64, 32, 64], { algorithm: "exact", lodAlgorithm: "jfa", focus: { center: [1, 0, 1], size: [2, 2, 2] } });
    try {
      assert.deepEqual(focused.focus, { center: [1, 0, 1], size: [2, 2, 2] });
      assert.equal(focused.lodAlgorithm, "jfa");
      assert.equal((await client.updateWorld(focused.id, { focus: null })).focus, null);
    } finally {
      await client.deleteWorld(focused.id);
    }
    const terrain = await client.createWorld([64, 64, 64], {
      storage: "sparse", maxDistance: 8, generate: { kind: "terrain", seed: 7, base: 20, amplitude: 8 },
    });
    try {
      assert.equal(terrain.storage, "sparse");
      assert.equal(terrain.generate?.seed, 7);
      const column = await client.readVoxels(terrain.id, { box: [[5, 0, 5], [6, 64, 6]], minVersion: 0 });
      assert.ok(column.data.some((v) => v !== 0), "the terrain has ground");
      assert.ok(column.data.some((v) => v === 0), "and sky");
    } finally {
      await client.deleteWorld(terrain.id);
    }
  });
});

describe("edits and reads", () => {
  test("random edits: the field equals the capped taxicab distance, the voxels the edits", async () => {
    const size: Vec3 = [32, 24, 16];
    const cap = 20;
    const world = await client.createWorld(size, { chunkSize: 8, maxDistance: cap });
    try {
      const seed = Date.now() % 100_000;
      const rand = random(seed);
      const int = (n: number) => Math.floor(rand() * n);
      const quads: number[][] = Array.from({ length: 40 }, () => [int(32), int(24), int(16), 1 + int(255)]);
      const version = await client.edit(world.id, [
        box([2, 0, 2], [10, 3, 9], 0x1c),
        sphere([20, 12, 8], 4, 0xe0),
        voxels(quads),
        eraseBox([0, 0, 0], [4, 24, 4]),
      ]);
      assert.equal(version, 1);

      const solid = new Uint8Array(size[0] * size[1] * size[2]);
      const at = (x: number, y: number, z: number) => (z * size[1] + y) * size[0] + x;
      for (let z = 0; z < 16; z++) for (let y = 0; y < 24; y++) for (let x = 0; x < 32; x++) {
        if (x >= 2 && x < 10 && y < 3 && z >= 2 && z < 9) solid[at(x, y, z)] = 0x1c;
        if ((x - 20) ** 2 + (y - 12) ** 2 + (z - 8) ** 2 <= 16) solid[at(x, y, z)] = 0xe0;
      }
      for (const [x, y, z, c] of quads) solid[at(x, y, z)] = c;
      for (let z = 0; z < 4; z++) for (let y = 0; y < 24; y++) for (let x = 0; x < 4; x++) solid[at(x, y, z)] = 0;

      const voxelBlock = await client.readVoxels(world.id, { minVersion: version });
      assert.deepEqual(voxelBlock.shape, [16, 24, 32]);
      assert.ok(voxelBlock.data instanceof Uint8Array);
      assert.deepEqual(voxelBlock.data, solid, `seed ${seed}`);

      const field = await client.readField(world.id, { minVersion: version });
      assert.equal(field.dtype, "uint8");
      assert.equal(field.content, "distance");
      assert.ok(field.data instanceof Uint8Array);
      assert.ok(field.version >= version);
      assert.deepEqual(field.data, taxicab(solid, size, cap), `seed ${seed}`);

      const part = await client.readField(world.id, { box: [[8, 4, 2], [20, 10, 6]], format: "packed" });
      assert.deepEqual(part.origin, [8, 4, 2]);
      assert.deepEqual(part.shape, [4, 6, 12]);
      assert.ok(part.data instanceof Uint16Array);
      assert.equal(part.content, "distance_colour");
      const i = (1 * 6 + 2) * 12 + 3; // (x, y, z) = (11, 6, 3)
      assert.equal(part.data[i], (field.data[at(11, 6, 3)] << 8) | solid[at(11, 6, 3)]);
      const whole = await client.readField(world.id, { format: "packed" });
      assert.deepEqual(distances(whole), field.data);
      assert.deepEqual(colours(whole), solid);
      assert.throws(() => colours(field), TypeError);
    } finally {
      await client.deleteWorld(world.id);
    }
  });

  test("the answer's dtype decides the array: int16 signed Manhattan, float32 Euclidean", async () => {
    const signed = await client.createWorld([16, 16, 16], { maxDistance: 8, signed: true });
    const euclid = await client.createWorld([16, 16, 16], { maxDistance: 8, metric: "euclidean" });
    try {
      for (const world of [signed, euclid]) await client.edit(world.id, [box([0, 0, 0], [16, 4, 16], 9)]);
      const s = await client.readField(signed.id, { box: [[5, 0, 5], [6, 16, 6]], minVersion: 1 });
      assert.ok(s.data instanceof Int16Array);
      assert.deepEqual(Array.from(s.data), [-1, -2, -2, -1, 1, 2, 3, 4, 5, 6, 7, 8, 8, 8, 8, 8]);
      const e = await client.readField(euclid.id, { box: [[5, 0, 5], [6, 16, 6]], minVersion: 1 });
      assert.ok(e.data instanceof Float32Array);
      assert.deepEqual(Array.from(e.data), [0, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 8, 8, 8, 8]);
      const packed = await client.readField(euclid.id, { box: [[5, 0, 5], [6, 16, 6]], format: "packed" });
      assert.equal(packed.content, "squared_distance");
      assert.deepEqual(distances(packed), e.data);
    } finally {
      await client.deleteWorld(signed.id);
      await client.deleteWorld(euclid.id);
    }
  });

  test("an Idempotency-Key applies a retried batch once", async () => {
    const world = await client.createWorld([16, 16, 16]);
    try {
      const batch = [sphere([8, 8, 8], 3, 7)];
      const first = await client.edit(world.id, batch, { idempotencyKey: "retry-me-1" });
      const again = await client.edit(world.id, batch, { idempotencyKey: "retry-me-1" });
      assert.equal(again, first);
      assert.equal((await client.getWorld(world.id)).version, first);
    } finally {
      await client.deleteWorld(world.id);
    }
  });
});

describe("queries", () => {
  let worldId: string;
  let version: number;

  before(async () => {
    const world = await client.createWorld([32, 32, 32], { maxDistance: 16 });
    worldId = world.id;
    version = await client.edit(worldId, [box([0, 0, 0], [32, 1, 32], 0x1c), box([20, 0, 0], [24, 16, 32], 9)]);
  });

  after(async () => {
    await client.deleteWorld(worldId);
  });

  test("points: distances, gradients and colours", async () => {
    const result = await client.query(worldId, [[10.5, 3.5, 12.5], [10.5, 0.5, 12.5]], { minVersion: version });
    assert.ok(result.distances instanceof Float32Array);
    assert.deepEqual(Array.from(result.distances), [3, 0]);
    assert.deepEqual(Array.from(result.gradients.subarray(0, 3)), [0, 1, 0]);
    assert.deepEqual(Array.from(result.colours), [0, 0x1c]);
    const flat = await client.query(worldId, new Float32Array([10.5, 5.5, 12.5]), { minVersion: version });
    assert.deepEqual(Array.from(flat.distances), [5]);
  });

  test("spheres: clearances and ways out", async () => {
    const result = await client.querySpheres(worldId, [[10.5, 6.5, 12.5, 2], [10.5, 1.5, 12.5, 2]], { minVersion: version });
    assert.deepEqual(Array.from(result.clearances), [4, -1]);
    assert.deepEqual(Array.from(result.directions), [0, 1, 0, 0, 1, 0]);
  });

  test("rays: hits, distances, normals, colours and voxels", async () => {
    const rays = [[2.5, 5.5, 7.5, 1, 0, 0, 100], [2.5, 5.5, 7.5, 1, 0, 0, 10], [30.5, 5.5, 7.5, -1, 0, 0, 100]];
    const result = await client.queryRays(worldId, rays, { minVersion: version });
    assert.deepEqual(Array.from(result.hits), [1, 0, 1]);
    assert.deepEqual(Array.from(result.distances), [17.5, 10, 6.5]);
    assert.deepEqual(Array.from(result.normals), [-1, 0, 0, 0, 0, 0, 1, 0, 0]);
    assert.deepEqual(Array.from(result.colours), [9, 0, 9]);
    assert.ok(result.voxels instanceof Int32Array);
    assert.deepEqual(Array.from(result.voxels), [20, 5, 7, -1, -1, -1, 23, 5, 7]);
  });

  test("frames, picks, export and import", async () => {
    const camera = { position: [40, 24, 40] as Vec3, target: [16, 4, 16] as Vec3, width: 80, height: 60 };
    const png = await client.render(worldId, camera);
    assert.deepEqual(Array.from(png.data.subarray(0, 4)), [0x89, 0x50, 0x4e, 0x47]);
    assert.equal(png.width, 80);
    assert.ok(png.fieldVersion >= version);
    const jpeg = await client.render(worldId, camera, { format: "jpeg", quality: 70, shadows: false });
    assert.deepEqual(Array.from(jpeg.data.subarray(0, 2)), [0xff, 0xd8]);
    const rgba = await client.render(worldId, camera, { format: "rgba" });
    assert.equal(rgba.data.length, 80 * 60 * 4);

    const picked = await client.pick(worldId, camera, 40, 30);
    assert.ok(picked !== null && picked.normal.some((v) => v !== 0));
    const sky = { position: [16, 20, 16] as Vec3, target: [17, 40, 16] as Vec3, width: 8, height: 8 };
    assert.equal(await client.pick(worldId, sky, 4, 4), null);

    const exported = await client.exportWorld(worldId, "npy");
    assert.equal(exported.version, version);
    const imported = await client.importWorld(exported.data, { format: "npy", maxDistance: 16 });
    try {
      const a = await client.readVoxels(worldId);
      const b = await client.readVoxels(imported.id, { minVersion: 1 });
      assert.deepEqual(b.data, a.data);
    } finally {
      await client.deleteWorld(imported.id);
    }
  });

  test("an imported array as a sparse world, exported with its version", async () => {
    const exported = await client.exportWorld(worldId, "npy");
    const sparse = await client.importWorld(exported.data, { storage: "sparse", maxDistance: 16 });
    try {
      assert.equal(sparse.storage, "sparse");
      assert.ok(sparse.version >= 1);
      assert.ok(Array.isArray(sparse.warnings));
      const a = await client.readVoxels(worldId);
      const b = await client.readVoxels(sparse.id, { minVersion: sparse.version });
      assert.deepEqual(b.data, a.data);
      const snapshot = await client.exportWorld(sparse.id, "snapshot");
      assert.equal(snapshot.version, sparse.version);
      const copy = await client.importWorld(snapshot.data);
      try {
        assert.equal(copy.storage, "sparse");
        assert.deepEqual((await client.readVoxels(copy.id)).data, a.data);
      } finally {
        await client.deleteWorld(copy.id);
      }
    } finally {
      await client.deleteWorld(sparse.id);
    }
    await assert.rejects(client.importWorld(exported.data, { storage: "bricks" as "sparse" }), RangeError);
  });
});

describe("errors", () => {
  test("an unknown world is NotFound", async () => {
    await assert.rejects(client.getWorld("000000000000"), (error: unknown) => {
      assert.ok(error instanceof NotFound && error instanceof ServerError);
      assert.equal(error.status, 404);
      assert.equal(error.code, "not_found");
      return true;
    });
    await assert.rejects(client.readField("000000000000"), NotFound);
  });

  test("bad input is InvalidInput (and a bad edit InvalidEdit); nothing changes", async () => {
    await assert.rejects(client.createWorld([32, 32, 32], { chunkSize: 7 }), (error: unknown) => {
      assert.ok(error instanceof InvalidInput);
      assert.equal(error.status, 422);
      assert.match(error.message, /chunk_size/);
      return true;
    });
    const world = await client.createWorld([16, 16, 16]);
    try {
      await assert.rejects(client.query(world.id, [[99, 0, 0]]), InvalidInput);
      await assert.rejects(client.edit(world.id, [voxels([[40, 0, 0, 1]])]), InvalidEdit);
      assert.equal((await client.getWorld(world.id)).version, 0);
    } finally {
      await client.deleteWorld(world.id);
    }
  });
});
