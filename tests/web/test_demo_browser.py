"""The web demo in a real headless Chromium against a real `sdfserver serve` on loopback.

The page opens with no world on the server, so it creates its default world
(floor and shapes); the test waits for streamed frames, clicks the canvas to
place voxels, and checks that the world's version rises and the picture
changes. Screenshots are saved under a tmp dir and their paths printed.
On a server with API keys the page asks for a key, takes one from its form or
the address, and streams with it. Chromium is driven over the DevTools
protocol (its WebSocket).
"""

from __future__ import annotations

import asyncio
import base64
import io
import itertools
import json
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
import websockets
from PIL import Image

from .conftest import KEYS, serve

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's `chromium` is not installed "
                                "(apt-get install -y chromium); CI installs it")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--window-size=1100,700", "--remote-debugging-port=0", "--remote-allow-origins=*"]


class Chromium:
    def __init__(self, tmp: Path):
        self.proc = subprocess.Popen([CHROMIUM, *FLAGS, f"--user-data-dir={tmp / 'profile'}", "about:blank"],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        self.ids = itertools.count(1)

    def devtools_url(self) -> str:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            line = self.proc.stderr.readline()
            match = re.search(r"DevTools listening on (ws://\S+)", line)
            if match:
                return match.group(1)
        raise RuntimeError("chromium did not print its DevTools address")

    async def open_page(self):
        port = int(re.search(r":(\d+)/", self.devtools_url()).group(1))
        deadline = time.monotonic() + 10
        while True:
            targets = httpx.get(f"http://127.0.0.1:{port}/json").json()
            pages = [t for t in targets if t["type"] == "page"]
            if pages or time.monotonic() > deadline:
                break
            await asyncio.sleep(0.1)
        self.ws = await websockets.connect(pages[0]["webSocketDebuggerUrl"], max_size=64 << 20)

    async def call(self, method: str, **params):
        call_id = next(self.ids)
        await self.ws.send(json.dumps({"id": call_id, "method": method, "params": params}))
        while True:
            message = json.loads(await self.ws.recv())
            if message.get("id") == call_id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message["result"]

    async def evaluate(self, expression: str):
        result = await self.call("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        return result["result"].get("value")

    async def wait_for(self, expression: str, timeout_s: float = 60.0):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            value = await self.evaluate(expression)
            if value:
                return value
            await asyncio.sleep(0.2)
        state = await self.evaluate("JSON.stringify(window.sdfDemo)")
        raise AssertionError(f"timed out waiting for {expression}; page state: {state}")

    async def screenshot(self, path: Path) -> np.ndarray:
        data = base64.b64decode((await self.call("Page.captureScreenshot", format="png"))["data"])
        path.write_bytes(data)
        print(f"screenshot: {path}")
        return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))

    async def click(self, x: float, y: float, button: str = "left"):
        for kind in ("mouseMoved", "mousePressed", "mouseReleased"):
            await self.call("Input.dispatchMouseEvent", type=kind, x=x, y=y, button=button,
                            buttons=0 if kind == "mouseMoved" else 1, clickCount=1)

    async def close(self):
        if getattr(self, "ws", None) is not None:
            await self.ws.close()
        self.proc.terminate()
        self.proc.wait(10)
        self.proc.stderr.close()


def test_demo_streams_frames_and_paints(server):
    tmp = Path(tempfile.mkdtemp(prefix="sdfserver-demo-"))
    asyncio.run(asyncio.wait_for(_drive(server, tmp), timeout=150))


