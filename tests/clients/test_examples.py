"""The scripts in clients/python/examples run against a real server and print what they should."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest
from clients_support import CLIENTS, ROOT, env_with_paths

from sdfclient import Client


def _run(name: str, server_url: str, *args: str) -> str:
    proc = subprocess.run([sys.executable, str(CLIENTS / "python" / "examples" / name), server_url, *args],
                          cwd=ROOT, env=env_with_paths(), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc.stdout


def _worlds(server_url: str) -> set[str]:
    with Client(server_url) as client:
        return {w.id for w in client.list_worlds()}


def test_paint_sphere(server_url):
    before = _worlds(server_url)
    out = _run("paint_sphere.py", server_url)
    z, y, x = np.mgrid[:32, :32, :32]
    solid = int(((x - 16) ** 2 + (y - 16) ** 2 + (z - 16) ** 2 <= 25).sum())
    assert "version 1, field (32, 32, 32) uint8" in out
    assert "distance at the centre (16,16,16): 0\n" in out
    assert "3 voxels off the surface: 3\n" in out
    # The nearest sphere voxel to the corner: L1 distance 48 - ... capped at 32.
    assert "distance at the corner (0,0,0): 32\n" in out
    assert f"solid voxels: {solid}\n" in out
    assert _worlds(server_url) == before  # it cleans up


def test_query_points(server_url):
    out = _run("query_points.py", server_url)
    found = re.findall(r"point \[10.5, (\d+).5, 12.5\]: distance ([\d.]+), gradient \[(.*)\]", out)
    assert len(found) == 6
    for height, dist, grad in found:
        assert float(dist) == float(height)
        gx, gy, gz = (float(v) for v in grad.split(","))
        assert gy > 0 and gx == 0 and gz == 0
    assert "sphere clearance 2, way out [0.0, 1.0, 0.0]\n" in out
    assert "ray down: hit True at 4.5, voxel [10, 0, 12], normal [0.0, 1.0, 0.0]\n" in out


def test_stream_changes(server_url):
    out = _run("stream_changes.py", server_url)
    assert "subscribed: 16 chunks at version 0\n" in out
    assert "edit acknowledged: version 1\n" in out
    match = re.search(r"version (\d+): (\d+) changed chunks at (.*)", out)
    assert match and int(match.group(1)) >= 1 and int(match.group(2)) >= 1
    assert "(0, 0, 0)" in match.group(3) and "(32," not in match.group(3) and "(48," not in match.group(3)


def test_render_and_save(server_url, tmp_path):
    from PIL import Image

    before = _worlds(server_url)
    tmp_path = tmp_path / "made" / "by the example"  # a folder that does not exist yet
    out = _run("render_and_save.py", server_url, str(tmp_path))
    assert re.search(r"scene.png: 320x200, field version 1, \d+ bytes", out)
    assert re.search(r"scene.vox: version 1, \d+ bytes", out)
    assert re.search(r"imported as world \S+: size \(64, 32, 64\), voxels equal: True", out)
    with Image.open(tmp_path / "scene.png") as image:
        pixels = np.asarray(image.convert("RGB"))
    assert pixels.shape == (200, 320, 3) and len(np.unique(pixels.reshape(-1, 3), axis=0)) > 8
    assert (tmp_path / "scene.vox").read_bytes()[:4] == b"VOX "
    assert _worlds(server_url) == before


DOC_BLOCKS = re.findall(r"^```python\n(.*?)^```", (ROOT / "docs" / "clients.md").read_text(), flags=re.S | re.M)


@pytest.mark.parametrize("block", DOC_BLOCKS, ids=[f"block{i}" for i in range(len(DOC_BLOCKS))])
def test_docs_clients_blocks_run_as_written(block, server_url, tmp_path):
    """Each Python block of docs/clients.md, fed to a fresh interpreter in an empty folder; only
    the documented server address is swapped for the test server's."""
    assert "http://127.0.0.1:8000" in block
    before = _worlds(server_url)
    proc = subprocess.run([sys.executable, "-"], input=block.replace("http://127.0.0.1:8000", server_url),
                          cwd=tmp_path, env=env_with_paths(), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert _worlds(server_url) == before  # it cleans up
