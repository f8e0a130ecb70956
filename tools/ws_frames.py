"""Frames delivered to WebSocket clients while an edit arrives every frame (issues 4 and 35):
frame rate, Mbit/s, render-to-send latency and PSNR against the raw frames, per format.

    python tools/ws_frames.py --url http://127.0.0.1:8000 --size 512 --width 1920 --height 1080 \\
        --formats jpeg,h264 --bitrate 8000000 --duration 10 --streams 1 --json frames.json

For each format in turn, on a world of its own (a floor and spheres): --streams WebSocket clients
each ask for frames of a camera (orbiting at --orbit degrees a second, each from its own side),
the first sends a brush edit on its stream at --edit-hz (default 60: an edit for every frame at
the target rate), and every frame that arrives is counted and decoded (a video chunk needs the
ones before it; --psnr-samples 0 decodes nothing, so that only the server's work is timed).

Reported per format and stream: frames per second, Mbit/s of frame data, the server's latency
from a rendered frame's arrival in the API process to its message leaving for the socket
(``latency_ms``: encoding and waiting for the socket; p50, p99), the encoder and its encode time,
the client's decode time, and PSNR (RGB and BT.709 luma) of --psnr-samples frames against raw
RGBA frames of the same camera at the same field version. Those are rendered afterwards on a
replica world that replays the same edit batches (each batch is one version, so version N of
the replica is version N of the original).
"""

from __future__ import annotations

import argparse
import asyncio
import io
import json
import math
import sys
import time

import httpx
import msgpack
import numpy as np
import websockets

VIDEO_FORMATS = ("h264", "vp9", "av1")
DECODERS = {"h264": ("h264", {}), "vp9": ("vp9", {}), "av1": ("libdav1d", {"max_frame_delay": "1"})}
LUMA = np.array([0.2126, 0.7152, 0.0722])


