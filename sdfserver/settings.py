"""The server's one settings object.

Read from ``SDFSERVER_*`` environment variables, overridden by ``sdfserver
serve --flags``, built once in ``main()`` and passed down — never at import
time. Every field carries a description; ``docs/configuration.md`` lists them
all and a test keeps the two in step. pydantic-settings ignores an ``SDFSERVER_*``
variable that names no setting, so ``sdfserver serve`` logs a warning for each
(``log_unknown_environment``), with the setting it probably meant.
"""

from __future__ import annotations

import difflib
import functools
import logging
import os
from typing import Literal, Mapping

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from sdfserver.edits import EditLimits
from sdfserver.recompute_cost import DEFAULT_MAX_VISITS
from sdfserver.wire import WireLimits
from sdfserver.world_config import MAX_WORLD_VOXELS


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="SDFSERVER_", extra="forbid", frozen=True)

    host: str = Field("127.0.0.1", description="Address to listen on.")
    port: int = Field(8000, ge=0, le=65535, description="TCP port to listen on (0 picks a free one).")
    device: str = Field(
        "", description="OpenCL device: empty prefers a GPU, an index into `sdfserver devices`, "
                        "or a substring of '<platform> / <device>' such as 'nvidia' or 'pocl'.")
    memory_budget_bytes: int | None = Field(
        None, ge=1, description="Device memory worlds may use, in bytes; unset means 85% of the "
                                "device's global memory. A world that does not fit gets 507.")
    log_format: Literal["text", "json"] = Field("text", description="Log line format: 'text' or 'json' "
                                                                    "(one JSON object per line).")
    log_level: Literal["debug", "info", "warning", "error"] = Field("info", description="Lowest level logged.")
    workers: int | None = Field(
        None, ge=1, le=64, description="Identical API processes (uvicorn + FastAPI) sharing the listening socket; "
                                       "each parses HTTP and WebSocket traffic and sends typed requests to the "
                                       "engine processes. Unset: 4, or the number of CPUs if fewer (4 gave the "
                                       "most batches/s on the H100 host; 6 and 8 gave fewer, docs/benchmarks.md).")
    devices: str = Field(
        "", description="Comma-separated device specs (as `device` takes them), one engine process each; "
                        "worlds are placed on the engine with the most free device memory. Empty: one engine "
                        "on `device`.")
    cluster: str = Field(
        "", pattern=r"^(|local|auto|ray://.+)$",
        description="Run the engines as Ray actors (the `ray` extra): 'local' starts a Ray cluster on this "
                    "machine, 'auto' joins the one running here, 'ray://HOST:PORT' a remote one. Empty: engine "
                    "processes on this machine (`devices`), no Ray.")
    engines: int = Field(1, ge=1, le=256, description="With `cluster`: engine actors, each asking Ray for "
                                                      "`engine_gpus` GPUs.")
    engine_gpus: float | None = Field(
        None, ge=0, le=8, description="With `cluster`: the GPUs each engine actor asks Ray for; a fraction shares a "
                                      "GPU, 0 runs the engines on CPU devices. Unset: 1 when the Ray cluster has "
                                      "GPUs, 0 when it has none.")
    engine_bind_host: str = Field(
        "", description="With `cluster`: the address each engine actor listens on. Empty: the one it advertises to "
                        "the API processes (127.0.0.1 on a local cluster, its node's address otherwise); 0.0.0.0: "
                        "every interface, for a node reached at an address that is not its own. Whatever the "
                        "address, every connection must prove it holds the engine's credential.")
    access_log: bool = Field(False, description="Log every HTTP request (costs throughput).")
    switch_interval_ms: float = Field(
        0.1, gt=0, le=100, description="Longest a thread of an engine process keeps Python's GIL while another "
                                       "waits for it (sys.setswitchinterval), in milliseconds. Every socket read "
                                       "or write of the input and output threads, every log sync of the log "
                                       "writer and every device wait of the engine thread lets go of the GIL, "
                                       "and each may then wait up to this long to get it back; Python's default "
                                       "is 5.")
    max_request_bytes: int = Field(
        16 << 20, ge=1024, description="Largest request body or WebSocket frame, in bytes (413 above it); an "
                                       "import's body has a limit of its own, max_import_bytes.")
    max_import_bytes: int = Field(
        1 << 31, ge=1024, description="Largest body of an import (POST /v1/worlds/import), in bytes (413 above "
                                      "it, before any world is made). The body is written to a temporary file as "
                                      "it arrives (in data_dir's imports/, or the system's temporary directory "
                                      "without persist), never held whole in memory; the voxels decoded from it "
                                      "are bounded by max_world_voxels.")
    max_ops_per_batch: int = Field(1024, ge=1, description="Most operations in one edit batch (413 above it).")
    max_voxels_per_batch: int = Field(
        1 << 20, ge=1, description="Most explicit voxels in one edit batch (413 above it).")
    max_brush_voxels_per_batch: int = Field(
        1 << 30, ge=1, description="Most voxels one edit batch's boxes and spheres may cover, clipped to the world "
                                   "and summed over its edits (413 above it); a batch may always cover its world "
                                   "once, whatever this is. Each such voxel costs the device a visit while the "
                                   "engine waits: 1,024 boxes over a whole 128^3 world are 2.1e9.")
    max_brush_radius_vox: float = Field(
        256.0, gt=0, description="Largest sphere radius an edit may use, in voxels (422 above it).")
    max_world_voxels: int = Field(
        1 << 30, ge=512, le=MAX_WORLD_VOXELS,
        description="Largest dense world, in voxels (sx*sy*sz); larger ones get 413. At most 2048^3 (2048 voxels "
                    "a side); whatever it allows, a world whose buffers (5 bytes a voxel) do not fit the device's "
                    "free memory budget or its largest single buffer is refused with 507 before anything is "
                    "allocated. Sparse worlds (storage sparse) are bounded by their sides and by the memory their "
                    "stored bricks take, not by this.")
    max_recompute_voxel_visits: int = Field(
        DEFAULT_MAX_VISITS, ge=0,
        description="Most work one full recompute of a world may take, in voxel visits (one voxel reading one "
                    "other's value; sdfserver/recompute_cost.py estimates it from the world's size, cap, "
                    "algorithm, borders and focus): a create, import or PATCH past it gets 422 "
                    "recompute_cost_exceeded and changes nothing. The default, 3e10, is about 50 ms of an H100 "
                    "and admits a 2048^3 world with 'exact'; it refuses brute force at 128^3 with cap 255 "
                    "(4.4e12) and fim at 1024^3. 0: no limit.")
    busy_step_ms: float = Field(
        20.0, gt=0, description="An engine step running longer than this, in milliseconds, shows in /readyz "
                                "(still 200, with the engine, world and time) and in /metrics "
                                "(sdfserver_engine_busy_seconds).")
    step_budget_ms: float = Field(
        8.0, gt=0, le=10_000,
        description="How long the engine may run long recomputes in one step, in milliseconds: a recompute by an "
                    "algorithm that can pause (fim, jfa, jfa+1, jfa+2, jfa_fim, brute) that would take longer runs "
                    "in pieces of a quarter of this over several steps, after each step's answers, stopping after a "
                    "piece whenever a request waits; that world's own edits, reads and frames wait for its end. "
                    "exact, conservative and the Euclidean transform run whole (bounded by "
                    "max_recompute_voxel_visits).")
    max_worlds: int = Field(64, ge=1, description="Most worlds that may live in the server at once (413 above it).")
    max_read_voxels: int = Field(
        1 << 27, ge=1, description="Largest box one field or voxel read may cover, in voxels (413 above it).")
    max_query_points: int = Field(1 << 17, ge=1, description="Most points, spheres or rays in one query "
                                                             "(POST /v1/worlds/{id}/query; 413 above it).")
    move_release_timeout_s: float = Field(
        10.0, gt=0, le=600, description="How long a world's move (POST /v1/worlds/{id}/move) waits for its engine "
                                        "to hand it over; past that the target engine takes the world over and its "
                                        "new epoch fences the old holder.")
    rebalance_below: float = Field(
        0.0, ge=0, lt=1, description="With several engines and a data directory: every rebalance_every_s seconds, "
                                     "an engine whose free device memory is under this fraction of its budget moves "
                                     "its smallest world that fits to the engine with the most free memory. 0: off "
                                     "(POST /v1/engines/rebalance does one pass on demand).")
    rebalance_every_s: float = Field(5.0, gt=0, le=3600, description="How often the automatic rebalance looks "
                                                                     "(rebalance_below).")
    max_wait_ms: int = Field(
        5000, ge=0, description="Longest a read with min_version waits for the field to reach that version, "
                                "in milliseconds; after it the read fails with 503.")
    max_subscription_voxels: int = Field(
        1 << 27, ge=1, description="Largest region one WebSocket subscription may cover, in voxels "
                                   "(bounds each subscriber's mailbox).")
    warm_up: bool = Field(True, description="Build the kernels (on a tiny world, and every variant of the "
                                            "exact transform) before the server listens.")
    # -- connections (sdfserver/api/connections.py), checked before a key or a body is read --
    max_connections: int = Field(
        4096, ge=1, description="Open connections (HTTP and WebSocket) the server keeps, shared evenly by its "
                                "API processes; a connection past its process's share is answered 503 and "
                                "closed at once. Keep LimitNOFILE well above it (deploy/sdfserver.service).")
    max_header_bytes: int = Field(
        65536, ge=1024, le=1 << 24, description="Largest request line plus headers, in bytes: past it the "
                                                "request is answered 431 and the connection closed, however "
                                                "much of the header has arrived.")
    max_header_count: int = Field(100, ge=8, le=10000, description="Most header lines in one request "
                                                                   "(431 above it).")
    header_timeout_s: float = Field(
        10.0, gt=0, le=3600, description="Time a client has to send a request's line and headers, from "
                                         "connecting or from the request's first byte, in seconds: past it "
                                         "the request is answered 408 and the connection closed (slow clients "
                                         "cannot hold connections open by trickling headers).")
    idle_timeout_s: float = Field(15.0, gt=0, le=3600, description="Time a kept-alive HTTP connection may stay "
                                                                   "idle between requests, in seconds.")
    max_subscriptions: int = Field(1024, ge=1, description="WebSocket subscriptions one engine holds at once, "
                                                           "every client together (429 above it).")
    max_subscriptions_per_key: int = Field(
        64, ge=1, description="WebSocket subscriptions one API key (or, on an open server, one client address) "
                              "may hold at once on one engine (429 above it).")
    ws_deflate: bool = Field(False, description="Offer WebSocket per-message compression. Off: a compressed "
                                                "message cannot inflate past what it cost to send, and the "
                                                "binary msgpack the stream carries gains little from it.")
    ws_max_queue: int = Field(4, ge=1, le=1024, description="WebSocket messages received and not yet handled "
                                                            "that one connection may buffer (each up to "
                                                            "max_request_bytes) before reading from it pauses.")
    ws_ping_interval_s: float = Field(20.0, ge=0, description="Seconds between WebSocket pings; a peer that "
                                                              "does not answer one within as long is closed "
                                                              "(0: no pings).")
    ws_send_timeout_s: float = Field(30.0, ge=0, le=3600, description="Time a WebSocket peer may take none of "
                                     "the bytes waiting for it (its socket buffers full: a client that sends "
                                     "and never reads) before the connection is aborted, logged and counted in "
                                     "sdfserver_websocket_send_timeouts_total; seen within 1.5 times this "
                                     "(0: never).")
    # -- durability (sdfserver/storage) --
    persist: bool = Field(True, description="Keep every world on disk (write-ahead log and snapshots in "
                                            "data_dir) and restore them at start-up; off: worlds live in memory only.")
    data_dir: str = Field("data", description="Directory of the worlds' logs, snapshots and catalog; created if "
                                              "missing; a relative path starts at the working directory.")
    sync: bool = Field(True, description="fdatasync the log before an edit batch is acknowledged (batches that "
                                         "arrive together share one sync). Off only for measurements: a crash "
                                         "can then lose acknowledged edits.")
    sync_inline: bool = Field(False, description="fdatasync the log on the engine thread right after each step's "
                              "write instead of on the committer thread: no thread hand-off before an "
                              "acknowledgement, but the engine waits for the disk (see docs/benchmarks.md).")
    commit_window_ms: float = Field(0.0, ge=0, le=100, description="With sync_inline off: extra wait before each "
                                    "log sync so that more batches share it, in milliseconds (0: sync as soon as "
                                    "one is waiting).")
    snapshot_every_batches: int = Field(5000, ge=1, description="Snapshot a world's voxels (and trim its log) "
                                        "after this many logged batches; bounds replay time at start-up.")
    snapshot_min_interval_s: float = Field(5.0, ge=0, description="Least time between two snapshots of a world, "
                                           "in seconds: a busy world snapshots at most this often, however many "
                                           "batches it takes (each snapshot copies, compresses and writes every "
                                           "voxel); 0: by batches alone.")
    # -- access (sdfserver/api/auth.py) --
    api_keys: str = Field("", description="API keys, comma-separated 'name:token' (16+ character tokens; "
                                          "'name:token:admin' for a key that sees every world). None here or in "
                                          "api_key_file: the server is open and listens on loopback only.")
    api_key_file: str = Field("", description="A file of API keys, one 'name token [admin]' per line, "
                                              "'#' comments; adds to api_keys.")
    max_worlds_per_key: int = Field(16, ge=1, description="Most worlds one (non-admin) API key may own "
                                                          "(413 above it).")
    rate_limit_per_s: float = Field(0.0, ge=0, description="Requests (and WebSocket frames) per second each "
                                    "API key may make, a token bucket; 0 turns the limit off (429 above it).")
    rate_limit_burst: int = Field(200, ge=1, description="Token-bucket size of the per-key rate limit: the "
                                                         "requests a key may make at once after being idle.")

    def edit_limits(self) -> EditLimits:
        return EditLimits(max_ops_per_batch=self.max_ops_per_batch,
                          max_voxels_per_batch=self.max_voxels_per_batch,
                          max_brush_radius_vox=self.max_brush_radius_vox,
                          max_brush_voxels_per_batch=self.max_brush_voxels_per_batch)

    @functools.cached_property
    def wire_limits(self) -> WireLimits:
        """Built once: every msgpack body is decoded with them."""
        n = self.max_request_bytes
        largest = max(self.max_voxels_per_batch, self.max_query_points)  # rows of the longest list
        return WireLimits(max_bin_len=n, max_str_len=min(n, 1 << 20), max_array_len=min(n, largest + 1024),
                          max_map_len=1 << 12, max_buffer_size=n,
                          max_containers=largest + 64 * self.max_ops_per_batch + 4096)


