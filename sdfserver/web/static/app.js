// The voxel painter: frames streamed from the server over the world's WebSocket, a fly camera,
// brush edits over HTTP, all through the TypeScript client (vendor/sdfclient, which index.html's
// import map names "sdfclient"). No build step; ES modules only.
//
// On a server with API keys the page needs one: `#key=<token>` or `?key=<token>` in the address,
// or the key form.
// It is kept in sessionStorage (this tab only); the client sends it as `Authorization: Bearer` on
// requests and as `?access_token=` on the WebSocket (browsers cannot set its headers).
import { Client, NotFound, NotReady, TransportError, Unauthorized } from "sdfclient";
import { demoScene } from "./scene.js";
import { Benchmark } from "./benchmode.js";
import { nearestValue, rgbHex, selectSwatch, showSwatches, worldPalette } from "./palette.js";
import { VIDEO_FORMATS, VideoPlayer, canDecode } from "./video.js";

const ALGORITHMS = ["exact", "brute", "fim", "jfa", "jfa_fim"];
const $ = (id) => document.getElementById(id);
const canvas = $("frame");
const ctx = canvas.getContext("2d");

const demo = { framesReceived: 0, lastVersion: -1, world: null, ready: false, edits: 0, errors: [],
  needsKey: false, misses: 0, notReady: null };
window.sdfDemo = demo;  // read by the browser test

const cam = { position: [0, 0, 0], yaw: 0, pitch: 0, fov: 60 };
demo.camera = cam;
const brush = { mode: "place", colour: 0xe4, size: 2 };  // colour: a voxel value, the palette's index + 1
demo.brush = brush;
let palette = worldPalette(null);
// A generous timeout: making a large sparse terrain can take a while, and the page waits for it.
const newClient = (key) => new Client(location.origin, { apiKey: key || undefined, timeoutMs: 300_000 });
let client = newClient("");
let stream = null, cursor = null, viewDirty = true, lastSent = 0, worldSize = [64, 64, 64];
const keys = new Set();

// ---------------------------------------------------------------------------------------------- API key

const KEY_ITEM = "sdfserver.apiKey";
let memoryKey = "";  // where sessionStorage is unavailable (some privacy settings)

function apiKey() {
  try { return sessionStorage.getItem(KEY_ITEM) ?? ""; } catch { return memoryKey; }
}

function setApiKey(key) {
  memoryKey = key;
  try {
    if (key) sessionStorage.setItem(KEY_ITEM, key); else sessionStorage.removeItem(KEY_ITEM);
  } catch { /* memoryKey holds it */ }
  client = newClient(key);
  $("key-state").textContent = key ? "Using an API key (this tab only)." : "No API key.";
  $("forget-key").hidden = !key;
}

// `?key=` or `#key=` in the address (the fragment never reaches the server): keep it for this tab
// and take it out of the address bar and history.
function takeKeyFromAddress() {
  const url = new URL(location.href);
  const hash = new URLSearchParams(url.hash.slice(1));
  const key = hash.get("key") ?? url.searchParams.get("key");
  if (key === null) return;
  setApiKey(key.trim());
  url.searchParams.delete("key");
  hash.delete("key");
  const rest = hash.toString();
  history.replaceState(null, "", url.pathname + url.search + (rest ? `#${rest}` : ""));
}

// A missing or refused key: say so plainly, stop reconnecting, and ask for one.
function needKey(reason) {
  demo.needsKey = true;
  demo.ready = false;
  closeStream();
  const text = apiKey()
    ? `The API key was refused (${reason}). Enter a valid key to continue.`
    : "This server requires an API key. Enter yours, or open the page as /#key=<your key>.";
  showStatus("");
  demo.errors.push(text);
  $("world-line").textContent = "API key needed";
  $("key-message").textContent = text;
  $("key-dialog").classList.add("error");
  $("key-dialog").hidden = false;
  $("api-key").focus();
}

// ---------------------------------------------------------------------------------------------- HTTP

// A call of the client's; a refused key opens the key form before the error goes on.
async function api(call) {
  try {
    return await call(client);
  } catch (err) {
    if (err instanceof Unauthorized) needKey(err.serverMessage);
    throw err;
  }
}

// What the server said (a ServerError's own message), else the error's.
const said = (err) => err.serverMessage ?? err.message;

function showStatus(text, isError = false) {
  const el = $("status");
  el.hidden = !text;
  el.textContent = text || "";
  el.classList.toggle("error", isError);
  if (isError) demo.errors.push(text);
}

