// Starting the real device-host server for the browser tests and the benchmark.
//
// `startServer()` builds the `softhaptic` binary with cargo (debug profile unless told
// otherwise; into CARGO_TARGET_DIR when set), runs it on a free local port and resolves with the
// viewer URL it prints ("viewer: http://HOST:PORT/", or "replay: ..." for `softhaptic replay`).
// A server with tokens (`--tokens`) prints the instructor's link with its token in the fragment
// ("viewer: http://HOST:PORT/#token=...") and the observer's ("observer: http://...#token=..."):
// both are captured.
// SOFTHAPTIC_URL points the tests at a server that is already running instead (tests that need
// a server of their own, such as a replay, say `external: false`); SOFTHAPTIC_BIN at a binary
// that is already built. `hdStandinPath()` gives the stand-in for OpenHaptics' libHD that plays
// a PHANTOM in tests (tests/standin/), for `env: { SOFTHAPTIC_HD_LIBRARY: ... }`.
// `stopProcess()` ends any child process the tests start, the same way the server is stopped.
import { spawn, spawnSync } from 'node:child_process';
import { existsSync } from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';

export const REPO = fileURLToPath(new URL('../../', import.meta.url));

function targetDir() {
  return process.env.CARGO_TARGET_DIR ? path.resolve(REPO, process.env.CARGO_TARGET_DIR) : path.join(REPO, 'target');
}

const built = new Map();

/** Builds the server binary (once per process and profile) and returns its path. */
export function buildServer({ release = false } = {}) {
  if (process.env.SOFTHAPTIC_BIN) return process.env.SOFTHAPTIC_BIN;
  if (built.has(release)) return built.get(release);
  const args = ['build', '-p', 'softhaptic-server', '--bin', 'softhaptic'];
  if (release) args.push('--release');
  const result = spawnSync('cargo', args, { cwd: REPO, stdio: ['ignore', 'inherit', 'inherit'] });
  if (result.error) throw new Error(`cannot run cargo: ${result.error.message}`);
  if (result.status !== 0) throw new Error(`cargo ${args.join(' ')} failed with status ${result.status}`);
  const bin = path.join(targetDir(), release ? 'release' : 'debug', 'softhaptic');
  if (!existsSync(bin)) throw new Error(`cargo built, but ${bin} does not exist`);
  built.set(release, bin);
  return bin;
}

let standin = null;

/**
 * The path of the stand-in for OpenHaptics' libHD (built by the `softhaptic-tests` crate):
 * SOFTHAPTIC_HD_STANDIN, else what `cargo run -q -p softhaptic-tests --bin hd-standin-path`
 * prints; asked once per process.
 */
export function hdStandinPath() {
  if (standin !== null) return standin;
  // `make test-web` passes the one its test build made, so that cargo compiles nothing more.
  if (process.env.SOFTHAPTIC_HD_STANDIN) {
    if (!existsSync(process.env.SOFTHAPTIC_HD_STANDIN)) {
      throw new Error(`SOFTHAPTIC_HD_STANDIN=${process.env.SOFTHAPTIC_HD_STANDIN} is not a file`);
    }
    standin = process.env.SOFTHAPTIC_HD_STANDIN;
    return standin;
  }
  const args = ['run', '-q', '-p', 'softhaptic-tests', '--bin', 'hd-standin-path'];
  const result = spawnSync('cargo', args, { cwd: REPO, encoding: 'utf8', stdio: ['ignore', 'pipe', 'pipe'] });
  if (result.error) throw new Error(`cannot run cargo: ${result.error.message}`);
  if (result.status !== 0) {
    throw new Error(`cargo ${args.join(' ')} failed with status ${result.status}:\n${result.stderr}`);
  }
  const found = result.stdout.trim();
  if (!found || !existsSync(found)) {
    throw new Error(`cargo ${args.join(' ')} printed ${JSON.stringify(found)}, which is not a file`);
  }
  standin = found;
  return standin;
}

/** A printed URL with a trailing `/` on its path; its fragment (a token) is kept as printed. */
function normaliseUrl(printed) {
  const url = new URL(printed);
  if (!url.pathname.endsWith('/')) url.pathname += '/';
  return url.href;
}

/**
 * Runs the server and resolves with `{url, observerUrl, baseUrl, stop, output}` once it prints
 * its viewer URL: `url` as printed (with the instructor's token in the fragment when the server
 * has tokens), `observerUrl` the observer's link (null without tokens), `baseUrl` the page
 * without any fragment.
 * `command` comes first (e.g. `['replay', 'tests/sessions/x.mcap']`; none runs a live
 * session), then `--addr` and `extraArgs` (e.g. a scene); paths are relative to the repository.
 * `addr` defaults to a free local port. `env` is added to the server's environment (e.g. the
 * OpenHaptics library). With `external` (the default), SOFTHAPTIC_URL, when set, is used instead
 * of starting anything.
 */
export async function startServer({
  release = false,
  command = [],
  extraArgs = [],
  addr = '127.0.0.1:0',
  env = {},
  timeoutMs = 60000,
  external = true,
} = {}) {
  if (external && process.env.SOFTHAPTIC_URL) {
    const url = process.env.SOFTHAPTIC_URL;
    return { url, observerUrl: null, baseUrl: url.split('#')[0], stop: async () => {}, output: () => '' };
  }
  const bin = buildServer({ release });
  const child = spawn(bin, [...command, '--addr', addr, ...extraArgs], {
    cwd: REPO,
    env: { ...process.env, ...env },
    stdio: ['ignore', 'pipe', 'pipe'],
  });
  let output = '';
  const { url, observerUrl } = await new Promise((resolve, reject) => {
    const timer = setTimeout(
      () => reject(new Error(`server printed no viewer URL within ${timeoutMs} ms:\n${output}`)),
      timeoutMs,
    );
    const onData = (chunk) => {
      output += chunk.toString();
      const m = /\b(?:viewer|replay|instructor): (https?:\/\/\S+)/.exec(output);
      if (!m) return;
      // A link with a token comes with the observer's, printed next.
      const observer = /\bobserver: (https?:\/\/\S+)/.exec(output);
      if (m[1].includes('#') && !observer) return;
      clearTimeout(timer);
      resolve({ url: normaliseUrl(m[1]), observerUrl: observer ? normaliseUrl(observer[1]) : null });
    };
    child.stdout.on('data', onData);
    child.stderr.on('data', onData);
    child.on('exit', (code, signal) => {
      clearTimeout(timer);
      reject(new Error(`server exited (code ${code}, signal ${signal}) before printing its URL:\n${output}`));
    });
  });
  const stop = () => stopProcess(child);
  return { url, observerUrl, baseUrl: url.split('#')[0], stop, output: () => output, child };
}

/**
 * Ends a child process: SIGTERM, then SIGKILL if it is still running 5 s later. Resolves once it
 * has exited (at once if it already had).
 */
export function stopProcess(child) {
  return new Promise((resolve) => {
    if (child.exitCode !== null || child.signalCode !== null) return resolve();
    child.once('exit', () => resolve());
    child.kill('SIGTERM');
    setTimeout(() => child.kill('SIGKILL'), 5000).unref();
  });
}