async def _drive(base: str, tmp: Path) -> None:
    browser = Chromium(tmp)
    try:
        await browser.open_page()
        await browser.call("Page.enable")
        # A newcomer: no world exists (the server's data directory is its own, so no other test's
        # world can be there), the page makes its demo scene and frames start to arrive.
        assert httpx.get(base + "/v1/worlds").json()["worlds"] == []
        await browser.call("Page.navigate", url=base + "/")
        await browser.wait_for("window.sdfDemo && window.sdfDemo.framesReceived > 0 "
                               "&& window.sdfDemo.lastVersion >= 1")
        worlds = httpx.get(base + "/v1/worlds").json()["worlds"]
        assert len(worlds) == 1 and worlds[0]["version"] >= 1
        await asyncio.sleep(1.0)  # let the last frame of the starting view settle
        before = await browser.screenshot(tmp / "before.png")
        rect = await browser.evaluate("(() => { const r = document.getElementById('frame')"
                                      ".getBoundingClientRect(); return [r.left, r.top, r.width, r.height]; })()")
        left, top, width, height = rect
        # The picker shows the world's palette (RGB332: it has none), a button per value.
        assert await browser.evaluate("document.querySelectorAll('#palette button').length") == 255
        assert await browser.evaluate("document.querySelector('#palette button.selected').dataset.value") == "228"
        # A cyan brush (RGB332 0x1f), three voxels wide, at the middle of the picture.
        await browser.evaluate("document.querySelector('#palette button[data-value=\"31\"]').click()")
        assert await browser.evaluate("window.sdfDemo.brush.colour") == 31
        version = worlds[0]["version"]
        await browser.click(left + width / 2, top + height / 2)
        await browser.wait_for("window.sdfDemo.edits >= 1 || window.sdfDemo.misses >= 1", 30)
        assert await browser.evaluate("window.sdfDemo.edits") == 1, "the click at the middle hit nothing"
        await browser.wait_for(f"window.sdfDemo.lastVersion > {version}", 30)
        await asyncio.sleep(1.0)
        after = await browser.screenshot(tmp / "after.png")
        assert httpx.get(base + f"/v1/worlds/{worlds[0]['id']}").json()["version"] > version
        view = (slice(int(top), int(top + height)), slice(int(left), int(left + width)))
        changed = np.any(np.abs(after[view].astype(int) - before[view].astype(int)) > 40, axis=-1)
        assert changed.mean() > 0.001, "placing voxels did not change the picture"
        assert not await browser.evaluate("window.sdfDemo.errors.length"), \
            await browser.evaluate("window.sdfDemo.errors")

        # Benchmark mode (§3.5): seeded brushes every 200 ms while the camera orbits; the page shows
        # FPS over all frames and over the frames that came while a recompute was in flight.
        version = httpx.get(base + f"/v1/worlds/{worlds[0]['id']}").json()["version"]
        await browser.evaluate("document.getElementById('bench-seed').value = '7'; "
                               "document.getElementById('bench-on').click()")
        await browser.wait_for("window.sdfDemo.benchmark.edits >= 5 && window.sdfDemo.benchmark.recomputeFrames >= 2",
                               60)
        await browser.evaluate("document.getElementById('bench-on').click()")
        stats = await browser.evaluate("window.sdfDemo.benchmark")
        assert stats["seed"] == 7 and not stats["running"]
        assert stats["fpsOverall"] > 0 and stats["fpsRecompute"] > 0, stats
        shown = [float(await browser.evaluate(f"document.getElementById('{i}').textContent"))
                 for i in ("bench-fps", "bench-fps-recompute")]
        assert shown == pytest.approx([stats["fpsOverall"], stats["fpsRecompute"]], abs=0.051)
        assert httpx.get(base + f"/v1/worlds/{worlds[0]['id']}").json()["version"] >= version + stats["edits"]
        await browser.screenshot(tmp / "benchmark.png")
        await _field_and_palette_controls(browser, base, worlds[0]["id"], tmp)
    finally:
        await browser.close()