// Show a line for a while; a later message is left alone.
function flash(text, ms, isError = false) {
  showStatus(text, isError);
  setTimeout(() => { if ($("status").textContent === text) showStatus(""); }, ms);
}

async function guarded(what, fn) {
  try {
    return await fn();
  } catch (err) {
    // not ready, or unreachable: it says why, for as long as it lasts
    if (err instanceof NotReady || err instanceof TransportError) waitForServer();
    else if (!(err instanceof Unauthorized)) flash(`${what}: ${said(err)}`, 4000, true);  // needKey spoke
    return undefined;
  }
}

// ---------------------------------------------------------------------------------------------- readiness

// Why the server cannot serve, from /readyz; null once it can.
async function notReadyReason() {
  try {
    const response = await fetch("/readyz", { headers: { Accept: "application/json" } });
    if (response.ok) return null;
    const data = await response.json().catch(() => null);
    return data?.error?.message ?? `/readyz answered ${response.status}`;
  } catch (err) {
    return `the server cannot be reached (${err.message})`;
  }
}

// Say why the server cannot serve, checking every few seconds; resolves once it can. One wait at a time.
let serverWait = null;
function waitForServer() {
  serverWait ??= (async () => {
    let shown = null;
    for (let reason = await notReadyReason(); reason !== null; reason = await notReadyReason()) {
      if (reason !== shown) {
        shown = reason;
        demo.ready = false;
        demo.notReady = reason;
        $("world-line").textContent = `server not ready: ${reason}`;
        showStatus(`server not ready: ${reason}`, true);
      }
      await new Promise((resolve) => setTimeout(resolve, 2000));
    }
    demo.notReady = null;
    if (shown !== null) {
      showStatus("");
      $("world-line").textContent = "connecting…";
    }
    serverWait = null;
  })();
  return serverWait;
}

// ---------------------------------------------------------------------------------------------- worlds

function describeWorld(w) {
  const [sx, sy, sz] = w.size;
  const shape = sx === sy && sy === sz ? `${sx}³` : `${sx}×${sy}×${sz}`;
  const field = `${w.metric === "euclidean" ? " · euclidean" : ""}${w.signed ? " · signed" : ""}`;
  return `${w.id} · ${shape} · ${w.algorithm}${field}${w.storage === "sparse" ? " · sparse" : ""}`;
}

async function refreshWorlds(selectId) {
  const worlds = await api((c) => c.listWorlds());
  const select = $("world-select");
  select.replaceChildren(...worlds.map((w) => new Option(describeWorld(w), w.id)));
  if (selectId) select.value = selectId;
  return worlds;
}

async function createWorld(choice, algorithm) {  // "64", or "terrain-4096" for a sparse terrain
  if (String(choice).startsWith("terrain-")) return createTerrain(Number(String(choice).slice(8)), algorithm);
  const size = Number(choice);
  showStatus(`Creating a ${size}³ world…`);
  const world = await api((c) => c.createWorld([size, size, size], { algorithm }));
  await api((c) => c.edit(world.id, demoScene(world.size)));
  showStatus("");
  return world;
}

// A large sparse world: only the bricks near the generated surface take device memory.
async function createTerrain(side, algorithm) {
  showStatus(`Generating a ${side}×${side / 8}×${side} terrain…`);
  const world = await api((c) => c.createWorld([side, side / 8, side], {
    chunkSize: 32, maxDistance: 31, algorithm, storage: "sparse",
    generate: { kind: "terrain", seed: Math.floor(Math.random() * 2 ** 31) },
  }));
  showStatus("");
  return world;
}

function lookAt(position, target) {
  const d = target.map((t, i) => t - position[i]);
  cam.position = position.slice();
  cam.yaw = Math.atan2(d[0], -d[2]) * 180 / Math.PI;
  cam.pitch = Math.atan2(d[1], Math.hypot(d[0], d[2])) * 180 / Math.PI;
}

async function openWorld(world) {
  demo.world = world.id;
  worldSize = world.size;
  location.hash = `world=${encodeURIComponent(world.id)}`;
  const [sx, sy, sz] = world.size;
  if (world.storage === "sparse") lookAt([sx * 0.5, sy * 0.8, sz * 0.5], [sx * 0.5 + 400, sy * 0.35, sz * 0.5 + 400]);
  else lookAt([sx * 1.02, sy * 0.62, sz * 1.12], [sx * 0.5, sy * 0.12, sz * 0.5]);
  $("algorithm").value = world.algorithm;
  $("lod-algorithm").value = world.lodAlgorithm || "jfa";
  $("focus-on").checked = !!world.focus;
  $("metric").value = world.metric ?? "manhattan";
  $("signed").checked = !!world.signed;
  showPalette(world);
  if (world.focus) {
    $("focus-center").value = world.focus.center.join(",");
    $("focus-size").value = world.focus.size.join(",");
  }
  $("world-line").textContent = describeWorld(world);
  connect(world.id);
}

