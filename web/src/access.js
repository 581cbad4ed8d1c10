// The viewer's token: where it comes from, where it is kept, and the prompt that asks for one
// (proto/WIRE.md, "Roles and tokens"). The server gives one token per role (instructor,
// observer) and prints them in ready-to-open links; the role a token grants comes back in `hello`.
//
// A token reaches the page in its URL's fragment, `http://HOST:PORT/#token=<hex>`: a browser
// never sends the fragment to the server, so the token reaches no request log and no proxy. The
// viewer reads it once and removes it from the address bar (`history.replaceState`, no reload),
// so a screenshot, a bookmark or a link copied from the address bar does not carry it on. It
// keeps the token in memory and in sessionStorage, which only this tab reads and which is
// forgotten with the tab: a reload keeps the session, where localStorage would leave the token on
// the disk for the next person at the machine. The token leaves the page only in the WebSocket's
// first message (`auth`) and in the `Authorization: Bearer` header of fetches from the page's own
// server; never in a URL's query, a log line, an error message or the page's text.
//
// `tokenFromFragment`, `tokenFromInput` and `TokenKeeper` are plain code (unit-tested);
// `AccessPrompt` binds the prompt's field and button.

/**
 * The characters a token may have: RFC 6750's `b64token`, so that it goes into an
 * `Authorization: Bearer` header as it is. The server prints hex; a lab's own token file may
 * hold base64.
 */
const TOKEN_SYNTAX = /^[A-Za-z0-9\-._~+/]+=*$/;
const TOKEN_MAX_LENGTH = 1024;

/**
 * A fragment without `token=` is taken for a bare token only when it looks like one the server
 * prints (128 bits or more of hex), not like a page anchor.
 */
const BARE_TOKEN = /^[0-9a-f]{32,}$/i;

/** Whether `text` can be presented as a token (not whether the server takes it). */
export function isToken(text) {
  return typeof text === 'string' && text.length <= TOKEN_MAX_LENGTH && TOKEN_SYNTAX.test(text);
}

/**
 * The token in a URL fragment (`location.hash`, with or without its `#`): `#token=<token>`
 * (among other `key=value` pairs joined by `&`), or a bare token (`#<32+ hex digits>`).
 * Returns `{token, holdsToken}`: `token` is null when there is none or it is not valid;
 * `holdsToken` says the fragment names a token at all (valid or not), so it must leave the
 * address bar.
 */
