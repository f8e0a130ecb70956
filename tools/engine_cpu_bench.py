"""The engine thread's host (Python) time per edit batch and per step, phase by phase.

    .venv/bin/python tools/engine_cpu_bench.py [--device intel] [--size 128] [--steps 300]
        [--step-sizes 1,12] [--max-distance 255] [--worlds 1] [--profile] [--json FILE]

Builds an in-process Engine with a real StorageJournal on a temporary data directory (the log
synced, group commit), creates one world (``--worlds N``: N, each step's batches dealt to them
in turn) and feeds it one-sphere edit batches at random places
the way the engine process's input thread does: ``EngineService.handle`` with an
``ApplyEdits`` message whose batch is encoded as an API process encodes it
(``storage.codec.encode_batch``). Each step takes ``k`` batches (``--step-sizes``) and is run by
calling ``Engine.step()`` on this thread; the bench then waits until every batch of the step is
acknowledged (its log record synced), which is not counted.

Each phase is timed by wrapping the function that does it (``time.perf_counter`` for wall time,
``time.thread_time`` for the calling thread's CPU): per batch the input handling, planning, the
log record, the brushes' launch, the engine thread's acknowledgement work and the reply (on the
committer's thread) and the pooled worlds' brushes (one launch a slot pool); per step the
recompute, split into the dirty regions, the launches, the stacked runs of pooled worlds
(``sdfserver/stacked.py``), the wait for the device (``queue.finish``, not host work: the CPU OpenCL device runs the kernels
then) and the summaries, and the metrics. ``--profile`` adds cProfile's top functions over the
measured steps. Phases nest (indented): a parent's time includes its children's.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import pstats
import random
import shutil
import sys
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path

import pyopencl as cl

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import sdfserver.engine.batches as batches_module  # noqa: E402
import sdfserver.engine.core as core_module  # noqa: E402
import sdfserver.engine.service as service_module  # noqa: E402
import sdfserver.world as world_module  # noqa: E402
from sdfserver.engine import Engine  # noqa: E402
from sdfserver.engine import messages as msg  # noqa: E402
from sdfserver.engine.access import Doorkeeper, RateLimiter  # noqa: E402
from sdfserver.engine.batches import BatchPipeline  # noqa: E402
from sdfserver.engine.commands import CreateWorld  # noqa: E402
from sdfserver.engine.metrics import EngineMetrics  # noqa: E402
from sdfserver.engine.service import EngineService  # noqa: E402
from sdfserver.gpu import GpuContext  # noqa: E402
from sdfserver.gpu.uploads import UploadRing  # noqa: E402
from sdfserver.recompute import PendingRecompute  # noqa: E402
from sdfserver.storage import Storage  # noqa: E402
from sdfserver.storage.codec import encode_batch  # noqa: E402
from sdfserver.storage.journal import StorageJournal  # noqa: E402
from sdfserver.world import World, WorldConfig  # noqa: E402

# (phase, depth, per): what each row of the table is; "batch" rows are divided by batches,
# "step" rows by steps
PHASES = [
    ("input (EngineService.handle)", 0, "batch"),
    ("decode_batch", 1, "batch"),
    ("parse_edits", 1, "batch"),
    ("plan (BatchPipeline.plan)", 0, "batch"),
    ("World.plan_edits", 1, "batch"),
    ("run (BatchPipeline.run)", 0, "batch"),
    ("log record (record_batches)", 1, "batch"),
    ("start_syncs (waits for the committer)", 1, "batch"),
    ("apply/launch (World.apply_plans)", 1, "batch"),
    ("pooled brushes (enqueue_pooled_brushes)", 1, "batch"),
    ("acknowledge (engine thread)", 1, "batch"),
    ("reply (committer thread)", 0, "batch"),
    ("step (Engine.step)", 0, "step"),
    ("recompute (Engine._recompute)", 1, "step"),
    ("dirty regions", 2, "step"),
    ("region launches (World.begin_recompute)", 2, "step"),
    ("stacked runs (begin_stacked)", 2, "step"),
    ("queue.finish (device wait)", 2, "step"),
    ("summarize", 2, "step"),
    ("recompute host (less queue.finish)", 1, "step"),
    ("metrics (observe_recompute[s])", 2, "step"),
]


class Clock:
    """Wall and CPU seconds per phase, summed while ``on``."""

    def __init__(self) -> None:
        self.on = False
        self.wall: dict[str, float] = defaultdict(float)
        self.cpu: dict[str, float] = defaultdict(float)
        self.lock = threading.Lock()

    def add(self, phase: str, wall_s: float, cpu_s: float) -> None:
        if self.on:
            with self.lock:
                self.wall[phase] += wall_s
                self.cpu[phase] += cpu_s

    def wrap(self, owner, name: str, phase: str) -> None:
        """Time every call of ``owner.name`` (a class's method or a module's function), where the
        build being measured has it."""
        original = getattr(owner, name, None)
        if original is None:
            return
        clock = self

        def timed(*args, **kwargs):
            wall, cpu = time.perf_counter(), time.thread_time()
            try:
                return original(*args, **kwargs)
            finally:
                clock.add(phase, time.perf_counter() - wall, time.thread_time() - cpu)

        setattr(owner, name, timed)


class TimedQueue(cl.CommandQueue):
    """The engine's queue, its ``finish`` (a wait for the device) timed apart from host work."""

    clock: Clock

    def finish(self):
        wall, cpu = time.perf_counter(), time.thread_time()
        try:
            return super().finish()
        finally:
            self.clock.add("queue.finish (device wait)", time.perf_counter() - wall, time.thread_time() - cpu)


