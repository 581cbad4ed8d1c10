// The viewer's token: where it comes from, where it is kept, and the prompt that asks for one
// (proto/WIRE.md, "Roles and tokens"). The server gives one token per role (instructor,
// observer) and prints them in ready-to-open links; the role a token grants comes back in `hello`.
//
// A token reaches the page in its URL's fragment, `http://HOST:PORT/#token=<hex>&role=<role>`: a
// browser never sends the fragment to the server, so the token reaches no request log and no
// proxy. The `role` the link was printed for is a hint for the viewer's words only: the server
// decides the role from the token alone and says it in `hello`; when the two differ the viewer
// says "this is an observer link" rather than leaving an instructor without controls and no
// reason. A link without the hint (a bare token, an older server's link) works as before. The
// viewer reads it once and removes it from the address bar (`history.replaceState`, no reload),
// so a screenshot, a bookmark or a link copied from the address bar does not carry it on. It
// keeps the token in memory and in sessionStorage, which only this tab reads and which is
// forgotten with the tab: a reload keeps the session, where localStorage would leave the token on
// the disk for the next person at the machine. The token leaves the page only in the WebSocket's
// first message (`auth`) and in the `Authorization: Bearer` header of fetches from the page's own
// server; never in a URL's query, a log line, an error message or the page's text.
//
// Why a token is refused: a server makes new tokens each time it starts (unless they come from a
// file or the environment), so the usual refused link is one from an earlier start. The viewer
// says "expired" when this tab was greeted with the token before (the server has restarted since)
// and "not valid for this server, or from an earlier start" when it never was.
//
// `tokenFromFragment`, `tokenFromInput`, `roleNotice`, `promptDetail` and `TokenKeeper` are plain
// code (unit-tested); `AccessPrompt` binds the prompt's field and button.

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

/** The roles a link may name in its `role=` hint, as `hello.role` names them. */
export const ROLES = Object.freeze(['instructor', 'observer']);

/** `value` when it names a role, else null (a hint the viewer does not know is no hint). */
function roleOrNull(value) {
  return ROLES.includes(value) ? value : null;
}

/** Whether `text` can be presented as a token (not whether the server takes it). */
export function isToken(text) {
  return typeof text === 'string' && text.length <= TOKEN_MAX_LENGTH && TOKEN_SYNTAX.test(text);
}

/**
 * The token in a URL fragment (`location.hash`, with or without its `#`): `#token=<token>`
 * (among other `key=value` pairs joined by `&`, such as the `role=` the link was printed for), or
 * a bare token (`#<32+ hex digits>`). Returns `{token, holdsToken, role}`: `token` is null when
 * there is none or it is not valid; `holdsToken` says the fragment names a token at all (valid or
 * not), so it must leave the address bar; `role` is the link's hint (`instructor`, `observer`),
 * null when it has none or names no role, and always null without a valid token.
 */
