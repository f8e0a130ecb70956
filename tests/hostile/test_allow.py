"""A 405's ``Allow`` names every method the path is served with, not only those of the first
route whose path matched: ``/v1/worlds`` is a GET route and a POST route, ``/v1/worlds/{id}``
a GET, a PATCH and a DELETE route."""

from __future__ import annotations

import re

from sdfserver.api.app import create_app
from sdfserver.settings import Settings

UNSERVED = "TRACE"  # no route takes it, so every path that has a route answers it 405


def http_routes() -> list:
    """The app's HTTP routes, one per (path, methods), those of included routers too."""
    routes = create_app(Settings(persist=False)).routes
    try:  # newer FastAPI keeps an included router as one entry of app.routes
        from fastapi.routing import iter_route_contexts
    except ImportError:
        pass
    else:
        routes = list(iter_route_contexts(routes))
    return [r for r in routes if getattr(r, "methods", None)]


def served_at(routes: list, path: str) -> set[str]:
    """The methods of every route whose path pattern takes ``path``."""
    return {m for r in routes if r.path_regex.match(path) for m in r.methods}


def allow_of(response) -> set[str]:
    return {m.strip() for m in response.headers["allow"].split(",")}


def test_allow_lists_every_method_of_every_route_path(start_server):
    server = start_server()
    world = server.new_world()
    routes = http_routes()
    paths = {re.sub(r"\{[^}]+\}", world, r.path) for r in routes}
    assert f"/v1/worlds/{world}" in paths and "/v1/worlds" in paths
    for path in sorted(paths):
        r = server.http.request(UNSERVED, path)
        assert r.status_code == 405, (path, r.text)
        assert allow_of(r) == served_at(routes, path), path
        # each method listed is served there (at a world that does not exist: nothing changes)
        elsewhere = path.replace(world, "absent")
        for method in served_at(routes, elsewhere):
            assert server.http.request(method, elsewhere).status_code != 405, (method, elsewhere)


def test_the_worlds_paths_allow_what_they_serve(start_server):
    server = start_server()
    world = server.new_world()
    assert allow_of(server.http.request("PUT", "/v1/worlds")) == {"GET", "POST"}
    assert allow_of(server.http.request("PUT", f"/v1/worlds/{world}")) == {"GET", "PATCH", "DELETE"}
    assert allow_of(server.http.request("POST", "/static/app.js")) == {"GET", "HEAD"}