def instrument(clock: Clock) -> None:
    clock.wrap(EngineService, "handle", "input (EngineService.handle)")
    clock.wrap(service_module, "decode_batch", "decode_batch")
    clock.wrap(service_module, "parse_edits", "parse_edits")
    clock.wrap(BatchPipeline, "plan", "plan (BatchPipeline.plan)")
    clock.wrap(World, "plan_edits", "World.plan_edits")
    clock.wrap(BatchPipeline, "run", "run (BatchPipeline.run)")
    clock.wrap(StorageJournal, "record_batches", "log record (record_batches)")
    clock.wrap(StorageJournal, "start_syncs", "start_syncs (waits for the committer)")
    clock.wrap(World, "apply_plans", "apply/launch (World.apply_plans)")
    clock.wrap(EngineService, "_reply", "reply (committer thread)")
    clock.wrap(Engine, "step", "step (Engine.step)")
    clock.wrap(Engine, "_recompute", "recompute (Engine._recompute)")
    clock.wrap(World, "dirty_regions", "dirty regions")
    clock.wrap(world_module, "summarize", "summarize")  # builds before PendingRecompute.summary
    clock.wrap(PendingRecompute, "summary", "summarize")
    # the engine calls observe_recomputes once a step (observe_recompute once a world before)
    clock.wrap(EngineMetrics, "observe_recomputes", "metrics (observe_recompute[s])")
    clock.wrap(EngineMetrics, "observe_recompute", "metrics (observe_recompute[s])")
    clock.wrap(World, "begin_recompute", "region launches (World.begin_recompute)")
    clock.wrap(batches_module, "enqueue_pooled_brushes", "pooled brushes (enqueue_pooled_brushes)")
    clock.wrap(core_module, "begin_stacked", "stacked runs (begin_stacked)")


def timed_gpu(device: str | None, clock: Clock) -> GpuContext:
    gpu = GpuContext.create(device)
    TimedQueue.clock = clock
    gpu.queue = TimedQueue(gpu.context, properties=cl.command_queue_properties.PROFILING_ENABLE)
    gpu.uploads = UploadRing(gpu.context, gpu.queue)
    return gpu


class Replies:
    """The service's output side: counts replies, keeps failures."""

    def __init__(self) -> None:
        self.count = 0
        self.failures: list = []
        self.arrived = threading.Condition()

    def send(self, client: bytes, item) -> None:
        with self.arrived:
            self.count += 1
            if isinstance(item, msg.Reply) and item.failure is not None:
                self.failures.append(item.failure)
            self.arrived.notify_all()

    def wait_for(self, count: int, timeout_s: float = 30.0) -> None:
        with self.arrived:
            if not self.arrived.wait_for(lambda: self.count >= count, timeout_s):
                raise TimeoutError(f"{self.count} of {count} replies after {timeout_s} s")


def sphere_batch(rng: random.Random, size: int, radius: tuple[float, float]) -> bytes:
    """One sphere as the load test paints it, encoded as an API process encodes a batch."""
    center = [float(rng.randrange(size)) for _ in range(3)]
    colour = 0 if rng.random() < 0.25 else rng.randrange(1, 256)
    return encode_batch([{"op": "sphere", "center": center, "radius": rng.uniform(*radius), "colour": colour}])