async def _field_and_palette_controls(browser: Chromium, base: str, world: str, tmp: Path) -> None:
    """The metric and signed controls PATCH the world; the picker follows the world's palette."""
    frames = await browser.evaluate("window.sdfDemo.framesReceived")
    await browser.evaluate("document.getElementById('metric').value = 'euclidean'; "
                           "document.getElementById('metric').dispatchEvent(new Event('change')); "
                           "document.getElementById('signed').click(); "
                           "document.getElementById('apply-field').click()")
    deadline = time.monotonic() + 30
    while (described := httpx.get(base + f"/v1/worlds/{world}").json())["metric"] != "euclidean":
        assert time.monotonic() < deadline, described
        await asyncio.sleep(0.2)
    assert described["signed"] is True and described["algorithm"] == "exact" and described["focus"] is None
    await browser.wait_for(f"window.sdfDemo.framesReceived > {frames}", 30)  # the new field streams
    assert "euclidean · signed" in await browser.evaluate("document.getElementById('world-line').textContent")

    rng = np.random.default_rng()
    palette = rng.integers(0, 256, (255, 3)).tolist()
    palette[31 - 1] = [10, 200, 30]
    assert httpx.patch(base + f"/v1/worlds/{world}", json={"palette": palette}).status_code == 200
    await browser.evaluate("document.getElementById('world-select').dispatchEvent(new Event('change'))")
    await browser.wait_for("window.sdfDemo.palette[30][1] === 200", 30)
    assert await browser.evaluate("document.querySelector('#palette button[data-value=\"31\"]').style.background") \
        == "rgb(10, 200, 30)"
    assert await browser.evaluate("document.getElementById('colour-picker').value") == "#0ac81e"
    await browser.evaluate("document.querySelector('#palette button[data-value=\"200\"]').click()")
    assert await browser.evaluate("window.sdfDemo.brush.colour") == 200
    assert await browser.evaluate("document.getElementById('colour-picker').value") == \
        "#" + "".join(f"{c:02x}" for c in palette[199])
    # A custom colour picks the palette's nearest.
    await browser.evaluate("const p = document.getElementById('colour-picker'); p.value = '#0bc81f'; "
                           "p.dispatchEvent(new Event('input'))")
    assert await browser.evaluate("window.sdfDemo.brush.colour") == 31
    await browser.screenshot(tmp / "palette.png")
    assert not await browser.evaluate("window.sdfDemo.errors.length"), await browser.evaluate("window.sdfDemo.errors")


def test_demo_with_api_keys(keyed_server):
    tmp = Path(tempfile.mkdtemp(prefix="sdfserver-demo-keyed-"))
    asyncio.run(asyncio.wait_for(_drive_keyed(keyed_server, tmp), timeout=120))


def _worlds_of(base: str, token: str) -> list[dict]:
    r = httpx.get(base + "/v1/worlds", headers={"authorization": f"Bearer {token}"})
    assert r.status_code == 200, r.text
    return r.json()["worlds"]


async def _drive_keyed(server, tmp: Path) -> None:
    base = server.url
    painter, other = KEYS["painter"], KEYS["other"]
    streaming = "window.sdfDemo && window.sdfDemo.framesReceived > 0 && window.sdfDemo.lastVersion >= 1"
    browser = Chromium(tmp)
    try:
        await browser.open_page()
        await browser.call("Page.enable")
        # No key: a clear request for one, nothing created.
        assert httpx.get(base + "/v1/worlds").status_code == 401
        await browser.call("Page.navigate", url=base + "/")
        await browser.wait_for("window.sdfDemo && window.sdfDemo.needsKey")
        assert not await browser.evaluate("document.getElementById('key-dialog').hidden")
        said = await browser.evaluate("document.getElementById('key-message').textContent")
        assert "requires an API key" in said, said
        await browser.screenshot(tmp / "asks-for-key.png")
        assert _worlds_of(base, painter) == [] and _worlds_of(base, other) == []

        # The key form: the page makes painter's world and streams it over ?access_token=.
        await browser.evaluate(f"document.getElementById('api-key').value = {json.dumps(painter)}; "
                               "document.getElementById('key-dialog').requestSubmit()")
        await browser.wait_for(streaming)
        assert await browser.evaluate("sessionStorage.getItem('sdfserver.apiKey')") == painter
        assert await browser.evaluate("document.getElementById('key-dialog').hidden")
        mine = _worlds_of(base, painter)
        assert len(mine) == 1 and mine[0]["id"] == await browser.evaluate("window.sdfDemo.world")
        assert _worlds_of(base, other) == []  # tenants stay apart
        await browser.screenshot(tmp / "keyed.png")

        # A wrong key in the address is refused, plainly.
        await browser.call("Page.navigate", url=base + "/?again=1#key=wrong-token-0123456789")
        await browser.wait_for("window.sdfDemo && window.sdfDemo.needsKey")
        said = await browser.evaluate("document.getElementById('key-message').textContent")
        assert "refused" in said and "unknown API key" in said, said

        # ?key= in the address: kept for the tab and taken out of the address bar.
        await browser.call("Page.navigate", url=base + f"/?key={other}")
        await browser.wait_for(streaming)
        assert other not in await browser.evaluate("location.href")
        theirs = _worlds_of(base, other)
        assert len(theirs) == 1 and theirs[0]["id"] != mine[0]["id"]
        assert not await browser.evaluate("window.sdfDemo.needsKey")
    finally:
        await browser.close()
    log = server.log.read_text()
    assert "[redacted]" in log and painter not in log and other not in log  # no token in the log


