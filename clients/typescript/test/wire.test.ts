/** The wire format and the error mapping without a server: blobs both ways, the dtype deciding
 * the typed array, what the decoder refuses, and the error classes chosen by code and status. */

import assert from "node:assert/strict";
import { test } from "node:test";

import { encode as msgpackEncode, ExtData } from "@msgpack/msgpack";

import {
  InternalServerError, InvalidEdit, InvalidInput, NotFound, NotReady, ProtocolError, RateLimited, VersionNotReached,
  WritesDisabled, blob, decode, encode, retryAfter, serverError, toArray, voxels,
} from "sdfclient";

test("a blob travels as {dtype, shape, data} and comes back as its typed array", () => {
  const sent = new Float32Array([1.5, -2, 3.25, 0, 7, 8]);
  const message = decode(encode({ points: blob(sent, [2, 3]) })) as { points: unknown };
  const { array, shape } = toArray(message.points);
  assert.ok(array instanceof Float32Array);
  assert.deepEqual(shape, [2, 3]);
  assert.deepEqual(array, sent);
});

test("each dtype decides its array, wherever the bytes lie in the message", () => {
  const cases = [
    ["uint8", Uint8Array], ["uint16", Uint16Array], ["int16", Int16Array], ["int32", Int32Array],
    ["float32", Float32Array], ["float64", Float64Array],
  ] as const;
  for (const [dtype, cls] of cases) {
    const values = new cls([1, 2, 3, 4]);
    for (let pad = 0; pad < 8; pad++) { // a string before the blob shifts its bytes off alignment
      const message = { pad: "x".repeat(pad), data: { dtype, shape: [4], data: new Uint8Array(values.buffer) } };
      const { array } = toArray((decode(msgpackEncode(message)) as { data: unknown }).data);
      assert.ok(array instanceof cls, dtype);
      assert.deepEqual(Array.from(array), [1, 2, 3, 4]);
    }
  }
});

test("bad blobs and extension types are ProtocolErrors", () => {
  const bytes = new Uint8Array(12);
  assert.throws(() => toArray({ dtype: "float16", shape: [6], data: bytes }), ProtocolError);
  assert.throws(() => toArray({ dtype: "float32", shape: [4], data: bytes }), ProtocolError);
  assert.throws(() => toArray({ dtype: "float32", shape: [-3], data: bytes }), ProtocolError);
  assert.throws(() => toArray([1, 2, 3]), ProtocolError);
  assert.throws(() => decode(msgpackEncode(new ExtData(5, new Uint8Array([1])))), ProtocolError);
  assert.throws(() => decode(new Uint8Array([0xc1])), ProtocolError);
});

test("voxels: rows or a flat list become one uint16 N x 4 blob; out of range is refused", () => {
  const edit = voxels([[1, 2, 3, 255], [4, 5, 6, 0]]);
  assert.equal(edit.op, "voxels");
  const { array, shape } = toArray(edit.op === "voxels" ? edit.voxels : null);
  assert.ok(array instanceof Uint16Array);
  assert.deepEqual(shape, [2, 4]);
  assert.deepEqual(Array.from(array), [1, 2, 3, 255, 4, 5, 6, 0]);
  assert.throws(() => voxels([1, 2, 3]), RangeError);
  assert.throws(() => voxels([[1, 2, 3, 70000]]), RangeError);
  assert.throws(() => voxels([[1, 2, -3, 1]]), RangeError);
});

test("the error class comes from the code first, then the status", () => {
  const body = (code: string) => ({ error: { code, message: "m", detail: [{ loc: ["x"] }] } });
  assert.ok(serverError(422, body("invalid_edit")) instanceof InvalidEdit);
  assert.ok(serverError(422, body("invalid_input")) instanceof InvalidInput);
  assert.ok(serverError(503, body("version_not_reached")) instanceof VersionNotReached);
  assert.ok(serverError(503, body("writes_disabled")) instanceof WritesDisabled);
  assert.ok(serverError(503, body("world_moved")) instanceof NotReady);
  assert.ok(serverError(404, "plain text") instanceof NotFound);
  assert.ok(serverError(502, null) instanceof InternalServerError);
  const limited = serverError(429, body("rate_limited"), retryAfter("2"));
  assert.ok(limited instanceof RateLimited);
  assert.equal(limited.retryAfterS, 2);
  assert.equal(limited.code, "rate_limited");
  assert.equal(limited.serverMessage, "m");
  assert.deepEqual(limited.detail, [{ loc: ["x"] }]);
  const streamed = serverError(null, { code: "not_found", message: "gone" }); // a stream's error frame
  assert.ok(streamed instanceof NotFound);
  assert.equal(streamed.status, 404);
  assert.equal(retryAfter(undefined), null);
  assert.equal(retryAfter("soon"), null);
  assert.ok(retryAfter(new Date(Date.now() + 5000).toUTCString())! > 3);
});
