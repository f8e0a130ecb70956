/**
 * `Client`: the HTTP API of sdfserver, the calls of the Python client's `Client`.
 *
 *     const client = new Client("http://127.0.0.1:8000", { apiKey });
 *     const world = await client.createWorld([64, 64, 64], { maxDistance: 32 });
 *     const version = await client.edit(world.id, [sphere([32, 32, 32], 6)]);
 *     const field = await client.readField(world.id, { minVersion: version }); // reads its own write
 *
 * Bodies travel as msgpack (arrays as typed-array blobs); `apiKey` is sent as
 * `Authorization: Bearer <key>` on every request and on the stream. Requests use the global
 * `fetch` (or the one given, for tests) and say `User-Agent: sdfclient-ts/<version>` (browsers
 * keep their own).
 *
 * A 429, or a 503 to a call that may be sent twice (not a world's creation, import or deletion,
 * nor an edit batch without an `idempotencyKey`), is sent again after the server's `Retry-After`,
 * doubled at each further attempt and stretched by up to 25% so that refused clients come back
 * spread out, up to `retries` times (0: never) and as long as the wait stays within
 * `maxRetryWaitS`; then its error is thrown, `retryAfterS` and all. A 503 `writes_disabled` is
 * never retried: it lasts until the server restarts.
 */
import { ProtocolError, Timeout, TransportError, WritesDisabled, errorClass, isRecord, retryAfter, serverError } from "./errors.js";
import * as parse from "./parse.js";
import { Stream } from "./stream.js";
import { USER_AGENT } from "./version.js";
import { CONTENT_TYPE, CONTENT_TYPES, blob, decode, encode } from "./wire.js";
export const DEFAULT_TIMEOUT_MS = 30_000;
export const DEFAULT_RETRIES = 2;
export const DEFAULT_MAX_RETRY_WAIT_S = 30;
const RETRY_JITTER = 0.25;
const OCTET = "application/octet-stream";
const FRAME_TYPES = { png: "image/png", jpeg: "image/jpeg", rgba: OCTET };
/** The options' names on the wire (`chunkSize` -> `chunk_size`, ...). */
const WIRE_NAMES = {
    chunkSize: "chunk_size",
    maxDistance: "max_distance",
    algorithm: "algorithm",
    lodAlgorithm: "lod_algorithm",
    focus: "focus",
    borders: "borders",
    storage: "storage",
    generate: "generate",
    metric: "metric",
    signed: "signed",
    voxelSize: "voxel_size",
    origin: "origin",
    palette: "palette",
};
function worldPath(worldId) {
    if (typeof worldId !== "string" || worldId === "" || worldId.includes("/")) {
        throw new TypeError(`a world id is a non-empty string without '/', got ${JSON.stringify(worldId)}`);
    }
    return `/v1/worlds/${encodeURIComponent(worldId)}`;
}
function readParams({ box, minVersion }) {
    const params = {};
    if (box !== undefined) {
        const [lo, hi] = box;
        if (lo.length !== 3 || hi.length !== 3)
            throw new RangeError("a box is [[x, y, z], [x, y, z]]");
        params.min = lo.map((v) => Math.trunc(v)).join(",");
        params.max = hi.map((v) => Math.trunc(v)).join(",");
    }
    if (minVersion !== undefined)
        params.min_version = String(Math.trunc(minVersion));
    return params;
}
function wireOptions(options) {
    const body = {};
    for (const [key, value] of Object.entries(options)) {
        if (value === undefined)
            continue;
        const name = WIRE_NAMES[key];
        if (name === undefined)
            throw new TypeError(`unknown world option ${JSON.stringify(key)}`);
        body[name] = value;
    }
    return body;
}
/** `kind` rows of `width` finite numbers as one float32 (N, width) blob. */
function rowsBlob(kind, rows, width) {
    const list = rows;
    const flat = list.length > 0 && Array.isArray(list[0])
        ? Float32Array.from(rows.flatMap((row) => {
            if (row.length !== width)
                throw new RangeError(`${kind}: each row has ${width} numbers, got ${row.length}`);
            return row;
        }))
        : rows instanceof Float32Array ? rows : Float32Array.from(rows);
    if (flat.length === 0 || flat.length % width !== 0) {
        throw new RangeError(`${kind} must be a non-empty N x ${width} array, got ${flat.length} numbers`);
    }
    if (!flat.every(Number.isFinite))
        throw new RangeError(`query ${kind} must be finite`);
    return blob(flat, [flat.length / width, width]);
}
/**
 * Seconds to wait before sending `call` again after `response` (its `attempt`-th refusal, from 0),
 * or null when it is not sent again: only 429 and 503 answers that carry a `Retry-After` are, a 503
 * only for a repeatable call and never for `writes_disabled`; one past `maxWaitS` is not waited for.
 */
