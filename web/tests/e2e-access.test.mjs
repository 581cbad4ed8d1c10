// End to end, access: the real server with tokens (`--tokens`), the real viewer page in headless
// Chromium, under the Content-Security-Policy the server sends.
//
//   npm run test:e2e    (builds the server with cargo; SOFTHAPTIC_BIN to reuse a built one)
//
// Checks: the server prints an instructor's and an observer's link, each with its own token and
// the role it is for in the fragment; the page opened from the instructor's link takes the token
// off the address bar, keeps it for a reload, shows the role, loads the scene and draws a press
// exactly as the profile says; opened without the fragment it shows the prompt, and the
// observer's link pasted there connects as an observer; a link whose token the server does not
// know says it is not valid here (or from an earlier start), and the right token then opened in
// the same tab as a link without the role (only the fragment changes) connects; Chromium reports
// no CSP violation on any of these pages.
import { after, before, test } from 'node:test';
import assert from 'node:assert/strict';

import { launchBrowser } from './browser.mjs';
import { assertPressBendsMesh, freezeOnPress, watchCsp } from './e2e-checks.mjs';
import { startServer } from './server.mjs';

const SERVER_ARGS = ['--no-realtime', '--no-record', '--tokens'];
/** The token of a printed link, and the role the link names after it. */
const TOKEN_IN_LINK = /#token=([0-9a-f]{32})&role=(instructor|observer)$/;
const WAIT = { timeout: 30000 };

let server;
let browser;
/**
 * Every page opened, with its CSP watch and its page errors; once its test is done with it
 * (`done`), its address and the CSP violations it reported.
 */
const opened = [];

/** A page in a context of its own (its own sessionStorage), watched for CSP violations. */
async function openPage() {
  const context = await browser.newContext({ viewport: { width: 1280, height: 800 } });
  const page = await context.newPage();
  const errors = [];
  page.on('pageerror', (e) => errors.push(e.message));
  const csp = await watchCsp(page);
  opened.push({ page, csp, errors });
  return page;
}

/**
 * The test is done with `page`: its address and CSP violations are kept for the last test, and
 * its context is closed, so that its drawing (WebGL on SwiftShader, every frame) does not slow
 * the pages the next tests open.
 */
async function done(page) {
  const entry = opened.find((o) => o.page === page);
  entry.url = page.url();
  entry.violations = await entry.csp.list();
  await page.context().close();
}

const hook = (page, fn, arg) => page.evaluate(fn, arg);

before(async () => {
  // A server of its own, even when SOFTHAPTIC_URL names a running one: it must have tokens.
  server = await startServer({ extraArgs: SERVER_ARGS, external: false });
  browser = await launchBrowser();
});

after(async () => {
  await browser?.close();
  await server?.stop();
});

test('the server prints an instructor’s and an observer’s link, each with its token and role in the fragment', () => {
  assert.match(server.url, TOKEN_IN_LINK, server.url);
  assert.match(server.observerUrl ?? '', TOKEN_IN_LINK, String(server.observerUrl));
  assert.equal(TOKEN_IN_LINK.exec(server.url)[2], 'instructor');
  assert.equal(TOKEN_IN_LINK.exec(server.observerUrl)[2], 'observer');
  assert.notEqual(TOKEN_IN_LINK.exec(server.url)[1], TOKEN_IN_LINK.exec(server.observerUrl)[1]);
  assert.equal(server.observerUrl.split('#')[0], server.baseUrl);
});

test('opened from the instructor’s link the page works, shows the role, and takes the token off the address bar', async () => {
  const page = await openPage();
  const token = TOKEN_IN_LINK.exec(server.url)[1];
  const response = await page.goto(server.url);
  assert.match(response.headers()['content-security-policy'] ?? '', /script-src 'self'/, 'the page is under a CSP');
  await page.waitForFunction(() => window.__softhaptic?.ready(), null, { timeout: 120000 });
  assert.equal(await hook(page, () => window.__softhaptic.role()), 'instructor');
  assert.equal(await hook(page, () => window.__softhaptic.mode()), 'live');
  assert.equal(await page.locator('#role').textContent(), 'instructor');
  assert.equal(await hook(page, () => window.__softhaptic.prompt().shown), false);
  assert.ok(!(await page.locator('#token-prompt').isVisible()));
  // Off the address bar, kept for this tab only.
  assert.equal(page.url(), server.baseUrl);
  assert.equal(await hook(page, () => sessionStorage.getItem('softhaptic.token')), token);
  assert.equal(await hook(page, () => localStorage.length), 0);
  assert.ok(!(await page.content()).includes(token), 'the token is not in the page');

  // The stream: stats, and a press drawn exactly as the profile says.
  await page.waitForFunction(() => window.__softhaptic.lastStats() !== null, null, WAIT);
  await freezeOnPress(page, 2e-3, WAIT);
  await assertPressBendsMesh(page);
  await hook(page, () => window.__softhaptic.pause(false));
  const conn = await hook(page, () => window.__softhaptic.connection());
  assert.equal(conn.state, 'open');
  assert.equal(conn.stats.malformed, 0, conn.lastError ?? '');
  assert.equal(conn.stats.unknown, 0);

  // A reload keeps the session: the token comes from sessionStorage.
  await page.reload();
  await page.waitForFunction(() => window.__softhaptic?.ready(), null, { timeout: 120000 });
  assert.equal(await hook(page, () => window.__softhaptic.role()), 'instructor');
  assert.equal(await hook(page, () => window.__softhaptic.prompt().shown), false);
  await done(page);
});

