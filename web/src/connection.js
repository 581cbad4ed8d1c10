// The viewer's connection to the server (proto/WIRE.md): the socket URL, the
// close codes with a meaning of their own, and a connection that presents its token first,
// reconnects with exponential backoff and jitter, and stops for good when the server says the
// token is missing or not valid (4401). What travels on it is decoded by protocol.js.

import { decodeMessage, encodeAuth } from './protocol.js';

/**
 * The WebSocket URL of the server that served the page (wire contract). The page's query is not
 * passed on: the upgrade's URL reaches the server's and any proxy's request log, and the token
 * travels in the `auth` message instead.
 */
export function webSocketUrl(location) {
  const scheme = location.protocol === 'https:' ? 'wss:' : 'ws:';
  return `${scheme}//${location.host}/ws`;
}

/**
 * Close codes with a meaning of their own to the viewer (proto/WIRE.md). Any other close is
 * retried with backoff.
 */
export const CLOSE_CODES = Object.freeze({
  /** The server wants a token and none was presented, or the one presented is not valid: stop. */
  unauthorized: 4401,
  /** The server has as many viewers as it takes: say so and retry with backoff. */
  tooManyViewers: 4429,
  /** Policy violation: this connection sent messages faster than the server takes them. */
  policy: 1008,
  malformed: 1007,
  normal: 1000,
  noStatus: 1005,
});

/** Why the viewer stopped at a 4401: no token was presented, or the one presented was refused. */
export const UNAUTHORIZED_REASONS = Object.freeze({
  needs_token: 'this session needs the link you were given',
  token_refused: 'this link is not valid for this server, or has expired',
});

/**
 * Delay before reconnection attempt `attempt` (0-based): exponential growth capped at `maxMs`,
 * with "equal jitter" (half fixed, half random) so that many viewers of a restarted server do
 * not all knock at the same instant, while none retries immediately.
 */
export function backoffDelayMs(attempt, random, { initialMs = 250, maxMs = 8000, factor = 2 } = {}) {
  const ceiling = Math.min(maxMs, initialMs * Math.pow(factor, Math.max(0, attempt)));
  return ceiling / 2 + random() * (ceiling / 2);
}

/**
 * One viewer's connection to the server. States: `idle` → `connecting` → `open` →
 * (`reconnecting` → `connecting` ...); `unauthorized` when the server closed with 4401 (no
 * reconnection until `reconnectNow()`, usually with a new token from `setToken()`); `stopped`
 * after `stop()`.
 *
 * With a token (`token`, `setToken`), the first message on every connection is `auth`, sent as
 * the socket opens, before anything else can be sent. Decoded messages go to
 * `onMessage(message, receivedAtMs)`; state changes to `onStateChange(state, detail)`, where
 * `detail` is `{delayMs, error}` for `reconnecting` and `{reason, code, serverReason}` for
 * `unauthorized` (`reason`: a key of `UNAUTHORIZED_REASONS`). Everything outside the browser
 * (socket class, timers, clock, random numbers) can be injected, so the behaviour is tested
 * without waiting.
 */
export class ViewerConnection {
  constructor({
    url,
    token = null,
    onMessage = () => {},
    onStateChange = () => {},
    WebSocketImpl = globalThis.WebSocket,
    setTimer = (fn, ms) => setTimeout(fn, ms),
    clearTimer = (id) => clearTimeout(id),
    now = () => performance.now(),
    random = Math.random,
    backoff = {},
    warn = (...args) => console.warn(...args),
  }) {
    this.url = url;
    /** The token presented on each connection; never logged, never in `lastError`. */
    this.token = token || null;
    this.onMessage = onMessage;
    this.onStateChange = onStateChange;
    this.WebSocketImpl = WebSocketImpl;
    this.setTimer = setTimer;
    this.clearTimer = clearTimer;
    this.now = now;
    this.random = random;
    this.backoff = backoff;
    this.warn = warn;
    this.state = 'idle';
    this.socket = null;
    /** Whether `auth` went out on the current socket: a 4401 then means the token was refused. */
    this.presented = false;
    this.timer = null;
    this.attempt = 0;
    /** Counters shown by the viewer and read by tests; `sent` counts `send()`, not `auth`. */
    this.stats = { messages: 0, unknown: 0, malformed: 0, connects: 0, reconnects: 0, sent: 0, auths: 0 };
    this.lastError = null;
    this.nextRetryMs = 0;
    /** `{reason, code, serverReason}` of the last 4401, until the next `hello`. */
    this.unauthorized = null;
  }

  /**
   * Sends one text frame (e.g. from `encodeReplayControl`) on the open connection; returns
   * false, sending nothing, when there is none.
   */
  send(text) {
    if (this.state !== 'open' || this.socket === null) return false;
    try {
      this.socket.send(text);
    } catch (e) {
      this.lastError = `could not send: ${e.message}`;
      return false;
    }
    this.stats.sent++;
    return true;
  }