async function retryDelay(call, response, attempt, maxWaitS) {
    if (response.status !== 429 && response.status !== 503)
        return null;
    const after = retryAfter(response.headers.get("retry-after"));
    if (after === null)
        return null;
    if (response.status === 503) {
        if (call.repeatable === false)
            return null;
        if (errorClass(503, await errorCode(response.clone())) === WritesDisabled)
            return null;
    }
    const delay = after * 2 ** attempt * (1 + RETRY_JITTER * Math.random());
    return delay <= maxWaitS ? delay : null;
}
/** The `error.code` of an error body, or null where there is none to read. */
async function errorCode(response) {
    try {
        const bytes = new Uint8Array(await response.arrayBuffer());
        const ctype = (response.headers.get("content-type") ?? "").split(";")[0].trim().toLowerCase();
        const body = CONTENT_TYPES.has(ctype) ? decode(bytes) : JSON.parse(new TextDecoder().decode(bytes));
        const error = isRecord(body) ? body.error : null;
        return isRecord(error) && error.code ? String(error.code) : null;
    }
    catch {
        return null;
    }
}
function checkedRetries(retries, maxWaitS) {
    if (!Number.isInteger(retries) || retries < 0)
        throw new RangeError(`retries must be an integer >= 0, got ${retries}`);
    if (!(maxWaitS >= 0))
        throw new RangeError(`maxRetryWaitS must be >= 0, got ${maxWaitS}`);
    return [retries, maxWaitS];
}
function checkedKey(apiKey) {
    if (typeof apiKey !== "string" || apiKey.trim() === "" || /\s/.test(apiKey)) {
        throw new TypeError("apiKey must be a non-empty token without spaces");
    }
    return apiKey;
}
export class Client {
    baseUrl;
    timeoutMs;
    apiKey;
    retries;
    maxRetryWaitS;
    headers;
    fetch;
    constructor(baseUrl = "http://127.0.0.1:8000", options = {}) {
        this.baseUrl = baseUrl.replace(/\/+$/, "");
        this.timeoutMs = options.timeoutMs ?? DEFAULT_TIMEOUT_MS;
        this.apiKey = options.apiKey === undefined ? undefined : checkedKey(options.apiKey);
        [this.retries, this.maxRetryWaitS] = checkedRetries(options.retries ?? DEFAULT_RETRIES, options.maxRetryWaitS ?? DEFAULT_MAX_RETRY_WAIT_S);
        this.headers = {
            "user-agent": USER_AGENT,
            ...(this.apiKey === undefined ? {} : { authorization: `Bearer ${this.apiKey}` }),
            ...options.headers,
        };
        // A browser's fetch throws "Illegal invocation" when called as another object's method.
        this.fetch = options.fetch ?? globalThis.fetch.bind(globalThis);
    }
    // -- sending ----------------------------------------------------------------------------------
    /** The answer to `call`, sent again while the server refuses it for a while (see the banner). */
    async request(call) {
        for (let attempt = 0;; attempt++) {
            const response = await this.fetchOnce(call);
            const delay = attempt < this.retries ? await retryDelay(call, response, attempt, this.maxRetryWaitS) : null;
            if (delay === null)
                return response;
            await response.arrayBuffer().catch(() => undefined); // frees the connection for the next attempt
            await new Promise((resolve) => setTimeout(resolve, delay * 1000));
        }
    }
    async fetchOnce(call) {
        const url = new URL(this.baseUrl + call.path);
        for (const [key, value] of Object.entries(call.params ?? {}))
            url.searchParams.set(key, value);
        const headers = { ...this.headers, accept: call.accept ?? CONTENT_TYPE, ...call.headers };
        let body;
        if (call.body !== undefined) {
            headers["content-type"] = CONTENT_TYPE;
            body = encode(call.body);
        }
        else if (call.content !== undefined) {
            headers["content-type"] = OCTET;
            body = call.content;
        }
        try {
            return await this.fetch(url, {
                method: call.method, headers, body, signal: AbortSignal.timeout(this.timeoutMs),
            });
        }
        catch (error) {
            const err = error;
            const cls = err.name === "TimeoutError" || err.name === "AbortError" ? Timeout : TransportError;
            const cause = err.cause?.message;
            throw new cls(`${call.method} ${call.path}: ${err.name}: ${err.message}${cause ? ` (${cause})` : ""}`);
        }
    }
    /** The decoded body of a successful answer, or the ServerError its error body describes. */
    async send(call) {
        const response = await this.request(call);
        if (response.status >= 400)
            throw await this.failure(call, response);
        return this.decode(call, response);
    }
    async decode(call, response) {
        const bytes = new Uint8Array(await this.body(call, response));
        if (bytes.byteLength === 0)
            return null;
        const ctype = (response.headers.get("content-type") ?? "").split(";")[0].trim().toLowerCase();
        if (CONTENT_TYPES.has(ctype))
            return decode(bytes);
        if (ctype === "application/json" || ctype.endsWith("+json")) {
            try {
                return JSON.parse(new TextDecoder().decode(bytes));
            }
            catch (error) {
                throw new ProtocolError(`${call.method} ${call.path}: unreadable JSON: ${error.message}`);
            }
        }
        throw new ProtocolError(`${call.method} ${call.path}: unexpected content type ${JSON.stringify(ctype)} (status ${response.status})`);
    }
    async body(call, response) {
        try {
            return await response.arrayBuffer();
        }
        catch (error) {
            const err = error;
            const cls = err.name === "TimeoutError" ? Timeout : TransportError;
            throw new cls(`${call.method} ${call.path}: reading the answer: ${err.name}: ${err.message}`);
        }
    }
    async failure(call, response) {
        let body;
        try {
            body = await this.decode(call, response);
        }
        catch (error) {
            if (!(error instanceof ProtocolError))
                return error;
            body = null;
        }
        return serverError(response.status, body, retryAfter(response.headers.get("retry-after")));
    }
    /** A binary answer (a frame, a file) and its headers. */
    async binary(call, expected) {
        const response = await this.request(call);
        if (response.status >= 400)
            throw await this.failure(call, response);
        const ctype = (response.headers.get("content-type") ?? "").split(";")[0].trim().toLowerCase();
        if (ctype !== expected)
            throw new ProtocolError(`${call.path}: expected ${expected}, got ${JSON.stringify(ctype)}`);
        return { data: new Uint8Array(await this.body(call, response)), headers: response.headers };
    }
    // -- worlds -----------------------------------------------------------------------------------
    /** A new world of `size` voxels (x, y, z); every creation option of docs/api.md, "Worlds". */
    async createWorld(size, options = {}) {
        const body = { size: [...size], ...wireOptions(options) };
        return parse.world(await this.send({ method: "POST", path: "/v1/worlds", body, repeatable: false }));
    }
    async listWorlds() {
        return parse.worlds(await this.send({ method: "GET", path: "/v1/worlds" }));
    }
    async getWorld(worldId) {
        return parse.world(await this.send({ method: "GET", path: worldPath(worldId) }));
    }
    /** PATCH the settings given; `focus: null` removes the focus. */
    async updateWorld(worldId, update) {
        const body = wireOptions(update);
        if (Object.keys(body).length === 0)
            throw new TypeError("updateWorld needs at least one setting");
        return parse.world(await this.send({ method: "PATCH", path: worldPath(worldId), body }));
    }
    async deleteWorld(worldId) {
        await this.send({ method: "DELETE", path: worldPath(worldId), repeatable: false }); // a second one: 404
    }
    // -- edits and reads --------------------------------------------------------------------------
    /**
     * One atomic batch (see `edits`); answers the world's new version. With `idempotencyKey`
     * (1-128 printable ASCII characters) a retried batch is applied once and answers the first version.
     */
    async edit(worldId, edits, options = {}) {
        if (edits.length === 0)
            throw new RangeError("an edit batch needs at least one edit");
        const headers = options.idempotencyKey === undefined ? undefined : { "idempotency-key": options.idempotencyKey };
        const answer = parse.record(await this.send({
            method: "POST", path: worldPath(worldId) + "/edits", body: { edits }, headers,
            repeatable: options.idempotencyKey !== undefined,
        }), "edits");
        if (typeof answer.version !== "number")
            throw new ProtocolError("edits: no version in the answer");
        return answer.version;
    }
    /** The field of a box: `distance` (the answer's dtype: uint8, int16 or float32) or `packed` (uint16). */
    async readField(worldId, options = {}) {
        const format = options.format ?? "distance";
        if (format !== "distance" && format !== "packed")
            throw new RangeError(`format is "distance" or "packed", got ${JSON.stringify(format)}`);
        const params = { ...readParams(options), format };
        return parse.block(await this.send({ method: "GET", path: worldPath(worldId) + "/field", params }), format);
    }
    /** The voxel values (uint8 palette indices) of a box. */
    async readVoxels(worldId, options = {}) {
        const params = readParams(options);
        return parse.block(await this.send({ method: "GET", path: worldPath(worldId) + "/voxels", params }), "voxels");
    }
    async queryCall(worldId, body, minVersion) {
        const params = minVersion === undefined ? undefined : { min_version: String(Math.trunc(minVersion)) };
        return this.send({ method: "POST", path: worldPath(worldId) + "/query", params, body });
    }
    /** Distances, gradients and voxel values at points (rows of x y z, world units). */
    async query(worldId, points, options = {}) {
        return parse.points(await this.queryCall(worldId, { points: rowsBlob("points", points, 3) }, options.minVersion));
    }
    /** Clearances and ways out of collision of spheres (rows of x y z r, world units). */
    async querySpheres(worldId, spheres, options = {}) {
        return parse.spheres(await this.queryCall(worldId, { spheres: rowsBlob("spheres", spheres, 4) }, options.minVersion));
    }
    /** First hits of rays (rows of ox oy oz dx dy dz maxLength, world units). */
    async queryRays(worldId, rays, options = {}) {
        return parse.rays(await this.queryCall(worldId, { rays: rowsBlob("rays", rays, 7) }, options.minVersion));
    }
    // -- files ------------------------------------------------------------------------------------
    /** The world as a file: `snapshot` (re-imports as the same world), `npy` (uint8 z, y, x) or `vox`. */
    async exportWorld(worldId, format = "snapshot") {
        const { data, headers } = await this.binary({ method: "GET", path: worldPath(worldId) + "/export", params: { format }, accept: OCTET }, OCTET);
        const disposition = headers.get("content-disposition") ?? "";
        const filename = /filename="([^"]*)"/.exec(disposition)?.[1] ?? "";
        return { format, version: intHeader(headers, "x-sdf-version"), data, filename };
    }
    /**
     * A new world from a file's bytes; the server tells the format by its content. A dense world is
     * at version 1; `storage: "sparse"` (npy and vox) writes its solid voxels as edit batches, its
     * version their number, and `warnings` says where it costs more device memory than a dense one.
     */
    async importWorld(data, options = {}) {
        const params = {};
        if (options.format !== undefined)
            params.format = options.format;
        if (options.chunkSize !== undefined)
            params.chunk_size = String(options.chunkSize);
        if (options.maxDistance !== undefined)
            params.max_distance = String(options.maxDistance);
        if (options.algorithm !== undefined)
            params.algorithm = options.algorithm;
        if (options.model !== undefined)
            params.model = String(options.model);
        if (options.storage !== undefined) {
            if (options.storage !== "dense" && options.storage !== "sparse") {
                throw new RangeError(`storage is dense or sparse, got ${JSON.stringify(options.storage)}`);
            }
            params.storage = options.storage;
        }
        return parse.world(await this.send({ method: "POST", path: "/v1/worlds/import", params, content: data, repeatable: false }));
    }
    // -- frames -----------------------------------------------------------------------------------
    /** One frame: PNG, JPEG (`quality` 1..100) or raw RGBA bytes. */
    async render(worldId, camera, options = {}) {
        const { format = "png", quality, ...view } = options;
        if (!Object.hasOwn(FRAME_TYPES, format))
            throw new RangeError(`format is png, jpeg or rgba, got ${JSON.stringify(format)}`);
        const body = { ...parse.cameraWire(camera), ...view, ...(quality === undefined ? {} : { quality }) };
        const { data, headers } = await this.binary({
            method: "POST", path: worldPath(worldId) + "/render", params: { format }, body, accept: FRAME_TYPES[format],
        }, FRAME_TYPES[format]);
        const renderMs = headers.get("x-render-ms");
        return {
            format, data, fieldVersion: intHeader(headers, "x-field-version"), width: intHeader(headers, "x-frame-width"),
            height: intHeader(headers, "x-frame-height"), renderMs: renderMs === null ? null : Number(renderMs),
        };
    }
    /** The voxel under pixel (x, y) (a pixel's centre is +0.5), or null for sky. */
    async pick(worldId, camera, x, y) {
        const body = { ...parse.cameraWire(camera), x, y };
        return parse.pick(await this.send({ method: "POST", path: worldPath(worldId) + "/pick", body }));
    }
    // -- the stream and the service ---------------------------------------------------------------
    /** The world's WebSocket stream, with this client's key. */
    stream(worldId, options = {}) {
        worldPath(worldId);
        return Stream.connect(this.baseUrl, worldId, { apiKey: this.apiKey, ...options });
    }
    /** True when `/readyz` answers 200. */
    async ready() {
        try {
            const response = await this.fetch(this.baseUrl + "/readyz", { signal: AbortSignal.timeout(this.timeoutMs) });
            await response.arrayBuffer();
            return response.status === 200;
        }
        catch {
            return false;
        }
    }
}
function intHeader(headers, name) {
    const value = Number(headers.get(name) ?? "x");
    if (!Number.isInteger(value))
        throw new ProtocolError(`missing or bad ${name} header`);
    return value;
}
