/**
 * The wire format of `sdfserver/wire.py`: msgpack, with arrays as blobs
 * `{dtype, shape, data}` (little-endian, C order), never nested lists of voxels.
 *
 * Decoding refuses extension types and bounds every length, like the server's decoder; the
 * client trusts its server more than the server trusts its clients, so an answer may be as large
 * as a whole world's field.
 */
import { Decoder, encode as msgpackEncode } from "@msgpack/msgpack";
import { ProtocolError, isRecord } from "./errors.js";
export const CONTENT_TYPE = "application/msgpack";
export const CONTENT_TYPES = new Set([CONTENT_TYPE, "application/x-msgpack", "application/vnd.msgpack"]);
/** The typed array for each dtype the wire carries. */
export const DTYPES = {
    uint8: Uint8Array,
    uint16: Uint16Array,
    uint32: Uint32Array,
    int8: Int8Array,
    int16: Int16Array,
    int32: Int32Array,
    int64: BigInt64Array,
    float32: Float32Array,
    float64: Float64Array,
};
const RESPONSE_LIMIT_BYTES = 1 << 30;
const decoder = new Decoder({
    maxBinLength: RESPONSE_LIMIT_BYTES,
    maxStrLength: 1 << 20,
    maxArrayLength: 1 << 24,
    maxMapLength: 1 << 12,
    maxExtLength: 0,
});
if (new Uint8Array(new Uint16Array([1]).buffer)[0] !== 1) {
    // Typed arrays use the platform's byte order and the wire's is little-endian.
    throw new Error("sdfclient needs a little-endian platform");
}
export function encode(message) {
    return msgpackEncode(message);
}
/** One message; blobs stay maps (`toArray` turns one into its typed array). */
export function decode(data) {
    try {
        return decoder.decode(data);
    }
    catch (error) {
        throw new ProtocolError(`malformed msgpack: ${error.message}`);
    }
}
function isDtype(value) {
    return typeof value === "string" && Object.hasOwn(DTYPES, value);
}
export function isBlob(value) {
    return isRecord(value) && isDtype(value.dtype) && Array.isArray(value.shape) && value.data instanceof Uint8Array;
}
/** A typed array over `data` read as `dtype` (copied only when its offset is not aligned). */
export function view(dtype, data, count, where = "array") {
    if (!isDtype(dtype))
        throw new ProtocolError(`${where}: unknown dtype ${JSON.stringify(dtype)}`);
    if (!(data instanceof Uint8Array))
        throw new ProtocolError(`${where}: data must be binary`);
    const cls = DTYPES[dtype];
    const size = cls.BYTES_PER_ELEMENT;
    if (data.byteLength % size !== 0 || (count !== undefined && count * size !== data.byteLength)) {
        throw new ProtocolError(`${where}: ${data.byteLength} bytes do not hold ${count ?? "whole"} ${dtype} values`);
    }
    const bytes = data.byteOffset % size === 0 ? data : data.slice();
    return new cls(bytes.buffer, bytes.byteOffset, bytes.byteLength / size);
}
/** A blob map as its typed array and shape. */
export function toArray(value, where = "array") {
    if (!isRecord(value) || !Array.isArray(value.shape))
        throw new ProtocolError(`${where}: expected a blob {dtype, shape, data}`);
    const shape = value.shape.map(Number);
    if (shape.some((n) => !Number.isSafeInteger(n) || n < 0)) {
        throw new ProtocolError(`${where}: bad shape ${JSON.stringify(value.shape)}`);
    }
    const count = shape.reduce((a, b) => a * b, 1);
    return { array: view(value.dtype, value.data, count, where), shape };
}
/** A typed array as a blob of `shape` (its length must be the shape's product). */
export function blob(array, shape) {
    const dtype = Object.keys(DTYPES).find((name) => array instanceof DTYPES[name]);
    if (dtype === undefined)
        throw new TypeError(`cannot send a ${array.constructor.name} as a blob`);
    const count = shape.reduce((a, b) => a * b, 1);
    if (count !== array.length) {
        throw new RangeError(`${array.length} values do not fill the shape [${shape.join(", ")}]`);
    }
    return { dtype, shape, data: new Uint8Array(array.buffer, array.byteOffset, array.byteLength) };
}
