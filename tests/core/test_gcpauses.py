"""Garbage-collector pause accounting (API and engine processes freeze their start-up objects; see
test_fields for that, through a real server)."""

import gc

from prometheus_client import CollectorRegistry

from sdfserver.gcpauses import GcPauses


def sample(registry, name, generation):
    return registry.get_sample_value(name, {"generation": generation})


def test_collections_are_counted_and_timed_by_generation():
    registry = CollectorRegistry()
    pauses = GcPauses(registry)
    try:
        before = sample(registry, "sdfserver_gc_collections_total", "2")
        for _ in range(3):
            gc.collect()
        assert sample(registry, "sdfserver_gc_collections_total", "2") == before + 3
        assert sample(registry, "sdfserver_gc_pause_seconds_total", "2") > 0
        longest = sample(registry, "sdfserver_gc_longest_pause_seconds", "2")
        assert 0 < longest <= sample(registry, "sdfserver_gc_pause_seconds_total", "2")
        gc.collect(0)
        assert sample(registry, "sdfserver_gc_collections_total", "0") >= 1
    finally:
        pauses.close()
    assert pauses._callback not in gc.callbacks
    assert registry.get_sample_value("sdfserver_gc_collections_total", {"generation": "2"}) is None
