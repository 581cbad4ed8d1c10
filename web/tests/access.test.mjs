// The viewer's token: read from the page's fragment (with and without `token=`, empty, junk, with
// and without the link's role hint), from what someone pastes into the prompt, kept in
// sessionStorage and off the address bar; a refused token said to have expired only when this tab
// was greeted with it; a link granted another role than it names said to be so; the prompt driven
// through stand-ins of its field and button.
import { test } from 'node:test';
import assert from 'node:assert/strict';

import {
  AccessPrompt,
  GREETED_STORAGE_KEY,
  PROMPT_DETAILS,
  ROLE_STORAGE_KEY,
  TOKEN_STORAGE_KEY,
  TokenKeeper,
  isToken,
  promptDetail,
  roleNotice,
  storageOrNull,
  tokenFromFragment,
  tokenFromInput,
} from '../src/access.js';

/** A token as the server prints it: 128 bits in hex. */
const TOKEN = '0123456789abcdef0123456789abcdef';
const OTHER = 'fedcba9876543210fedcba9876543210';

test('a fragment with token= gives its token, among other pairs and percent-encoded', () => {
  assert.deepEqual(tokenFromFragment(`#token=${TOKEN}`), { token: TOKEN, holdsToken: true, role: null });
  assert.deepEqual(
    tokenFromFragment(`token=${TOKEN}`),
    { token: TOKEN, holdsToken: true, role: null },
    'without the #',
  );
  assert.deepEqual(tokenFromFragment(`#view=top&token=${TOKEN}&x=1`), { token: TOKEN, holdsToken: true, role: null });
  // A lab's own token may be base64 (RFC 6750 b64token): `+`, `/` and `=` padding survive.
  assert.equal(tokenFromFragment('#token=ab%2Bcd/ef%3D%3D').token, 'ab+cd/ef==');
  assert.equal(tokenFromFragment('#token=ab+cd/ef==').token, 'ab+cd/ef==');
});

test('a bare fragment is a token only when it looks like one the server prints', () => {
  assert.deepEqual(tokenFromFragment(`#${TOKEN}`), { token: TOKEN, holdsToken: true, role: null });
  assert.deepEqual(tokenFromFragment(`#${TOKEN.toUpperCase()}`), {
    token: TOKEN.toUpperCase(),
    holdsToken: true,
    role: null,
  });
  // A page anchor or a short hex word is not a token, and stays in the address bar.
  for (const hash of ['#replay-panel', '#deadbeef', `#${TOKEN.slice(1)}`, `#${TOKEN}g`, '#token']) {
    assert.deepEqual(tokenFromFragment(hash), { token: null, holdsToken: false, role: null }, hash);
  }
});

test('an empty fragment has no token; a junk token= is no token but still leaves the address bar', () => {
  for (const hash of ['', '#', undefined, null]) {
    assert.deepEqual(tokenFromFragment(hash), { token: null, holdsToken: false, role: null }, String(hash));
  }
  for (const hash of ['#token=', '#token=has space', '#token=%E0%A4%A', '#token=<script>', '#token=a"b', '#token=é']) {
    assert.deepEqual(tokenFromFragment(hash), { token: null, holdsToken: true, role: null }, hash);
  }
  assert.deepEqual(tokenFromFragment('#view=top&x=1'), { token: null, holdsToken: false, role: null });
  assert.equal(isToken('x'.repeat(1024)), true);
  assert.equal(isToken('x'.repeat(1025)), false, 'a bounded length');
  assert.equal(isToken(''), false);
  assert.equal(isToken(null), false);
});

test('the prompt takes a whole link (whatever its host), a fragment or a bare token', () => {
  for (const input of [
    `http://127.0.0.1:8080/#token=${TOKEN}`,
    `  https://lab-pc.example:8443/?x=1#token=${TOKEN}\n`,
    `http://10.0.0.5:8080/#${TOKEN}`,
    `#token=${TOKEN}`,
    `token=${TOKEN}`,
    TOKEN,
  ]) {
    assert.deepEqual(tokenFromInput(input), { token: TOKEN, role: null, error: null }, input);
  }
  // Any well-formed token pasted alone is tried: the server says whether it takes it.
  assert.deepEqual(tokenFromInput('bGFiLXRva2Vu'), { token: 'bGFiLXRva2Vu', role: null, error: null });
});

