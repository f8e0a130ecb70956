"""A driver that gives no profiling info for an event is a gap in a measurement, not a lost device."""

import pyopencl as cl

from sdfserver.algorithms.base import AlgorithmRun
from sdfserver.algorithms.stats import summarize
from sdfserver.gpu.profiling import event_ms


class NoProfile:
    """An event whose driver answers PROFILING_INFO_NOT_AVAILABLE, as NVIDIA's sometimes does."""

    @property
    def profile(self):
        raise cl.RuntimeError("clGetEventProfilingInfo failed: PROFILING_INFO_NOT_AVAILABLE")


def test_an_event_without_profiling_info_has_no_time():
    assert event_ms(NoProfile()) is None


def test_a_recompute_summary_counts_it_as_zero(gpu):
    real = cl.enqueue_marker(gpu.queue)
    gpu.queue.finish()
    run = AlgorithmRun([real, NoProfile()])
    each, by_name = summarize([("exact", run)])
    assert len(each) == 2 and each[1] == 0.0 and each[0] >= 0.0
    assert by_name["exact"].device_ms == each[0]