// ---------------------------------------------------------------------------------------------- stream

function closeStream() {
  if (!stream) return;
  const old = stream;
  stream = null;
  old.close();
}

// The world's stream: the client reconnects a dropped connection by itself (and sends the camera
// again); this reads frames until the stream ends, then says why or opens it again.
async function connect(worldId) {
  closeStream();
  let opened;
  try {
    opened = await client.stream(worldId, { onReconnected: () => { if (stream === opened) showStatus(""); } });
  } catch (err) {
    streamEnded(worldId, null, err);
    return;
  }
  if (demo.world !== worldId || stream) { opened.close(); return; }  // another world was opened meanwhile
  stream = opened;
  viewDirty = true;
  demo.ready = true;
  showStatus("");
  for (;;) {
    let message;
    try {
      message = await opened.recv();
    } catch (err) {
      if (stream !== opened) return;
      if (opened.closed) { streamEnded(worldId, opened, err); return; }
      // an error message: the server refused one frame, the stream goes on
      if (err instanceof NotReady) waitForServer();
      else showStatus(`Server: ${said(err)}`, true);
      continue;
    }
    if (stream !== opened) return;
    if (message.type === "frame") onFrame(message.raw);
    else if (message.type === "video") video.start(message.raw);
    else if (message.type === "reconnected") viewDirty = true;
  }
}

function streamEnded(worldId, ended, err) {
  if (stream !== ended) return;  // closed here: another world, or a key to ask for
  stream = null;
  demo.ready = false;
  if (err instanceof Unauthorized) { needKey(said(err)); return; }
  if (err instanceof NotFound) {
    showStatus(`World ${worldId} is gone (or not yours): pick or create another.`, true);
    return;
  }
  showStatus("Disconnected — reconnecting…", true);
  // a server that cannot serve says why until it can; then the stream comes back
  setTimeout(() => waitForServer().then(() => { if (!stream && demo.world === worldId) connect(worldId); }), 1000);
}

// The camera and the stream's render options for the canvas as it is now.
function view() {
  const scale = Number($("resolution").value);
  const width = Math.max(16, Math.round(canvas.clientWidth * scale));
  const height = Math.max(16, Math.round(canvas.clientHeight * scale));
  if (canvas.width !== width || canvas.height !== height) {
    canvas.width = width;
    canvas.height = height;
  }
  const camera = { position: cam.position, yawDeg: cam.yaw, pitchDeg: cam.pitch, fovYDeg: cam.fov, width, height };
  const options = {
    maxFps: Math.max(1, Math.min(240, Number($("max-fps").value) || 60)),
    format: frameFormat, ...(VIDEO_FORMATS.includes(frameFormat) ? {} : { quality: 82 }),
    ambient_occlusion: $("ao").checked, shadows: $("shadows").checked,
    highlight_radius: brush.size,
  };
  if (cursor) options.cursor = [cursor[0] * scale, cursor[1] * scale];
  return { camera, options };
}

// One camera message at a time: while the stream reconnects, views do not pile up behind it
// (the reconnection sends the last one again).
let sendingView = false;
function sendView(now) {
  if (!stream || !demo.ready || sendingView || !viewDirty) return;
  if (now - lastSent < 1000 / 120) return;
  const { camera, options } = view();
  sendingView = true;
  stream.setCamera(camera, options)
    .catch(() => {})  // the stream ended: its reader says why
    .finally(() => { sendingView = false; });
  viewDirty = false;
  lastSent = now;
}

// Frames come as video (H.264 where WebCodecs decodes it; ?frames=jpeg|h264|vp9|av1 or the View
// panel chooses) or as JPEG pictures. Pictures: one decoded at a time, a frame arriving meanwhile
// replaces any waiting one. Video: every chunk decoded, in order (video.js).
let frameFormat = "jpeg";
const video = new VideoPlayer((frame) => ctx.drawImage(frame, 0, 0, canvas.width, canvas.height), () => {
  stream?.requestKeyframe().catch(() => {});  // the stream ended: its reader says why
});
demo.video = video.stats;
let decoding = false, waiting = null;
const frameTimes = [], frameBytes = [];

