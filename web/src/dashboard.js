// The lab dashboard (`GET /dashboard` on a hub; docs/dashboard.md): one tile per station, live,
// from the hub's `dashboard` message about once a second, and the instructor's actions on a
// station (`station_action`, answered by `action_result`).
//
// Reading order: `init()` binds the page once; `onMessage()` takes the hub's messages; `render()`
// draws the tiles and the alert list from the latest `dashboard` message, keeping each tile's
// elements from one message to the next (a button under the pointer is never replaced). What a
// tile says, the order and filter, and the force history are plain code in dashboard-model.js.
//
// Access is the viewer's (access.js, connection.js): a token from the link's fragment or this
// tab's storage, presented first on the WebSocket (`/ws?dashboard`), the prompt when the hub wants
// one. `hello.role` decides whether the controls show: an observer sees every tile and alert but
// no control, and the hub refuses an observer's action anyway.

import { AccessPrompt, TokenKeeper, storageOrNull } from './access.js';
import { ViewerConnection } from './connection.js';
import {
  activityOf,
  alertList,
  ALERT_WORDS,
  arrange,
  canAct,
  clockTime,
  dashboardSocketUrl,
  DEFAULT_VIEW,
  deviceHealth,
  exerciseLine,
  ForceHistory,
  inAlert,
  newtons,
  openAlerts,
  resultLine,
  sparkline,
  stationViewUrl,
  tileActions,
  VIEW_STORAGE_KEY,
  viewFromStored,
  viewToStored,
} from './dashboard-model.js';
import { encodeStationAction } from './protocol.js';

/** A dashboard older than this (no message from the hub) greys its tiles. */
const STALE_MS = 5000;
/** An acknowledgement not seen in a `dashboard` message by then is offered again. */
const ACK_PENDING_MS = 10000;
/** Open alerts a tile lists; the rest are counted (the alert list has them all). */
const TILE_ALERTS = 3;

const $ = (id) => document.getElementById(id);

const page = {
  role: null,
  /** The latest `dashboard` message and when it came (performance.now()). */
  message: null,
  receivedAtMs: 0,
  /** Per station: its ForceHistory. */
  histories: new Map(),
  /** Per station: its tile's elements. */
  tiles: new Map(),
  /** `station#alert` of acknowledgements sent, with when. */
  pendingAcks: new Map(),
  /** Per station: the latest answer to an action, `{text, refused}`. */
  results: new Map(),
  /** The station of the last action sent: a `refused` names no station. */
  lastActionStation: null,
  /** Every action sent, for the test hook: `{station, action}`. */
  sent: [],
  view: { ...DEFAULT_VIEW },
};

let connection = null;
let keeper = null;
let prompt = null;

/** What the dashboard lets an instructor's link do, in the words of the role notice. */
const DASHBOARD_POWERS = 'act on the stations';

function init() {
  keeper = new TokenKeeper({ storage: storageOrNull(() => window.sessionStorage), powers: DASHBOARD_POWERS });
  keeper.adopt(window.location, window.history);
  prompt = new AccessPrompt({
    panel: $('token-prompt'),
    detail: $('token-prompt-detail'),
    input: $('token-input'),
    button: $('token-connect'),
    note: $('token-prompt-note'),
    onToken: useToken,
  });
  window.addEventListener('hashchange', () => {
    const token = keeper.takeFragment(window.location, window.history);
    if (token !== null) useToken(token);
  });
  connection = new ViewerConnection({
    url: dashboardSocketUrl(window.location),
    token: keeper.token,
    onMessage,
    onStateChange: onConnectionState,
  });

  restoreView();
  for (const id of ['sort', 'show']) {
    $(id).addEventListener('change', () => {
      page.view[id] = $(id).value;
      viewChanged();
    });
  }
  $('filter').addEventListener('input', () => {
    page.view.text = $('filter').value;
    viewChanged();
  });
  $('compact').addEventListener('change', () => {
    page.view.compact = $('compact').checked;
    viewChanged();
  });
  $('tiles').addEventListener('click', onTileClick);
  $('tiles').addEventListener('submit', onMarkSubmit);
  $('alert-list').addEventListener('click', (event) => {
    const button = event.target.closest('button[data-alert]');
    if (button) acknowledge(button.dataset.station, Number(button.dataset.alert));
  });
  // The stale look and the "updated … ago" line follow the clock, not only the messages.
  setInterval(showUpdated, 1000);
  window.addEventListener('resize', () => render());

  if (navigator.webdriver) {
    import('./dashboard-testhook.js')
      .then(({ installDashboardHook }) => installDashboardHook({ page, connection: () => connection, act }))
      .catch((e) => console.warn(`softhaptic: no test hook: ${e.message}`));
  }
  connection.start();
}