export function tokenFromFragment(hash) {
  const body = String(hash ?? '').replace(/^#/, '');
  if (body === '') return { token: null, holdsToken: false };
  if (!body.includes('=')) {
    return BARE_TOKEN.test(body) ? { token: body, holdsToken: true } : { token: null, holdsToken: false };
  }
  for (const pair of body.split('&')) {
    const eq = pair.indexOf('=');
    if (eq < 0 || pair.slice(0, eq) !== 'token') continue;
    let value;
    try {
      value = decodeURIComponent(pair.slice(eq + 1));
    } catch {
      value = '';
    }
    return { token: isToken(value) ? value : null, holdsToken: true };
  }
  return { token: null, holdsToken: false };
}

/**
 * What someone pasted into the prompt: a link (`http://HOST:PORT/#token=...`, whatever its host:
 * the server may print an address the browser reaches by another name), a fragment
 * (`#token=...`, `token=...`) or a bare token. Returns `{token, error}`; the error never repeats
 * the input, which may be a secret.
 */
export function tokenFromInput(text) {
  const input = String(text ?? '').trim();
  if (input === '') return { token: null, error: 'paste the link you were given, or its token' };
  const hashAt = input.indexOf('#');
  if (hashAt >= 0 || input.startsWith('token=')) {
    const { token, holdsToken } = tokenFromFragment(input.slice(Math.max(hashAt, 0)));
    if (token !== null) return { token, error: null };
    return {
      token: null,
      error: holdsToken ? 'the token in that link is not well formed' : 'that link holds no token (#token=…)',
    };
  }
  if (/^[a-z][a-z0-9+.-]*:\/\//i.test(input)) return { token: null, error: 'that link holds no token (#token=…)' };
  if (isToken(input)) return { token: input, error: null };
  return { token: null, error: 'that is neither a link nor a token' };
}

/** Where this tab keeps its token (sessionStorage). */
export const TOKEN_STORAGE_KEY = 'softhaptic.token';

/**
 * The viewer's token: in memory (`token`, null when there is none) and in `storage`
 * (sessionStorage; null when the browser gives none). A storage that throws (disabled,
 * full) only costs the reload its token.
 */
export class TokenKeeper {
  constructor({ storage = null } = {}) {
    this.storage = storage;
    this.token = null;
  }

  /**
   * Takes the token of the page's fragment, else the one this tab kept before a reload. A token
   * in the fragment leaves the address bar at once. Returns where the token came from:
   * `'fragment'`, `'storage'` or null (none).
   */
  adopt(location, history) {
    if (this.takeFragment(location, history) !== null) return 'fragment';
    const kept = this.#read();
    if (isToken(kept)) {
      this.token = kept;
      return 'storage';
    }
    return null;
  }

  /**
   * Takes the token of the page's fragment (on load, or when a new link is opened in the same
   * tab: the page is not reloaded then) and removes it from the address bar. Returns the token,
   * or null when the fragment holds none (the token in use stays).
   */
  takeFragment(location, history) {
    const { token, holdsToken } = tokenFromFragment(location.hash);
    if (holdsToken) history.replaceState(history.state, '', `${location.pathname}${location.search}`);
    if (token !== null) this.set(token);
    return token;
  }

  /** Uses `token` from now on, and keeps it for a reload of this tab. */
  set(token) {
    this.token = token;
    try {
      this.storage?.setItem(TOKEN_STORAGE_KEY, token);
    } catch {
      // Not kept across a reload; nothing else changes.
    }
  }

  /** Drops the token (the server refused it): a reload will not present it again. */
  forget() {
    this.token = null;
    try {
      this.storage?.removeItem(TOKEN_STORAGE_KEY);
    } catch {
      // Nothing was kept.
    }
  }

  #read() {
    try {
      return this.storage?.getItem(TOKEN_STORAGE_KEY) ?? null;
    } catch {
      return null;
    }
  }
}

/** What the prompt says under its title, for each reason the viewer needs a token. */
export const PROMPT_DETAILS = Object.freeze({
  needs_token: 'Paste the link (…/#token=…) or the token here.',
  token_refused: 'This link is not valid for this server, or has expired. Paste the link you were given.',
});

/**
 * The prompt that asks for a link or a token: `panel` (hidden until needed), `detail` (why it is
 * asked), `input`, `button` and `note` (what went wrong with the input, or "connecting…").
 * `onToken(token)` receives a well-formed token from a click on the button or Enter in the field;
 * the field is emptied at once, so the token does not stay in the page.
 */
export class AccessPrompt {
  constructor({ panel, detail, input, button, note, onToken }) {
    this.el = { panel, detail, input, button, note };
    this.onToken = onToken;
    this.shown = false;
    /** Why it is shown: a key of `PROMPT_DETAILS`, or null. */
    this.reason = null;
    button.addEventListener('click', () => this.#submit());
    input.addEventListener('keydown', (event) => {
      if (event.key !== 'Enter') return;
      event.preventDefault();
      this.#submit();
    });
  }

  /** Shows the prompt, saying why (`needs_token` or `token_refused`). */
  show(reason) {
    const { panel, detail, input, note } = this.el;
    this.reason = reason;
    detail.textContent = PROMPT_DETAILS[reason] ?? PROMPT_DETAILS.needs_token;
    note.textContent = '';
    if (!this.shown) {
      this.shown = true;
      panel.hidden = false;
      input.focus?.();
    }
  }

  /** Hides the prompt (the server greeted this viewer). */
  hide() {
    if (!this.shown) return;
    this.shown = false;
    this.reason = null;
    this.el.panel.hidden = true;
    this.el.note.textContent = '';
  }

  #submit() {
    const { input, note } = this.el;
    const { token, error } = tokenFromInput(input.value);
    if (token === null) {
      note.textContent = error;
      return;
    }
    input.value = '';
    note.textContent = 'connecting…';
    this.onToken(token);
  }
}