async function chooseFrameFormat() {
  const asked = new URLSearchParams(location.search).get("frames");
  const choices = asked ? [asked] : ["h264", "jpeg"];
  for (const choice of choices) {
    if (choice === "jpeg" || (VIDEO_FORMATS.includes(choice) && await canDecode(choice))) {
      setFrameFormat(choice);
      return;
    }
  }
  setFrameFormat("jpeg");  // asked for a video format this browser cannot decode
}

function setFrameFormat(format) {
  frameFormat = format;
  demo.frameFormat = format;
  $("frame-format").value = format;
  if (!VIDEO_FORMATS.includes(format)) video.close();
  viewDirty = true;
}

function onFrame(msg) {
  demo.framesReceived++;
  demo.lastVersion = msg.version;
  benchmark.onFrame(msg.version);
  const now = performance.now();
  frameTimes.push(now);
  frameBytes.push([now, msg.data.byteLength]);
  $("render-ms").textContent = msg.render_ms != null ? msg.render_ms.toFixed(2) : "–";
  $("field-ms").textContent = msg.field_ms != null ? msg.field_ms.toFixed(2) : "–";
  if (VIDEO_FORMATS.includes(msg.format)) video.decode(msg);
  else draw(msg);
}

async function draw(msg) {
  if (decoding) { waiting = msg; return; }
  decoding = true;
  try {
    const type = msg.format === "png" ? "image/png" : "image/jpeg";
    const bitmap = await createImageBitmap(new Blob([msg.data], { type }));
    ctx.drawImage(bitmap, 0, 0, canvas.width, canvas.height);
    bitmap.close();
  } finally {
    decoding = false;
  }
  if (waiting) { const next = waiting; waiting = null; draw(next); }
}

function updateStats(now) {
  while (frameTimes.length && now - frameTimes[0] > 1000) frameTimes.shift();
  while (frameBytes.length && now - frameBytes[0][0] > 1000) frameBytes.shift();
  // No frames while neither the view nor the world changes: the server sends none.
  $("fps").textContent = frameTimes.length ? String(frameTimes.length) : "idle ·";
  demo.bitrateMbps = frameBytes.reduce((sum, [, bytes]) => sum + bytes, 0) * 8 / 1e6;
  $("mbps").textContent = demo.bitrateMbps.toFixed(2);
  $("frame-kind").textContent = VIDEO_FORMATS.includes(frameFormat) && video.stats.encoder
    ? `${frameFormat} · ${video.stats.encoder}` : frameFormat;
  if (demo.world) {
    $("world-line").textContent = `${$("world-select").selectedOptions[0]?.textContent ?? demo.world} · v${demo.lastVersion}`;
  }
}

// ---------------------------------------------------------------------------------------------- editing

async function paint(px, py, erase) {
  if (!demo.world) return;
  const scale = Number($("resolution").value);
  const { camera } = view();
  const world = demo.world;
  const hit = await guarded("Pick", () => api((c) => c.pick(world, camera, px * scale, py * scale)));
  if (hit === undefined) return;  // failed: guarded said why
  if (hit === null) {  // the ray met no voxel: nothing to place against
    demo.misses++;
    flash("Nothing under the cursor to paint on: aim at a surface.", 1800);
    return;
  }
  const edit = erase
    ? { op: "sphere", center: hit.voxel, radius: brush.size, colour: 0 }
    : { op: "sphere", center: hit.place, radius: brush.size, colour: brush.colour };
  const done = await guarded("Edit", () => api((c) => c.edit(world, [edit])));
  if (done !== undefined) demo.edits++;
}

// ---------------------------------------------------------------------------------------------- input

function basis() {
  const y = cam.yaw * Math.PI / 180, p = cam.pitch * Math.PI / 180;
  return {
    forward: [Math.sin(y) * Math.cos(p), Math.sin(p), -Math.cos(y) * Math.cos(p)],
    right: [Math.cos(y), 0, Math.sin(y)],
  };
}

function turn(dx, dy) {
  cam.yaw = (cam.yaw + dx * 0.25) % 360;
  cam.pitch = Math.max(-89, Math.min(89, cam.pitch - dy * 0.25));
  viewDirty = true;
}

