/** Retries against a stand-in server (node:http) that refuses with 429 or 503 and Retry-After,
 * then answers: the waits, which calls are sent again, and the user agent. */

import assert from "node:assert/strict";
import { readFile } from "node:fs/promises";
import { createServer, type IncomingMessage, type ServerResponse } from "node:http";
import { after, before, test } from "node:test";

import { Client, NotReady, RateLimited, USER_AGENT, VERSION, WritesDisabled, encode, sphere } from "sdfclient";

const MSGPACK = "application/msgpack";
const WORLD = { id: "w1", size: [16, 16, 16], chunk_size: 16, max_distance: 10, version: 0 };
const RETRY_AFTER_S = 0.2;

interface Arrival { method: string; path: string; atMs: number; userAgent: string | undefined }

/** What the stand-in answers: `refusals` refusals of `status` (with `code`), then 200. */
let plan = { status: 429, code: "rate_limited", refusals: 0, retryAfter: String(RETRY_AFTER_S) as string | null };
let arrivals: Arrival[] = [];
let baseUrl: string;
const standIn = createServer((request: IncomingMessage, response: ServerResponse) => {
  request.resume();
  request.on("end", () => {
    const path = new URL(request.url ?? "/", "http://x").pathname;
    arrivals.push({ method: request.method ?? "", path, atMs: performance.now(), userAgent: request.headers["user-agent"] });
    if (arrivals.length <= plan.refusals) {
      const headers: Record<string, string> = { "content-type": MSGPACK };
      if (plan.retryAfter !== null) headers["retry-after"] = plan.retryAfter;
      response.writeHead(plan.status, headers);
      response.end(encode({ error: { code: plan.code, message: "refused by the stand-in" } }));
    } else if (path.endsWith("/edits")) {
      response.writeHead(200, { "content-type": MSGPACK }).end(encode({ version: 3 }));
    } else if (request.method === "DELETE") {
      response.writeHead(204).end();
    } else {
      response.writeHead(200, { "content-type": MSGPACK }).end(encode(WORLD));
    }
  });
});

before(async () => {
  await new Promise<void>((resolve) => standIn.listen(0, "127.0.0.1", resolve));
  baseUrl = `http://127.0.0.1:${(standIn.address() as { port: number }).port}`;
});

after(async () => {
  standIn.closeAllConnections();
  await new Promise((resolve) => standIn.close(resolve));
});

function refuse(status: number, code: string, refusals: number, retryAfter: string | null = String(RETRY_AFTER_S)): void {
  plan = { status, code, refusals, retryAfter };
  arrivals = [];
}

/** The waits between arrivals, in seconds. */
function waits(): number[] {
  return arrivals.slice(1).map((a, i) => (a.atMs - arrivals[i].atMs) / 1000);
}

/** Each wait is Retry-After doubled per attempt, stretched by at most 25% (and a little for the loop). */
function assertBackoff(observed: number[]): void {
  observed.forEach((wait, attempt) => {
    const base = RETRY_AFTER_S * 2 ** attempt;
    assert.ok(wait >= base * 0.99 && wait <= base * 1.25 + 0.1, `wait ${attempt}: ${wait} s, base ${base} s`);
  });
}

test("a 429 is sent again after Retry-After, doubled, then answers", async () => {
  refuse(429, "rate_limited", 2);
  const world = await new Client(baseUrl).getWorld("w1");
  assert.equal(world.id, "w1");
  assert.equal(arrivals.length, 3);
  assertBackoff(waits());
});

test("a 429 to a creation is sent again too (the server did nothing)", async () => {
  refuse(429, "rate_limited", 1);
  await new Client(baseUrl).createWorld([16, 16, 16]);
  assert.deepEqual(arrivals.map((a) => a.method), ["POST", "POST"]);
});

test("past `retries` refusals the error is thrown with its retryAfterS", async () => {
  refuse(429, "rate_limited", 5);
  await assert.rejects(new Client(baseUrl, { retries: 1 }).getWorld("w1"), (error: unknown) => {
    assert.ok(error instanceof RateLimited);
    assert.equal(error.retryAfterS, RETRY_AFTER_S);
    return true;
  });
  assert.equal(arrivals.length, 2);
  refuse(429, "rate_limited", 5);
  await assert.rejects(new Client(baseUrl, { retries: 0 }).getWorld("w1"), RateLimited);
  assert.equal(arrivals.length, 1);
});

test("a wait past maxRetryWaitS is not waited for", async () => {
  refuse(429, "rate_limited", 1, "5");
  const started = performance.now();
  await assert.rejects(new Client(baseUrl, { maxRetryWaitS: 1 }).getWorld("w1"), RateLimited);
  assert.equal(arrivals.length, 1);
  assert.ok(performance.now() - started < 1000);
});

test("without Retry-After a refusal is not sent again", async () => {
  refuse(429, "rate_limited", 1, null);
  await assert.rejects(new Client(baseUrl).getWorld("w1"), RateLimited);
  assert.equal(arrivals.length, 1);
});

test("a 503 is sent again for calls safe to repeat: reads, and edits with an idempotency key", async () => {
  refuse(503, "not_ready", 2);
  await new Client(baseUrl).getWorld("w1");
  assert.equal(arrivals.length, 3);
  assertBackoff(waits());
  refuse(503, "not_ready", 1);
  assert.equal(await new Client(baseUrl).edit("w1", [sphere([1, 1, 1], 1)], { idempotencyKey: "k1" }), 3);
  assert.equal(arrivals.length, 2);
});

test("a 503 is not sent again for creations, imports, deletions and edits without a key", async () => {
  const client = new Client(baseUrl);
  const calls: [string, () => Promise<unknown>][] = [
    ["create", () => client.createWorld([16, 16, 16])],
    ["import", () => client.importWorld(new Uint8Array([1, 2, 3]))],
    ["delete", () => client.deleteWorld("w1")],
    ["edit", () => client.edit("w1", [sphere([1, 1, 1], 1)])],
  ];
  for (const [name, call] of calls) {
    refuse(503, "not_ready", 1);
    await assert.rejects(call(), NotReady, name);
    assert.equal(arrivals.length, 1, name);
  }
});

test("a 503 writes_disabled is never sent again", async () => {
  refuse(503, "writes_disabled", 1);
  await assert.rejects(new Client(baseUrl).getWorld("w1"), WritesDisabled);
  assert.equal(arrivals.length, 1);
});

test("bad retry options are refused", () => {
  assert.throws(() => new Client(baseUrl, { retries: -1 }), RangeError);
  assert.throws(() => new Client(baseUrl, { retries: 1.5 }), RangeError);
  assert.throws(() => new Client(baseUrl, { maxRetryWaitS: -1 }), RangeError);
});

test("every request says User-Agent: sdfclient-ts/<package version>", async () => {
  const manifest = JSON.parse(await readFile(new URL("../../package.json", import.meta.url), "utf8")) as { version: string };
  assert.equal(VERSION, manifest.version);
  assert.equal(USER_AGENT, `sdfclient-ts/${manifest.version}`);
  refuse(429, "rate_limited", 1);
  await new Client(baseUrl).getWorld("w1");
  assert.deepEqual(arrivals.map((a) => a.userAgent), [USER_AGENT, USER_AGENT]);
});
