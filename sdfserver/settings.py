"""The server's one settings object.

Read from ``SDFSERVER_*`` environment variables, overridden by ``sdfserver
serve --flags``, built once in ``main()`` and passed down — never at import
time. Every field carries a description; ``docs/configuration.md`` lists them
all and a test keeps the two in step.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from sdfserver.edits import EditLimits
from sdfserver.wire import WireLimits


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
    access_log: bool = Field(False, description="Log every HTTP request (costs throughput).")
    max_request_bytes: int = Field(
        16 << 20, ge=1024, description="Largest request body or WebSocket frame, in bytes (413 above it).")
    max_ops_per_batch: int = Field(1024, ge=1, description="Most operations in one edit batch (413 above it).")
    max_voxels_per_batch: int = Field(
        1 << 20, ge=1, description="Most explicit voxels in one edit batch (413 above it).")
    max_brush_radius_vox: float = Field(
        256.0, gt=0, description="Largest sphere radius an edit may use, in voxels (422 above it).")
    max_world_voxels: int = Field(
        1 << 30, ge=512, description="Largest world, in voxels (sx*sy*sz); larger worlds get 413.")
    max_worlds: int = Field(64, ge=1, description="Most worlds that may live in the server at once (413 above it).")
    max_read_voxels: int = Field(
        1 << 27, ge=1, description="Largest box one field or voxel read may cover, in voxels (413 above it).")
    max_query_points: int = Field(1 << 16, ge=1, description="Most points in one point query (413 above it).")
    max_wait_ms: int = Field(
        5000, ge=0, description="Longest a read with min_version waits for the field to reach that version, "
                                "in milliseconds; after it the read fails with 503.")
    max_subscription_voxels: int = Field(
        1 << 27, ge=1, description="Largest region one WebSocket subscription may cover, in voxels "
                                   "(bounds each subscriber's mailbox).")
    warm_up: bool = Field(True, description="Build the kernels on a tiny world before /readyz answers 200.")

    def edit_limits(self) -> EditLimits:
        return EditLimits(max_ops_per_batch=self.max_ops_per_batch,
                          max_voxels_per_batch=self.max_voxels_per_batch,
                          max_brush_radius_vox=self.max_brush_radius_vox)

    def wire_limits(self) -> WireLimits:
        n = self.max_request_bytes
        return WireLimits(max_bin_len=n, max_str_len=min(n, 1 << 20), max_array_len=n,
                          max_map_len=1 << 12, max_buffer_size=n)


__all__ = ["Settings"]
