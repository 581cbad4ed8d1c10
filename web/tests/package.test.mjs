// The Debian package as an operator gets it (docs/install.md): unpacked with `dpkg-deb -x` into
// an empty directory outside the source tree, its binary run from another empty directory with
// the station unit's own command line and settings (the unit's paths moved under the unpacked
// root), with no source tree and no node_modules in reach:
// - the files it holds are the ones docs/install.md promises, no more, no fewer; its settings
//   are conffiles; its postinst makes the user from the sysusers file it installs;
// - the page and every module it imports answer 200 with the right type, over the TLS the
//   station's settings ask for, trusting only the certificate the station made;
// - in Chromium, the liver is drawn, a press bends it and contact frames keep arriving;
// - the tokens the postinst's recipe makes are accepted, the recording goes to the unit's
//   state directory and nothing is written where the binary was started;
// - systemd accepts both units (`systemd-analyze verify`, where installed), and the hub's
//   command line is one the binary accepts.
//
//   make test-package     (builds the package from the debug binary and runs this file)
//
// SOFTHAPTIC_DEB names the package; without it the test fails, saying how to make one.
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';
import { execFileSync, spawn, spawnSync } from 'node:child_process';
import {
  existsSync,
  mkdirSync,
  mkdtempSync,
  readFileSync,
  readdirSync,
  rmSync,
  statSync,
  writeFileSync,
} from 'node:fs';
import https from 'node:https';
import os from 'node:os';
import path from 'node:path';
import { gunzipSync } from 'node:zlib';

import { launchBrowser } from './browser.mjs';
import { freezeOnPress } from './e2e-checks.mjs';
import { REPO, stopProcess } from './server.mjs';

const DEB = process.env.SOFTHAPTIC_DEB;
let work; // everything of this test, under the system's temporary directory
let pkg; // the unpacked package
let control; // its control files
let station; // the running station: {child, url, output}
let ca; // the certificate the station made, the only one trusted

/** The unit's directives, continuation lines joined, comments left out. */
function directives(unit) {
  return unit
    .replace(/\\\n/g, ' ')
    .split('\n')
    .map((l) => l.trim())
    .filter((l) => l && !l.startsWith('#') && !l.startsWith('[') && l.includes('='))
    .map((l) => [l.slice(0, l.indexOf('=')), l.slice(l.indexOf('=') + 1).trim()]);
}

/** KEY=VALUE lines of an EnvironmentFile. */
function environmentFile(text) {
  return Object.fromEntries(
    text
      .split('\n')
      .map((l) => l.trim())
      .filter((l) => l && !l.startsWith('#'))
      .map((l) => [l.slice(0, l.indexOf('=')), l.slice(l.indexOf('=') + 1)]),
  );
}

/**
 * An ExecStart= as systemd expands it (systemd.service(5)): `${VAR}` is one word, `$VAR` is
 * split at white space (and vanishes when empty).
 */
function expand(exec, env) {
  return exec.split(/\s+/).flatMap((word) => {
    const whole = /^\$\{(\w+)\}$/.exec(word);
    if (whole) return [env[whole[1]] ?? ''];
    const split = /^\$(\w+)$/.exec(word);
    if (split) return (env[split[1]] ?? '').split(/\s+/).filter(Boolean);
    return [word];
  });
}

/** The unit's paths moved under the unpacked root. */
function rooted(arg) {
  for (const prefix of ['/usr/bin/', '/etc/softhaptic', '/var/lib/softhaptic']) {
    if (arg.startsWith(prefix)) return path.join(pkg, arg);
  }
  return arg;
}

/** GET over https trusting only `ca`: `{status, type, body}`. */
function get(url) {
  return new Promise((resolve, reject) => {
    https
      .get(url, { ca }, (res) => {
        const chunks = [];
        res.on('data', (c) => chunks.push(c));
        res.on('end', () =>
          resolve({ status: res.statusCode, type: res.headers['content-type'], body: Buffer.concat(chunks) }),
        );
      })
      .on('error', reject);
  });
}

