// A teaching lab for the dashboard's browser test and its screenshot: a real nats-server, real
// stations made to differ in what an instructor should see, and a hub with tokens.
//
// The stations run copies of the default scene written into a scratch directory (the scene's
// calibration table named by its absolute path), so that each can be given its own safe force
// or device:
//   - `calm`: the simulated PHANTOM presses well below its safe force (50 N): no alert;
//   - `hard`: the same press, its safe force 0.05 N: an `above_safe_force` alert within seconds;
//   - `unplugged`: a SpaceMouse played from a report stream that is unplugged 2 s after it
//     opens and never plugged back: the device is `disconnected`, a `device_fault` alert;
//   - `exercises`: the calm scene running `exercises/press-hold.toml` (its copy naming the calm
//     scene, and another time limit when asked) for a trainee, the next exercise left to an
//     instructor (`--exercise-pause wait`). The simulated hand presses harder than the task
//     asks, so an attempt that reaches its time limit fails (an `exercise_failed` alert).
// For a room of fifty without fifty 1 kHz loops on the machine, `copyHeartbeats` publishes one
// real station's heartbeat again under other names: a hub's dashboard reads nothing else of a
// station.
import { readFileSync, writeFileSync } from 'node:fs';
import { join } from 'node:path';

import { connect } from 'nats';

import { startNats } from './e2e-fixtures.mjs';
import { REPO, startServer } from './server.mjs';

/** The default scene with `safeForceN` and, when given, another `[device]` table. */
function sceneText(safeForceN, device = null) {
  let text = readFileSync(join(REPO, 'scenes/default.toml'), 'utf8').replaceAll(
    '"calibration/',
    JSON.stringify(join(REPO, 'scenes/calibration')).slice(0, -1) + '/',
  );
  text = text.replace(/^\[haptics\]\n/m, `[haptics]\nsafe_force_n = ${safeForceN}\n`);
  if (device !== null) {
    const start = text.indexOf('[device]');
    const end = text.indexOf('\n[', start + 1) + 1;
    text = text.slice(0, start) + device + text.slice(end);
  }
  return text;
}

/**
 * Writes the stations' scenes and files into `dir`; returns the command-line arguments of each
 * kind of station (without `--station` and `--nats`).
 */
export function writeStationFiles(dir) {
  const calm = join(dir, 'calm.toml');
  writeFileSync(calm, sceneText(50));
  writeFileSync(join(dir, 'hard.toml'), sceneText(0.05));
  const stream = join(dir, 'unplug.hid');
  writeFileSync(
    stream,
    ['# a SpaceMouse at rest, then unplugged', 'model 046d:c626', '0 01 00 00 00 00 00 00', '2000 unplug', ''].join(
      '\n',
    ),
  );
  writeFileSync(
    join(dir, 'unplugged.toml'),
    sceneText(50, ['[device]', 'kind = "spacemouse"', `report_script = ${JSON.stringify(stream)}`, ''].join('\n')),
  );
  const exercise = readFileSync(join(REPO, 'exercises/press-hold.toml'), 'utf8').replace(
    /^scene = .*$/m,
    'scene = "calm.toml"',
  );
  /** The exercise's copy with its time limit, s (the shipped one's, 20 s, when not given). */
  const exerciseFile = (timeLimitS) => {
    if (timeLimitS === undefined) {
      writeFileSync(join(dir, 'press-hold.toml'), exercise);
      return join(dir, 'press-hold.toml');
    }
    const file = join(dir, `press-hold-${timeLimitS}s.toml`);
    writeFileSync(file, exercise.replace(/^time_limit_s = .*$/m, `time_limit_s = ${timeLimitS}`));
    return file;
  };
  return {
    calm: ['--no-record', '--scene', calm],
    hard: ['--no-record', '--scene', join(dir, 'hard.toml')],
    unplugged: ['--no-record', '--scene', join(dir, 'unplugged.toml')],
    exercises: (trainee, { timeLimitS } = {}) => [
      '--record-dir',
      join(dir, `recordings-${trainee}`),
      '--scene',
      calm,
      '--exercises',
      exerciseFile(timeLimitS),
      '--trainee',
      trainee,
      '--exercise-pause',
      'wait',
    ],
  };
}

/**
 * Starts a lab in `dir`: a nats-server, one station per `[name, args]` of `stations` (every
 * station `--no-realtime`, as the browser tests run them), and a hub with tokens. Resolves with
 * `{stations: Map name → server, hub, natsUrl, dashboardUrl, observerDashboardUrl, stop}`; the URLs are the
 * dashboard links the hub printed, each role's token in their fragment.
 */
export async function startDashboardLab(dir, stations) {
  const nats = await startNats(dir);
  const lab = { stations: new Map(), hub: null, natsUrl: nats.url };
  lab.stop = async () => {
    await lab.hub?.stop();
    for (const s of lab.stations.values()) await s.stop();
    await nats.stop();
  };
  try {
    for (const [name, args] of stations) {
      lab.stations.set(
        name,
        await startServer({
          extraArgs: ['--no-realtime', ...args, '--station', name, '--nats', nats.url],
          external: false,
        }),
      );
    }
    lab.hub = await startServer({ command: ['hub', '--nats', nats.url], extraArgs: ['--tokens'], external: false });
  } catch (e) {
    await lab.stop();
    throw e;
  }
  try {
    lab.dashboardUrl = await printedLink(lab.hub, 'hub dashboard');
    lab.observerDashboardUrl = await printedLink(lab.hub, 'hub observer dashboard');
  } catch (e) {
    await lab.stop();
    throw e;
  }
  return lab;
}

/** The link a `server` printed after `label: ` (within 10 s of its viewer's links). */
async function printedLink(server, label) {
  const line = new RegExp(`^${label}: (https?://\\S+)$`, 'm');
  const deadline = Date.now() + 10000;
  for (;;) {
    const m = line.exec(server.output());
    if (m) return m[1];
    if (Date.now() > deadline) throw new Error(`the hub printed no "${label}:" link:\n${server.output()}`);
    await new Promise((resolve) => setTimeout(resolve, 50));
  }
}

/**
 * Publishes each heartbeat of station `from` again as the heartbeat of each of `names`, through
 * the lab's nats-server at `natsUrl`, until `stop()`: to a hub, as many more stations saying
 * what `from` says, once a second.
 */
export async function copyHeartbeats(natsUrl, from, names) {
  const nc = await connect({ servers: natsUrl });
  const sub = nc.subscribe(`softhaptic.stations.${from}`);
  const copying = (async () => {
    for await (const m of sub) {
      const status = JSON.parse(new TextDecoder().decode(m.data));
      for (const name of names) {
        status.name = name;
        nc.publish(`softhaptic.stations.${name}`, new TextEncoder().encode(JSON.stringify(status)));
      }
    }
  })();
  return {
    stop: async () => {
      await nc.drain();
      await copying;
    },
  };
}
