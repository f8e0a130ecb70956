"""HTTP and WebSocket API (FastAPI); the only layer that knows about requests."""

from sdfserver.api.app import build_engine, create_app

__all__ = ["build_engine", "create_app"]