/** The modules a module imports: `import … from`, `export … from`, `import '…'`, `import('…')`. */
function imports(js) {
  const patterns = [
    /(?:^|;)\s*(?:import|export)\s[^;'"]*?\bfrom\s*(['"])([^'"\n]+)\1/gm,
    /(?:^|;)\s*import\s*(['"])([^'"\n]+)\1/gm,
    /\bimport\(\s*(['"])([^'"\n]+)\1\s*\)/g,
  ];
  return patterns.flatMap((p) => [...js.matchAll(p)].map((m) => m[2]));
}

function resolve(spec, base, map) {
  if (map[spec]) return map[spec];
  const prefix = Object.keys(map)
    .filter((k) => k.endsWith('/') && spec.startsWith(k))
    .sort((a, b) => b.length - a.length)[0];
  if (prefix) return map[prefix] + spec.slice(prefix.length);
  return new URL(spec, `https://x${base}`).pathname;
}

before(async () => {
  assert.ok(
    DEB && existsSync(DEB),
    `SOFTHAPTIC_DEB must name the package (got ${JSON.stringify(DEB)}): run \`make test-package\`, which makes it`,
  );
  work = mkdtempSync(path.join(os.tmpdir(), 'softhaptic-package-'));
  assert.ok(!work.startsWith(REPO), 'the test runs outside the source tree');
  pkg = path.join(work, 'root');
  control = path.join(work, 'control');
  execFileSync('dpkg-deb', ['-x', DEB, pkg]);
  execFileSync('dpkg-deb', ['-e', DEB, control]);
});

after(async () => {
  if (station) await stopProcess(station.child);
  if (work) rmSync(work, { recursive: true, force: true });
});

test('the package holds exactly the files docs/install.md promises, its settings as conffiles', () => {
  const doc = readFileSync(path.join(REPO, 'docs/install.md'), 'utf8');
  const section = doc.slice(doc.indexOf('## What the package installs'));
  const block = section.slice(section.indexOf('```') + 3, section.indexOf('```', section.indexOf('```') + 3));
  const promised = block
    .split('\n')
    .map((l) => l.trim())
    .filter((l) => l.startsWith('/'));
  assert.ok(promised.length >= 10, `docs/install.md lists ${promised.length} paths`);
  const listing = execFileSync('dpkg-deb', ['-c', DEB], { encoding: 'utf8' });
  const files = listing
    .split('\n')
    .filter((l) => l.startsWith('-'))
    .map((l) => ({ mode: l.split(/\s+/)[0], path: l.slice(l.indexOf('./') + 1) }));
  const pattern = (p) => new RegExp(`^${p.replace(/[.+?^${}()|[\]\\]/g, '\\$&').replace(/\*/g, '[^/]*')}$`);
  for (const p of promised) {
    assert.ok(
      files.some((f) => pattern(p).test(f.path)),
      `docs/install.md promises ${p}; the package has none`,
    );
  }
  for (const f of files) {
    assert.ok(
      promised.some((p) => pattern(p).test(f.path)),
      `the package holds ${f.path}, which docs/install.md does not list`,
    );
  }
  // Every scene of the source tree, with the tables the scenes name.
  for (const scene of readdirSync(path.join(REPO, 'scenes')).filter((f) => f.endsWith('.toml'))) {
    assert.ok(
      files.some((f) => f.path === `/usr/share/softhaptic/scenes/${scene}`),
      scene,
    );
  }
  // Every exercise, beside the scenes it names.
  for (const exercise of readdirSync(path.join(REPO, 'exercises')).filter((f) => f.endsWith('.toml'))) {
    assert.ok(
      files.some((f) => f.path === `/usr/share/softhaptic/exercises/${exercise}`),
      exercise,
    );
  }
  const bin = files.find((f) => f.path === '/usr/bin/softhaptic');
  assert.equal(bin.mode, '-rwxr-xr-x');
  assert.deepEqual(readFileSync(path.join(control, 'conffiles'), 'utf8').trim().split('\n').sort(), [
    '/etc/softhaptic/hub.conf',
    '/etc/softhaptic/station.conf',
  ]);
  // The user is made from the sysusers file the package installs, by its installed name.
  const postinst = readFileSync(path.join(control, 'postinst'), 'utf8');
  const sysusers = /^\s*systemd-sysusers .* (\S+)$/m.exec(postinst);
  assert.ok(sysusers, postinst);
  assert.ok(existsSync(path.join(pkg, 'usr/lib/sysusers.d', sysusers[1])), sysusers[1]);
  assert.match(readFileSync(path.join(pkg, 'usr/lib/sysusers.d', sysusers[1]), 'utf8'), /^u softhaptic /m);
  assert.match(postinst, /systemd-tmpfiles --create softhaptic\.conf/);
  // The manual pages and completions are the binary's own.
  const man = gunzipSync(readFileSync(path.join(pkg, 'usr/share/man/man1/softhaptic-run.1.gz'))).toString();
  assert.match(man, /^\.TH softhaptic-run 1/m);
  assert.match(man, /\\-\\-web\\-dir/);
  assert.match(
    readFileSync(path.join(pkg, 'usr/share/bash-completion/completions/softhaptic'), 'utf8'),
    /_softhaptic\(\)/,
  );
});

test("the station unit's command line serves the page and every module it imports from the package alone", async (t) => {
  const unit = readFileSync(path.join(pkg, 'usr/lib/systemd/system/softhaptic-station.service'), 'utf8');
  const d = directives(unit);
  const envFile = d.find(([k]) => k === 'EnvironmentFile')[1];
  const env = environmentFile(readFileSync(path.join(pkg, envFile), 'utf8'));
  // A free port on loopback instead of every address.
  env.SOFTHAPTIC_ADDR = '127.0.0.1:0';
  const [bin, ...args] = expand(d.find(([k]) => k === 'ExecStart')[1], env).map(rooted);
  assert.equal(bin, path.join(pkg, 'usr/bin/softhaptic'));
  // The directories and the tokens the postinst makes, with the postinst's own token recipe.
  const postinst = readFileSync(path.join(control, 'postinst'), 'utf8');
  const recipe = /^\s*(token\(\) \{.*\})\s*$/m.exec(postinst);
  assert.ok(recipe, 'the postinst makes the tokens with a token() function');
  mkdirSync(path.join(pkg, 'etc/softhaptic/tls'), { recursive: true, mode: 0o700 });
  mkdirSync(path.join(pkg, 'var/lib/softhaptic/sessions'), { recursive: true });
  const tokens = spawnSync('sh', ['-c', `${recipe[1]}; echo "instructor = $(token)"; echo "observer = $(token)"`], {
    encoding: 'utf8',
  });
  assert.equal(tokens.status, 0, tokens.stderr);
  writeFileSync(path.join(pkg, 'etc/softhaptic/tokens'), tokens.stdout, { mode: 0o600 });

  const cwd = path.join(work, 'cwd');
  mkdirSync(cwd);
  const child = spawn(bin, [...args, '--no-realtime'], {
    cwd,
    // Nothing of the developer's environment: no HOME with a data directory, no token variables.
    env: { PATH: '/usr/bin:/bin', HOME: path.join(work, 'home') },
    stdio: ['ignore', 'pipe', 'pipe'],
  });
  let output = '';
  const url = await new Promise((ok, fail) => {
    const timer = setTimeout(() => fail(new Error(`the station printed no link within 120 s:\n${output}`)), 120000);
    const onData = (chunk) => {
      output += chunk.toString();
      const m = /\bviewer: (https:\/\/\S+)/.exec(output);
      if (m) {
        clearTimeout(timer);
        ok(m[1]);
      }
    };
    child.stdout.on('data', onData);
    child.stderr.on('data', onData);
    child.on('exit', (code) => fail(new Error(`the station exited (${code}) before its link:\n${output}`)));
  });
  station = { child, url };
  // Found where the package installs it, from a directory with no scenes/.
  assert.match(output, new RegExp(`scene=${path.join(pkg, 'usr/share/softhaptic/scenes/default.toml')}`));
  ca = readFileSync(path.join(pkg, 'etc/softhaptic/tls/self-signed-cert.pem'));
  assert.equal(statSync(path.join(pkg, 'etc/softhaptic/tls/self-signed-key.pem')).mode & 0o777, 0o600);

  const base = new URL(url).origin;
  const page = await get(`${base}/`);
  assert.equal(page.status, 200);
  assert.equal(page.type, 'text/html; charset=utf-8');
  const html = page.body.toString();
  const map = JSON.parse(/<script type="importmap">([\s\S]*?)<\/script>/.exec(html)[1]).imports;
  const queue = [...html.matchAll(/\b(?:src|href)="(\/[^"]+)"/g)].map((m) => m[1]);
  const seen = new Set();
  while (queue.length) {
    const p = queue.pop();
    if (seen.has(p)) continue;
    seen.add(p);
    const answer = await get(`${base}${p}`);
    assert.equal(answer.status, 200, p);
    const type = p.endsWith('.css') ? 'text/css' : 'text/javascript';
    assert.equal(answer.type, `${type}; charset=utf-8`, p);
    if (type === 'text/javascript') for (const s of imports(answer.body.toString())) queue.push(resolve(s, p, map));
  }
  for (const must of ['/src/main.js', '/vendor/three/three.module.js', '/vendor/three/three.core.js']) {
    assert.ok(seen.has(must), `${must} not reached: ${[...seen].join(', ')}`);
  }
  assert.ok(seen.has('/vendor/three/addons/controls/OrbitControls.js'), [...seen].join(', '));
  t.diagnostic(`the page and ${seen.size} files it loads: 200, with their types`);
});

test('in Chromium the liver is drawn, a press bends it and the frames keep arriving', async () => {
  assert.ok(station, 'the station runs (previous test)');
  const browser = await launchBrowser();
  try {
    const context = await browser.newContext({ viewport: { width: 1280, height: 800 }, ignoreHTTPSErrors: true });
    const page = await context.newPage();
    const errors = [];
    page.on('pageerror', (e) => errors.push(e.message));
    await page.goto(station.url);
    await page.waitForFunction(() => window.__softhaptic?.ready(), null, { timeout: 120000 });
    const info = await page.evaluate(() => ({
      scene: window.__softhaptic.scene(),
      vertices: window.__softhaptic.vertexCount(),
      webgl: window.__softhaptic.webgl(),
      frames: window.__softhaptic.contactFrames(),
      role: window.__softhaptic.role(),
    }));
    assert.equal(info.scene.render_meshes[0].name, 'liver');
    assert.equal(info.vertices, info.scene.render_meshes[0].vertex_count);
    assert.ok(info.vertices > 1000, `${info.vertices} vertices`);
    assert.equal(info.role, 'instructor');
    await page.waitForFunction((n) => window.__softhaptic.contactFrames() >= n + 50, info.frames, {
      timeout: 120000,
    });
    if (info.webgl) {
      await freezeOnPress(page, 1e-3);
      const moved = await page.evaluate(() => window.__softhaptic.movedVertices().length);
      assert.ok(moved > 0, `a press moved ${moved} vertices`);
    }
    assert.deepEqual(errors, []);
  } finally {
    await browser.close();
  }
  await stopProcess(station.child);
  assert.equal(station.child.exitCode, 0, 'the station stops cleanly on SIGTERM');
  station = null;
  // The recording went to the unit's state directory, nothing to the working directory.
  assert.equal(readdirSync(path.join(pkg, 'var/lib/softhaptic/sessions')).filter((f) => f.endsWith('.mcap')).length, 1);
  assert.deepEqual(readdirSync(path.join(work, 'cwd')), []);
});

test('systemd accepts both units, and the hub unit runs a command line the binary accepts', (t) => {
  const bin = path.join(pkg, 'usr/bin/softhaptic');
  const units = path.join(work, 'units');
  mkdirSync(units);
  for (const name of ['softhaptic-station', 'softhaptic-hub']) {
    const unit = readFileSync(path.join(pkg, `usr/lib/systemd/system/${name}.service`), 'utf8');
    const d = directives(unit);
    const env = environmentFile(readFileSync(path.join(pkg, d.find(([k]) => k === 'EnvironmentFile')[1]), 'utf8'));
    const [, ...args] = expand(d.find(([k]) => k === 'ExecStart')[1], env);
    // clap reads the arguments in order and stops at --help: an unknown option fails first.
    const help = spawnSync(bin, [...args, '--help'], { encoding: 'utf8' });
    assert.equal(help.status, 0, `${name}: ${args.join(' ')}: ${help.stderr}`);
    writeFileSync(
      path.join(units, `${name}.service`),
      unit
        .replaceAll('/usr/bin/softhaptic', bin)
        .replaceAll('EnvironmentFile=/etc/softhaptic/', `EnvironmentFile=${path.join(pkg, 'etc/softhaptic')}/`),
    );
  }
  const version = spawnSync('systemd-analyze', ['--version']);
  if (version.error) {
    t.diagnostic('systemd-analyze is not installed: the units were checked by the binary alone');
    return;
  }
  for (const name of ['softhaptic-station', 'softhaptic-hub']) {
    const verify = spawnSync('systemd-analyze', ['verify', '--man=no', path.join(units, `${name}.service`)], {
      encoding: 'utf8',
    });
    assert.equal(verify.status, 0, `${name}: ${verify.stdout}${verify.stderr}`);
    // A warning is an error too: a misspelt directive is only warned about.
    assert.equal(verify.stderr.trim(), '', `${name}: ${verify.stderr}`);
  }
});