let drag = null;
canvas.addEventListener("contextmenu", (e) => e.preventDefault());
canvas.addEventListener("pointerdown", (e) => {
  canvas.focus();
  drag = { x: e.clientX, y: e.clientY, button: e.button, shift: e.shiftKey, moved: false };
  canvas.setPointerCapture(e.pointerId);
});
canvas.addEventListener("pointermove", (e) => {
  if (document.pointerLockElement === canvas) { turn(e.movementX, e.movementY); return; }
  const rect = canvas.getBoundingClientRect();
  cursor = [e.clientX - rect.left, e.clientY - rect.top];
  viewDirty = true;
  if (!drag) return;
  const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
  if (!drag.moved && Math.hypot(dx, dy) > 4) drag.moved = true;
  if (drag.moved) { turn(e.movementX, e.movementY); }
});
canvas.addEventListener("pointerup", (e) => {
  const d = drag;
  drag = null;
  if (!d || d.moved) return;
  const locked = document.pointerLockElement === canvas;
  const rect = canvas.getBoundingClientRect();
  const [px, py] = locked ? [rect.width / 2, rect.height / 2] : [e.clientX - rect.left, e.clientY - rect.top];
  const erase = d.button === 2 || d.shift || brush.mode === "erase";
  paint(px, py, erase);
});
canvas.addEventListener("pointerleave", () => { cursor = null; viewDirty = true; });
canvas.addEventListener("wheel", (e) => {
  e.preventDefault();
  setBrushSize(brush.size + (e.deltaY < 0 ? 1 : -1));
}, { passive: false });
document.addEventListener("pointerlockchange", () => {
  const locked = document.pointerLockElement === canvas;
  $("crosshair").hidden = !locked;
  if (locked) {
    cursor = [canvas.clientWidth / 2, canvas.clientHeight / 2];
    viewDirty = true;
  }
});
window.addEventListener("keydown", (e) => {
  if (e.target instanceof HTMLInputElement || e.target instanceof HTMLSelectElement) return;
  const key = e.key.toLowerCase();
  if (key === "l") {
    if (document.pointerLockElement === canvas) document.exitPointerLock();
    else canvas.requestPointerLock();
    return;
  }
  keys.add(key);
});
window.addEventListener("keyup", (e) => keys.delete(e.key.toLowerCase()));
window.addEventListener("blur", () => keys.clear());
window.addEventListener("resize", () => { viewDirty = true; });

let lastTick = performance.now();
function tick(now) {
  const dt = Math.min(0.1, (now - lastTick) / 1000);
  lastTick = now;
  const speed = Math.min(Math.max(...worldSize) * 0.4, 600) * dt;  // voxels a second, large worlds too
  const { forward, right } = basis();
  const move = [0, 0, 0];
  const add = (v, s) => { for (let i = 0; i < 3; i++) move[i] += v[i] * s; };
  if (keys.has("w")) add(forward, 1);
  if (keys.has("s")) add(forward, -1);
  if (keys.has("d")) add(right, 1);
  if (keys.has("a")) add(right, -1);
  if (keys.has("e") || keys.has(" ")) move[1] += 1;
  if (keys.has("q")) move[1] -= 1;
  if (move.some((v) => v !== 0)) {
    for (let i = 0; i < 3; i++) cam.position[i] += move[i] * speed;
    viewDirty = true;
  }
  benchmark.tick(now);
  sendView(now);
  updateStats(now);
  requestAnimationFrame(tick);
}

// ---------------------------------------------------------------------------------------------- panel

function setBrushSize(size) {
  brush.size = Math.max(0, Math.min(12, size));
  $("brush-size").value = brush.size;
  $("brush-size-out").textContent = brush.size;
  viewDirty = true;
}

function pickColour(value) {
  brush.colour = value;
  selectSwatch($("palette"), value);
  $("colour-picker").value = rgbHex(palette[value - 1]);
}

function showPalette(world) {
  palette = worldPalette(world);
  demo.palette = palette;
  showSwatches($("palette"), palette, brush.colour, pickColour);
  pickColour(brush.colour);
}

// The §3.5 benchmark mode; its numbers are in window.sdfDemo.benchmark for the browser test.
demo.benchmark = {};
const benchmark = new Benchmark({ edit: (edits) => api((c) => c.edit(demo.world, edits)), lookAt,
  viewChanged: () => { viewDirty = true; }, size: () => worldSize, stats: demo.benchmark });

