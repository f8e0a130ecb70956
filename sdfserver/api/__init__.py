"""HTTP and WebSocket API (FastAPI); the only layer that knows about requests."""

from sdfserver.api.app import create_app

__all__ = ["create_app"]