test('the prompt says what is wrong with what was pasted, without repeating it', () => {
  const cases = [
    ['', /paste the link/],
    ['   ', /paste the link/],
    ['http://127.0.0.1:8080/', /holds no token/],
    ['http://127.0.0.1:8080/#replay-panel', /holds no token/],
    ['http://127.0.0.1:8080/#token=', /not well formed/],
    ['token=not a token', /not well formed/],
    ['my secret words', /neither a link nor a token/],
  ];
  for (const [input, pattern] of cases) {
    const { token, error } = tokenFromInput(input);
    assert.equal(token, null, input);
    assert.match(error, pattern, input);
    if (input.trim()) assert.ok(!error.includes(input.trim()), `"${error}" repeats the input`);
  }
});

/** sessionStorage as the browser gives it (or one that throws, as when storage is disabled). */
class FakeStorage {
  constructor({ throws = false } = {}) {
    this.items = new Map();
    this.throws = throws;
  }
  getItem(key) {
    if (this.throws) throw new Error('storage disabled');
    return this.items.has(key) ? this.items.get(key) : null;
  }
  setItem(key, value) {
    if (this.throws) throw new Error('storage disabled');
    this.items.set(key, String(value));
  }
  removeItem(key) {
    if (this.throws) throw new Error('storage disabled');
    this.items.delete(key);
  }
}

/** `location` and `history` of a page at `hash`; `replaceState` rewrites the location. */
function page(hash, { pathname = '/', search = '' } = {}) {
  const location = { hash, pathname, search };
  const calls = [];
  const history = {
    state: { kept: true },
    replaceState(state, title, url) {
      calls.push({ state, url });
      const at = url.indexOf('#');
      location.hash = at < 0 ? '' : url.slice(at);
    },
  };
  return { location, history, calls };
}

test('a token in the fragment is kept in memory and sessionStorage and leaves the address bar', () => {
  const storage = new FakeStorage();
  const keeper = new TokenKeeper({ storage });
  const { location, history, calls } = page(`#token=${TOKEN}`, { pathname: '/', search: '?scene=liver' });
  assert.equal(keeper.adopt(location, history), 'fragment');
  assert.equal(keeper.token, TOKEN);
  assert.equal(storage.getItem(TOKEN_STORAGE_KEY), TOKEN);
  assert.deepEqual(calls, [{ state: { kept: true }, url: '/?scene=liver' }], 'no fragment left, query kept');
  assert.equal(location.hash, '');
});

test('after a reload without a fragment the kept token is used; a fragment wins over it', () => {
  const storage = new FakeStorage();
  storage.setItem(TOKEN_STORAGE_KEY, OTHER);
  const reload = page('');
  const keeper = new TokenKeeper({ storage });
  assert.equal(keeper.adopt(reload.location, reload.history), 'storage');
  assert.equal(keeper.token, OTHER);
  assert.deepEqual(reload.calls, [], 'nothing to remove from the address bar');

  const fresh = page(`#${TOKEN}`);
  const second = new TokenKeeper({ storage });
  assert.equal(second.adopt(fresh.location, fresh.history), 'fragment');
  assert.equal(second.token, TOKEN);
  assert.equal(storage.getItem(TOKEN_STORAGE_KEY), TOKEN);
});

test('no token anywhere, a junk token= removed, an anchor left alone; a refused token is forgotten', () => {
  const storage = new FakeStorage();
  const none = page('');
  const keeper = new TokenKeeper({ storage });
  assert.equal(keeper.adopt(none.location, none.history), null);
  assert.equal(keeper.token, null);

  const junk = page('#token=not%20a%20token');
  assert.equal(new TokenKeeper({ storage }).adopt(junk.location, junk.history), null);
  assert.equal(junk.calls.length, 1, 'a token=, even a junk one, does not stay in the address bar');

  const anchor = page('#replay-panel');
  assert.equal(new TokenKeeper({ storage }).adopt(anchor.location, anchor.history), null);
  assert.equal(anchor.calls.length, 0);

  // A kept value that is not a token (written by something else) is not presented.
  storage.setItem(TOKEN_STORAGE_KEY, 'not a token');
  assert.equal(new TokenKeeper({ storage }).adopt(none.location, none.history), null);

  keeper.set(TOKEN);
  keeper.forget();
  assert.equal(keeper.token, null);
  assert.equal(storage.getItem(TOKEN_STORAGE_KEY), null);
});