// ----- the view: order, filter, size -----

/** This browser's localStorage, or null where it gives none. */
function viewStorage() {
  return storageOrNull(() => window.localStorage);
}

/** The view this browser chose last time, shown in the controls; the default without one. */
function restoreView() {
  page.view = viewFromStored(viewStorage()?.getItem(VIEW_STORAGE_KEY) ?? null);
  $('sort').value = page.view.sort;
  $('show').value = page.view.show;
  $('filter').value = page.view.text;
  $('compact').checked = page.view.compact;
  $('tiles').classList.toggle('compact', page.view.compact);
}

/** A control changed the view: drawn, and kept for the next visit (a full storage costs only that). */
function viewChanged() {
  $('tiles').classList.toggle('compact', page.view.compact);
  try {
    viewStorage()?.setItem(VIEW_STORAGE_KEY, viewToStored(page.view));
  } catch {
    // Kept for this visit only.
  }
  render();
}

// ----- access -----

function useToken(token, role) {
  keeper.set(token, role);
  connection.setToken(token);
  connection.reconnectNow();
}

function onConnectionState(state, detail) {
  if (state === 'unauthorized') {
    const linkRole = keeper.role;
    let why = detail.reason;
    if (why === 'token_refused') {
      why = keeper.refusal();
      keeper.forget();
      connection.setToken(null);
    }
    prompt.show(why, { linkRole });
  }
  const badge = $('conn-state');
  const words = {
    connecting: 'connecting',
    open: 'connected',
    reconnecting: 'reconnecting',
    unauthorized: 'needs a link',
    stopped: 'stopped',
  };
  badge.textContent = words[state] ?? state;
  badge.className = `badge ${state === 'open' ? 'ok' : state === 'unauthorized' ? 'bad' : 'warn'}`;
  const error = $('conn-error');
  const text = state === 'reconnecting' && detail?.error ? `connection lost (${detail.error}); retrying` : '';
  error.textContent = text;
  error.hidden = text === '';
}

// ----- messages -----

function onMessage(message, receivedAtMs) {
  switch (message.type) {
    case 'hello': {
      page.role = message.role;
      const role = $('role');
      role.textContent = message.role;
      role.className = `badge ${canAct(message.role) ? 'active' : ''}`;
      prompt.greeted(keeper.greeted(message.role));
      render();
      break;
    }
    case 'dashboard':
      onDashboard(message, receivedAtMs);
      break;
    case 'action_result':
      showResult(message.station, { text: resultLine(message), refused: !message.done });
      if (!message.done) {
        for (const key of page.pendingAcks.keys())
          if (key.startsWith(`${message.station}#`)) page.pendingAcks.delete(key);
        render();
      }
      break;
    case 'refused':
      if (message.request === 'station_action' && page.lastActionStation !== null) {
        showResult(page.lastActionStation, { text: resultLine(message), refused: true });
        page.pendingAcks.clear();
        render();
      } else {
        console.warn(`softhaptic: the hub refused ${message.request}: ${message.reason}`);
      }
      break;
    default:
      break;
  }
}

function onDashboard(message, receivedAtMs) {
  page.message = message;
  page.receivedAtMs = receivedAtMs;
  const names = new Set();
  for (const s of message.stations) {
    names.add(s.name);
    let history = page.histories.get(s.name);
    if (!history) {
      history = new ForceHistory();
      page.histories.set(s.name, history);
    }
    if (s.summary !== null) history.push(s.summary, message.time_unix_ms);
    else history.advance(message.time_unix_ms);
    // An acknowledgement the hub now shows is no longer pending.
    for (const a of s.summary?.alerts ?? []) {
      if (a.acknowledged !== null) page.pendingAcks.delete(`${s.name}#${a.id}`);
    }
  }
  for (const name of [...page.histories.keys()]) if (!names.has(name)) page.histories.delete(name);
  render();
}

function showResult(station, result) {
  page.results.set(station, result);
  const tile = page.tiles.get(station);
  if (tile) drawResult(tile, station);
}

// ----- actions -----

