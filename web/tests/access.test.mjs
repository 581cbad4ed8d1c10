// The viewer's token: read from the page's fragment (with and without `token=`, empty, junk),
// from what someone pastes into the prompt, kept in sessionStorage and off the address bar; the
// prompt driven through stand-ins of its field and button.
import { test } from 'node:test';
import assert from 'node:assert/strict';

import {
  AccessPrompt,
  PROMPT_DETAILS,
  TOKEN_STORAGE_KEY,
  TokenKeeper,
  isToken,
  tokenFromFragment,
  tokenFromInput,
} from '../src/access.js';

/** A token as the server prints it: 128 bits in hex. */
const TOKEN = '0123456789abcdef0123456789abcdef';
const OTHER = 'fedcba9876543210fedcba9876543210';

test('a fragment with token= gives its token, among other pairs and percent-encoded', () => {
  assert.deepEqual(tokenFromFragment(`#token=${TOKEN}`), { token: TOKEN, holdsToken: true });
  assert.deepEqual(tokenFromFragment(`token=${TOKEN}`), { token: TOKEN, holdsToken: true }, 'without the #');
  assert.deepEqual(tokenFromFragment(`#view=top&token=${TOKEN}&x=1`), { token: TOKEN, holdsToken: true });
  // A lab's own token may be base64 (RFC 6750 b64token): `+`, `/` and `=` padding survive.
  assert.equal(tokenFromFragment('#token=ab%2Bcd/ef%3D%3D').token, 'ab+cd/ef==');
  assert.equal(tokenFromFragment('#token=ab+cd/ef==').token, 'ab+cd/ef==');
});

test('a bare fragment is a token only when it looks like one the server prints', () => {
  assert.deepEqual(tokenFromFragment(`#${TOKEN}`), { token: TOKEN, holdsToken: true });
  assert.deepEqual(tokenFromFragment(`#${TOKEN.toUpperCase()}`), { token: TOKEN.toUpperCase(), holdsToken: true });
  // A page anchor or a short hex word is not a token, and stays in the address bar.
  for (const hash of ['#replay-panel', '#deadbeef', `#${TOKEN.slice(1)}`, `#${TOKEN}g`, '#token']) {
    assert.deepEqual(tokenFromFragment(hash), { token: null, holdsToken: false }, hash);
  }
});

test('an empty fragment has no token; a junk token= is no token but still leaves the address bar', () => {
  for (const hash of ['', '#', undefined, null]) {
    assert.deepEqual(tokenFromFragment(hash), { token: null, holdsToken: false }, String(hash));
  }
  for (const hash of ['#token=', '#token=has space', '#token=%E0%A4%A', '#token=<script>', '#token=a"b', '#token=é']) {
    assert.deepEqual(tokenFromFragment(hash), { token: null, holdsToken: true }, hash);
  }
  assert.deepEqual(tokenFromFragment('#view=top&x=1'), { token: null, holdsToken: false });
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
    assert.deepEqual(tokenFromInput(input), { token: TOKEN, error: null }, input);
  }
  // Any well-formed token pasted alone is tried: the server says whether it takes it.
  assert.deepEqual(tokenFromInput('bGFiLXRva2Vu'), { token: 'bGFiLXRva2Vu', error: null });
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
  const p = new AccessPrompt({ ...el, onToken: (t) => tokens.push(t) });
  return { p, el, tokens };
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

  // The server refused it: the prompt says so.
  p.show('token_refused');
  assert.match(el.detail.textContent, /not valid for this server, or has expired/);
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
