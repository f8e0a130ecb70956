/** The stream's resume against a real server behind a TCP proxy the test cuts: it reconnects,
 * subscribes again and keeps delivering changes; a pending edit learns that its ack was lost;
 * `resume: false` ends at the cut. */

import assert from "node:assert/strict";
import { createConnection, createServer, type Server, type Socket } from "node:net";
import { after, before, test } from "node:test";

import { Client, StreamClosed, TransportError, sphere, type Reconnected } from "sdfclient";

import { until } from "./messages.js";
import { TestServer } from "./server.js";

let server: TestServer;
let client: Client;
let worldId: string;

/** Forwards connections to the server; `cut` drops every open one (both sides), as a network would. */
class Proxy {
  url = "";
  private readonly sockets = new Set<Socket>();
  private readonly listener: Server;

  constructor(target: string) {
    const { hostname, port } = new URL(target);
    this.listener = createServer((inbound) => {
      const outbound = createConnection(Number(port), hostname);
      for (const [a, b] of [[inbound, outbound], [outbound, inbound]]) {
        this.sockets.add(a);
        a.on("close", () => this.sockets.delete(a));
        a.on("error", () => b.destroy());
        a.pipe(b);
      }
    });
  }

  static async start(target: string): Promise<Proxy> {
    const proxy = new Proxy(target);
    await new Promise<void>((resolve) => proxy.listener.listen(0, "127.0.0.1", resolve));
    proxy.url = `http://127.0.0.1:${(proxy.listener.address() as { port: number }).port}`;
    return proxy;
  }

  cut(): number {
    const count = this.sockets.size;
    for (const socket of this.sockets) socket.destroy();
    return count;
  }

  async stop(): Promise<void> {
    this.cut();
    await new Promise((resolve) => this.listener.close(resolve));
  }
}

before(async () => {
  server = await TestServer.start();
  client = new Client(server.url);
  worldId = (await client.createWorld([32, 16, 32], { chunkSize: 16, maxDistance: 10 })).id;
});

after(async () => {
  await server?.stop();
});

test("a dropped connection is resumed: reconnected, subscribed again, and changes keep coming", { timeout: 30_000 }, async () => {
  const proxy = await Proxy.start(server.url);
  const reconnections: Reconnected[] = [];
  const stream = await new Client(proxy.url).stream(worldId, { reconnectDelayMs: 50, onReconnected: (info) => reconnections.push(info) });
  try {
    await stream.subscribe([[0, 0, 0], [32, 16, 32]]);
    await until(stream, (m) => m.type === "chunks");
    await stream.setCamera({ position: [40, 20, 40], target: [16, 4, 16], width: 32, height: 16 }, { format: "png" });
    await until(stream, (m) => m.type === "frame");

    for (let round = 0; round < 2; round++) {
      assert.ok(proxy.cut() > 0);
      // a change made while the connection is down is not missed: the resubscription sends it
      const missed = await client.edit(worldId, [sphere([4 + 8 * round, 4, 4], 2, 7)]);
      const resumed = await until(stream, (m) => m.type === "chunks" && m.version! >= missed);
      const types = resumed.map((m) => m.type);
      assert.ok(types.includes("reconnected") && types.indexOf("reconnected") < types.indexOf("subscribed"), types.join(", "));
      assert.equal(resumed.at(-1)!.chunks.length, 4); // the whole region, as after a first subscribe

      const later = await client.edit(worldId, [sphere([20, 4, 20], 2, 9)]);
      const changed = (await until(stream, (m) => m.type === "chunks" && m.version! >= later)).at(-1)!;
      assert.ok(changed.chunks.some((c) => c.origin[0] === 16 && c.origin[2] === 16));
      await until(stream, (m) => m.type === "frame"); // the camera was sent again
      assert.equal(await stream.edit([sphere([8, 8, 8], 1, 5)]), later + 1); // and the stream takes edits
    }
    assert.equal(reconnections.length, 2);
    assert.equal(reconnections[0].code, 1006);
  } finally {
    await stream.close();
    await proxy.stop();
  }
});

test("an edit whose ack the drop lost throws; a subscribe in flight answers from the new connection", { timeout: 30_000 }, async () => {
  const proxy = await Proxy.start(server.url);
  const stream = await new Client(proxy.url).stream(worldId, { reconnectDelayMs: 50 });
  try {
    const pending = stream.edit([sphere([12, 4, 12], 2, 3)]);
    proxy.cut();
    await assert.rejects(pending, (error: unknown) => error instanceof TransportError && /may or may not/.test((error as Error).message));
    const subscribing = stream.subscribe([[0, 0, 0], [16, 16, 16]]);
    proxy.cut();
    const subscribed = await subscribing;
    assert.deepEqual(subscribed.raw.max, [16, 16, 16]);
    await stream.ping();
  } finally {
    await stream.close();
    await proxy.stop();
  }
});

test("resume: false ends the stream at the drop", { timeout: 30_000 }, async () => {
  const proxy = await Proxy.start(server.url);
  const stream = await new Client(proxy.url).stream(worldId, { resume: false });
  try {
    await stream.subscribe([[0, 0, 0], [16, 16, 16]]);
    await until(stream, (m) => m.type === "chunks");
    proxy.cut();
    await assert.rejects(until(stream, () => false), (error: unknown) => error instanceof StreamClosed && error.code === 1006);
    await assert.rejects(stream.ping(), StreamClosed);
  } finally {
    await stream.close();
    await proxy.stop();
  }
});

test("close() during a reconnection stops it", { timeout: 30_000 }, async () => {
  const proxy = await Proxy.start(server.url);
  const stream = await new Client(proxy.url).stream(worldId, { reconnectDelayMs: 60_000 });
  proxy.cut();
  await new Promise((resolve) => setTimeout(resolve, 100));
  await stream.close(); // would wait a minute for the first attempt otherwise
  await assert.rejects(stream.ping(), StreamClosed);
  await proxy.stop();
});