ENV_PREFIX = "SDFSERVER_"
# Variables of the project that are not server settings: the clients' key and the crash test.
OTHER_VARIABLES = frozenset({"SDFSERVER_API_KEY", "SDFSERVER_CRASH_TRIALS"})


def unknown_environment(environ: Mapping[str, str]) -> list[str]:
    """A line for each ``SDFSERVER_*`` variable that names no setting (names match in any case,
    as pydantic-settings matches them), with the closest setting's variable where one is close."""
    known = [ENV_PREFIX + name.upper() for name in Settings.model_fields]
    lines = []
    for name in sorted(environ):
        upper = name.upper()
        if not upper.startswith(ENV_PREFIX) or upper in known or upper in OTHER_VARIABLES:
            continue
        # compared without the prefix, which every name shares and which would make all look alike
        guess = difflib.get_close_matches(upper[len(ENV_PREFIX):], [k[len(ENV_PREFIX):] for k in known],
                                          n=1, cutoff=0.75)
        hint = f"; did you mean {ENV_PREFIX}{guess[0]}?" if guess else "; docs/configuration.md lists the settings"
        lines.append(f"{name} is set but names no setting, so it is ignored{hint}")
    return lines


def log_unknown_environment(environ: Mapping[str, str] = os.environ) -> None:
    log = logging.getLogger("sdfserver")
    for line in unknown_environment(environ):
        log.warning(line)


__all__ = ["Settings", "log_unknown_environment", "unknown_environment"]


DEFAULT_WORKERS = 4


def worker_count(settings: "Settings") -> int:
    """``settings.workers``, or its default: 4, or the number of CPUs if fewer."""
    return settings.workers or max(1, min(DEFAULT_WORKERS, os.cpu_count() or 1))