def test_demo_opens_a_sparse_terrain_and_flies_over_it(tmp_path):
    tmp = Path(tempfile.mkdtemp(prefix="sdfserver-demo-terrain-"))
    with serve(tmp_path / "data") as (base, _):  # its own: the paint test wants a server with no world
        asyncio.run(asyncio.wait_for(_drive_terrain(base, tmp), timeout=240))


async def _drive_terrain(base: str, tmp: Path) -> None:
    browser = Chromium(tmp)
    try:
        await browser.open_page()
        await browser.call("Page.enable")
        await browser.call("Page.navigate", url=base + "/")
        await browser.wait_for("window.sdfDemo && window.sdfDemo.framesReceived > 0")
        frames = await browser.evaluate("window.sdfDemo.framesReceived")
        # New: the smallest generated terrain (the larger ones need a GPU's memory and speed).
        await browser.evaluate("document.getElementById('new-size').value = 'terrain-1024'; "
                               "document.getElementById('create-world').click()")
        terrain = await browser.wait_for(
            "(() => { const w = window.sdfDemo.world; const s = document.getElementById('world-line').textContent;"
            " return s.includes('sparse') && s.startsWith(w) ? w : null; })()", 120)
        described = httpx.get(f"{base}/v1/worlds/{terrain}").json()
        assert described["storage"] == "sparse" and described["size"] == [1024, 128, 1024]
        assert 0 < described["stored_bricks"] < 32 * 4 * 32  # bricks near the surface only
        await browser.wait_for(f"window.sdfDemo.framesReceived > {frames}", 60)  # the terrain's first frame
        start = await browser.evaluate("window.sdfDemo.camera.position.slice()")
        before = await browser.screenshot(tmp / "terrain-before.png")
        # Fly forward over it: hold W for half a second (about 200 voxels at this world's speed).
        await browser.call("Input.dispatchKeyEvent", type="keyDown", key="w", code="KeyW", text="w")
        await asyncio.sleep(0.5)
        await browser.call("Input.dispatchKeyEvent", type="keyUp", key="w", code="KeyW")
        end = await browser.evaluate("window.sdfDemo.camera.position.slice()")
        moved = float(np.linalg.norm(np.subtract(end, start)))
        assert moved > 60, f"the camera moved {moved:.1f} voxels"
        frames = await browser.evaluate("window.sdfDemo.framesReceived")
        await asyncio.sleep(2.0)  # the frame of where the flight ended (frames follow the view)
        await browser.wait_for(f"window.sdfDemo.framesReceived >= {frames}", 60)
        after = await browser.screenshot(tmp / "terrain-after.png")
        rect = await browser.evaluate("(() => { const r = document.getElementById('frame')"
                                      ".getBoundingClientRect(); return [r.left, r.top, r.width, r.height]; })()")
        left, top, width, height = (int(v) for v in rect)
        view = (slice(top, top + height), slice(left, left + width))
        changed = np.any(np.abs(after[view].astype(int) - before[view].astype(int)) > 40, axis=-1)
        assert changed.mean() > 0.05, "flying over the terrain did not change the picture"
        for picture in (before, after):  # above the ground: sky over terrain, both in sight
            sky = np.all(np.abs(picture[view].astype(int) - [0x9C, 0xC8, 0xF0]) < 24, axis=-1).mean()
            assert 0.1 < sky < 0.9, f"sky covers {sky:.0%} of the picture"
        assert not await browser.evaluate("window.sdfDemo.errors.length"), \
            await browser.evaluate("window.sdfDemo.errors")
    finally:
        await browser.close()