function setupPanel() {
  $("bench-on").onchange = (e) => {
    if (e.target.checked && demo.world) benchmark.start(Number($("bench-seed").value) >>> 0);
    else { e.target.checked = false; benchmark.stop(); }
  };
  showPalette(null);
  $("colour-picker").oninput = (e) => {  // the nearest colour the world's palette has
    brush.colour = nearestValue(palette, e.target.value);
    selectSwatch($("palette"), brush.colour);
  };
  $("brush-size").oninput = (e) => setBrushSize(Number(e.target.value));
  for (const radio of document.querySelectorAll("input[name=mode]")) {
    radio.onchange = () => { brush.mode = radio.value; };
  }
  for (const id of ["algorithm", "lod-algorithm", "new-algorithm"]) {
    $(id).replaceChildren(...ALGORITHMS.map((a) => new Option(a, a)));
  }
  $("lod-algorithm").value = "jfa";
  // Euclidean and signed fields are computed by "exact" alone, with no focus (WorldConfig).
  for (const id of ["metric", "signed"]) {
    $(id).onchange = () => {
      if ($("metric").value !== "manhattan" || $("signed").checked) {
        $("algorithm").value = "exact";
        $("focus-on").checked = false;
      }
    };
  }
  for (const id of ["ao", "shadows", "resolution", "max-fps"]) $(id).onchange = () => { viewDirty = true; };
  $("frame-format").onchange = (e) => guarded("Frames", async () => {
    if (e.target.value !== "jpeg" && !await canDecode(e.target.value)) {
      flash(`This browser cannot decode ${e.target.value} (WebCodecs); JPEG frames instead.`, 3000);
      setFrameFormat("jpeg");
    } else setFrameFormat(e.target.value);
  });
  $("world-select").onchange = (e) => guarded("Open world", async () => {
    openWorld(await api((c) => c.getWorld(e.target.value)));
  });
  $("create-world").onclick = () => guarded("Create world", async () => {
    const world = await createWorld($("new-size").value, $("new-algorithm").value);
    await refreshWorlds(world.id);
    openWorld(world);
  });
  $("apply-field").onclick = () => guarded("Apply", async () => {
    const triple = (id) => $(id).value.split(",").map((v) => parseInt(v.trim(), 10));
    const update = { algorithm: $("algorithm").value, lodAlgorithm: $("lod-algorithm").value,
      focus: $("focus-on").checked ? { center: triple("focus-center"), size: triple("focus-size") } : null,
      metric: $("metric").value, signed: $("signed").checked };
    const world = await api((c) => c.updateWorld(demo.world, update));
    await refreshWorlds(world.id);
    showPalette(world);
    viewDirty = true;  // a stream sends a frame for a new view, not for a reconfigured field
    showStatus(`Field: ${world.metric ?? "manhattan"}${world.signed ? ", signed" : ""}, ${world.algorithm}`
      + `${world.focus ? " in focus, " + world.lodAlgorithm + " outside" : ""}`);
    setTimeout(() => showStatus(""), 1500);
  });
}

function setupKeyForm() {
  $("key-dialog").onsubmit = (e) => {
    e.preventDefault();
    setApiKey($("api-key").value.trim());
    $("api-key").value = "";
    $("key-dialog").hidden = true;
    demo.needsKey = false;
    showStatus("");
    openStartWorld();
  };
  $("key-cancel").onclick = () => { $("key-dialog").hidden = true; };
  $("change-key").onclick = () => {
    $("key-message").textContent = "API key for this server (kept in this tab only):";
    $("key-dialog").classList.remove("error");
    $("key-dialog").hidden = false;
    $("api-key").focus();
  };
  $("forget-key").onclick = () => { setApiKey(""); openStartWorld(); };
  setApiKey(apiKey());
}

async function start() {
  takeKeyFromAddress();
  setupPanel();
  setupKeyForm();
  await chooseFrameFormat();
  requestAnimationFrame(tick);
  await waitForServer();
  await openStartWorld();
}

// The world named in the address, else the first one this key sees, else a new demo world; once
// the server can serve, if it cannot now.
async function openStartWorld() {
  let notReady = false;
  await guarded("Start", async () => {
    try {
      const wanted = decodeURIComponent((location.hash.match(/world=([^&]+)/) || [])[1] || "");
      let worlds = await refreshWorlds();
      let world = worlds.find((w) => w.id === wanted) ?? worlds[0];
      if (!world) {
        world = await createWorld(64, "exact");
        worlds = await refreshWorlds(world.id);
      }
      $("world-select").value = world.id;
      openWorld(world);
    } catch (err) {
      notReady = err instanceof NotReady || err instanceof TransportError;
      throw err;
    }
  });
  if (notReady) {
    await waitForServer();
    await openStartWorld();
  }
}

start();