export function tokenFromFragment(hash) {
  const none = { token: null, holdsToken: false, role: null };
  const body = String(hash ?? '').replace(/^#/, '');
  if (body === '') return none;
  if (!body.includes('=')) {
    return BARE_TOKEN.test(body) ? { token: body, holdsToken: true, role: null } : none;
  }
  const pairs = new Map();
  for (const pair of body.split('&')) {
    const eq = pair.indexOf('=');
    // The first of a repeated key counts, as it did before the hint.
    if (eq < 0 || pairs.has(pair.slice(0, eq))) continue;
    let value;
    try {
      value = decodeURIComponent(pair.slice(eq + 1));
    } catch {
      value = '';
    }
    pairs.set(pair.slice(0, eq), value);
  }
  if (!pairs.has('token')) return none;
  const token = isToken(pairs.get('token')) ? pairs.get('token') : null;
  return { token, holdsToken: true, role: token === null ? null : roleOrNull(pairs.get('role')) };
}

/**
 * What someone pasted into the prompt: a link (`http://HOST:PORT/#token=...`, whatever its host:
 * the server may print an address the browser reaches by another name), a fragment
 * (`#token=...`, `token=...`) or a bare token. Returns `{token, role, error}` (`role` the link's
 * hint, null for a bare token); the error never repeats the input, which may be a secret.
 */
export function tokenFromInput(text) {
  const refused = (error) => ({ token: null, role: null, error });
  const input = String(text ?? '').trim();
  if (input === '') return refused('paste the link you were given, or its token');
  const hashAt = input.indexOf('#');
  if (hashAt >= 0 || input.startsWith('token=')) {
    const { token, holdsToken, role } = tokenFromFragment(input.slice(Math.max(hashAt, 0)));
    if (token !== null) return { token, role, error: null };
    return refused(holdsToken ? 'the token in that link is not well formed' : 'that link holds no token (#token=…)');
  }
  if (/^[a-z][a-z0-9+.-]*:\/\//i.test(input)) return refused('that link holds no token (#token=…)');
  if (isToken(input)) return { token: input, role: null, error: null };
  return refused('that is neither a link nor a token');
}

/**
 * What to tell the holder of a link printed for `linkRole` whom the server greeted as `granted`
 * (`hello.role`): null when they agree or the link named no role. Granted less, the holder learns
 * why the controls are missing; granted more, that the link does more than it was given for
 * (the lab's token file may name the roles the wrong way round). `powers` says what an
 * instructor's link does on the page at hand.
 */
export function roleNotice(linkRole, granted, powers = VIEWER_POWERS) {
  const link = roleOrNull(linkRole);
  const role = roleOrNull(granted);
  if (link === null || role === null || link === role) return null;
  if (role === 'observer') {
    return `This is an observer link: the server gives it read-only access, though it was given as the instructor’s. To ${powers}, paste the instructor’s link.`;
  }
  return `This is an instructor link: the server lets it ${powers}, though it was given as an observer’s. Tell whoever gave it to you.`;
}

/** What an instructor's link does in the viewer, in the words of `roleNotice`. */
export const VIEWER_POWERS = 'control the replay';

/**
 * A storage of the browser (`get` returns it, e.g. `() => window.sessionStorage`), or null where
 * the browser gives none: reading it throws when storage is disabled.
 */
export function storageOrNull(get) {
  try {
    return get() ?? null;
  } catch {
    return null;
  }
}

/** Where this tab keeps its token (sessionStorage). */
export const TOKEN_STORAGE_KEY = 'softhaptic.token';
/** Where this tab keeps the role its link was printed for. */
export const ROLE_STORAGE_KEY = 'softhaptic.role';
/** Where this tab notes that the server greeted its token (the value `1`). */
export const GREETED_STORAGE_KEY = 'softhaptic.greeted';

/**
 * The viewer's token: in memory (`token`, null when there is none; `role`, the role its link was
 * printed for, null when unknown; `wasGreeted`, whether the server has greeted this tab with it)
 * and in `storage` (sessionStorage; null when the browser gives none). A storage that throws
 * (disabled, full) only costs the reload its token. `powers` names what an instructor's link
 * does on this page (`roleNotice`).
 */
export class TokenKeeper {
  constructor({ storage = null, powers = VIEWER_POWERS } = {}) {
    this.storage = storage;
    this.powers = powers;
    this.token = null;
    this.role = null;
    this.wasGreeted = false;
  }

  /**
   * Takes the token of the page's fragment, else the one this tab kept before a reload. A token
   * in the fragment leaves the address bar at once. Returns where the token came from:
   * `'fragment'`, `'storage'` or null (none).
   */
  adopt(location, history) {
    if (this.takeFragment(location, history) !== null) return 'fragment';
    const kept = this.#read(TOKEN_STORAGE_KEY);
    if (isToken(kept)) {
      this.token = kept;
      this.role = roleOrNull(this.#read(ROLE_STORAGE_KEY));
      this.wasGreeted = this.#read(GREETED_STORAGE_KEY) === '1';
      return 'storage';
    }
    return null;
  }

  /**
   * Takes the token of the page's fragment (on load, or when a new link is opened in the same
   * tab: the page is not reloaded then) and its role hint, and removes them from the address bar.
   * Returns the token, or null when the fragment holds none (the token in use stays).
   */
  takeFragment(location, history) {
    const { token, holdsToken, role } = tokenFromFragment(location.hash);
    if (holdsToken) history.replaceState(history.state, '', `${location.pathname}${location.search}`);
    if (token !== null) this.set(token, role);
    return token;
  }

  /**
   * Uses `token` from now on, printed for `role` (null: unknown), and keeps both for a reload of
   * this tab. Without `role`, the same token again keeps what is known of it (a link opened in
   * the tab is taken here first, then handed on without its role); another token starts afresh.
   */
  set(token, role) {
    const same = token === this.token;
    if (role !== undefined || !same) this.role = roleOrNull(role);
    if (!same) this.wasGreeted = false;
    this.token = token;
    this.#write(TOKEN_STORAGE_KEY, token);
    this.#write(ROLE_STORAGE_KEY, this.role);
    this.#write(GREETED_STORAGE_KEY, this.wasGreeted ? '1' : null);
  }

  /**
   * The server greeted this token as `granted` (`hello.role`): noted for a later refusal, and
   * the notice for a link printed for another role (`roleNotice`), null when there is none.
   */
  greeted(granted) {
    if (this.token !== null && !this.wasGreeted) {
      this.wasGreeted = true;
      this.#write(GREETED_STORAGE_KEY, '1');
    }
    return roleNotice(this.role, granted, this.powers);
  }

  /**
   * Why the server refused the token in use (read it before `forget`): `token_expired` when the
   * server greeted this tab with it before (it has restarted with new tokens since), else
   * `token_refused` (never valid here, or from a start before this tab had it).
   */
  refusal() {
    return this.wasGreeted ? 'token_expired' : 'token_refused';
  }

  /** Drops the token (the server refused it): a reload will not present it again. */
  forget() {
    this.token = null;
    this.role = null;
    this.wasGreeted = false;
    for (const key of [TOKEN_STORAGE_KEY, ROLE_STORAGE_KEY, GREETED_STORAGE_KEY]) this.#write(key, null);
  }

  #read(key) {
    try {
      return this.storage?.getItem(key) ?? null;
    } catch {
      return null;
    }
  }

  /** Keeps `value` under `key`, or removes the key for null. */
  #write(key, value) {
    try {
      if (value === null) this.storage?.removeItem(key);
      else this.storage?.setItem(key, value);
    } catch {
      // Not kept across a reload; nothing else changes.
    }
  }
}

/**
 * What the prompt says under its title, for each reason the viewer needs a token; `{link}` is
 * "This link", or "This instructor link" when the link named its role.
 */
export const PROMPT_DETAILS = Object.freeze({
  needs_token: 'Paste the link (…/#token=…) or the token here.',
  token_refused:
    '{link} is not valid for this server. A server makes new links each time it starts (unless its tokens come from a file), so a link from an earlier start no longer works: paste the link it printed this time.',
  token_expired:
    '{link} has expired: it worked in this tab until the server restarted, and a server makes new links each time it starts. Paste the new link.',
});

/** The prompt's words for `reason` (a key of `PROMPT_DETAILS`) about a link printed for `linkRole`. */
export function promptDetail(reason, linkRole = null) {
  const role = roleOrNull(linkRole);
  const text = PROMPT_DETAILS[reason] ?? PROMPT_DETAILS.needs_token;
  return text.replace('{link}', role === null ? 'This link' : `This ${role} link`);
}

/**
 * The prompt that asks for a link or a token: `panel` (hidden until needed), `detail` (why it is
 * asked), `input`, `button` and `note` (what went wrong with the input, or "connecting…").
 * `onToken(token, role)` receives a well-formed token (and the role its link names, or null) from
 * a click on the button or Enter in the field; the field is emptied at once, so the token does not
 * stay in the page.
 */
export class AccessPrompt {
  constructor({ panel, detail, input, button, note, onToken }) {
    this.el = { panel, detail, input, button, note };
    this.onToken = onToken;
    this.shown = false;
    /** Why it is shown: a key of `PROMPT_DETAILS`, `wrong_role`, or null. */
    this.reason = null;
    button.addEventListener('click', () => this.#submit());
    input.addEventListener('keydown', (event) => {
      if (event.key !== 'Enter') return;
      event.preventDefault();
      this.#submit();
    });
  }

  /**
   * Shows the prompt, saying why: `needs_token`, `token_refused` or `token_expired` (about a link
   * printed for `linkRole`, when known), or `wrong_role` with the `notice` of `roleNotice`.
   */
  show(reason, { linkRole = null, notice = null } = {}) {
    const { panel, detail, input, note } = this.el;
    this.reason = reason;
    detail.textContent = reason === 'wrong_role' && notice !== null ? notice : promptDetail(reason, linkRole);
    note.textContent = '';
    if (!this.shown) {
      this.shown = true;
      panel.hidden = false;
      input.focus?.();
    }
  }

  /**
   * The server greeted this viewer: the prompt goes, unless `notice` (`TokenKeeper.greeted`) says
   * the link grants another role than the one it was given for; then it stays to say so, and
   * takes the right link.
   */
  greeted(notice = null) {
    if (notice === null) this.hide();
    else this.show('wrong_role', { notice });
  }

  /** Hides the prompt. */
  hide() {
    if (!this.shown) return;
    this.shown = false;
    this.reason = null;
    this.el.panel.hidden = true;
    this.el.note.textContent = '';
  }

  #submit() {
    const { input, note } = this.el;
    const { token, role, error } = tokenFromInput(input.value);
    if (token === null) {
      note.textContent = error;
      return;
    }
    input.value = '';
    note.textContent = 'connecting…';
    this.onToken(token, role);
  }
}
