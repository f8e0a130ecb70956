"""What waiting for the work queue costs on a device, several ways: a 16³ field read of a 256³
uint16 buffer (non-blocking copy then ``queue.finish()``, a blocking copy, the copy's event) and a
small fill (then ``finish``, its event, ``wait_for_events``, a marker), back to back and after a
0.5 ms idle gap, as a lone client's requests find the engine thread.

``python3 tools/device_waits.py [DEVICE]`` (DEVICE as ``sdfserver serve --device`` takes it)
prints the median and p90 of 900 of each."""

import sys
import time
from pathlib import Path

import numpy as np
import pyopencl as cl

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from sdfserver.gpu import GpuContext  # noqa: E402

gpu = GpuContext.create(sys.argv[1] if len(sys.argv) > 1 else None)
q = gpu.queue
n = 256 ** 3
buf = gpu.allocate(n * 2)
cl.enqueue_copy(q, buf, np.arange(n, dtype=np.uint16)); q.finish()
rng = np.random.default_rng(1)
los = rng.integers(0, 240, (2000, 3))
isz = 2
pat = np.zeros(1, np.uint16)

def rect(lo, blocking):
    out = np.empty((16, 16, 16), np.uint16)
    ev = cl.enqueue_copy(q, out, buf, buffer_origin=(int(lo[0]) * isz, int(lo[1]), int(lo[2])), host_origin=(0, 0, 0),
                         region=(16 * isz, 16, 16), buffer_pitches=(256 * isz, 256 * 256 * isz),
                         host_pitches=(16 * isz, 16 * 16 * isz), is_blocking=blocking)
    return out, ev

def read_finish(lo):
    out, _ = rect(lo, False); q.finish(); return out
def read_blocking(lo):
    out, _ = rect(lo, True); return out
def read_event_wait(lo):
    out, ev = rect(lo, False); ev.wait(); return out
def fill_finish(lo):
    cl.enqueue_fill_buffer(q, buf, pat, 0, 1 << 16); q.finish()
def fill_event_wait(lo):
    ev = cl.enqueue_fill_buffer(q, buf, pat, 0, 1 << 16); ev.wait()
def fill_wait_for_events(lo):
    ev = cl.enqueue_fill_buffer(q, buf, pat, 0, 1 << 16); cl.wait_for_events([ev])
def fill_marker_wait(lo):
    cl.enqueue_fill_buffer(q, buf, pat, 0, 1 << 16); cl.enqueue_marker(q).wait()

for name, fn in [("read: rect + finish", read_finish), ("read: rect blocking", read_blocking),
                 ("read: rect + event.wait", read_event_wait), ("fill + finish", fill_finish),
                 ("fill + event.wait", fill_event_wait), ("fill + wait_for_events", fill_wait_for_events),
                 ("fill + marker.wait", fill_marker_wait)]:
    for gap in (0, 0.0005):
        times = []
        for lo in los[:1000]:
            if gap:
                time.sleep(gap)
            t = time.perf_counter(); fn(lo); times.append(time.perf_counter() - t)
        t = np.array(times[100:]) * 1e6
        print(f"{name:28s} gap {gap * 1e3:3.1f} ms  p50 {np.median(t):6.1f} us  p90 {np.percentile(t, 90):6.1f} us", flush=True)
    cl.enqueue_copy(q, buf, np.arange(n, dtype=np.uint16)); q.finish()