/** Sends `action` to `station`; false (and a line on the tile) when it could not leave. */
function act(station, action) {
  let text;
  try {
    text = encodeStationAction(station, action);
  } catch (e) {
    showResult(station, { text: e.message, refused: true });
    return false;
  }
  page.lastActionStation = station;
  if (!connection.send(text)) {
    showResult(station, { text: 'not sent: the dashboard is not connected', refused: true });
    return false;
  }
  page.sent.push({ station, action: JSON.parse(text).action });
  showResult(station, { text: `${action.kind === 'rearm_device' ? 're-arm' : action.kind}: sent…`, refused: false });
  return true;
}

function acknowledge(station, alert) {
  if (act(station, { kind: 'acknowledge', alert })) {
    page.pendingAcks.set(`${station}#${alert}`, performance.now());
    render();
  }
}

function onTileClick(event) {
  const button = event.target.closest('button');
  if (!button) return;
  const station = button.closest('.tile')?.dataset.station;
  if (!station) return;
  const tile = page.tiles.get(station);
  switch (button.dataset.act) {
    case 'next':
    case 'repeat':
    case 'stop':
      act(station, { kind: 'exercise', control: button.dataset.act });
      break;
    case 'rearm':
      act(station, { kind: 'rearm_device' });
      break;
    case 'mark':
      tile.markForm.hidden = !tile.markForm.hidden;
      if (!tile.markForm.hidden) tile.markInput.focus();
      break;
    case 'ack':
      acknowledge(station, Number(button.dataset.alert));
      break;
    default:
      break;
  }
}

function onMarkSubmit(event) {
  const form = event.target.closest('.mark-form');
  if (!form) return;
  event.preventDefault();
  const station = form.closest('.tile').dataset.station;
  const tile = page.tiles.get(station);
  if (act(station, { kind: 'mark', note: tile.markInput.value })) {
    tile.markInput.value = '';
    tile.markForm.hidden = true;
  }
}

// ----- drawing -----

function showUpdated() {
  const el = $('updated');
  if (page.message === null) {
    el.textContent = '';
    return;
  }
  const ageMs = performance.now() - page.receivedAtMs;
  const stale = ageMs > STALE_MS;
  el.textContent = `updated ${clockTime(page.message.time_unix_ms)}${stale ? ` (${Math.round(ageMs / 1000)} s ago)` : ''}`;
  el.classList.toggle('muted', !stale);
  for (const tile of page.tiles.values()) tile.root.classList.toggle('stale', stale);
  // Acknowledgements that went unanswered are offered again.
  let expired = false;
  for (const [key, at] of page.pendingAcks) {
    if (performance.now() - at > ACK_PENDING_MS) {
      page.pendingAcks.delete(key);
      expired = true;
    }
  }
  if (expired) render();
}

function newTile(name) {
  const root = $('tile-template').content.firstElementChild.cloneNode(true);
  root.dataset.station = name;
  const q = (sel) => root.querySelector(sel);
  const tile = {
    root,
    name: q('.name'),
    contact: q('.contact'),
    activity: q('.activity'),
    trainee: q('.trainee'),
    exercise: q('.exercise'),
    spark: q('.spark'),
    forceNow: q('.force-now'),
    safe: q('.safe'),
    metrics: q('.metrics'),
    device: q('.device'),
    viewers: q('.viewers'),
    alerts: q('.tile-alerts'),
    tools: q('.tools'),
    actions: q('.actions'),
    buttons: Object.fromEntries([...root.querySelectorAll('button[data-act]')].map((b) => [b.dataset.act, b])),
    markForm: q('.mark-form'),
    markInput: q('.mark-form input'),
    result: q('.result'),
    alertsKey: '',
  };
  tile.name.textContent = name;
  tile.name.href = stationViewUrl(name);
  return tile;
}

/** Sets `el.textContent` only when it changes (no layout work for the same words). */
function text(el, value) {
  if (el.textContent !== value) el.textContent = value;
}

function drawResult(tile, station) {
  const r = page.results.get(station);
  text(tile.result, r?.text ?? '');
  tile.result.classList.toggle('refused', r?.refused === true);
}

