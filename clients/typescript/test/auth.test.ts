/** API keys: a bearer token on HTTP and on the stream (ws: a header; a browser-style WebSocket:
 * ?access_token=), Unauthorized without one, another key's world NotFound. */

import assert from "node:assert/strict";
import { after, before, test } from "node:test";

import WebSocket from "ws";

import { Client, NotFound, Stream, Unauthorized, sphere, type WebSocketClass } from "sdfclient";

import { TestServer } from "./server.js";

const ALICE = "alice-token-0123456789";
const BOB = "bob-token-0123456789ab";
let server: TestServer;

before(async () => {
  server = await TestServer.start("--api-keys", `alice:${ALICE},bob:${BOB}`);
});

after(async () => {
  await server?.stop();
});

test("a key sees its own worlds; none is Unauthorized; another's world is NotFound", async () => {
  const alice = new Client(server.url, { apiKey: ALICE });
  const world = await alice.createWorld([16, 16, 16]);
  try {
    assert.equal(world.owner, "alice");
    await assert.rejects(new Client(server.url).listWorlds(), Unauthorized);
    await assert.rejects(new Client(server.url, { apiKey: "wrong-token-0123456789" }).getWorld(world.id), Unauthorized);
    await assert.rejects(new Client(server.url, { apiKey: BOB }).getWorld(world.id), NotFound);
    assert.throws(() => new Client(server.url, { apiKey: "two words" }), TypeError);
  } finally {
    await alice.deleteWorld(world.id);
  }
});

test("the stream takes the key as a header (ws) or as access_token (a browser-style WebSocket)", async () => {
  const alice = new Client(server.url, { apiKey: ALICE });
  const world = await alice.createWorld([16, 16, 16]);
  // ws has the browser's interface; given as `WebSocket` it is used as a browser's would be
  const BrowserStyle = class extends WebSocket {
    constructor(url: string) {
      super(url);
    }
  } as unknown as WebSocketClass;
  try {
    for (const options of [{}, { WebSocket: BrowserStyle }]) {
      const stream = await alice.stream(world.id, options);
      try {
        assert.equal(await stream.edit([sphere([8, 8, 8], 2)]) > 0, true);
      } finally {
        await stream.close();
      }
    }
    await assert.rejects(async () => {
      const stream = await Stream.connect(server.url, world.id, { apiKey: BOB });
      try {
        await stream.ping();
      } finally {
        await stream.close();
      }
    }, NotFound);
    await assert.rejects(async () => {
      const stream = await Stream.connect(server.url, world.id);
      try {
        await stream.ping();
      } finally {
        await stream.close();
      }
    }, Unauthorized);
  } finally {
    await alice.deleteWorld(world.id);
  }
});
