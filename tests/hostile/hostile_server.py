"""Helpers of the hostile-client tests: a real ``sdfserver serve`` on loopback with small limits,
faults injected through a ``sitecustomize`` module, and the state of a world (description,
voxels, field) to compare before and after an attack."""

from __future__ import annotations

import hashlib
from pathlib import Path

import httpx

import server_process

FLAGS = ["--memory-budget-bytes", str(64 << 20), "--no-warm-up", "--max-request-bytes", str(1 << 20),
         "--max-brush-radius-vox", "40", "--max-wait-ms", "2000", "--max-world-voxels", str(1 << 18)]
WORLD = {"size": [16, 16, 16], "chunk_size": 8, "max_distance": 16}
OCTET = {"accept": "application/octet-stream"}


class HostileServer(server_process.ServerProcess):
    def __init__(self, data_dir: Path, *flags: str, hooks: str | None = None):
        env = None
        if hooks is not None:  # run at the start of every interpreter of the server
            directory = Path(data_dir).parent / "hooks"
            directory.mkdir(exist_ok=True)
            (directory / "sitecustomize.py").write_text(hooks)
            env = server_process.checkout_env(directory)
        super().__init__(data_dir, *FLAGS, *flags, env=env)
        self.http = httpx.Client(base_url=self.url, timeout=30)
        self.ws_url = self.url.replace("http://", "ws://")

    def close(self) -> None:
        self.http.close()
        super().close()

    def new_world(self, **config) -> str:
        r = self.http.post("/v1/worlds", json={**WORLD, **config})
        assert r.status_code == 201, r.text
        return r.json()["id"]

    def state(self, world: str) -> tuple:
        """What an attack must leave alone: the world's description, voxels and field, and the
        list of worlds."""
        described = self.http.get(f"/v1/worlds/{world}").json()
        voxels = self.http.get(f"/v1/worlds/{world}/voxels", headers=OCTET).content
        field = self.http.get(f"/v1/worlds/{world}/field?format=packed", headers=OCTET).content
        ids = sorted(w["id"] for w in self.http.get("/v1/worlds").json()["worlds"])
        kept = {k: described[k] for k in ("size", "chunk_size", "max_distance", "algorithm", "lod_algorithm",
                                          "focus", "borders", "version", "field_version")}
        return kept, hashlib.sha256(voxels).hexdigest(), hashlib.sha256(field).hexdigest(), ids


def error_of(response: httpx.Response) -> tuple[int, str]:
    """(status, code) of an answer with the one error body; (status, the start of the body)
    for any other answer."""
    try:
        error = response.json()["error"]
        if isinstance(error["message"], str) and len(error["message"]) < 2000:
            return response.status_code, error["code"]
    except (ValueError, KeyError, TypeError):
        pass
    return response.status_code, f"not an error body: {response.content[:120]!r}"