test('a new link opened in the same tab replaces the token; a fragment without one keeps it', () => {
  const keeper = new TokenKeeper({ storage: new FakeStorage() });
  const p = page(`#token=${TOKEN}`);
  keeper.adopt(p.location, p.history);
  p.location.hash = `#token=${OTHER}`;
  assert.equal(keeper.takeFragment(p.location, p.history), OTHER);
  assert.equal(keeper.token, OTHER);
  p.location.hash = '#replay-panel';
  assert.equal(keeper.takeFragment(p.location, p.history), null);
  assert.equal(keeper.token, OTHER);
});

test('without a working sessionStorage the token is still used, only not kept for a reload', () => {
  for (const storage of [null, new FakeStorage({ throws: true })]) {
    const keeper = new TokenKeeper({ storage });
    const p = page(`#token=${TOKEN}`);
    assert.equal(keeper.adopt(p.location, p.history), 'fragment');
    assert.equal(keeper.token, TOKEN);
    assert.equal(p.location.hash, '');
    keeper.forget();
    assert.equal(keeper.token, null);
  }
});

/** Just enough of the prompt's elements. */
class FakeElement {
  constructor(props = {}) {
    this.listeners = {};
    this.hidden = false;
    this.textContent = '';
    this.value = '';
    this.focused = 0;
    Object.assign(this, props);
  }
  addEventListener(type, fn) {
    (this.listeners[type] ??= []).push(fn);
  }
  fire(type, event = {}) {
    let prevented = false;
    for (const fn of this.listeners[type] ?? []) fn({ type, preventDefault: () => (prevented = true), ...event });
    return prevented;
  }
  focus() {
    this.focused++;
  }
}

function prompt() {
  const tokens = [];
  const el = {
    panel: new FakeElement({ hidden: true }),
    detail: new FakeElement(),
    input: new FakeElement(),
    button: new FakeElement(),
    note: new FakeElement(),
  };
  const roles = [];
  const p = new AccessPrompt({
    ...el,
    onToken: (t, role) => {
      tokens.push(t);
      roles.push(role);
    },
  });
  return { p, el, tokens, roles };
}

test('the prompt says why it asks, and hands over a pasted link’s token on a click or Enter', () => {
  const { p, el, tokens } = prompt();
  assert.equal(p.shown, false);
  p.show('needs_token');
  assert.equal(el.panel.hidden, false);
  assert.equal(p.reason, 'needs_token');
  assert.equal(el.detail.textContent, PROMPT_DETAILS.needs_token);
  assert.equal(el.input.focused, 1);

  el.input.value = `http://127.0.0.1:8080/#token=${TOKEN}`;
  el.button.fire('click');
  assert.deepEqual(tokens, [TOKEN]);
  assert.equal(el.input.value, '', 'the token does not stay in the page');
  assert.equal(el.note.textContent, 'connecting…');

  // The server refused it: the prompt says so, and why a link stops working.
  p.show('token_refused');
  assert.match(el.detail.textContent, /^This link is not valid for this server\. .*each time it starts/);
  assert.equal(el.note.textContent, '');

  el.input.value = OTHER;
  assert.equal(el.input.fire('keydown', { key: 'a' }), false);
  assert.deepEqual(tokens, [TOKEN], 'only Enter submits');
  assert.equal(el.input.fire('keydown', { key: 'Enter' }), true);
  assert.deepEqual(tokens, [TOKEN, OTHER]);

  p.hide();
  assert.equal(el.panel.hidden, true);
  assert.equal(p.shown, false);
  assert.equal(p.reason, null);
});