function drawTile(tile, s) {
  const summary = s.summary;
  tile.root.classList.toggle('alert', inAlert(s));
  tile.root.classList.toggle('offline', s.state === 'offline');
  const activity = activityOf(s);
  text(tile.activity, activity.words);
  // A compact tile may cut the words short.
  tile.activity.title = activity.words;
  tile.activity.className = `activity badge ${activity.level === 'muted' ? '' : activity.level}`;
  tile.contact.classList.toggle('on', summary?.in_contact === true);
  text(tile.trainee, summary?.trainee ?? (summary === null ? s.scene : 'no trainee'));
  text(tile.exercise, summary === null ? '' : exerciseLine(summary));
  tile.root.title = s.scene;

  const history = page.histories.get(s.name);
  const safeDrawn = drawSpark(tile.spark, history?.values() ?? [], summary?.safe_force_n ?? null);
  const latest = summary?.force_n.at(-1);
  text(tile.forceNow, latest === undefined ? '' : `now ${newtons(latest)}`);
  text(tile.safe, summary === null ? '' : `safe ${newtons(summary.safe_force_n)}${safeDrawn ? '' : ' ↑'}`);
  tile.safe.title = safeDrawn ? 'the dashed line' : 'above the plot: the force stayed far below it';
  text(
    tile.metrics,
    summary === null
      ? ''
      : `peak ${newtons(summary.peak_force_n)} · above safe ${summary.time_above_safe_s.toFixed(1)} s · ` +
          `contact ${summary.time_in_contact_s.toFixed(1)} s · ${summary.pushes} pushes`,
  );
  if (summary === null) {
    text(tile.device, s.state === 'offline' ? 'offline' : 'sends no summary');
    tile.device.className = 'device small muted';
  } else {
    const health = deviceHealth(summary.device);
    text(tile.device, `device ${health.words}`);
    tile.device.className = `device small ${health.level}`;
  }
  text(tile.viewers, `viewers: ${s.viewers} at the station, ${s.hub_viewers} here`);

  drawTileAlerts(tile, s);
  const allowed = tileActions(s, page.role);
  tile.actions.hidden = !canAct(page.role);
  // An observer has nothing to open over a compact tile (no button, and no answer to one).
  tile.tools.hidden = !canAct(page.role);
  for (const [act, button] of Object.entries(tile.buttons)) {
    const on = allowed[act];
    if (act === 'rearm') button.hidden = !on;
    else button.disabled = !on;
  }
  if (!canAct(page.role)) tile.markForm.hidden = true;
  drawResult(tile, s.name);
}

function drawTileAlerts(tile, s) {
  const open = openAlerts(s);
  const acting = canAct(page.role);
  const shown = open.slice(-TILE_ALERTS);
  const key = JSON.stringify([
    acting,
    open.length,
    shown.map((a) => [a.id, a.detail, page.pendingAcks.has(`${s.name}#${a.id}`)]),
  ]);
  if (key === tile.alertsKey) return;
  tile.alertsKey = key;
  const items = shown.map((a) => {
    const li = document.createElement('li');
    li.dataset.alert = String(a.id);
    li.dataset.kind = a.kind;
    const what = document.createElement('span');
    what.className = 'what';
    what.textContent = `${clockTime(a.unix_ms)} ${ALERT_WORDS[a.kind]}: ${a.detail}`;
    what.title = what.textContent;
    li.append(what);
    if (acting) {
      const button = document.createElement('button');
      button.type = 'button';
      button.className = 'ack';
      button.dataset.act = 'ack';
      button.dataset.alert = String(a.id);
      const pending = page.pendingAcks.has(`${s.name}#${a.id}`);
      button.textContent = pending ? 'ack…' : 'ack';
      button.disabled = pending;
      button.title = 'acknowledge: you have seen it';
      li.append(button);
    }
    return li;
  });
  if (open.length > shown.length) {
    const more = document.createElement('li');
    more.textContent = `+${open.length - shown.length} earlier (in the alert list)`;
    items.unshift(more);
  }
  tile.alerts.replaceChildren(...items);
}

/**
 * Draws a sparkline: the force over the last 30 s, the safe force dashed, what lies above it red.
 * Returns whether the safe force's line is drawn (false: it lies above the plot).
 */
