"""The links between API processes and an engine: what each end proves before the other
believes it, and how large a frame each may send.

Every API process opens two connections to each engine (``transport.py``): its requests and
the engine's answers. A connection that can come from another machine (TCP: a cluster's engine
actors) proves that it holds the engine's credential — 32 random bytes made by the cluster
process with the engine, handed to the engine and to the API processes through Ray and the
launcher, never on a command line, in the settings or in a log — before its first request is
read, and the engine proves the same to it:

    engine -> API   CHALLENGE  MAGIC + nonce_e (32 random bytes)
    API -> engine   HELLO      nonce_c (32 random bytes) + HMAC(credential, "api", ...) + identity
    engine -> API   PROOF      HMAC(credential, "engine", ...)

Both MACs (HMAC-SHA256, compared in constant time) cover both nonces, the connection's role
(requests or answers) and the API process's identity, so neither can be replayed on another
connection or passed off as the other side's. An API process sends no request to, and believes
no answer from, an engine that did not prove itself; an engine reads nothing past a HELLO that
does not prove its sender. A Unix socket (engine processes on one machine) proves nothing: the
kernel lets only the server's user open its directory (``frames.check_private``), so its first
frame is the identity alone.

Until a connection has proven itself its frames may be HELLO_BYTES long at most, and it must do
so within PROOF_TIMEOUT_S; after that ``LinkLimits`` bound every frame, derived from the
settings so that no request or answer the server can legitimately make is refused.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
from dataclasses import dataclass

from sdfserver.engine import frames
from sdfserver.engine import messages as msg
from sdfserver.render.camera import RenderLimits
from sdfserver.settings import Settings
from sdfserver.storage.uploads import upload_limit_bytes

MAGIC = b"sdfserver-link/1"
CREDENTIAL_BYTES = 32
NONCE_BYTES = 32
MAC_BYTES = 32  # SHA-256
MAX_IDENTITY_BYTES = 128
HELLO_BYTES = len(MAGIC) + NONCE_BYTES + MAC_BYTES + MAX_IDENTITY_BYTES  # the largest frame before a proof
PROOF_TIMEOUT_S = 5.0  # a connection that has not proven itself by then is closed
REQUESTS, ANSWERS = b"requests", b"answers"  # the two roles a connection to an engine has
WELCOME = msg.REQUEST_ENCODER.encode(msg.Outputs([]))  # the engine's first frame on a proven answers link


class LinkRefused(Exception):
    """The other end did not prove itself; ``reason`` is the label /metrics counts it under."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


def new_credential() -> bytes:
    return secrets.token_bytes(CREDENTIAL_BYTES)


def _mac(credential: bytes, speaker: bytes, role: bytes, nonce_e: bytes, nonce_c: bytes, identity: bytes) -> bytes:
    # every field but the identity has a fixed length or comes from a fixed set, so no two
    # different field lists make the same message
    message = b"|".join((MAGIC, speaker, role)) + nonce_e + nonce_c + identity
    return hmac.new(credential, message, hashlib.sha256).digest()


def _checked_identity(identity: bytes) -> bytes:
    if not 0 < len(identity) <= MAX_IDENTITY_BYTES:
        raise LinkRefused("identity", f"an identity of {len(identity)} bytes (1 to {MAX_IDENTITY_BYTES} are taken)")
    return identity


class EngineSide:
    """The engine's half of one connection's proof. It does no I/O: the transport sends what
    ``opening`` and ``heard`` return."""

    def __init__(self, credential: bytes | None, role: bytes):
        self.credential, self.role = credential, role
        self.nonce = secrets.token_bytes(NONCE_BYTES)

    def opening(self) -> bytes:
        """What the engine sends as the connection opens: the challenge (nothing on a Unix socket)."""
        return b"" if self.credential is None else frames.frame(MAGIC + self.nonce)

    def heard(self, hello: bytes) -> tuple[bytes, bytes]:
        """(the API process's identity, what to send it) from the connection's first frame;
        LinkRefused unless that frame proves its sender holds the credential."""
        hello = bytes(hello)
        if self.credential is None:
            return _checked_identity(hello), b""
        if len(hello) <= NONCE_BYTES + MAC_BYTES:
            raise LinkRefused("credential", f"a first frame of {len(hello)} bytes is no proof")
        nonce_c, mac, identity = hello[:NONCE_BYTES], hello[NONCE_BYTES:NONCE_BYTES + MAC_BYTES], \
            hello[NONCE_BYTES + MAC_BYTES:]
        if not hmac.compare_digest(mac, _mac(self.credential, b"api", self.role, self.nonce, nonce_c, identity)):
            raise LinkRefused("credential", "its proof does not match the engine's credential")
        _checked_identity(identity)
        return identity, frames.frame(_mac(self.credential, b"engine", self.role, self.nonce, nonce_c, identity))