test('the prompt keeps what cannot be a token out of the connection and says why', () => {
  const { p, el, tokens } = prompt();
  p.show('needs_token');
  el.input.value = 'http://127.0.0.1:8080/';
  el.button.fire('click');
  assert.deepEqual(tokens, []);
  assert.match(el.note.textContent, /holds no token/);
  assert.equal(el.input.value, 'http://127.0.0.1:8080/', 'left to correct');
});

test('a link’s role hint comes with its token; without a valid token, or naming no role, there is none', () => {
  assert.deepEqual(tokenFromFragment(`#token=${TOKEN}&role=observer`), {
    token: TOKEN,
    holdsToken: true,
    role: 'observer',
  });
  assert.deepEqual(tokenFromFragment(`#role=instructor&token=${TOKEN}`), {
    token: TOKEN,
    holdsToken: true,
    role: 'instructor',
  });
  // An old link, a bare token: no hint, and the token works as before.
  assert.deepEqual(tokenFromFragment(`#token=${TOKEN}`), { token: TOKEN, holdsToken: true, role: null });
  assert.deepEqual(tokenFromFragment(`#${TOKEN}`), { token: TOKEN, holdsToken: true, role: null });
  for (const hint of ['admin', 'Observer', '', 'observer%00', 'instructor&role=observer']) {
    assert.equal(
      tokenFromFragment(`#token=${TOKEN}&role=${hint}`).role,
      hint.startsWith('instructor&') ? 'instructor' : null,
      hint,
    );
  }
  // The first of a repeated key counts, for the token as for the hint.
  assert.deepEqual(tokenFromFragment(`#token=${TOKEN}&token=${OTHER}&role=observer&role=instructor`), {
    token: TOKEN,
    holdsToken: true,
    role: 'observer',
  });
  // A hint alone is no token, and a junk token carries no hint.
  assert.deepEqual(tokenFromFragment('#role=instructor'), { token: null, holdsToken: false, role: null });
  assert.deepEqual(tokenFromFragment('#token=bad%20one&role=instructor'), {
    token: null,
    holdsToken: true,
    role: null,
  });
  // Pasted: the link's hint comes along; a bare token has none.
  assert.deepEqual(tokenFromInput(`https://lab:8443/#token=${TOKEN}&role=observer`), {
    token: TOKEN,
    role: 'observer',
    error: null,
  });
  assert.deepEqual(tokenFromInput(TOKEN), { token: TOKEN, role: null, error: null });
});

test('a link granted another role than it names says so; agreeing or unhinted ones say nothing', () => {
  assert.match(
    roleNotice('instructor', 'observer'),
    /^This is an observer link: .*read-only.*paste the instructor’s link/,
  );
  assert.match(roleNotice('observer', 'instructor'), /^This is an instructor link: .*control the replay/);
  // Another page says what its instructor's link does there, and so does its keeper.
  assert.match(roleNotice('instructor', 'observer', 'act on the stations'), /To act on the stations, paste/);
  const keeper = new TokenKeeper({ powers: 'act on the stations' });
  keeper.set(TOKEN, 'observer');
  assert.match(keeper.greeted('instructor'), /lets it act on the stations, though/);
  for (const [hint, granted] of [
    ['instructor', 'instructor'],
    ['observer', 'observer'],
    [null, 'observer'],
    [null, 'instructor'],
    ['observer', null],
    ['admin', 'observer'],
  ]) {
    assert.equal(roleNotice(hint, granted), null, `${hint} → ${granted}`);
  }
});

