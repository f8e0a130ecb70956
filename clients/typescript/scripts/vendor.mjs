// The web demo's copy of this client and of @msgpack/msgpack, as ES modules a browser loads
// without a bundler: sdfserver/web/static/vendor/.
//
//   node scripts/vendor.mjs          rewrite the copy from src/ and node_modules/ (after npm ci)
//   node scripts/vendor.mjs --check  exit 1, naming the files, where the copy differs from that
//
// The client is compiled here with this package's tsc into a fresh folder (so a stale dist/ never
// leaks in); @msgpack/msgpack is its package's own ESM build (dist.esm/) with the source-map
// comments left out, since the maps are not copied. The page maps the bare specifier
// "@msgpack/msgpack" to the copy with an import map (index.html). tests/web/test_vendored.py runs
// --check, so the copy cannot fall behind the sources unnoticed.

import { execFileSync } from "node:child_process";
import { existsSync, mkdirSync, mkdtempSync, readFileSync, readdirSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { dirname, join, relative } from "node:path";
import { fileURLToPath } from "node:url";

const PACKAGE = dirname(dirname(fileURLToPath(import.meta.url)));
const ROOT = join(PACKAGE, "..", "..");
const VENDOR = join(ROOT, "sdfserver", "web", "static", "vendor");
const MSGPACK = join(PACKAGE, "node_modules", "@msgpack", "msgpack");
const SOURCE_MAP = /^\/\/# sourceMappingURL=.*\n?/m;

const README = `# Vendored ES modules (generated: do not edit)

The web demo's copy of the TypeScript client (\`sdfclient/\`, compiled from
\`clients/typescript/src/\`) and of \`@msgpack/msgpack\` (\`msgpack/\`, its package's ESM build,
version ${JSON.parse(readFileSync(join(MSGPACK, "package.json"), "utf8")).version}, ISC license in \`msgpack/LICENSE\`).
\`index.html\`'s import map resolves \`sdfclient\` and \`@msgpack/msgpack\` to them.

Regenerate with \`cd clients/typescript && npm ci && npm run vendor\`;
\`tests/web/test_vendored.py\` fails while this copy differs from what that would write.
`;

function walk(dir, keep) {
  const found = [];
  for (const entry of readdirSync(dir, { withFileTypes: true })) {
    const path = join(dir, entry.name);
    if (entry.isDirectory()) found.push(...walk(path, keep));
    else if (keep(entry.name)) found.push(path);
  }
  return found.sort();
}

/** Every file the vendor folder should hold: relative path -> contents. */
function expected() {
  const files = new Map([["README.md", README]]);
  const out = mkdtempSync(join(tmpdir(), "sdfclient-vendor-"));
  try {
    const tsc = join(PACKAGE, "node_modules", "typescript", "bin", "tsc");
    execFileSync(process.execPath, [tsc, "-p", join(PACKAGE, "tsconfig.json"), "--outDir", out, "--declaration", "false"],
      { stdio: "inherit" });
    for (const path of walk(out, (name) => name.endsWith(".js"))) {
      files.set(join("sdfclient", relative(out, path)), readFileSync(path, "utf8"));
    }
  } finally {
    rmSync(out, { recursive: true, force: true });
  }
  const esm = join(MSGPACK, "dist.esm");
  for (const path of walk(esm, (name) => name.endsWith(".mjs"))) {
    files.set(join("msgpack", relative(esm, path)), readFileSync(path, "utf8").replace(SOURCE_MAP, ""));
  }
  files.set(join("msgpack", "LICENSE"), readFileSync(join(MSGPACK, "LICENSE"), "utf8"));
  return files;
}

function differences(files) {
  const present = existsSync(VENDOR) ? walk(VENDOR, () => true).map((path) => relative(VENDOR, path)) : [];
  const problems = present.filter((path) => !files.has(path)).map((path) => `${path}: not produced from the sources`);
  for (const [path, text] of files) {
    const target = join(VENDOR, path);
    if (!existsSync(target)) problems.push(`${path}: missing`);
    else if (readFileSync(target, "utf8") !== text) problems.push(`${path}: differs`);
  }
  return problems;
}

const files = expected();
if (process.argv.includes("--check")) {
  const problems = differences(files);
  if (problems.length > 0) {
    console.error(`${relative(ROOT, VENDOR)} is stale (cd clients/typescript && npm run vendor):\n  ${problems.join("\n  ")}`);
    process.exit(1);
  }
  console.log(`${relative(ROOT, VENDOR)}: ${files.size} files, up to date`);
} else {
  rmSync(VENDOR, { recursive: true, force: true });
  for (const [path, text] of files) {
    mkdirSync(dirname(join(VENDOR, path)), { recursive: true });
    writeFileSync(join(VENDOR, path), text);
  }
  console.log(`wrote ${files.size} files under ${relative(ROOT, VENDOR)}`);
}
