/** What the stream tests share: reading a stream until a message comes. */

import assert from "node:assert/strict";

import type { Stream, StreamMessage } from "sdfclient";

/** Messages until `done` says so; fails after `limit` messages. */
export async function until(
  stream: Stream, done: (message: StreamMessage) => boolean, limit = 100,
): Promise<StreamMessage[]> {
  const seen: StreamMessage[] = [];
  for await (const message of stream) {
    seen.push(message);
    if (done(message)) return seen;
    assert.ok(seen.length < limit, `no match in ${limit} messages: ${seen.map((m) => m.type).join(", ")}`);
  }
  assert.fail("the stream ended");
}