test('the keeper keeps the link’s role with its token, across a reload and the same token handed on again', () => {
  const storage = new FakeStorage();
  const keeper = new TokenKeeper({ storage });
  const p = page(`#token=${TOKEN}&role=instructor`);
  assert.equal(keeper.adopt(p.location, p.history), 'fragment');
  assert.deepEqual([keeper.token, keeper.role, keeper.wasGreeted], [TOKEN, 'instructor', false]);
  assert.equal(p.location.hash, '', 'the hint leaves the address bar with the token');
  assert.equal(storage.getItem(ROLE_STORAGE_KEY), 'instructor');
  // The page hands a link's token on without its role: what is known of it stays.
  keeper.set(TOKEN);
  assert.equal(keeper.role, 'instructor');
  assert.equal(keeper.greeted('instructor'), null);
  assert.equal(storage.getItem(GREETED_STORAGE_KEY), '1');

  const reload = new TokenKeeper({ storage });
  assert.equal(reload.adopt(page('').location, page('').history), 'storage');
  assert.deepEqual([reload.token, reload.role, reload.wasGreeted], [TOKEN, 'instructor', true]);

  // Another token starts afresh: its own hint or none, not greeted yet.
  reload.set(OTHER);
  assert.deepEqual([reload.role, reload.wasGreeted], [null, false]);
  assert.equal(storage.getItem(ROLE_STORAGE_KEY), null);
  assert.equal(storage.getItem(GREETED_STORAGE_KEY), null);
  reload.set(TOKEN, 'observer');
  assert.equal(reload.role, 'observer');
  // A hint in storage that names no role is none.
  storage.setItem(ROLE_STORAGE_KEY, 'admin');
  const odd = new TokenKeeper({ storage });
  odd.adopt(page('').location, page('').history);
  assert.equal(odd.role, null);
});

test('a refused token is called expired only when this tab was greeted with it before', () => {
  const storage = new FakeStorage();
  const keeper = new TokenKeeper({ storage });
  keeper.set(TOKEN, 'observer');
  // Never greeted: not valid here, or from an earlier start than this tab knows.
  assert.equal(keeper.refusal(), 'token_refused');
  assert.equal(keeper.greeted('observer'), null);
  // Greeted, then refused: the server has restarted with new tokens since.
  assert.equal(keeper.refusal(), 'token_expired');
  keeper.forget();
  assert.deepEqual([keeper.token, keeper.role, keeper.wasGreeted], [null, null, false]);
  for (const key of [TOKEN_STORAGE_KEY, ROLE_STORAGE_KEY, GREETED_STORAGE_KEY])
    assert.equal(storage.getItem(key), null, key);
  // Greeted without a token (a server without tokens): nothing to expire.
  assert.equal(keeper.greeted('instructor'), null);
  assert.equal(keeper.refusal(), 'token_refused');
});

test('the prompt says expired, not valid, or wrong role precisely, naming the link’s role when known', () => {
  assert.equal(promptDetail('needs_token'), PROMPT_DETAILS.needs_token);
  assert.match(
    promptDetail('token_refused'),
    /^This link is not valid for this server\. .*earlier start no longer works/,
  );
  assert.match(promptDetail('token_refused', 'observer'), /^This observer link is not valid for this server\./);
  assert.match(
    promptDetail('token_expired'),
    /^This link has expired: it worked in this tab until the server restarted/,
  );
  assert.match(promptDetail('token_expired', 'instructor'), /^This instructor link has expired/);
  assert.equal(promptDetail('token_refused', 'admin'), promptDetail('token_refused'));
  for (const reason of ['needs_token', 'token_refused', 'token_expired']) {
    assert.ok(!promptDetail(reason).includes('{link}'), reason);
  }

  const { p, el, tokens, roles } = prompt();
  p.show('token_expired', { linkRole: 'instructor' });
  assert.equal(p.reason, 'token_expired');
  assert.match(el.detail.textContent, /^This instructor link has expired/);
  // Greeted as the link's role: the prompt goes.
  p.greeted(null);
  assert.equal(p.shown, false);
  assert.equal(el.panel.hidden, true);
  // Greeted as another: it stays to say so, and takes the right link with its hint.
  const notice = roleNotice('instructor', 'observer');
  p.greeted(notice);
  assert.equal(p.shown, true);
  assert.equal(p.reason, 'wrong_role');
  assert.equal(el.detail.textContent, notice);
  el.input.value = `http://127.0.0.1:8080/#token=${OTHER}&role=instructor`;
  el.button.fire('click');
  assert.deepEqual(tokens, [OTHER]);
  assert.deepEqual(roles, ['instructor']);
});

test('a browser storage that throws when reached is no storage', () => {
  const storage = new FakeStorage();
  assert.equal(
    storageOrNull(() => storage),
    storage,
  );
  assert.equal(
    storageOrNull(() => undefined),
    null,
  );
  assert.equal(
    storageOrNull(() => {
      throw new Error('SecurityError: storage is disabled');
    }),
    null,
  );
});
