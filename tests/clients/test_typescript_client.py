"""The TypeScript client (clients/typescript): ``npm ci``, ``npm run build`` and its own tests
(``node --test``), which start real servers with this interpreter and this checkout; and
docs/clients.md quotes its examples exactly, as the tests run them."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time

import pytest
from clients_support import CLIENTS, ROOT

PACKAGE = CLIENTS / "typescript"
STEPS = (  # (command, timeout in seconds)
    (["npm", "ci", "--no-audit", "--no-fund"], 300),
    (["npm", "run", "build"], 180),
    (["npm", "test"], 240),
)
LINGER_S = 5.0  # a stopped server's engine and API processes end just after it


def _run(command: list[str], timeout_s: float) -> tuple[int, str]:
    """``command`` in its own process group; fails the test if anything it started (a server
    the Node tests forgot to stop) is still running once it has exited."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("SDFSERVER_")}
    env.update(SDF_TEST_PYTHON=sys.executable, SDF_TEST_ROOT=str(ROOT))
    proc = subprocess.Popen(command, cwd=PACKAGE, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    try:
        output, _ = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        output, _ = proc.communicate()
        pytest.fail(f"{' '.join(command)} took over {timeout_s} s:\n{output[-8000:]}")
    deadline = time.monotonic() + LINGER_S
    while time.monotonic() < deadline:
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            return proc.returncode, output
        time.sleep(0.1)
    os.killpg(proc.pid, signal.SIGKILL)
    pytest.fail(f"{' '.join(command)} left processes running (killed now):\n{output[-8000:]}")


@pytest.mark.skipif(shutil.which("npm") is None, reason="npm is not installed")
def test_typescript_client_builds_and_passes_its_tests():
    for command, timeout_s in STEPS:
        code, output = _run(command, timeout_s)
        assert code == 0, f"{' '.join(command)} exited {code}:\n{output[-12000:]}"
    assert re.search(r"^# fail 0$", output, flags=re.M), output[-12000:]
    assert not re.search(r"^# (pass|tests) 0$", output, flags=re.M), output[-12000:]


TS_BLOCKS = re.findall(r"^```ts\n(.*?)^```", (ROOT / "docs" / "clients.md").read_text(), flags=re.S | re.M)
EXAMPLES = sorted((PACKAGE / "examples").glob("*.ts"))


@pytest.mark.parametrize("example", EXAMPLES, ids=[p.name for p in EXAMPLES])
def test_docs_quote_the_typescript_examples_exactly(example):
    """The examples are what the Node tests run (test/example.test.ts); the document shows them."""
    assert example.read_text() in TS_BLOCKS, f"docs/clients.md has no ```ts block equal to {example.name}"


def test_every_typescript_block_of_the_docs_is_an_example():
    assert TS_BLOCKS, "docs/clients.md shows no TypeScript"
    examples = {p.read_text() for p in EXAMPLES}
    for block in TS_BLOCKS:
        assert block in examples, f"a ```ts block of docs/clients.md that no test runs:\n{block}"
