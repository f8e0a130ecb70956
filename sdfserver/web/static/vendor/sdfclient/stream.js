/**
 * The WebSocket stream of one world: send edits, subscribe to regions, receive changed chunks
 * and rendered frames.
 *
 *     const stream = await client.stream(worldId);
 *     await stream.subscribe([[0, 0, 0], [64, 64, 64]]);          // then: all its chunks, once
 *     const version = await stream.edit([sphere([32, 32, 32], 5)]); // waits for the ack
 *     for await (const message of stream) {                         // changed chunks, acks, frames
 *       if (message.type === "chunks" && message.version! >= version) break;
 *     }
 *     await stream.close();
 *
 * The socket is the global `WebSocket` where there is one (browsers, Node 22 and later) and
 * the `ws` package otherwise (Node 20, whose global one is behind a flag). `ws` sends the API
 * key as `Authorization: Bearer <key>`; a browser-style `WebSocket` cannot set headers, so there
 * the key travels as `?access_token=<key>`, which the server also takes.
 *
 * Frames are binary msgpack both ways. The stream is meant for one consumer: `edit`,
 * `subscribe`, `ping` and `unsubscribe` read until their answer and keep the messages they pass
 * for `recv` and the iterator, in order. A frame the server refuses answers an `error` message,
 * thrown here as its ServerError; the connection stays open. A refused stream closes with
 * 4000 + an HTTP status (4401, 4404), thrown as Unauthorized or NotFound.
 *
 * When the connection drops (closed abnormally, or the server going away or restarting), the
 * stream reconnects after a wait that doubles at each failed attempt (`reconnectDelayMs` up to
 * `maxReconnectDelayMs`, stretched by up to 25%), up to `maxReconnectAttempts` times in a row,
 * and sends its subscription and camera again. The reader then sees a `reconnected` message
 * (`raw`: attempts, code, reason; `onReconnected` is called with the same), followed by
 * `subscribed` and every chunk of the region as after a first subscribe, so no change is missed.
 * Edits are not sent again: an `edit` whose ack the drop lost throws TransportError (the batch
 * may or may not have been applied); `subscribe`, `unsubscribe` and `ping` answer from the new
 * connection. `resume: false` ends the stream at the first drop, as a closed one.
 */
import { NotReady, ProtocolError, RateLimited, StreamClosed, Timeout, TransportError, isRecord, serverError, } from "./errors.js";
import { cameraWire, streamMessage } from "./parse.js";
import { decode, encode } from "./wire.js";
export const DEFAULT_MAX_FRAME_BYTES = 64 << 20;
export const DEFAULT_RECONNECT_DELAY_MS = 250;
export const DEFAULT_MAX_RECONNECT_DELAY_MS = 5_000;
export const DEFAULT_MAX_RECONNECT_ATTEMPTS = 10;
const RECONNECT_JITTER = 0.25;
const OPEN = 1;
/** Ends a connection may come back from: dropped (1005, 1006), the server going away, failing or
 * restarting. A normal close (1000), a refusal (4xxx) or a protocol fault would end the same way again. */