def make_scene(n: int, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    scene = [{"op": "box", "min": [0, 0, 0], "max": [n, 4, n], "colour": 0x49}]
    scene += [{"op": "sphere", "center": [float(v) for v in rng.uniform(0, n, 3)],
               "radius": float(rng.uniform(4, n / 16)), "colour": int(rng.integers(1, 256))} for _ in range(64)]
    return scene


def camera_at(args, stream: int, elapsed_s: float) -> dict:
    n = args.size
    angle = math.radians(45 + 360 * stream / args.streams + args.orbit * elapsed_s)
    return {"position": [n / 2 + n * 0.85 * math.cos(angle), n * 0.6, n / 2 + n * 0.85 * math.sin(angle)],
            "target": [n / 2, 0, n / 2], "width": args.width, "height": args.height}


def frame_settings(args, fmt: str) -> dict:
    if fmt not in VIDEO_FORMATS:
        return {"format": fmt, "quality": args.quality}
    rate = {"bitrate": args.bitrate} if args.bitrate else {"crf": args.crf} if args.crf is not None else {}
    extra = {"encoder": args.encoder} if args.encoder else {}
    if args.preset and fmt == "h264":
        extra["preset"] = args.preset
    return {"format": fmt, "keyframe_s": args.keyframe_s, **rate, **extra}


class Decoder:
    def __init__(self) -> None:
        self.context, self.video = None, None

    def feed(self, message: dict) -> np.ndarray | None:
        if message["type"] == "video":
            import av

            name, options = DECODERS[message["format"]]
            self.context, self.video = av.CodecContext.create(name, "r"), message
            self.context.options = dict(options)
            return None
        fmt = message["format"]
        if fmt in VIDEO_FORMATS:
            import av

            pictures = self.context.decode(av.Packet(message["data"]))
            return pictures[-1].to_ndarray(format="rgb24") if pictures else None
        if fmt == "rgba":
            return np.frombuffer(message["data"], np.uint8).reshape(message["height"], message["width"], 4)[..., :3]
        from PIL import Image

        return np.asarray(Image.open(io.BytesIO(message["data"])).convert("RGB"))


class Stream:
    """One client: its camera, what it received, the pictures kept for PSNR."""

    def __init__(self, args, index: int, fmt: str, ws_url: str):
        self.args, self.index, self.fmt, self.url = args, index, fmt, ws_url
        self.cameras: dict[int, dict] = {}
        self.times, self.sizes, self.latency, self.encode, self.decode_ms = [], [], [], [], []
        self.versions, self.keys, self.video, self.acks = [], 0, None, 0
        self.samples: list[tuple[int, int, np.ndarray]] = []  # (version, view id, decoded picture)

    async def run(self, start: float, edits: list | None) -> None:
        args, decode = self.args, self.args.psnr_samples > 0
        decoder, sample_every = Decoder(), args.duration / max(1, args.psnr_samples)
        next_sample = sample_every / 2
        async with websockets.connect(self.url, max_size=256 << 20, compression=None) as ws:
            tasks = [asyncio.create_task(self._steer(ws, start))]
            if edits is not None:
                tasks.append(asyncio.create_task(self._edit(ws, start, edits)))
            try:
                while time.perf_counter() - start < args.duration:
                    left = args.duration - (time.perf_counter() - start)
                    try:  # generous for the first frame (kernels may be building); then until the end
                        raw = await asyncio.wait_for(ws.recv(), 120 if not self.times else max(0.05, left))
                    except asyncio.TimeoutError:
                        if self.times:
                            break
                        raise
                    message = msgpack.unpackb(raw, raw=False)
                    kind = message.get("type")
                    if kind == "error":
                        raise RuntimeError(message)
                    if kind == "ack":
                        self.acks += 1
                    if kind == "video":
                        self.video = {k: v for k, v in message.items() if k != "type"}
                    if kind not in ("frame", "video"):
                        continue
                    if decode:
                        t = time.perf_counter()
                        picture = decoder.feed(message)
                        if kind == "frame":
                            self.decode_ms.append((time.perf_counter() - t) * 1e3)
                    if kind == "video":
                        continue
                    now = time.perf_counter()
                    self.times.append(now)
                    self.sizes.append(len(message["data"]))
                    self.versions.append(message["version"])
                    self.latency.append(message.get("latency_ms", float("nan")))
                    self.encode.append(message.get("encode_ms", float("nan")))
                    self.keys += bool(message.get("key"))
                    # A server older than view_id cannot say which camera a frame shows: no PSNR then.
                    if decode and picture is not None and message.get("view_id") and now - start >= next_sample:
                        self.samples.append((message["version"], message["view_id"], picture))
                        next_sample += sample_every
            finally:
                for task in tasks:
                    task.cancel()
                await asyncio.gather(*tasks, return_exceptions=True)

    async def _steer(self, ws, start: float) -> None:
        """The camera: once, or --view-hz times a second while it orbits."""
        view_id = 0
        while True:
            view_id += 1
            camera = camera_at(self.args, self.index, time.perf_counter() - start)
            self.cameras[view_id] = camera
            await ws.send(msgpack.packb({"type": "camera", "id": view_id, **camera, "max_fps": self.args.max_fps,
                                         **frame_settings(self.args, self.fmt)}))
            if not self.args.orbit:
                return
            await asyncio.sleep(1 / self.args.view_hz)

    async def _edit(self, ws, start: float, edits: list) -> None:
        rng = np.random.default_rng(self.args.seed + 1)
        n, next_at = self.args.size, time.perf_counter()
        while time.perf_counter() - start < self.args.duration:
            batch = [{"op": "sphere", "center": [float(v) for v in rng.uniform(n * 0.2, n * 0.8, 3)], "radius": 3.0,
                      "colour": int(rng.integers(1, 256)) if len(edits) % 2 else 0}]
            edits.append(batch)  # in send order: the replica replays them so
            await ws.send(msgpack.packb({"type": "edits", "id": len(edits), "edits": batch}))
            next_at += 1.0 / self.args.edit_hz
            await asyncio.sleep(max(0.0, next_at - time.perf_counter()))

    def report(self) -> dict:
        elapsed = self.times[-1] - self.times[0] if len(self.times) > 1 else float("nan")
        dt = np.diff(self.times) * 1e3 if len(self.times) > 1 else np.array([float("nan")])

        def spread(values) -> dict:
            v = np.asarray(values, float)
            v = v[np.isfinite(v)]
            return {} if not len(v) else {"p50": float(np.percentile(v, 50)), "p99": float(np.percentile(v, 99)),
                                          "max": float(v.max())}

        return {"frames": len(self.times), "fps": (len(self.times) - 1) / elapsed,
                "mbit_s": sum(self.sizes[1:]) * 8 / elapsed / 1e6, "bytes_per_frame": float(np.mean(self.sizes)),
                "keyframes": self.keys, "video": self.video, "acks": self.acks,
                "frame_interval_ms": spread(dt), "latency_ms": spread(self.latency), "encode_ms": spread(self.encode),
                "client_decode_ms": spread(self.decode_ms),
                "versions": {"first": self.versions[0], "last": self.versions[-1], "distinct": len(set(self.versions))}}


async def replica_psnr(http: httpx.AsyncClient, args, scene: list, edits: list, streams: list[Stream]) -> dict:
    """Each kept picture against the raw RGBA frame of its camera at its version, on a replica."""
    samples = sorted((v, s.index, view, picture) for s in streams for v, view, picture in s.samples)
    if not samples:
        return {}
    replica = await create_world(http, args, scene)
    version, rgb, luma = 1, [], []
    try:
        for target, index, view_id, picture in samples:
            while version < target:
                r = await http.post(f"/v1/worlds/{replica}/edits", json={"edits": edits[version - 1]})
                r.raise_for_status()
                version = r.json()["version"]
            camera = streams[index].cameras[view_id]
            deadline = time.monotonic() + 60
            while True:  # the field of the last batch may still be computing
                r = await http.post(f"/v1/worlds/{replica}/render", json={**camera, "format": "rgba"})
                r.raise_for_status()
                if int(r.headers["x-field-version"]) >= target or time.monotonic() > deadline:
                    break
                await asyncio.sleep(0.01)
            assert int(r.headers["x-field-version"]) == target, (r.headers["x-field-version"], target)
            raw = np.frombuffer(r.content, np.uint8).reshape(camera["height"], camera["width"], 4)[..., :3]
            raw = raw[:picture.shape[0], :picture.shape[1]].astype(float)  # 4:2:0 drops an odd row or column
            error = picture.astype(float) - raw
            rgb.append(10 * np.log10(255 ** 2 / max(np.mean(error ** 2), 1e-12)))
            luma.append(10 * np.log10(255 ** 2 / max(np.mean((error @ LUMA) ** 2), 1e-12)))
    finally:
        await http.delete(f"/v1/worlds/{replica}")
    return {"samples": len(rgb), "rgb_db": {"min": min(rgb), "mean": float(np.mean(rgb))},
            "luma_db": {"min": min(luma), "mean": float(np.mean(luma))}}


async def create_world(http: httpx.AsyncClient, args, scene: list) -> str:
    n = args.size
    r = await http.post("/v1/worlds", json={"size": [n, n, n], "chunk_size": 32, "max_distance": args.cap})
    r.raise_for_status()
    world = r.json()["id"]
    (await http.post(f"/v1/worlds/{world}/edits", json={"edits": scene})).raise_for_status()
    return world


async def run_format(args, fmt: str) -> dict:
    scene = make_scene(args.size, args.seed)
    async with httpx.AsyncClient(base_url=args.url, timeout=120) as http:
        world = await create_world(http, args, scene)
        ws_url = args.url.replace("http", "ws", 1) + f"/v1/worlds/{world}/stream"
        streams = [Stream(args, i, fmt, ws_url) for i in range(args.streams)]
        edits: list = []
        start = time.perf_counter()
        await asyncio.gather(*(s.run(start, edits if s.index == 0 else None) for s in streams))
        quality = await replica_psnr(http, args, scene, edits, streams)
        await http.delete(f"/v1/worlds/{world}")
    reports = [s.report() for s in streams]
    return {"format": fmt, "settings": frame_settings(args, fmt), "streams": reports, "psnr": quality,
            "edits": len(edits), "fps_min": min(r["fps"] for r in reports),
            "mbit_s_max": max(r["mbit_s"] for r in reports),
            "latency_p99_ms_max": max(r["latency_ms"].get("p99", float("nan")) for r in reports)}


def _ms(spread: dict, key: str) -> str:
    return f"{spread[key]:.2f}" if key in spread else "n/a"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--url", default="http://127.0.0.1:8000")
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--cap", type=int, default=255)
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--height", type=int, default=720)
    p.add_argument("--max-fps", type=int, default=240)
    p.add_argument("--duration", type=float, default=10.0)
    p.add_argument("--edit-hz", type=float, default=60.0, help="edits sent per second on the first stream")
    p.add_argument("--formats", default="jpeg", help="comma-separated: jpeg, png, rgba, h264, vp9, av1")
    p.add_argument("--quality", type=int, default=80, help="JPEG quality")
    p.add_argument("--bitrate", type=int, default=None, help="video bit/s (else --crf, else the server's default)")
    p.add_argument("--crf", type=int, default=None, help="video constant quality")
    p.add_argument("--keyframe-s", type=float, default=2.0)
    p.add_argument("--encoder", default=None, help="pin the video encoder (libx264, h264_nvenc, ...)")
    p.add_argument("--preset", default=None, help="libx264's preset (h264): ultrafast .. fast")
    p.add_argument("--streams", type=int, default=1, help="clients at once on the world, each its own camera")
    p.add_argument("--orbit", type=float, default=0.0, help="camera orbit, degrees a second (0: still)")
    p.add_argument("--view-hz", type=float, default=60.0, help="camera messages a second while orbiting")
    p.add_argument("--psnr-samples", type=int, default=20, help="frames a stream compares with raw frames "
                   "(0: decode nothing)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--json", default=None)
    args = p.parse_args()
    results = []
    for fmt in args.formats.split(","):
        result = asyncio.run(run_format(args, fmt.strip()))
        results.append(result)
        psnr = result["psnr"]
        for i, s in enumerate(result["streams"]):
            video = s["video"] or {}
            print(f"{fmt} stream {i}: {s['frames']} frames, {s['fps']:.1f} FPS, {s['mbit_s']:.2f} Mbit/s, "
                  f"{s['bytes_per_frame'] / 1e3:.1f} kB/frame, latency p50 {_ms(s['latency_ms'], 'p50')} "
                  f"p99 {_ms(s['latency_ms'], 'p99')} ms, decode p99 {_ms(s['client_decode_ms'], 'p99')} ms"
                  + (f", encode p99 {_ms(s['encode_ms'], 'p99')} ms ({video.get('encoder')}, {video.get('codec')}, "
                     f"{s['keyframes']} keyframes)" if video else "")
                  + f", versions {s['versions']['first']}..{s['versions']['last']}")
        if psnr:
            print(f"{fmt} PSNR over {psnr['samples']} frames: RGB min {psnr['rgb_db']['min']:.2f} mean "
                  f"{psnr['rgb_db']['mean']:.2f} dB, luma min {psnr['luma_db']['min']:.2f} mean "
                  f"{psnr['luma_db']['mean']:.2f} dB")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"config": vars(args), "results": results}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
