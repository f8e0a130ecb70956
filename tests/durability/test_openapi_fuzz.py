"""schemathesis against the server's OpenAPI spec, through a real server: generated requests
(valid and invalid, JSON and msgpack bodies) never get a 5xx, and answers conform to the spec."""

from __future__ import annotations

import random

import msgpack
import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schemathesis import GenerationMode
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import content_type_conformance, response_schema_conformance

from durable_server import ServerProcess

WORLD_IDS: list[str] = []


def _fit(value):
    """msgpack has no integers beyond 64 bits: send those as floats (still out of range)."""
    if isinstance(value, int) and not isinstance(value, bool) and not -2 ** 63 <= value < 2 ** 64:
        return float(value)
    if isinstance(value, dict):
        return {k: _fit(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_fit(v) for v in value]
    return value


@schemathesis.serializer("application/msgpack")
def _msgpack(ctx, value):  # msgpack bodies are fuzzed too
    return msgpack.packb(_fit(value), use_bin_type=True)


@pytest.fixture(scope="module")
def fuzz_server(tmp_path_factory):
    server = ServerProcess(tmp_path_factory.mktemp("fuzz") / "data", "--max-world-voxels", str(1 << 18),
                           "--max-worlds", "400").wait_ready()
    for _ in range(3):
        r = server.http.post("/v1/worlds", json={"size": [16, 16, 16], "chunk_size": 8, "max_distance": 6})
        WORLD_IDS.append(r.json()["id"])
    yield server
    server.stop()


def operations(url: str):
    schema = schemathesis.openapi.from_url(url + "/openapi.json")
    return [result.ok() for result in schema.get_all_operations()]


def test_no_server_errors_and_answers_match_the_spec(fuzz_server):
    ops = operations(fuzz_server.url)
    assert len(ops) >= 8, [op.label for op in ops]
    checked, failures, media = [], [], set()
    for op in ops:  # schemathesis' pytest plugin does not run on this pytest; drive Hypothesis directly
        @given(case=st.one_of(op.as_strategy(generation_mode=GenerationMode.POSITIVE),
                              op.as_strategy(generation_mode=GenerationMode.NEGATIVE)))
        @settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck), database=None)
        def check(case):
            if case.path_parameters and "world_id" in case.path_parameters and random.random() < 0.7:
                case.path_parameters["world_id"] = random.choice(WORLD_IDS)  # real worlds, not only 404s
            if case.method.upper() == "DELETE" and case.path_parameters.get("world_id") in WORLD_IDS:
                return  # keep the worlds the other cases use
            response = case.call(timeout=30)
            media.add(case.media_type)
            case.validate_response(response, checks=[not_a_server_error, response_schema_conformance,
                                                     content_type_conformance])
            checked.append(response.status_code)

        try:
            check()
        except (Exception, BaseExceptionGroup) as exc:  # collected, then reported all together below
            parts = exc.exceptions if isinstance(exc, BaseExceptionGroup) else [exc]
            failures.append(f"{op.label}: " + "\n".join(str(e)[:3000] for e in parts))
    assert not failures, "\n\n".join(failures)
    assert len(checked) > 100 and not any(code >= 500 for code in checked)
    assert {"application/json", "application/msgpack"} <= media
