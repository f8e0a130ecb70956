/** The WebSocket stream against a real server: chunks after edits (over the socket and over
 * HTTP), camera frames, error frames, an unknown world. */

import assert from "node:assert/strict";
import { createServer } from "node:http";
import { after, before, test } from "node:test";

import { Client, InvalidEdit, NotFound, NotReady, Stream, box, sphere, voxels } from "sdfclient";

import { until } from "./messages.js";
import { TestServer } from "./server.js";

let server: TestServer;
let client: Client;
let worldId: string;

before(async () => {
  server = await TestServer.start();
  client = new Client(server.url);
  worldId = (await client.createWorld([32, 16, 32], { chunkSize: 16, maxDistance: 10 })).id;
});

after(async () => {
  await server?.stop();
});

test("subscribe: every chunk once, then the chunks an edit changed, equal to a field read", async () => {
  const stream = await client.stream(worldId);
  try {
    const subscribed = await stream.subscribe([[0, 0, 0], [20, 10, 20]]);
    assert.deepEqual(subscribed.raw.max, [32, 16, 32]); // widened to whole chunks
    assert.equal(subscribed.raw.dtype, "uint8");
    const initial = await until(stream, (m) => m.type === "chunks");
    assert.equal(initial.at(-1)!.chunks.length, 4);

    const version = await stream.edit([sphere([4, 4, 4], 2, 0xe0)]);
    assert.equal(version, 1);
    const changed = (await until(stream, (m) => m.type === "chunks" && m.version! >= version)).at(-1)!;
    const first = changed.chunks.find((c) => c.chunk.every((v) => v === 0));
    assert.ok(first, `chunk (0, 0, 0) among ${JSON.stringify(changed.chunks.map((c) => c.chunk))}`);
    assert.deepEqual(first.shape, [16, 16, 16]);
    assert.ok(first.data instanceof Uint8Array);
    const field = await client.readField(worldId, { box: [[0, 0, 0], [16, 16, 16]], minVersion: changed.version! });
    assert.deepEqual(first.data, field.data);

    // an edit over HTTP reaches the stream too
    const second = await client.edit(worldId, [box([20, 0, 20], [24, 2, 24], 3)]);
    const later = (await until(stream, (m) => m.type === "chunks" && m.version! >= second)).at(-1)!;
    assert.ok(later.chunks.some((c) => c.origin[0] === 16 && c.origin[2] === 16));
  } finally {
    await stream.close();
  }
});

test("a refused frame throws its error and the stream stays open", async () => {
  const stream = await client.stream(worldId);
  try {
    await assert.rejects(stream.edit([voxels([[99, 0, 0, 1]])]), InvalidEdit);
    await stream.ping();
  } finally {
    await stream.close();
  }
});

test("a camera gets frames", async () => {
  const stream = await client.stream(worldId);
  try {
    await stream.setCamera({ position: [40, 20, 40], target: [16, 4, 16], width: 48, height: 32 }, { format: "png", maxFps: 30 });
    const frame = (await until(stream, (m) => m.type === "frame")).at(-1)!;
    assert.equal(frame.raw.width, 48);
    const data = frame.raw.data as Uint8Array;
    assert.deepEqual(Array.from(data.subarray(0, 4)), [0x89, 0x50, 0x4e, 0x47]);
  } finally {
    await stream.close();
  }
});

test("an unknown world's stream is NotFound", async () => {
  await assert.rejects(async () => {
    const stream = await client.stream("000000000000");
    try {
      await stream.subscribe([[0, 0, 0], [16, 16, 16]]);
    } finally {
      await stream.close();
    }
  }, NotFound);
});

test("a handshake refused with an HTTP answer throws the error its body names", async () => {
  // what a server past its connection limit answers before any route
  const refusing = createServer((_, response) => {
    response.writeHead(503, { "content-type": "application/json" });
    response.end(JSON.stringify({ error: { code: "not_ready", message: "too many connections" } }));
  });
  await new Promise<void>((resolve) => refusing.listen(0, "127.0.0.1", resolve));
  const { port } = refusing.address() as { port: number };
  try {
    await assert.rejects(Stream.connect(`http://127.0.0.1:${port}`, worldId), (error: unknown) => {
      assert.ok(error instanceof NotReady);
      assert.match(error.message, /too many connections/);
      return true;
    });
  } finally {
    refusing.closeAllConnections();
    await new Promise((resolve) => refusing.close(resolve));
  }
});