test('opened without the fragment the page asks for the link, and the observer’s link pasted there connects', async () => {
  const page = await openPage();
  await page.goto(server.baseUrl);
  // The scene's 401 shows the prompt at once, without waiting for the socket's auth timeout.
  await page.waitForFunction(() => window.__softhaptic?.prompt().shown, null, { timeout: 30000 });
  const prompt = await hook(page, () => window.__softhaptic.prompt());
  assert.equal(prompt.reason, 'needs_token');
  assert.ok(await page.locator('#token-prompt').isVisible());
  assert.match(await page.locator('#token-prompt').textContent(), /This session needs the link you were given/);
  assert.equal(await hook(page, () => window.__softhaptic.ready()), false);
  assert.equal(await hook(page, () => window.__softhaptic.role()), null);
  assert.notEqual(await hook(page, () => window.__softhaptic.connection().state), 'open');

  // Something that is not a link stays in the field, and says why.
  await page.fill('#token-input', 'not a link');
  await page.click('#token-connect');
  assert.match(await page.locator('#token-prompt-note').textContent(), /neither a link nor a token/);

  await page.fill('#token-input', server.observerUrl);
  await page.click('#token-connect');
  await page.waitForFunction(() => window.__softhaptic.role() === 'observer', null, WAIT);
  await page.waitForFunction(() => window.__softhaptic.ready(), null, { timeout: 120000 });
  assert.equal(await page.locator('#role').textContent(), 'observer');
  assert.equal(await hook(page, () => window.__softhaptic.prompt().shown), false);
  assert.ok(!(await page.locator('#token-prompt').isVisible()));
  assert.equal(await page.inputValue('#token-input'), '', 'the pasted link does not stay in the page');
  await page.waitForFunction(() => window.__softhaptic.contactFrames() > 10, null, WAIT);
  // An observer of a live session has no replay panel.
  assert.ok(!(await page.locator('#replay-panel').isVisible()));
  await done(page);
});

test('a link whose token this server does not know says so and is not kept; the right one opened in the tab is taken', async () => {
  const page = await openPage();
  await page.goto(`${server.baseUrl}#token=${'0'.repeat(32)}`);
  await page.waitForFunction(() => window.__softhaptic?.prompt().shown, null, { timeout: 30000 });
  const prompt = await hook(page, () => window.__softhaptic.prompt());
  assert.equal(prompt.reason, 'token_refused');
  assert.match(
    prompt.detail,
    /^This link is not valid for this server\. .*a link from an earlier start no longer works/,
  );
  assert.equal(page.url(), server.baseUrl);
  assert.equal(await hook(page, () => sessionStorage.getItem('softhaptic.token')), null);
  assert.equal(await hook(page, () => window.__softhaptic.hasToken()), false);
  assert.match(await page.locator('#conn-state').textContent(), /token refused/);

  // The right link opened in the same tab changes only the fragment (no reload): it is taken.
  const token = TOKEN_IN_LINK.exec(server.url)[1];
  await page.evaluate((t) => {
    window.location.hash = `#token=${t}`;
  }, token);
  await page.waitForFunction(() => window.__softhaptic.role() === 'instructor', null, WAIT);
  await page.waitForFunction(() => window.__softhaptic.ready(), null, { timeout: 120000 });
  assert.equal(page.url(), server.baseUrl, 'taken off the address bar again');
  assert.equal(await hook(page, () => window.__softhaptic.prompt().shown), false);
  assert.equal(await hook(page, () => sessionStorage.getItem('softhaptic.token')), token);
  await done(page);
});

test('an observer’s token in a link that names the instructor says this is an observer link', async () => {
  const page = await openPage();
  const observer = TOKEN_IN_LINK.exec(server.observerUrl)[1];
  await page.goto(`${server.baseUrl}#token=${observer}&role=instructor`);
  await page.waitForFunction(() => window.__softhaptic?.role() === 'observer', null, { timeout: 120000 });
  await page.waitForFunction(() => window.__softhaptic.prompt().shown, null, WAIT);
  const prompt = await hook(page, () => window.__softhaptic.prompt());
  assert.equal(prompt.reason, 'wrong_role');
  assert.match(prompt.detail, /^This is an observer link: .*read-only/);
  // The instructor's link pasted there: greeted as the instructor, the prompt goes.
  await page.fill('#token-input', server.url);
  await page.click('#token-connect');
  await page.waitForFunction(() => window.__softhaptic.role() === 'instructor', null, WAIT);
  await page.waitForFunction(() => !window.__softhaptic.prompt().shown, null, WAIT);
  await done(page);
});

test('after the server restarts, the link this tab was greeted with is said to have expired', async () => {
  const page = await openPage();
  await page.goto(server.url);
  await page.waitForFunction(() => window.__softhaptic?.role() === 'instructor', null, { timeout: 120000 });
  const addr = new URL(server.baseUrl).host;
  await server.stop();
  // The same address, new tokens: the tab reconnects with its old one and is refused.
  server = await startServer({ extraArgs: SERVER_ARGS, external: false, addr });
  await page.waitForFunction(() => window.__softhaptic.prompt().shown, null, { timeout: 60000 });
  const prompt = await hook(page, () => window.__softhaptic.prompt());
  assert.equal(prompt.reason, 'token_expired');
  assert.match(prompt.detail, /^This instructor link has expired: it worked in this tab until the server restarted/);
  assert.equal(await hook(page, () => window.__softhaptic.hasToken()), false);
  await done(page);
});

test('Chromium reports no CSP violation and no page error on any of the pages', async () => {
  assert.ok(opened.length >= 3);
  // A page whose test failed before it was done is still open: read it now.
  for (const { page, csp, errors, url = page.url(), violations } of opened) {
    assert.deepEqual(violations ?? (await csp.list()), [], url);
    assert.deepEqual(errors, [], url);
  }
});
