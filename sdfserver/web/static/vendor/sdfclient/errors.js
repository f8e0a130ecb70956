/**
 * The client's exception tree, the same as the Python client's (`sdfclient.errors`).
 *
 *     SdfClientError
 *     ├── TransportError          the server could not be reached or the connection broke
 *     │   └── Timeout             no answer in time
 *     ├── ProtocolError           the server answered something the client cannot read
 *     ├── StreamClosed            the WebSocket stream ended (carries the close code and reason)
 *     └── ServerError             the server refused the request (carries status, code, message)
 *         ├── InvalidInput        422: bad request data; nothing was changed
 *         │   └── InvalidEdit     422: an edit batch that cannot be applied
 *         ├── Unauthorized        401: a missing or unknown API key
 *         ├── NotFound            404: an unknown world (or another tenant's)
 *         ├── TooLarge            413: a body, batch or region over a limit
 *         ├── RateLimited         429: the key is over its request rate (retryAfterS)
 *         ├── DeviceMemoryExceeded 507: the world does not fit in device memory
 *         ├── NotReady            503: the device cannot serve requests now
 *         │   ├── VersionNotReached 503: a read's minVersion was not reached in time
 *         │   └── WritesDisabled  503: the server's write-ahead log failed; no edit is accepted
 *         └── InternalServerError 500 and anything else
 *
 * A ServerError is chosen from the server's error `code` first, then from the HTTP status;
 * `serverError` is the one place that does it.
 */
export class SdfClientError extends Error {
    get name() {
        return this.constructor.name;
    }
}
export class TransportError extends SdfClientError {
}
export class Timeout extends TransportError {
}
export class ProtocolError extends SdfClientError {
}
export class StreamClosed extends SdfClientError {
    code;
    reason;
    constructor(code, reason = "") {
        super(reason ? `stream closed (code ${code}): ${reason}` : `stream closed (code ${code})`);
        this.code = code;
        this.reason = reason;
    }
}
/** The server answered with an error body. */
export class ServerError extends SdfClientError {
    serverMessage;
    static status = 500;
    status;
    code;
    detail;
    /** Seconds from the answer's `Retry-After` header (429 and 503 carry one), else null. */
    retryAfterS;
    constructor(serverMessage, init) {
        super(`${init.status} ${init.code}: ${serverMessage}`);
        this.serverMessage = serverMessage;
        this.status = init.status;
        this.code = init.code;
        this.detail = init.detail;
        this.retryAfterS = init.retryAfterS ?? null;
    }
}
export class InvalidInput extends ServerError {
    static status = 422;
}
export class InvalidEdit extends InvalidInput {
}
/** A missing or unknown API key: pass `apiKey` to the client. */
export class Unauthorized extends ServerError {
    static status = 401;
}
export class NotFound extends ServerError {
    static status = 404;
}
export class TooLarge extends ServerError {
    static status = 413;
}
/** The key made more requests than the server allows; `retryAfterS` says when to ask again. */
export class RateLimited extends ServerError {
    static status = 429;
}
export class DeviceMemoryExceeded extends ServerError {
    static status = 507;
}
export class NotReady extends ServerError {
    static status = 503;
}
export class VersionNotReached extends NotReady {
}
/** The server's write-ahead log failed: it refuses every edit until it is restarted. */
export class WritesDisabled extends NotReady {
}
export class InternalServerError extends ServerError {
}
const BY_CODE = {
    invalid_input: InvalidInput,
    invalid_edit: InvalidEdit,
    unauthorized: Unauthorized,
    not_found: NotFound,
    rate_limited: RateLimited,
    too_large: TooLarge,
    device_memory_exceeded: DeviceMemoryExceeded,
    not_ready: NotReady,
    no_opencl_device: NotReady,
    version_not_reached: VersionNotReached,
    writes_disabled: WritesDisabled,
    method_not_allowed: InvalidInput,
    not_acceptable: InvalidInput,
    unsupported_media_type: InvalidInput,
};
const BY_STATUS = {
    400: InvalidInput,
    401: Unauthorized,
    404: NotFound,
    405: InvalidInput,
    413: TooLarge,
    415: InvalidInput,
    422: InvalidInput,
    429: RateLimited,
    503: NotReady,
    507: DeviceMemoryExceeded,
};
export function errorClass(status, code) {
    if (code !== null && Object.hasOwn(BY_CODE, code))
        return BY_CODE[code];
    return BY_STATUS[status] ?? InternalServerError;
}
/** Seconds from a `Retry-After` header (delta-seconds or an HTTP date); null if absent or unreadable. */
export function retryAfter(header) {
    const value = header?.trim();
    if (!value)
        return null;
    if (/^\d+(\.\d+)?$/.test(value))
        return Number(value);
    const when = Date.parse(value);
    return Number.isNaN(when) ? null : Math.max(0, (when - Date.now()) / 1000);
}
/**
 * The exception for an error body (`{"error": {code, message, detail}}` or flat).
 * `status` null (a stream's error frame) takes the status of the code's class.
 */
export function serverError(status, body, retryAfterS = null) {
    const outer = isRecord(body) && isRecord(body.error) ? body.error : body;
    let code = "";
    let message = "";
    let detail;
    if (isRecord(outer)) {
        code = String(outer.code ?? "");
        message = String(outer.message ?? outer.detail ?? "");
        detail = outer.detail;
    }
    else if (body !== null && body !== undefined) {
        message = String(body);
    }
    const cls = errorClass(status ?? 0, code || null);
    const finalStatus = status ?? cls.status;
    return new cls(message || `HTTP ${finalStatus}`, {
        status: finalStatus,
        code: code || `http_${finalStatus}`,
        detail,
        retryAfterS,
    });
}
export function isRecord(value) {
    return typeof value === "object" && value !== null && !Array.isArray(value) && !ArrayBuffer.isView(value);
}
