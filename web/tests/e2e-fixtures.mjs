// What several browser tests set up the same way: a teaching lab (a real nats-server, stations
// and hubs), a headless Chromium page that collects its own errors, and waiting on that page
// with the servers' logs in the error.
import { spawn } from 'node:child_process';
import { existsSync } from 'node:fs';
import { connect, createServer } from 'node:net';
import { join } from 'node:path';

import { launchBrowser } from './browser.mjs';
import { startServer, stopProcess } from './server.mjs';

/** How long a wait on the page may take: generous, so that a slow machine only delays a test. */
const WAIT_MS = 60000;

/** A free loopback port. */
export function freePort() {
  return new Promise((resolve, reject) => {
    const s = createServer();
    s.once('error', reject);
    s.listen(0, '127.0.0.1', () => {
      const { port } = s.address();
      s.close(() => resolve(port));
    });
  });
}

/** Resolves once `port` accepts a connection (polling, generous deadline); `what` names it in the error. */
async function listening(port, what) {
  const deadline = Date.now() + 30000;
  for (;;) {
    const ok = await new Promise((resolve) => {
      const c = connect(port, '127.0.0.1', () => {
        c.destroy();
        resolve(true);
      });
      c.once('error', () => resolve(false));
    });
    if (ok) return;
    if (Date.now() > deadline) throw new Error(`${what} did not listen on ${port}`);
    await new Promise((r) => setTimeout(r, 50));
  }
}

/**
 * A nats-server with JetStream on a free loopback port, its store in `dir`/nats. Resolves with
 * `{url, stop}` once it accepts connections; `stop()` resolves when the process has ended.
 */
export async function startNats(dir) {
  const port = await freePort();
  const program = existsSync('/usr/sbin/nats-server') ? '/usr/sbin/nats-server' : 'nats-server';
  const child = spawn(program, ['-a', '127.0.0.1', '-p', String(port), '-js', '-sd', join(dir, 'nats')], {
    stdio: 'ignore',
  });
  // A missing program shows as this error rather than as a port that never opens.
  const failed = new Promise((_, reject) =>
    child.once('error', (e) => reject(new Error(`cannot run ${program}: ${e.message}`))),
  );
  await Promise.race([listening(port, 'nats-server'), failed]);
  const stop = () => stopProcess(child);
  return { url: `nats://127.0.0.1:${port}`, stop };
}

/**
 * Headless Chromium with one 1280×800 page. Resolves with `{browser, page, pageErrors, close}`:
 * `pageErrors` collects the message of every uncaught error in the page, for a test to assert
 * there were none.
 */
export async function openPage() {
  const browser = await launchBrowser();
  const page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
  const pageErrors = [];
  page.on('pageerror', (e) => pageErrors.push(e.message));
  return { browser, page, pageErrors, close: () => browser.close() };
}

/**
 * A teaching lab in `dir`: a nats-server, one station per entry of `stations` (the station's own
 * arguments, e.g. `['--no-record', '--station', 'desk-1']`; `--nats` is added), then `hubs` hubs.
 * Resolves with `{url, stations, hubs, stop}` (`stations` and `hubs` as `startServer` gives
 * them); `stop()` stops the hubs, the stations, then the nats-server. A part that fails to start
 * stops the parts already started before the error is passed on.
 */
export async function startLab(dir, { stations, hubs = 1 }) {
  const nats = await startNats(dir);
  const lab = { url: nats.url, stations: [], hubs: [] };
  lab.stop = async () => {
    for (const h of lab.hubs) await h.stop();
    for (const s of lab.stations) await s.stop();
    await nats.stop();
  };
  try {
    for (const args of stations) {
      lab.stations.push(await startServer({ extraArgs: [...args, '--nats', nats.url], external: false }));
    }
    for (let i = 0; i < hubs; i++) {
      lab.hubs.push(await startServer({ command: ['hub', '--nats', nats.url], external: false }));
    }
  } catch (e) {
    await lab.stop();
    throw e;
  }
  return lab;
}

/** The last `lines` lines of a server's output, headed by `name`. */
export function logTail(name, server, lines = 20) {
  return `${name} log (end):\n${server.output().split('\n').slice(-lines).join('\n')}`;
}

/**
 * Waits until `predicate(arg)` holds in `page`; on a timeout the error names `what` and adds
 * `log()` (the servers' logs, read only then).
 */
export async function waitOnPage(page, what, predicate, arg, log) {
  try {
    await page.waitForFunction(predicate, arg, { timeout: WAIT_MS });
  } catch (e) {
    throw new Error(`${what}: ${e.message}\n${log()}`, { cause: e });
  }
}
