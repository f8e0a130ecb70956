"""Kernel times from OpenCL profiling events, which a driver may decline to give.

NVIDIA's OpenCL answers ``PROFILING_INFO_NOT_AVAILABLE`` now and then for an event whose command
has completed (seen under load on H200 hosts). A missing time is a gap in a measurement, not a
lost device: the caller gets None and goes on.
"""

from __future__ import annotations

import logging

import pyopencl as cl

log = logging.getLogger(__name__)
_START, _END = cl.profiling_info.START, cl.profiling_info.END


def event_ms(event: cl.Event) -> float | None:
    """The command's device time in ms, or None where the driver gives no profiling info."""
    try:
        if type(event) is cl.Event:  # asked directly: ``event.profile`` builds a getter object per use
            return (event.get_profiling_info(_END) - event.get_profiling_info(_START)) * 1e-6
        return (event.profile.end - event.profile.start) * 1e-6
    except cl.Error as exc:
        log.debug("no profiling info for an event: %s", exc)
        return None
