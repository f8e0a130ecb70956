/** Reading the server's answers into the client's models; every shape check lives here. */
import { ProtocolError, isRecord } from "./errors.js";
import { toArray, view } from "./wire.js";
export function record(value, what) {
    if (!isRecord(value))
        throw new ProtocolError(`${what}: expected an object, got ${describe(value)}`);
    return value;
}
function describe(value) {
    return value === null ? "null" : Array.isArray(value) ? "an array" : typeof value;
}
export function vec3(value, what) {
    if (!Array.isArray(value) || value.length !== 3 || value.some((v) => typeof v !== "number")) {
        throw new ProtocolError(`${what}: expected [x, y, z], got ${JSON.stringify(value)}`);
    }
    return [value[0], value[1], value[2]];
}
function num(value, what, fallback) {
    if (value === undefined || value === null) {
        if (fallback !== undefined)
            return fallback;
        throw new ProtocolError(`${what}: missing`);
    }
    if (typeof value !== "number")
        throw new ProtocolError(`${what}: expected a number, got ${describe(value)}`);
    return value;
}
function focus(value) {
    if (value === null || value === undefined)
        return null;
    const raw = record(value, "focus");
    return { center: vec3(raw.center, "focus.center"), size: vec3(raw.size, "focus.size") };
}
export function world(value) {
    const raw = record(value, "world");
    if (typeof raw.id !== "string")
        throw new ProtocolError("world: missing id");
    return {
        id: raw.id,
        size: vec3(raw.size, "world.size"),
        chunkSize: num(raw.chunk_size, "world.chunk_size"),
        maxDistance: num(raw.max_distance, "world.max_distance"),
        algorithm: String(raw.algorithm),
        lodAlgorithm: String(raw.lod_algorithm ?? ""),
        borders: String(raw.borders ?? "exact"),
        storage: String(raw.storage ?? "dense"),
        generate: (raw.generate ?? null),
        metric: String(raw.metric ?? "manhattan"),
        signed: raw.signed === true,
        voxelSize: num(raw.voxel_size, "world.voxel_size", 1),
        origin: raw.origin === undefined ? [0, 0, 0] : vec3(raw.origin, "world.origin"),
        palette: (raw.palette ?? null),
        focus: focus(raw.focus),
        version: num(raw.version, "world.version", 0),
        fieldVersion: num(raw.field_version, "world.field_version", 0),
        dirtyChunks: num(raw.dirty_chunks, "world.dirty_chunks", 0),
        lastRecomputeMs: raw.last_recompute_ms === null || raw.last_recompute_ms === undefined
            ? null : num(raw.last_recompute_ms, "world.last_recompute_ms"),
        deviceBytes: num(raw.device_bytes, "world.device_bytes", 0),
        owner: typeof raw.owner === "string" ? raw.owner : null,
        warnings: Array.isArray(raw.warnings) ? raw.warnings.map(String) : [],
        raw,
    };
}
export function worlds(value) {
    const list = isRecord(value) ? value.worlds : value;
    if (!Array.isArray(list))
        throw new ProtocolError(`worlds: expected a list, got ${describe(list)}`);
    return list.map(world);
}
/** A field or voxel read: `data` holds bytes, read with the dtype the answer names. */
export function block(value, format) {
    const raw = record(value, format);
    const shape = vec3(raw.shape, `${format}.shape`);
    const dtype = raw.dtype;
    const data = view(dtype, raw.data, shape[0] * shape[1] * shape[2], format);
    return {
        origin: raw.origin === undefined ? [0, 0, 0] : vec3(raw.origin, `${format}.origin`),
        shape,
        dtype: dtype,
        data,
        version: num(raw.version, `${format}.version`, 0),
        format,
        content: String(raw.content ?? ""),
    };
}
function column(raw, key, cls, rows, width = 1) {
    const { array } = toArray(raw[key], key);
    const expected = rows === undefined ? array.length : rows * width;
    if (!(array instanceof cls) || array.length !== expected) {
        throw new ProtocolError(`${key}: expected ${expected} ${cls.name} values, got ${array.length} ${array.constructor.name}`);
    }
    return array;
}
export function points(value) {
    const raw = record(value, "query");
    const distances = column(raw, "distances", Float32Array);
    const n = distances.length;
    return {
        distances,
        gradients: column(raw, "gradients", Float32Array, n, 3),
        colours: column(raw, "colours", Uint8Array, n),
        version: num(raw.version, "query.version", 0),
    };
}
export function spheres(value) {
    const raw = record(value, "sphere query");
    const clearances = column(raw, "clearances", Float32Array);
    return {
        clearances,
        directions: column(raw, "directions", Float32Array, clearances.length, 3),
        version: num(raw.version, "sphere query.version", 0),
    };
}
export function rays(value) {
    const raw = record(value, "ray query");
    const hits = column(raw, "hits", Uint8Array);
    const n = hits.length;
    return {
        hits,
        distances: column(raw, "distances", Float32Array, n),
        normals: column(raw, "normals", Float32Array, n, 3),
        colours: column(raw, "colours", Uint8Array, n),
        voxels: column(raw, "voxels", Int32Array, n, 3),
        version: num(raw.version, "ray query.version", 0),
    };
}
export function pick(value) {
    const raw = record(value, "pick");
    if (!raw.hit)
        return null;
    return {
        voxel: vec3(raw.voxel, "pick.voxel"),
        normal: vec3(raw.normal, "pick.normal"),
        place: vec3(raw.place, "pick.place"),
        fieldVersion: num(raw.field_version, "pick.field_version", 0),
    };
}
function chunk(value) {
    const raw = record(value, "chunk");
    const { array, shape } = toArray(raw.data, "chunk.data");
    const dtype = raw.data.dtype;
    return { chunk: vec3(raw.chunk, "chunk.chunk"), origin: vec3(raw.origin, "chunk.origin"), shape, dtype, data: array };
}
export function streamMessage(value) {
    const raw = record(value, "stream frame");
    if (typeof raw.type !== "string")
        throw new ProtocolError("stream frame without a type");
    const chunks = raw.type === "chunks" && Array.isArray(raw.chunks) ? raw.chunks.map(chunk) : [];
    return {
        type: raw.type,
        id: typeof raw.id === "number" ? raw.id : null,
        version: typeof raw.version === "number" ? raw.version : null,
        chunks,
        raw,
    };
}
/** A camera in the wire's names. */
export function cameraWire(camera) {
    const wire = { position: [...camera.position] };
    if (camera.target !== undefined)
        wire.target = [...camera.target];
    if (camera.yawDeg !== undefined)
        wire.yaw_deg = camera.yawDeg;
    if (camera.pitchDeg !== undefined)
        wire.pitch_deg = camera.pitchDeg;
    if (camera.fovYDeg !== undefined)
        wire.fov_y_deg = camera.fovYDeg;
    if (camera.width !== undefined)
        wire.width = camera.width;
    if (camera.height !== undefined)
        wire.height = camera.height;
    return wire;
}
