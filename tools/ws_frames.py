"""Frames delivered to one WebSocket client while an edit arrives every frame (issue 4's target).

    python tools/ws_frames.py --url http://127.0.0.1:8000 --size 512 --duration 10

Creates a world with a floor and some spheres, sends a camera on the stream, and sends a brush
edit on the same stream at --edit-hz (default 60: an edit for every frame at the target rate)
while counting the frames that arrive. Reports frames per second, inter-frame times and the
versions the frames show (so it is visible that the field kept up).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time

import httpx
import msgpack
import numpy as np
import websockets


async def run(args) -> dict:
    n = args.size
    async with httpx.AsyncClient(base_url=args.url, timeout=60) as http:
        r = await http.post("/v1/worlds", json={"size": [n, n, n], "chunk_size": 32, "max_distance": args.cap})
        r.raise_for_status()
        world = r.json()["id"]
        scene = [{"op": "box", "min": [0, 0, 0], "max": [n, 4, n], "colour": 0x49}]
        rng = np.random.default_rng(args.seed)
        scene += [{"op": "sphere", "center": [float(v) for v in rng.uniform(0, n, 3)],
                   "radius": float(rng.uniform(4, n / 16)), "colour": int(rng.integers(1, 256))}
                  for _ in range(64)]
        (await http.post(f"/v1/worlds/{world}/edits", json={"edits": scene})).raise_for_status()
    ws_url = args.url.replace("http", "ws", 1) + f"/v1/worlds/{world}/stream"
    frame_times, versions, acks = [], [], 0
    async with websockets.connect(ws_url, max_size=64 << 20) as ws:
        await ws.send(msgpack.packb({"type": "camera", "id": 1, "position": [n * 1.1, n * 0.6, n * 1.1],
                                     "target": [n / 2, 0, n / 2], "width": args.width, "height": args.height,
                                     "max_fps": args.max_fps, "format": "jpeg"}))
        start = time.perf_counter()

        async def send_edits() -> None:
            edit_id = 10
            next_at = time.perf_counter()
            while time.perf_counter() - start < args.duration:
                edit_id += 1
                center = [float(v) for v in rng.uniform(n * 0.2, n * 0.8, 3)]
                await ws.send(msgpack.packb({"type": "edits", "id": edit_id, "edits": [
                    {"op": "sphere", "center": center, "radius": 3.0,
                     "colour": int(rng.integers(1, 256)) if edit_id % 2 else 0}]}))
                next_at += 1.0 / args.edit_hz
                await asyncio.sleep(max(0.0, next_at - time.perf_counter()))

        sender = asyncio.create_task(send_edits())
        while time.perf_counter() - start < args.duration:
            # Generous for the first frame (kernels may be building); then only until the end.
            left = args.duration - (time.perf_counter() - start)
            try:
                raw = await asyncio.wait_for(ws.recv(), 60 if not frame_times else max(0.05, left))
            except asyncio.TimeoutError:
                if frame_times:
                    break
                raise
            message = msgpack.unpackb(raw, raw=False)
            kind = message.get("type")
            if kind == "ack":
                acks += 1
            elif kind == "frame":
                frame_times.append(time.perf_counter())
                versions.append(message["version"])
            elif kind == "error":
                raise RuntimeError(message)
        await sender
    dt = np.diff(frame_times) * 1e3
    elapsed = frame_times[-1] - frame_times[0] if len(frame_times) > 1 else float("nan")
    return {"frames": len(frame_times), "fps": (len(frame_times) - 1) / elapsed, "acks": acks,
            "frame_interval_ms": {"p50": float(np.percentile(dt, 50)), "p95": float(np.percentile(dt, 95)),
                                  "max": float(dt.max())},
            "versions": {"first": versions[0], "last": versions[-1], "distinct": len(set(versions))},
            "config": vars(args)}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--url", default="http://127.0.0.1:8000")
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--cap", type=int, default=255)
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--height", type=int, default=720)
    p.add_argument("--max-fps", type=int, default=240)
    p.add_argument("--duration", type=float, default=10.0)
    p.add_argument("--edit-hz", type=float, default=60.0, help="edits sent per second on the stream")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--json", default=None)
    args = p.parse_args()
    result = asyncio.run(run(args))
    print(f"{result['frames']} frames, {result['fps']:.1f} FPS, interval p50 {result['frame_interval_ms']['p50']:.2f} ms "
          f"p95 {result['frame_interval_ms']['p95']:.2f} ms, {result['acks']} edits acknowledged, "
          f"versions {result['versions']['first']}..{result['versions']['last']}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