def run(args: argparse.Namespace, step_size: int, gpu: GpuContext, clock: Clock) -> dict:
    data = Path(tempfile.mkdtemp(prefix="sdf-engine-cpu-"))
    journal = StorageJournal(Storage(data, sync=not args.no_sync), snapshot_every_batches=1 << 62)
    engine = Engine(gpu, journal=journal)  # not started: this thread runs its steps
    replies = Replies()
    doorkeeper = Doorkeeper(RateLimiter(0.0), engine.owner_of, lambda: list(engine.owners.values()))
    service = EngineService(engine, doorkeeper, replies.send)
    config = WorldConfig(size=(args.size,) * 3, chunk_size=args.chunk_size, max_distance=args.max_distance)
    created = [engine.submit(CreateWorld(config)) for _ in range(args.worlds)]
    engine.step()
    world_ids = [future.result()["id"] for future in created]
    rng = random.Random(args.seed)
    request_id = 0

    def one_step() -> None:
        nonlocal request_id
        # decoded as the input thread decodes a frame, outside the measured phases
        requests = [msg.REQUEST_DECODER.decode(msg.REQUEST_ENCODER.encode(
            msg.ApplyEdits(request_id + i + 1, world_ids[(request_id + i) % len(world_ids)],
                           sphere_batch(rng, args.size, (1.0, 8.0)))))
            for i in range(step_size)]
        for request in requests:
            service.handle(b"api-1", request)
        request_id += step_size
        report = engine.step()
        clock.add("acknowledge (engine thread)", report.apply_ms["acknowledge"] / 1e3, 0.0)
        replies.wait_for(request_id)

    try:
        for _ in range(args.warm_up):
            one_step()
        clock.wall.clear()
        clock.cpu.clear()
        profiler = cProfile.Profile() if args.profile else None
        clock.on = True
        started = time.perf_counter()
        if profiler is not None:
            profiler.enable()
        for _ in range(args.steps):
            one_step()
        if profiler is not None:
            profiler.disable()
        elapsed = time.perf_counter() - started
        clock.on = False
        if replies.failures:
            raise RuntimeError(f"{len(replies.failures)} batches failed, the first: {replies.failures[0]}")
        versions = sum(engine.worlds[world_id].version for world_id in world_ids)
        if versions != request_id:
            raise RuntimeError(f"the worlds are at versions summing to {versions} after {request_id} batches")
    finally:
        journal.close()
        engine.table.release_all()
        shutil.rmtree(data, ignore_errors=True)
    batches = args.steps * step_size
    rows = {}
    for phase, depth, per in PHASES:
        wall = clock.wall.get(phase, 0.0)
        cpu = clock.cpu.get(phase, 0.0)
        if phase.startswith("recompute host"):
            wall = clock.wall["recompute (Engine._recompute)"] - clock.wall["queue.finish (device wait)"]
            cpu = clock.cpu["recompute (Engine._recompute)"] - clock.cpu["queue.finish (device wait)"]
        n = batches if per == "batch" else args.steps
        if phase.startswith("acknowledge"):
            cpu = float("nan")  # the step's report gives its wall time only
        rows[phase] = {"depth": depth, "per": per, "wall_us": wall / n * 1e6, "cpu_us": cpu / n * 1e6}
    profile = None
    if profiler is not None:
        out = io.StringIO()
        pstats.Stats(profiler, stream=out).sort_stats("tottime").print_stats(args.profile_lines)
        profile = out.getvalue()
    return {"step_size": step_size, "steps": args.steps, "batches": batches, "elapsed_s": elapsed,
            "rows": rows, "profile": profile}


def print_result(result: dict) -> None:
    print(f"\nsteps of {result['step_size']} batch(es): {result['steps']} steps, {result['batches']} batches, "
          f"{result['elapsed_s']:.2f} s")
    print(f"  {'phase':<44} {'per':>5} {'wall us':>9} {'cpu us':>9}")
    for phase, row in result["rows"].items():
        print(f"  {'  ' * row['depth'] + phase:<44} {row['per']:>5} {row['wall_us']:9.1f} {row['cpu_us']:9.1f}")
    if result["profile"]:
        print(result["profile"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default=None, help="as sdfserver serve --device (default: the first usable)")
    ap.add_argument("--size", type=int, default=128, help="the world's side in voxels")
    ap.add_argument("--chunk-size", type=int, default=16)
    ap.add_argument("--max-distance", type=int, default=255)
    ap.add_argument("--worlds", type=int, default=1, help="worlds, each step's batches spread over them in turn")
    ap.add_argument("--steps", type=int, default=300, help="measured steps per step size")
    ap.add_argument("--warm-up", type=int, default=30, help="steps first, not measured")
    ap.add_argument("--step-sizes", default="1,12", help="batches a step, comma-separated")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-sync", action="store_true", help="the log not synced")
    ap.add_argument("--profile", action="store_true", help="cProfile's top functions over the measured steps")
    ap.add_argument("--profile-lines", type=int, default=30)
    ap.add_argument("--json", default=None, help="write the figures here")
    args = ap.parse_args()
    clock = Clock()
    gpu = timed_gpu(args.device, clock)
    instrument(clock)
    print(f"{gpu.device_name}; {args.worlds} world(s) of {args.size}^3, chunk {args.chunk_size}, cap {args.max_distance}; "
          f"one sphere (radius 1..8) a batch; log {'not ' if args.no_sync else ''}synced")
    results = []
    for step_size in (int(s) for s in args.step_sizes.split(",")):
        result = run(args, step_size, gpu, clock)
        print_result(result)
        results.append(result)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
