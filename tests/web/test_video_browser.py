"""The web demo plays the stream's H.264 video in a real headless Chromium (WebCodecs'
VideoDecoder) against a real `sdfserver serve`, shows the bitrate beside the FPS, draws the same
picture as the JPEG frames of the same view, and falls back to JPEG where the browser has no
VideoDecoder."""

from __future__ import annotations

import asyncio
import tempfile
from pathlib import Path

import httpx
import numpy as np

from sdfserver.render.scene import demo_scene

from .conftest import serve
from .test_demo_browser import Chromium, pytestmark  # noqa: F401  (skips without chromium)

CANVAS = ("(() => { const r = document.getElementById('frame').getBoundingClientRect();"
          " return [r.left, r.top, r.width, r.height]; })()")


def test_the_demo_plays_h264_and_falls_back_to_jpeg(tmp_path):
    tmp = Path(tempfile.mkdtemp(prefix="sdfserver-video-"))
    with serve(tmp_path / "data") as (base, _):
        world = httpx.post(base + "/v1/worlds", json={"size": [64, 64, 64]}).json()["id"]
        httpx.post(base + f"/v1/worlds/{world}/edits", json={"edits": demo_scene((64, 64, 64))}).raise_for_status()
        asyncio.run(asyncio.wait_for(_plays_video(base, tmp), timeout=180))
        asyncio.run(asyncio.wait_for(_falls_back(base, tmp), timeout=120))


async def _canvas(browser: Chromium, path: Path) -> np.ndarray:
    left, top, width, height = (int(v) for v in await browser.evaluate(CANVAS))
    return (await browser.screenshot(path))[top + 2:top + height - 2, left + 2:left + width - 2].astype(int)


async def _plays_video(base: str, tmp: Path) -> None:
    browser = Chromium(tmp)
    try:
        await browser.open_page()
        await browser.call("Page.enable")
        await browser.call("Page.navigate", url=base + "/")  # H.264 is the default where WebCodecs has it
        await browser.wait_for("window.sdfDemo && window.sdfDemo.video.decoded >= 1", 90)
        assert await browser.evaluate("window.sdfDemo.frameFormat") == "h264"
        stats = await browser.evaluate("window.sdfDemo.video")
        assert stats["codec"].startswith("avc1.") and stats["encoder"] in ("libx264", "h264_nvenc"), stats
        # Fly forward: a frame for every view the page sends, each a chunk that needs the ones before.
        await browser.call("Input.dispatchKeyEvent", type="keyDown", key="w", code="KeyW", text="w")
        await asyncio.sleep(0.6)
        bitrate = float(await browser.evaluate("document.getElementById('mbps').textContent"))
        assert "h264 · " in await browser.evaluate("document.getElementById('frame-kind').textContent")
        await browser.call("Input.dispatchKeyEvent", type="keyUp", key="w", code="KeyW")
        await asyncio.sleep(1.0)  # the last chunks decode
        stats = await browser.evaluate("window.sdfDemo.video")
        received = await browser.evaluate("window.sdfDemo.framesReceived")
        assert bitrate > 0 and stats["decoded"] >= 5, (bitrate, stats)
        # Every chunk decoded, no decoder error, no keyframe needed beyond the stream's first.
        assert stats["decoded"] == received and stats["errors"] == [] and stats["skipped"] == 0, (stats, received)
        assert stats["keyframes"] >= 1
        played = await _canvas(browser, tmp / "h264.png")
        assert len(np.unique(played.reshape(-1, 3), axis=0)) > 50, "the video shows no scene"

        # The same view as JPEG pictures: the same picture, up to the two codecs' losses.
        before = received
        await browser.evaluate("const s = document.getElementById('frame-format'); s.value = 'jpeg'; "
                               "s.dispatchEvent(new Event('change'))")
        await browser.wait_for(f"window.sdfDemo.framesReceived > {before} && window.sdfDemo.frameFormat === 'jpeg'", 30)
        await asyncio.sleep(1.0)
        pictures = await _canvas(browser, tmp / "jpeg.png")
        difference = np.abs(played - pictures).mean()
        assert difference < 6, f"the video's picture differs from the JPEG's by {difference:.1f} on average"
        assert not await browser.evaluate("window.sdfDemo.errors.length"), await browser.evaluate("window.sdfDemo.errors")
    finally:
        await browser.close()


async def _falls_back(base: str, tmp: Path) -> None:
    browser = Chromium(tmp)
    try:
        await browser.open_page()
        await browser.call("Page.enable")
        await browser.call("Page.addScriptToEvaluateOnNewDocument", source="delete window.VideoDecoder;")
        await browser.call("Page.navigate", url=base + "/?frames=h264")
        await browser.wait_for("window.sdfDemo && window.sdfDemo.framesReceived >= 1", 90)
        assert await browser.evaluate("window.sdfDemo.frameFormat") == "jpeg"
        assert await browser.evaluate("window.sdfDemo.video.decoded") == 0
        shown = await _canvas(browser, tmp / "fallback.png")
        assert len(np.unique(shown.reshape(-1, 3), axis=0)) > 50, "the JPEG fallback shows no scene"
    finally:
        await browser.close()