function drawSpark(canvas, values, safeForceN) {
  const ratio = Math.min(window.devicePixelRatio || 1, 2);
  const width = Math.max(1, Math.round(canvas.clientWidth * ratio));
  const height = Math.max(1, Math.round(canvas.clientHeight * ratio));
  if (canvas.width !== width) canvas.width = width;
  if (canvas.height !== height) canvas.height = height;
  const ctx = canvas.getContext('2d');
  ctx.clearRect(0, 0, width, height);
  if (safeForceN === null || values.length === 0) return true;
  const pad = ratio;
  const { points, safeY, above } = sparkline(values, safeForceN, width, height - 2 * pad);
  if (safeY !== null) {
    ctx.lineWidth = ratio;
    ctx.strokeStyle = '#f85149';
    ctx.setLineDash([4 * ratio, 3 * ratio]);
    ctx.beginPath();
    ctx.moveTo(0, safeY + pad);
    ctx.lineTo(width, safeY + pad);
    ctx.stroke();
    ctx.setLineDash([]);
  }
  ctx.strokeStyle = '#58a6ff';
  ctx.lineWidth = 1.5 * ratio;
  ctx.beginPath();
  points.forEach(([x, y], i) => (i === 0 ? ctx.moveTo(x, y + pad) : ctx.lineTo(x, y + pad)));
  ctx.stroke();
  if (above.length > 0) {
    ctx.fillStyle = '#f85149';
    const w = Math.max(ratio, width / values.length);
    for (const i of above) ctx.fillRect(points[i][0] - w / 2, points[i][1] + pad, w, safeY - points[i][1]);
  }
  return safeY !== null;
}

function drawAlertList(stations) {
  const all = alertList(stations);
  const acting = canAct(page.role);
  const open = all.filter((e) => e.alert.acknowledged === null).length;
  text($('alerts-open'), all.length === 0 ? '' : `${open} open of ${all.length}`);
  $('alerts-none').hidden = all.length > 0;
  const items = all.map(({ station, alert }) => {
    const li = document.createElement('li');
    li.dataset.station = station;
    li.dataset.alert = String(alert.id);
    li.className = alert.acknowledged === null ? 'open' : 'acknowledged';
    const time = document.createElement('span');
    time.className = 'time';
    time.textContent = clockTime(alert.unix_ms);
    const name = document.createElement('span');
    name.className = 'station';
    name.textContent = station;
    const detail = document.createElement('div');
    detail.textContent = `${ALERT_WORDS[alert.kind]}: ${alert.detail}`;
    li.append(time, ' ', name);
    if (alert.acknowledged === null) {
      if (acting) {
        const button = document.createElement('button');
        button.type = 'button';
        button.dataset.station = station;
        button.dataset.alert = String(alert.id);
        const pending = page.pendingAcks.has(`${station}#${alert.id}`);
        button.textContent = pending ? 'ack…' : 'ack';
        button.disabled = pending;
        li.append(button);
      }
    } else {
      const by = document.createElement('div');
      by.className = 'ack-by';
      by.textContent = `acknowledged ${clockTime(alert.acknowledged.unix_ms)} by ${alert.acknowledged.by}`;
      li.append(detail, by);
      return li;
    }
    li.append(detail);
    return li;
  });
  // Rebuilt only when it changes: a button under the pointer stays put between messages.
  const key = JSON.stringify([acting, [...page.pendingAcks.keys()], all]);
  if ($('alert-list').dataset.key !== key) {
    $('alert-list').dataset.key = key;
    $('alert-list').replaceChildren(...items);
  }
}

function render() {
  const message = page.message;
  if (message === null) return;
  const board = $('tiles');
  const shown = arrange(message.stations, page.view);
  const names = new Set(message.stations.map((s) => s.name));
  for (const name of [...page.tiles.keys()]) {
    if (!names.has(name)) page.tiles.delete(name);
  }
  const elements = shown.map((s) => {
    let tile = page.tiles.get(s.name);
    if (!tile) {
      tile = newTile(s.name);
      page.tiles.set(s.name, tile);
    }
    return tile.root;
  });
  if (elements.length === 0) {
    const empty = document.createElement('p');
    empty.className = 'empty-board';
    empty.textContent =
      message.stations.length === 0 ? 'no station has published to this hub yet' : 'no station matches the filter';
    elements.push(empty);
  }
  // Moved only when the order changed: moving detaches an element for a moment.
  const current = [...board.children];
  if (current.length !== elements.length || current.some((el, i) => el !== elements[i])) {
    board.replaceChildren(...elements);
  }
  // Drawn after they are in the page, so the sparklines know their width.
  for (const s of shown) drawTile(page.tiles.get(s.name), s);
  const inAlertCount = message.stations.filter(inAlert).length;
  const hidden = message.stations.length - shown.length;
  text(
    $('counts'),
    `${message.stations.length} stations · ${inAlertCount} in alert` + (hidden > 0 ? ` · ${hidden} hidden` : ''),
  );
  drawAlertList(message.stations);
  showUpdated();
}

init();
