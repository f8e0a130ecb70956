"""The web demo's vendored ES modules (``sdfserver/web/static/vendor/``): what
``clients/typescript/scripts/vendor.mjs`` writes from the client's sources and the installed
``@msgpack/msgpack``, byte for byte, and served with a JavaScript type so browsers load them as modules."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest
import httpx

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "clients" / "typescript"
VENDOR = ROOT / "sdfserver" / "web" / "static" / "vendor"


@pytest.mark.skipif(shutil.which("npm") is None, reason="npm is not installed")
def test_vendored_copy_is_what_the_script_makes_from_the_sources():
    if not (PACKAGE / "node_modules" / "typescript").is_dir() or not (PACKAGE / "node_modules" / "@msgpack").is_dir():
        subprocess.run(["npm", "ci", "--no-audit", "--no-fund"], cwd=PACKAGE, check=True, capture_output=True, timeout=300)
    done = subprocess.run(["node", "scripts/vendor.mjs", "--check"], cwd=PACKAGE, capture_output=True, text=True,
                          timeout=180)
    assert done.returncode == 0, done.stdout + done.stderr


def test_vendored_modules_are_served_as_javascript(server):
    for path in ("vendor/sdfclient/index.js", "vendor/msgpack/index.mjs", "vendor/msgpack/utils/int.mjs", "app.js"):
        response = httpx.get(f"{server}/static/{path}")
        assert response.status_code == 200, path
        assert response.headers["content-type"].startswith("text/javascript"), (path, response.headers)
    page = httpx.get(server + "/").text  # the import map that names them
    assert '"sdfclient": "/static/vendor/sdfclient/index.js"' in page
    assert '"@msgpack/msgpack": "/static/vendor/msgpack/index.mjs"' in page
    assert not (VENDOR.parent / "msgpack.js").exists()  # the hand-written codec is gone
