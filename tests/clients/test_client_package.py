"""The Python client is a distribution of its own (clients/python): installed beside the server,
depending on httpx, websockets, msgpack and NumPy only, importing nothing of the server's, and
carrying the server's wire module as an exact copy."""

from __future__ import annotations

import ast
import importlib.metadata
import subprocess
import sys
import tomllib
from pathlib import Path

from clients_support import ROOT
from packaging.requirements import Requirement

PACKAGE = ROOT / "clients" / "python"
SERVER_MODULES = ("sdfserver", "pyopencl", "fastapi", "starlette", "scipy", "uvicorn", "pydantic")


def _imported_modules(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name.partition(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.partition(".")[0])
    return names


def test_the_wire_module_is_the_servers_byte_for_byte():
    assert (PACKAGE / "sdfclient" / "wire.py").read_bytes() == (ROOT / "sdfserver" / "wire.py").read_bytes(), (
        "clients/python/sdfclient/wire.py must stay a copy of sdfserver/wire.py: "
        "cp sdfserver/wire.py clients/python/sdfclient/wire.py")


def test_nothing_in_the_client_imports_the_server():
    sources = sorted(PACKAGE.rglob("*.py"))
    assert any(p.name == "client.py" for p in sources) and any(p.parent.name == "examples" for p in sources)
    for path in sources:
        found = _imported_modules(path) & set(SERVER_MODULES)
        assert not found, f"{path.relative_to(ROOT)} imports {sorted(found)}"


def test_its_dependencies_are_httpx_websockets_msgpack_and_numpy():
    project = tomllib.loads((PACKAGE / "pyproject.toml").read_text())["project"]
    assert project["name"] == "sdfclient"
    assert sorted(Requirement(r).name for r in project["dependencies"]) == ["httpx", "msgpack", "numpy", "websockets"]
    assert project["license"] == "MIT" and (PACKAGE / "LICENSE").read_text() == (ROOT / "LICENSE").read_text()


def test_importing_the_client_loads_nothing_of_the_servers():
    """In a fresh interpreter where ``sdfserver`` cannot be imported at all."""
    code = ("import sys; sys.modules['sdfserver'] = None\n"
            "import sdfclient, sdfclient.stream, sdfclient.client\n"
            f"print(sorted(m for m in {SERVER_MODULES!r} if sys.modules.get(m) is not None))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT.parent)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


def test_the_tests_use_the_installed_distribution():
    """The README's test command installs clients/python; nothing puts it on the path by hand."""
    import sdfclient

    assert importlib.metadata.version("sdfclient") == sdfclient.__version__
    assert Path(sdfclient.__file__).resolve().is_relative_to(PACKAGE)
    installed = importlib.metadata.distribution("sdfserver")
    assert not any(str(f).startswith("sdfclient/") for f in installed.files or ()), (
        "the server's distribution must not carry the client")
