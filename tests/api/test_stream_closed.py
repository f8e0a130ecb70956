"""A stream whose connection ends under a frame's answer (``api/stream.py``): Starlette refuses a
send after the connection was closed or aborted with a RuntimeError, not WebSocketDisconnect. The
frame then has nobody to answer, and the session ends as on a disconnect, with no error left for
the ASGI server to log as an unhandled exception."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

import pytest
from fastapi import WebSocketDisconnect
from starlette.websockets import WebSocketState

from sdfserver import wire
from sdfserver.api.stream import StreamSession


class AbortedUnderSend:
    """Hands over one ping; its first send finds the connection aborted (Starlette marks it
    disconnected, WebSocketDisconnect 1006) and every later one is refused as after a close."""

    def __init__(self) -> None:
        self.app = SimpleNamespace(state=SimpleNamespace(settings=SimpleNamespace(wire_limits=wire.DEFAULT_LIMITS),
                                                         metrics=None))
        self.application_state = WebSocketState.CONNECTED
        self.client_state = WebSocketState.CONNECTED
        self.frames = [{"type": "websocket.receive", "bytes": wire.encode({"type": "ping", "id": 1})}]
        self.sends = 0

    async def receive(self) -> dict:
        return self.frames.pop(0) if self.frames else {"type": "websocket.disconnect", "code": 1006}

    async def send_bytes(self, data: bytes) -> None:
        self.sends += 1
        if self.application_state == WebSocketState.DISCONNECTED:
            raise RuntimeError('Cannot call "send" once a close message has been sent.')
        self.application_state = WebSocketState.DISCONNECTED
        raise RuntimeError("the transport was aborted")  # as a write on an aborted transport fails


def test_a_frame_whose_answer_finds_the_connection_gone_ends_the_session_quietly():
    websocket = AbortedUnderSend()
    session = StreamSession(websocket, engine=None, world_id="w", chunk_size=8, size=(8, 8, 8), access=None)
    with pytest.raises(WebSocketDisconnect):
        asyncio.run(session._receive())
    assert websocket.sends == 1  # the pong only: no error answer sent into a closed connection
