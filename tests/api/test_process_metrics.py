"""/metrics shows every API process (process_*, their GC pauses) and the build, and is the same
whichever API process answers the scrape: a real server with two API processes, scraped over
fresh connections; and the collector over a shared table with a second process in it."""

from __future__ import annotations

import gc
import os
import subprocess
import sys

import httpx
import pytest
from prometheus_client import CollectorRegistry
from prometheus_client.parser import text_string_to_metric_families
from server_process import ServerProcess

from sdfserver import __version__
from sdfserver.api.counts import SharedCounts
from sdfserver.api.process_metrics import ApiProcessesCollector
from sdfserver.gcpauses import GcPauses

PROCESS_FAMILIES = ("process_cpu_seconds", "process_resident_memory_bytes", "process_virtual_memory_bytes",
                    "process_start_time_seconds", "process_open_fds", "process_max_fds")


def samples(text: str) -> dict[str, list]:
    return {family.name: family.samples for family in text_string_to_metric_families(text)}


def by_process(found: dict[str, list], family: str) -> dict[str, float]:
    return {s.labels["api_process"]: s.value for s in found[family]}


@pytest.fixture(scope="module")
def two_api_processes(tmp_path_factory):
    process = ServerProcess(tmp_path_factory.mktemp("metrics") / "data", "--workers", "2", "--no-warm-up").wait_ready()
    yield process
    process.stop()


def test_every_scrape_shows_every_api_process_whichever_answers(two_api_processes):
    scrapes = []
    for _ in range(12):  # a fresh connection each: the kernel hands them to either process
        with httpx.Client(base_url=two_api_processes.url, timeout=30) as http:
            r = http.get("/metrics")
        assert r.status_code == 200
        scrapes.append(samples(r.text))
    started = [by_process(found, "process_start_time_seconds") for found in scrapes]
    assert set(started[0]) == {"0", "1"} and started[0]["0"] > 0 and started[0]["1"] > 0
    assert all(s == started[0] for s in started), started  # the same two processes, in every scrape
    for found in scrapes:
        for family in PROCESS_FAMILIES:
            assert set(by_process(found, family)) == {"0", "1"}, family
        assert all(v > 1 << 20 for v in by_process(found, "process_resident_memory_bytes").values())
        (info,) = found["sdfserver_build_info"]
        assert info.labels == {"version": __version__} and info.value == 1
        (frozen,) = found["sdfserver_gc_frozen_objects"]
        assert frozen.value > 2 * 10_000  # both processes' start-up objects, summed
        assert {s.labels["generation"] for s in found["sdfserver_gc_collections"]} == {"0", "1", "2"}
        assert "sdfserver_edit_batches" in found  # and the engine's, as before


def test_the_collector_reads_each_process_of_the_table():
    table = SharedCounts(2)
    mine, other = table.for_process(0), table.for_process(1)
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        mine.claim(os.getpid())
        other.claim(child.pid)
        registry = CollectorRegistry()
        registry.register(ApiProcessesCollector(mine))
        pauses = GcPauses(None, publish=mine.set)
        try:
            gc.collect()
        finally:
            pauses.close()
        other.set("gc", 1.0)
        other.set("gc_collections_2", 5)
        other.set("gc_longest_2", 9.0)
        started = {row: registry.get_sample_value("process_start_time_seconds", {"api_process": row})
                   for row in ("0", "1")}
        assert started["0"] and started["1"] and started["0"] < started["1"]  # this test's process, then its child
        assert registry.get_sample_value("process_cpu_seconds_total", {"api_process": "0"}) > 0
        assert registry.get_sample_value("sdfserver_gc_collections_total", {"generation": "2"}) >= 6
        assert registry.get_sample_value("sdfserver_gc_longest_pause_seconds", {"generation": "2"}) == 9.0
        assert registry.get_sample_value("sdfserver_build_info", {"version": __version__}) == 1
    finally:
        child.kill()
        child.wait()
    # a process gone shows no process_* row; one that took its row over starts from nothing
    assert registry.get_sample_value("process_start_time_seconds", {"api_process": "1"}) is None
    other.claim(os.getpid())
    assert registry.get_sample_value("sdfserver_gc_longest_pause_seconds", {"generation": "2"}) < 9.0
    assert registry.get_sample_value("process_start_time_seconds", {"api_process": "1"}) == started["0"]
