/**
 * A real `sdfserver serve` for the tests: the pytest wrapper (tests/clients/test_typescript_client.py)
 * names the Python (SDF_TEST_PYTHON) and the checkout (SDF_TEST_ROOT). The server listens on a
 * free loopback port with its data in a fresh temporary directory, is waited for until `/readyz`
 * answers 200, and is stopped (SIGTERM, then SIGKILL) by `stop`.
 */

import { spawn, type ChildProcess } from "node:child_process";
import { mkdtemp, open, readFile, rm } from "node:fs/promises";
import { createServer } from "node:net";
import { tmpdir } from "node:os";
import { join } from "node:path";
import { setTimeout as sleep } from "node:timers/promises";

const READY_TIMEOUT_MS = 120_000; // PoCL builds the kernels while the server warms up
const STOP_TIMEOUT_MS = 15_000;

function required(name: string): string {
  const value = process.env[name];
  if (!value) throw new Error(`${name} is not set: run these tests through tests/clients/test_typescript_client.py`);
  return value;
}

async function freePort(): Promise<number> {
  const probe = createServer();
  await new Promise<void>((resolve) => probe.listen(0, "127.0.0.1", resolve));
  const address = probe.address();
  await new Promise((resolve) => probe.close(resolve));
  if (address === null || typeof address === "string") throw new Error("no port");
  return address.port;
}

export class TestServer {
  private constructor(
    readonly url: string,
    private readonly process: ChildProcess,
    private readonly directory: string,
    private readonly exited: Promise<void>,
  ) {}

  /** A ready server; `flags` go to `sdfserver serve` (e.g. `--api-keys`). */
  static async start(...flags: string[]): Promise<TestServer> {
    const root = required("SDF_TEST_ROOT");
    const directory = await mkdtemp(join(tmpdir(), "sdfclient-ts-"));
    const port = await freePort();
    const log = await open(join(directory, "server.log"), "w");
    const env = Object.fromEntries(Object.entries(process.env).filter(([k]) => !k.startsWith("SDFSERVER_")));
    env.PYTHONPATH = [root, env.PYTHONPATH].filter(Boolean).join(":");
    const child = spawn(required("SDF_TEST_PYTHON"),
      ["-m", "sdfserver", "serve", "--host", "127.0.0.1", "--port", String(port), "--data-dir", join(directory, "data"), ...flags],
      { cwd: root, env, stdio: ["ignore", log.fd, log.fd] });
    const exited = new Promise<void>((resolve) => child.once("exit", () => resolve()));
    await log.close();
    const server = new TestServer(`http://127.0.0.1:${port}`, child, directory, exited);
    await server.waitReady();
    return server;
  }

  private async waitReady(): Promise<void> {
    const deadline = Date.now() + READY_TIMEOUT_MS;
    for (;;) {
      if (this.process.exitCode !== null || this.process.signalCode !== null) {
        const output = await this.output();
        await this.stop();
        throw new Error(`server exited (${this.process.exitCode ?? this.process.signalCode}): ${output}`);
      }
      try {
        const response = await fetch(this.url + "/readyz", { signal: AbortSignal.timeout(2000) });
        await response.arrayBuffer();
        if (response.status === 200) return;
      } catch {
        // not listening yet
      }
      if (Date.now() > deadline) {
        const output = await this.output();
        await this.stop();
        throw new Error(`server not ready in ${READY_TIMEOUT_MS} ms: ${output}`);
      }
      await sleep(50);
    }
  }

  async output(): Promise<string> {
    return (await readFile(join(this.directory, "server.log"), "utf8")).slice(-4000);
  }

  async stop(): Promise<void> {
    if (this.process.exitCode === null && this.process.signalCode === null) {
      this.process.kill("SIGTERM");
      const stopped = await Promise.race([this.exited.then(() => true), sleep(STOP_TIMEOUT_MS, false, { ref: false })]);
      if (!stopped) {
        this.process.kill("SIGKILL");
        await this.exited;
      }
    }
    await rm(this.directory, { recursive: true, force: true });
  }
}
