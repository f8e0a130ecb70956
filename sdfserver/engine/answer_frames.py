"""An engine's answers for one API process as frames: a batch in one frame where it fits the
link's limit (``links.LinkLimits``), else cut in order; and whether a batch is small enough to
leave from the thread that completed it (``transport.EngineTransport.holding``)."""

from __future__ import annotations

import logging
from typing import Any

import msgspec

from sdfserver.engine import frames
from sdfserver.engine import messages as msg
from sdfserver.errors import TooLarge

log = logging.getLogger("sdfserver.engine")
# Answers up to this many bytes leave from the thread that completes them (holding()); larger
# ones (whole fields, frames) go to the output thread: copying them into a socket would hold up
# the engine thread's next step.
DIRECT_SEND_BYTES = 1 << 16


def small(outputs: list[tuple[bytes, Any]]) -> bool:
    """Whether these answers carry at most DIRECT_SEND_BYTES of arrays and byte strings (a
    subscription's news counts as large: its chunks are taken as it is sent)."""
    carried = 0
    for _, item in outputs:
        if not isinstance(item, msg.Reply):
            return False
        result = item.result
        if isinstance(result, msg.ReadResult):
            carried += len(result.array.data)
        elif isinstance(result, msg.Frame):
            carried += len(result.pixels.data)
        elif isinstance(result, msg.QueryResult):
            carried += sum(len(a.data) for a in result.arrays.values())
        elif isinstance(result, (bytes, str)):
            carried += len(result)
    return carried <= DIRECT_SEND_BYTES


def framed(items: list[Any], limit: int) -> list[bytes | bytearray]:
    """One API process's batch of outputs as frames of at most ``limit`` bytes, in order: one
    frame, or the batch's halves where that would pass the link's limit. An answer that cannot
    be encoded (a bug) is replaced by its failure, as is one past the limit alone (which the
    engine's own limits make impossible: ``links.largest_answer_bytes``)."""
    try:
        return [frames.encode_frame(msg.REQUEST_ENCODER.encode_into, msg.Outputs(items), limit)]
    except frames.FrameTooLarge:
        if len(items) > 1:
            half = len(items) // 2
            return framed(items[:half], limit) + framed(items[half:], limit)
        return framed(past_limit(items[0], limit), limit)
    except (TypeError, ValueError, OverflowError, msgspec.EncodeError):
        return framed(encodable(items), limit)


def past_limit(item: Any, limit: int) -> list[Any]:
    log.error("an engine answer passed the link's limit of %d bytes and was replaced by its failure", limit)
    if isinstance(item, msg.Reply):
        return [msg.Reply(item.id, None, msg.failure_of(TooLarge(
            f"the answer passes the engine link's limit of {limit} bytes (sdfserver/engine/links.py)")))]
    return []  # a subscription's update: its subscriber is sent the next one


def encodable(items: list[Any]) -> list[Any]:
    """One API process's batch of outputs, each answer that cannot be encoded (a bug) replaced by
    its failure, so that its request is answered and the others still go."""
    kept = []
    for item in items:
        try:
            msg.REQUEST_ENCODER.encode(item)
            kept.append(item)
        except (TypeError, ValueError, OverflowError, msgspec.EncodeError) as exc:
            log.exception("an engine answer could not be encoded", exc_info=exc)
            if isinstance(item, msg.Reply):
                kept.append(msg.Reply(item.id, None, msg.failure_of(exc)))
    return kept