const RESUMED_CLOSE_CODES = new Set([1001, 1005, 1006, 1011, 1012, 1013, 1014]);
export function streamUrl(baseUrl, worldId) {
    const base = baseUrl.replace(/\/+$/, "").replace(/^http(s?):\/\//, "ws$1://");
    return `${base}/v1/worlds/${encodeURIComponent(worldId)}/stream`;
}
/** The server closes with 4000 + an HTTP status for a refused stream (4404: unknown world). */
export function closedError(code, reason) {
    if (code !== null && code >= 4000 && code < 5000) {
        return serverError(code - 4000, { error: { code: "", message: reason } });
    }
    return new StreamClosed(code, reason);
}
async function open(url, options) {
    const Browser = options.WebSocket ?? globalThis.WebSocket;
    if (Browser !== undefined) {
        const target = new URL(url);
        if (options.apiKey !== undefined)
            target.searchParams.set("access_token", options.apiKey);
        return new Browser(target.toString());
    }
    const { default: WS } = await import("ws");
    const headers = options.apiKey === undefined ? {} : { authorization: `Bearer ${options.apiKey}` };
    const ws = new WS(url, { headers, maxPayload: options.maxFrameBytes ?? DEFAULT_MAX_FRAME_BYTES, perMessageDeflate: false });
    // A refused handshake: read the answer's error body rather than ws's bare "Unexpected server response".
    ws.on("unexpected-response", (request, response) => {
        const parts = [];
        response.on("data", (part) => parts.push(part));
        response.on("end", () => {
            const text = Buffer.concat(parts).toString("utf8");
            let body = text;
            try {
                body = JSON.parse(text);
            }
            catch {
                // not JSON: the text itself is the message
            }
            ws.emit("refused", serverError(response.statusCode ?? 0, body));
            request.destroy();
        });
    });
    return ws;
}
/** A socket to `url`, open, or the error its opening failed with. */
async function connectSocket(url, options) {
    const socket = await open(url, options);
    const timeoutMs = options.openTimeoutMs ?? 10_000;
    await new Promise((resolve, reject) => {
        const timer = setTimeout(() => {
            reject(new Timeout(`connect ${url}: not open after ${timeoutMs} ms`));
            socket.close();
        }, timeoutMs);
        const settle = (error) => {
            clearTimeout(timer);
            if (error === undefined)
                resolve();
            else
                reject(error);
        };
        socket.addEventListener("open", () => settle());
        socket.on?.("refused", settle);
        socket.addEventListener("error", (event) => {
            const cause = event.error?.message ?? event.message ?? "error";
            if (!/Unexpected server response/.test(cause))
                settle(new TransportError(`connect ${url}: ${cause}`));
        });
        socket.addEventListener("close", (event) => settle(closedError(event.code ?? null, event.reason ?? "")));
    });
    return socket;
}
/** A failed reconnection worth trying again: unreachable, or refused for a while. */
function passing(error) {
    return error instanceof TransportError || error instanceof NotReady || error instanceof RateLimited
        || (error instanceof StreamClosed && (error.code === null || RESUMED_CLOSE_CODES.has(error.code)));
}
export class Stream {
    url;
    options;
    inbox = []; // arrived, not yet read
    held = []; // read by a request while it waited for its answer
    wake = null;
    closedWith = null;
    closing;
    finished;
    nextId = 1;
    socket;
    generation = 0; // connections made after the first
    subscription = null; // the last subscribe frame, sent again on reconnecting
    resubscribedId = null;
    camera = null; // the last camera frame, likewise
    reconnecting = null;
    closedByUs = false;
    wakePause = null;
    changed = []; // senders waiting for the connection to reopen or end
    constructor(socket, url, options) {
        this.url = url;
        this.options = options;
        this.closing = new Promise((resolve) => (this.finished = resolve));
        this.attach(socket);
    }
    /** Open a world's stream (`Client.stream` passes the client's key). */
    static async connect(baseUrl, worldId, options = {}) {
        const url = streamUrl(baseUrl, worldId);
        return new Stream(await connectSocket(url, options), url, options);
    }
    /** Whether the stream has ended: `recv` throws why once the messages that came before are read. */
    get closed() {
        return this.closedWith !== null;
    }
    /** Close the socket and wait until it is closed; a reconnection under way stops. */
    async close() {
        this.closedByUs = true;
        this.wakePause?.();
        if (this.socket.readyState <= OPEN)
            this.socket.close(1000);
        await this.closing;
    }
    // -- the connection ---------------------------------------------------------------------------
    attach(socket) {
        this.socket = socket;
        socket.binaryType = "arraybuffer";
        socket.addEventListener("message", (event) => this.arrive(event.data));
        socket.addEventListener("close", (event) => this.dropped(event.code ?? null, event.reason ?? ""));
    }
    dropped(code, reason) {
        if (!this.closedByUs && (this.options.resume ?? true) && (code === null || RESUMED_CLOSE_CODES.has(code))) {
            this.reconnecting = this.reconnect(code, reason);
        }
        else {
            this.end(closedError(code, reason));
        }
        this.stateChanged();
    }
    end(error) {
        this.closedWith ??= error;
        this.reconnecting = null;
        this.notify();
        this.stateChanged();
        this.finished();
    }
    stateChanged() {
        for (const resolve of this.changed.splice(0))
            resolve();
    }
    async reconnect(code, reason) {
        const { reconnectDelayMs = DEFAULT_RECONNECT_DELAY_MS, maxReconnectDelayMs = DEFAULT_MAX_RECONNECT_DELAY_MS } = this.options;
        const maxAttempts = this.options.maxReconnectAttempts ?? DEFAULT_MAX_RECONNECT_ATTEMPTS;
        let failure = closedError(code, reason);
        for (let attempt = 0; attempt < maxAttempts && !this.closedByUs; attempt++) {
            const delayMs = Math.min(reconnectDelayMs * 2 ** attempt, maxReconnectDelayMs) * (1 + RECONNECT_JITTER * Math.random());
            await new Promise((resolve) => {
                const timer = setTimeout(resolve, delayMs);
                this.wakePause = () => {
                    clearTimeout(timer);
                    resolve();
                };
            });
            if (this.closedByUs)
                break;
            let socket;
            try {
                socket = await connectSocket(this.url, this.options);
            }
            catch (error) {
                failure = error;
                if (!passing(error))
                    break;
                continue;
            }
            if (this.closedByUs) {
                socket.close(1000);
                break;
            }
            this.attach(socket);
            this.generation++;
            const info = { attempts: attempt + 1, code, reason };
            this.inbox.push({ type: "reconnected", id: null, version: null, chunks: [], raw: { ...info } });
            this.reconnecting = null;
            // The server answers a subscribe with the region's current chunks, so nothing is missed.
            this.resubscribedId = null;
            if (this.subscription !== null) {
                this.resubscribedId = this.nextId++;
                socket.send(encode({ ...this.subscription, id: this.resubscribedId }));
            }
            if (this.camera !== null)
                socket.send(encode({ ...this.camera, id: this.nextId++ }));
            this.notify();
            this.stateChanged();
            this.options.onReconnected?.(info);
            return;
        }
        this.end(this.closedByUs ? new StreamClosed(1000, "closed by the client") : failure);
    }
    // -- sending ----------------------------------------------------------------------------------
    /**
     * Sends on the open connection, waiting for a reconnection under way; or throws why the stream
     * closed (a refused key or world closes it right after opening).
     */
    async send(message) {
        for (;;) {
            if (this.closedWith !== null)
                throw this.closedWith;
            if (this.reconnecting !== null) {
                await this.reconnecting;
            }
            else if (this.socket.readyState === OPEN) {
                this.socket.send(encode(message));
                return;
            }
            else {
                await new Promise((resolve) => this.changed.push(resolve)); // its close event is on its way
            }
        }
    }
    /**
     * Receive the chunks of `box` (widened to whole chunks): first all of them, then the changed
     * ones after every recompute. Replaces an earlier subscription; answers the `subscribed`
     * message (`raw` has the widened min/max, the chunk size, dtype and content).
     */
    subscribe(box, options = {}) {
        const [min, max] = box;
        this.subscription = { type: "subscribe", min: [...min], max: [...max], format: options.format ?? "distance" };
        return this.request(this.subscription, "subscribed");
    }
    async unsubscribe() {
        this.subscription = null;
        await this.request({ type: "unsubscribe" }, "unsubscribed");
    }
    async ping() {
        await this.request({ type: "ping" }, "pong");
    }
    /**
     * Ask for rendered frames of this view: `frame` messages (`raw`: data, format, width, height,
     * version, render_ms, seq) follow whenever the view or the field changes, at most `maxFps` a second.
     */
    async setCamera(camera, options = {}) {
        const { maxFps, ...rest } = options;
        const extra = maxFps === undefined ? {} : { max_fps: maxFps };
        this.camera = { ...cameraWire(camera), ...rest, ...extra, type: "camera" };
        await this.send({ ...this.camera, id: this.nextId++ });
    }
    /** The next video frame is a keyframe (after a chunk failed to decode, or a decoder fell behind). */
    async requestKeyframe() {
        await this.send({ type: "keyframe", id: this.nextId++ });
    }
    /** Send a batch without waiting; its `ack` message carries the returned id. */
    async sendEdits(edits) {
        const id = this.nextId++;
        await this.send({ type: "edits", id, edits });
        return id;
    }
    /** Send a batch and wait for its acknowledgement; answers the version it became. */
    async edit(edits) {
        const ack = await this.request({ type: "edits", edits }, "ack");
        if (ack.version === null)
            throw new ProtocolError("ack without a version");
        return ack.version;
    }
    /** Send `message` and read until its answer; across a reconnection see the banner. */
    async request(message, answer) {
        let id = this.nextId++;
        await this.send({ ...message, id });
        let generation = this.generation;
        for (;;) {
            const item = await this.next();
            if (!(item instanceof Error) && item.id === id && (item.type === answer || item.type === "error")) {
                return raiseIfError(item);
            }
            this.held.push(item);
            if (item instanceof Error || item.type !== "reconnected" || this.generation === generation)
                continue;
            // The connection it was sent on dropped before its answer.
            generation = this.generation;
            if (message.type === "edits") {
                throw new TransportError(`the connection dropped before edit ${id}'s ack (${String(item.raw.code)}); `
                    + "the stream reconnected, and the batch may or may not have been applied");
            }
            if (message.type === "subscribe" && this.resubscribedId !== null) {
                id = this.resubscribedId; // the reconnection sent this subscription again
            }
            else {
                id = this.nextId++;
                await this.send({ ...message, id });
            }
        }
    }
    // -- receiving --------------------------------------------------------------------------------
    arrive(data) {
        let item;
        try {
            if (!(data instanceof ArrayBuffer))
                throw new ProtocolError(`text frame on a binary stream: ${String(data).slice(0, 200)}`);
            item = streamMessage(decode(new Uint8Array(data)));
        }
        catch (error) {
            item = error;
        }
        this.inbox.push(item);
        this.notify();
    }
    notify() {
        const wake = this.wake;
        this.wake = null;
        wake?.();
    }
    async next() {
        while (this.inbox.length === 0) {
            if (this.closedWith !== null)
                throw this.closedWith;
            await new Promise((resolve) => (this.wake = resolve));
        }
        return this.inbox.shift();
    }
    /** The next message; an `error` message throws its ServerError. */
    async recv() {
        const item = this.held.length > 0 ? this.held.shift() : await this.next();
        if (item instanceof Error)
            throw item;
        return raiseIfError(item);
    }
    /** Messages until the stream closes normally (1000, 1001); any other end throws. */
    async *[Symbol.asyncIterator]() {
        for (;;) {
            try {
                yield await this.recv();
            }
            catch (error) {
                if (error instanceof StreamClosed && (error.code === 1000 || error.code === 1001))
                    return;
                throw error;
            }
        }
    }
}
function raiseIfError(message) {
    if (message.type !== "error")
        return message;
    const raw = message.raw;
    const status = typeof raw.status === "number" ? raw.status : null;
    throw serverError(status, isRecord(raw.error) ? raw.error : raw);
}
