"""A server short of file descriptors (``api/port.py`` ``Listener``, ``api/connections.py``): under
a 256-descriptor limit, connections past what the limit leaves room for are answered 503 rather
than dropped unseen, and an accept that fails for want of a descriptor leaves the connection
waiting; both are logged and counted in /metrics, and the server serves again once the
connections holding the descriptors are gone."""

from __future__ import annotations

import re
import socket
import time

import httpx

LOW_LIMIT = """
import resource
resource.setrlimit(resource.RLIMIT_NOFILE, (256, 256))
"""
# Descriptors every process of the server holds from its start (inherited through fork), so that
# the API processes run out before their connection limit does.
HELD_ELSEWHERE = LOW_LIMIT + "held = [open('/dev/null') for _ in range(180)]\n"


def idle_connections(server, n: int) -> list[socket.socket]:
    """``n`` connections that send nothing (the server holds each until header_timeout_s)."""
    return [socket.create_connection(("127.0.0.1", server.port), timeout=10) for _ in range(n)]


def probe(server) -> int | str:
    """The status of a well-behaved request, or what went wrong."""
    try:
        return httpx.get(server.url + "/livez", timeout=5).status_code
    except httpx.TransportError as exc:
        return type(exc).__name__


def counter(server, sample: str) -> float:
    text = server.http.get("/metrics").text
    return float(re.search(rf"^{re.escape(sample)} (\S+)$", text, re.M).group(1))


def test_connections_past_the_descriptor_limit_are_answered_503_logged_and_counted(start_server):
    server = start_server("--workers", "2", hooks=LOW_LIMIT)
    held = idle_connections(server, 600)
    try:
        answers = [probe(server) for _ in range(20)]
    finally:
        for sock in held:
            sock.close()
    assert set(answers) <= {200, 503}, answers  # an answer each, none dropped unseen
    assert 503 in answers
    log = server.log_path.read_text()
    assert "leaves each API process room for 192 connections" in log  # said at start-up
    assert "refusing connections with 503" in log and "file-descriptor limit (256)" in log
    assert probe(server) == 200
    refused = counter(server, 'sdfserver_connections_refused_total{reason="descriptors"}')
    assert 600 - 2 * 192 <= refused, refused


def test_an_accept_that_fails_for_want_of_descriptors_is_logged_counted_and_tried_again(start_server):
    server = start_server("--workers", "2", hooks=HELD_ELSEWHERE)
    held = idle_connections(server, 300)
    time.sleep(1)  # what the listeners make of the backlog
    for sock in held:
        sock.close()
    deadline = time.monotonic() + 15
    while probe(server) != 200 and time.monotonic() < deadline:  # the listeners accept again
        time.sleep(0.2)
    assert probe(server) == 200
    assert "cannot accept connections: Too many open files" in server.log_path.read_text()
    assert counter(server, "sdfserver_accept_failures_total") >= 1
