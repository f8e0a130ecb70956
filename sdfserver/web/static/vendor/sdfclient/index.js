/** sdfclient: the TypeScript client of sdfserver (docs/clients.md, "TypeScript"). */
export { colours, distances } from "./blocks.js";
export { Client, DEFAULT_MAX_RETRY_WAIT_S, DEFAULT_RETRIES, DEFAULT_TIMEOUT_MS } from "./client.js";
export { box, eraseBox, eraseSphere, sphere, voxels } from "./edits.js";
export * from "./errors.js";
export { DEFAULT_MAX_FRAME_BYTES, DEFAULT_MAX_RECONNECT_ATTEMPTS, DEFAULT_MAX_RECONNECT_DELAY_MS, DEFAULT_RECONNECT_DELAY_MS, Stream, closedError, streamUrl, } from "./stream.js";
export { USER_AGENT, VERSION } from "./version.js";
export { DTYPES, blob, decode, encode, toArray } from "./wire.js";