  #setState(state, detail = null) {
    if (this.state === state) return;
    this.state = state;
    this.onStateChange(state, detail);
  }

  /**
   * The token to present from the next connection on (null: none). Does not reconnect by itself:
   * `reconnectNow()` does.
   */
  setToken(token) {
    this.token = token || null;
  }

  /** Opens the first connection. */
  start() {
    if (this.state !== 'idle' && this.state !== 'stopped' && this.state !== 'unauthorized') return;
    this.attempt = 0;
    this.#open();
  }

  /**
   * Drops the current connection, or the wait for the next attempt, and connects at once from
   * the shortest backoff: a token just given should not wait for a retry timer.
   */
  reconnectNow() {
    if (this.timer !== null) this.clearTimer(this.timer);
    this.timer = null;
    const socket = this.socket;
    this.socket = null;
    if (socket) socket.close(CLOSE_CODES.normal, 'viewer reconnects');
    this.attempt = 0;
    this.#open();
  }

  /** Closes the connection for good (no reconnection). */
  stop() {
    if (this.timer !== null) this.clearTimer(this.timer);
    this.timer = null;
    const socket = this.socket;
    this.socket = null;
    this.#setState('stopped');
    if (socket) socket.close(CLOSE_CODES.normal, 'viewer closed');
  }

  #open() {
    this.timer = null;
    this.presented = false;
    this.#setState('connecting');
    let socket;
    try {
      socket = new this.WebSocketImpl(this.url);
    } catch (e) {
      this.lastError = `cannot open ${this.url}: ${e.message}`;
      this.#scheduleReconnect();
      return;
    }
    this.socket = socket;
    socket.onopen = () => {
      if (this.socket !== socket) return;
      this.stats.connects++;
      // The token goes first, before `open` lets anything else be sent.
      if (this.token !== null) {
        try {
          socket.send(encodeAuth(this.token));
          this.presented = true;
          this.stats.auths++;
        } catch (e) {
          // The close that follows a failed send reconnects.
          this.lastError = `could not present the token: ${e.message}`;
        }
      }
      this.#setState('open');
    };
    socket.onmessage = (event) => this.#receive(socket, event.data);
    socket.onerror = () => {
      if (this.socket === socket) this.lastError = `WebSocket error on ${this.url}`;
    };
    socket.onclose = (event) => {
      if (this.socket !== socket) return;
      this.socket = null;
      this.#closed(event?.code, event?.reason ?? '');
    };
  }

  /** The server (or the network) closed the current socket with `code`. */
  #closed(code, serverReason) {
    const said = serverReason ? `: ${serverReason}` : '';
    switch (code) {
      case CLOSE_CODES.unauthorized: {
        // Retrying would present the same token, or none, again: wait for a new one.
        const reason = this.presented ? 'token_refused' : 'needs_token';
        this.unauthorized = { reason, code, serverReason };
        this.lastError = UNAUTHORIZED_REASONS[reason];
        this.#setState('unauthorized', { ...this.unauthorized });
        return;
      }
      case CLOSE_CODES.tooManyViewers:
        this.lastError = `too many viewers on this server (code ${code}${said})`;
        break;
      case CLOSE_CODES.policy:
        this.lastError = `the server closed this connection: too many messages (code ${code}${said})`;
        break;
      default:
        if (code !== undefined && code !== CLOSE_CODES.normal && code !== CLOSE_CODES.noStatus && !this.lastError) {
          this.lastError = `connection closed (code ${code}${said})`;
        }
    }
    this.#scheduleReconnect();
  }

  #receive(socket, data) {
    if (this.socket !== socket) return;
    const receivedAtMs = this.now();
    let decoded;
    try {
      decoded = decodeMessage(data);
    } catch (e) {
      // A malformed message closes this connection only; the viewer connects again.
      this.stats.malformed++;
      this.lastError = `malformed message: ${e.message}`;
      this.warn(`softhaptic: ${this.lastError}`);
      this.socket = null;
      socket.close(CLOSE_CODES.malformed, 'malformed message');
      this.#scheduleReconnect();
      return;
    }
    this.stats.messages++;
    if (decoded.kind === 'unknown') {
      this.stats.unknown++;
      if (this.stats.unknown <= 5)
        this.warn(`softhaptic: ignoring message of unknown type ${JSON.stringify(decoded.type)}`);
      return;
    }
    if (decoded.message.type === 'hello') {
      // A server that greets us is healthy: the next outage starts from the shortest delay.
      this.attempt = 0;
      this.lastError = null;
      this.unauthorized = null;
    }
    this.onMessage(decoded.message, receivedAtMs);
  }

  #scheduleReconnect() {
    if (this.state === 'stopped') return;
    const delay = backoffDelayMs(this.attempt, this.random, this.backoff);
    this.attempt++;
    this.stats.reconnects++;
    this.nextRetryMs = this.now() + delay;
    this.#setState('reconnecting', { delayMs: delay, error: this.lastError });
    this.timer = this.setTimer(() => this.#open(), delay);
  }
}
