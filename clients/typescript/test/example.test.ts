/** The examples run against a real server and print what they should (docs/clients.md quotes them). */

import assert from "node:assert/strict";
import { execFile } from "node:child_process";
import { fileURLToPath } from "node:url";
import { promisify } from "node:util";
import { after, before, test } from "node:test";

import { Client } from "sdfclient";

import { TestServer } from "./server.js";

let server: TestServer;

before(async () => {
  server = await TestServer.start();
});

after(async () => {
  await server?.stop();
});

test("quickstart", async () => {
  const script = fileURLToPath(new URL("../examples/quickstart.js", import.meta.url));
  const { stdout } = await promisify(execFile)(process.execPath, [script, server.url], { timeout: 60_000 });
  assert.match(stdout, /^field 32x32x32 uint8, version 1$/m);
  assert.match(stdout, /^distance above the sphere \(16, 16, 16\): 4$/m);
  assert.match(stdout, /^point: distance 3, sphere clearance 2$/m);
  assert.match(stdout, /^ray down: hit true at 17.5, voxel 16,12,16$/m);
  const changed = /^version (\d+): (\d+) chunks, first at 0,0,0$/m.exec(stdout);
  assert.ok(changed && Number(changed[1]) >= 2 && Number(changed[2]) >= 1, stdout);
  assert.match(stdout, /^deleted: true$/m);
  assert.deepEqual(await new Client(server.url).listWorlds(), []); // it cleans up
});