class ApiSide:
    """An API process's half of one connection's proof (no I/O, as ``EngineSide``): ``proven``
    once the engine has shown it holds the credential (at once on a Unix socket)."""

    def __init__(self, credential: bytes | None, role: bytes, identity: bytes):
        self.credential, self.role, self.identity = credential, role, _checked_identity(identity)
        self.nonce = secrets.token_bytes(NONCE_BYTES)
        self.challenge: bytes | None = None
        self.proven = credential is None

    def opening(self) -> bytes:
        """What the API process sends as the connection opens: its identity on a Unix socket;
        nothing over TCP, where the engine speaks first."""
        return frames.frame(self.identity) if self.credential is None else b""

    def heard(self, payload: bytes) -> bytes:
        """What to send after the engine's frame ``payload`` (the challenge, then its proof);
        LinkRefused when it is neither."""
        payload = bytes(payload)
        if self.challenge is None:
            if len(payload) != len(MAGIC) + NONCE_BYTES or not payload.startswith(MAGIC):
                raise LinkRefused("challenge", "the engine's first frame is not an sdfserver link's challenge")
            self.challenge = payload[len(MAGIC):]
            mac = _mac(self.credential, b"api", self.role, self.challenge, self.nonce, self.identity)
            return frames.frame(self.nonce + mac + self.identity)
        expected = _mac(self.credential, b"engine", self.role, self.challenge, self.nonce, self.identity)
        if not hmac.compare_digest(payload, expected):
            raise LinkRefused("credential", "the engine's proof does not match this server's credential")
        self.proven = True
        return b""


# -- how large a frame may be ---------------------------------------------------------------------

ENVELOPE_BYTES = 1 << 20  # a message's other fields: ids, a world's configuration and palette, msgpack headers
# An edit batch is re-encoded from its body as msgpack: JSON's shortest float ("1e5" and its
# comma, 4 bytes) takes 9 bytes there, and no JSON or msgpack value grows more.
EDIT_RECORD_GROWTH = 3
QUERY_COLUMNS_MAX = 7  # a ray's row (origin, direction, length)
QUERY_ANSWER_ROW_BYTES = 128  # a ray's answer: hit, distance, normal, colour and voxel, 9 numbers, room to spare
DESCRIBED_WORLD_BYTES = 1 << 16  # one world described (its configuration, palette included), room to spare


@dataclass(frozen=True)
class LinkLimits:
    """The largest frame each end of a proven link takes, in bytes (a frame past it ends the
    connection before a buffer is set aside for it). Both are at most ``frames.MAX_FRAME``."""

    request_bytes: int  # one request from an API process
    answer_bytes: int  # one batch of an engine's answers; the engine cuts its batches to fit

    @classmethod
    def of(cls, settings: Settings) -> "LinkLimits":
        return cls(min(frames.MAX_FRAME, ENVELOPE_BYTES + largest_request_bytes(settings)),
                   min(frames.MAX_FRAME, ENVELOPE_BYTES + largest_answer_bytes(settings)))


def largest_request_bytes(s: Settings) -> int:
    """The largest payload an API process sends: a dense world imported whole (its voxels, at
    most max_world_voxels, a byte each), a sparse world's snapshot file as uploaded (an import's
    body, at most max_import_bytes), an edit batch re-encoded from its body, or a query's rows
    as float64."""
    return max(s.max_world_voxels, s.max_import_bytes, upload_limit_bytes("snapshot", s.max_request_bytes),
               EDIT_RECORD_GROWTH * s.max_request_bytes, s.max_query_points * QUERY_COLUMNS_MAX * 8)


def largest_answer_bytes(s: Settings) -> int:
    """The largest answer an engine sends: a read (at most max_read_voxels voxels of at most 4
    bytes, a Euclidean distance), a sparse world's export (at most max_read_voxels stored voxels
    and their brick table, compressed), a subscription's update (2 bytes a voxel and its chunks'
    corners), a rendered frame, a query's answer, or every world described."""
    return max(4 * s.max_read_voxels, upload_limit_bytes("snapshot", 2 * s.max_read_voxels),
               3 * s.max_subscription_voxels, 4 * RenderLimits().max_pixels,
               QUERY_ANSWER_ROW_BYTES * s.max_query_points, DESCRIBED_WORLD_BYTES * s.max_worlds)
