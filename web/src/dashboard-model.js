// The dashboard's plain logic (docs/dashboard.md), kept apart from the page so that it is tested
// without a browser: the force history behind each tile's sparkline, what a tile says of its
// station (activity, device health, alerts), the order and filter of the tiles, the alert list,
// and what an instructor may do.
//
// A `dashboard` message (proto/src/wire/dashboard.rs) carries, per station, the largest force in
// each 100 ms of the last second only; the page keeps the last `HISTORY_S` seconds itself
// (`ForceHistory`). Everything here reads validated messages (protocol.js) and touches no DOM.

import { webSocketUrl } from './connection.js';
import { FORCE_SAMPLES_PER_S } from './protocol.js';

/** The dashboard's WebSocket on the hub that served the page (`/ws?dashboard`). */
export function dashboardSocketUrl(location) {
  return `${webSocketUrl(location)}?dashboard`;
}

/** Seconds of force history a sparkline shows. */
export const HISTORY_S = 30;

/** Width of one force sample, ms (10 samples a second). */
export const SLOT_MS = 1000 / FORCE_SAMPLES_PER_S;

/**
 * One station's force over the last `historyS` seconds, in 100 ms slots keyed by the hub's clock
 * (`dashboard.time_unix_ms`): each summary's samples end at the time of the message that carried
 * them, oldest first. Two messages whose seconds overlap write the same slot: the larger value
 * stays (each is the largest force in that 100 ms, and the later one may have seen more of it).
 * A summary repeated unchanged (the hub sent the station's latest heartbeat again, before the
 * next one came) is not added twice, which would show one press as two.
 */
export class ForceHistory {
  constructor({ historyS = HISTORY_S } = {}) {
    this.slots = historyS * FORCE_SAMPLES_PER_S;
    /** Largest force per slot, by slot index (time_unix_ms / 100 ms). */
    this.bySlot = new Map();
    /** The latest slot the hub's clock reached. */
    this.latestSlot = null;
    /** The last summary added, as text, to recognise a repeat. */
    this.lastKey = null;
  }

  /**
   * Adds the samples of `summary` (a validated `StationSummary`) carried by a message made at
   * `timeUnixMs`. Returns whether they were added (false for a repeat).
   */
  push(summary, timeUnixMs) {
    const end = Math.floor(timeUnixMs / SLOT_MS);
    if (this.latestSlot === null || end > this.latestSlot) this.latestSlot = end;
    const key = JSON.stringify(summary);
    if (key === this.lastKey) {
      this.#trim();
      return false;
    }
    this.lastKey = key;
    const n = summary.force_n.length;
    summary.force_n.forEach((f, i) => {
      const slot = end - (n - 1 - i);
      const had = this.bySlot.get(slot);
      this.bySlot.set(slot, had === undefined ? f : Math.max(had, f));
    });
    this.#trim();
    return true;
  }

  /** The hub's clock moved on (a message without a summary for this station). */
  advance(timeUnixMs) {
    const end = Math.floor(timeUnixMs / SLOT_MS);
    if (this.latestSlot === null || end > this.latestSlot) this.latestSlot = end;
    this.#trim();
  }

  #trim() {
    const first = this.latestSlot - this.slots + 1;
    for (const slot of this.bySlot.keys()) if (slot < first) this.bySlot.delete(slot);
  }

  /**
   * The last `historyS` seconds, oldest first, one value per 100 ms: the force, N, or null where
   * no sample came (the station was silent, offline, or its summary repeated).
   */
  values() {
    if (this.latestSlot === null) return [];
    const out = new Array(this.slots);
    const first = this.latestSlot - this.slots + 1;
    for (let i = 0; i < this.slots; i++) out[i] = this.bySlot.get(first + i) ?? null;
    return out;
  }

  /** The largest force in the history, N (0 when empty). */
  max() {
    let m = 0;
    for (const f of this.bySlot.values()) if (f > m) m = f;
    return m;
  }
}

/**
 * The sparkline of `values` (from `ForceHistory.values`) in a `width`×`height` box with the safe
 * force `safeForceN` marked: `{points: [[x, y], …] (a missing sample drawn at zero force),
 * safeY (null when the safe force is off the scale), scaleN, above: [indices above the safe
 * force]}`. The scale fits the largest force and keeps the safe force in view unless it lies
 * more than three times above it: a press of 1 N under a safe force of 50 N still shows its
 * shape. With no force at all, the safe force sits near the top.
 */
export function sparkline(values, safeForceN, width, height) {
  let max = 0;
  for (const v of values) if (v !== null && v > max) max = v;
  const scaleN = max > 0 ? Math.max(max * 1.1, Math.min(safeForceN * 1.15, max * 3)) : safeForceN * 1.15;
  const y = (f) => height - (f / scaleN) * height;
  const step = values.length > 1 ? width / (values.length - 1) : 0;
  const points = values.map((v, i) => [i * step, y(v ?? 0)]);
  const above = [];
  values.forEach((v, i) => {
    if (v !== null && v > safeForceN) above.push(i);
  });
  return { points, safeY: safeForceN <= scaleN ? y(safeForceN) : null, scaleN, above };
}

/** The alerts of a summary not yet acknowledged (none without a summary). */
export function openAlerts(station) {
  return station.summary?.alerts.filter((a) => a.acknowledged === null) ?? [];
}

/** Whether a tile is in alert: its station has an alert no instructor has acknowledged. */
export function inAlert(station) {
  return openAlerts(station).length > 0;
}

/** What an alert's kind says on a tile and in the list. */
export const ALERT_WORDS = Object.freeze({
  above_safe_force: 'above the safe force',
  device_fault: 'device fault',
  needs_calibration: 'device needs calibration',
  exercise_failed: 'exercise failed',
});

/**
 * What the station is doing, for the tile's badge: `offline`, `no summary` (a station that sends
 * none), `exercise running`, `passed`, `failed`, `device fault` (a device down, outside an
 * exercise's result), `in contact` or `idle`; with `level` (`ok`,
 * `active`, `bad`, `muted`) for its colour.
 */
export function activityOf(station) {
  if (station.state === 'offline') return { words: 'offline', level: 'muted' };
  const s = station.summary;
  if (s === null) return { words: station.state === 'live' ? 'live, no summary' : station.state, level: 'muted' };
  if (s.exercise !== null) {
    if (s.exercise.state === 'running') return { words: 'exercise running', level: 'active' };
    if (s.exercise.passed === true) return { words: 'passed', level: 'ok' };
    if (s.exercise.passed === false) return { words: 'failed', level: 'bad' };
  }
  // A trainee whose device is down is not idle: nothing they do reaches the object.
  if (deviceHealth(s.device).level === 'bad') return { words: 'device fault', level: 'bad' };
  if (s.in_contact) return { words: 'in contact', level: 'active' };
  return { words: 'idle', level: 'muted' };
}

/** Short words for a device state on a tile (the viewer's panel has the long ones). */
export const DEVICE_WORDS = Object.freeze({
  ok: 'ok',
  disconnected: 'disconnected',
  not_answering: 'not answering',
  force_disabled: 'force disabled',
  needs_calibration: 'needs calibration',
  overrun: 'tick overran',
  driver_error: 'driver error',
  force_latched: 'force latched off',
  failed: 'servo failed',
  needs_calibration_reset: 'needs calibration (reset)',
  calibration_updating: 'calibration updating',
});

const CALIBRATION_STATES = ['needs_calibration', 'needs_calibration_reset', 'calibration_updating'];

/**
 * The device's health for the tile: `{level: 'ok' | 'warn' | 'bad', words, needsCalibration,
 * latched}`. A state other than `ok` is bad (calibration a warning: the trainee can fix it);
 * warm motors are a warning; lost and fault ticks are told but change the level only when
 * the state does.
 */
export function deviceHealth(device) {
  const needsCalibration = CALIBRATION_STATES.includes(device.state);
  const parts = [DEVICE_WORDS[device.state] ?? device.state];
  if (device.motors_warm) parts.push('motors warm');
  if (device.fault_ticks > 0) parts.push(`${device.fault_ticks} fault ticks`);
  if (device.lost_ticks > 0) parts.push(`${device.lost_ticks} lost ticks`);
  let level = 'ok';
  if (device.state !== 'ok') level = needsCalibration ? 'warn' : 'bad';
  else if (device.motors_warm) level = 'warn';
  return { level, words: parts.join(' · '), needsCalibration, latched: device.state === 'force_latched' };
}

/** Compares station names as a person would: `desk-2` before `desk-10`. */
export const compareNames = new Intl.Collator('en', { numeric: true }).compare;

/** Orders of the tiles. */
export const SORTS = Object.freeze({
  /** Tiles in alert first, the one waiting longest first; then by name. */
  alerts: (a, b) => {
    const oa = openAlerts(a);
    const ob = openAlerts(b);
    if (oa.length > 0 !== ob.length > 0) return oa.length > 0 ? -1 : 1;
    if (oa.length > 0) {
      const ta = Math.min(...oa.map((x) => x.unix_ms));
      const tb = Math.min(...ob.map((x) => x.unix_ms));
      if (ta !== tb) return ta - tb;
    }
    return compareNames(a.name, b.name);
  },
  name: (a, b) => compareNames(a.name, b.name),
  /** The largest peak force of the session first. */
  peak: (a, b) => (b.summary?.peak_force_n ?? -1) - (a.summary?.peak_force_n ?? -1) || compareNames(a.name, b.name),
  /** Trainees by name, stations without one last. */
  trainee: (a, b) => {
    const ta = a.summary?.trainee ?? null;
    const tb = b.summary?.trainee ?? null;
    if ((ta === null) !== (tb === null)) return ta === null ? 1 : -1;
    return (ta === null ? 0 : compareNames(ta, tb)) || compareNames(a.name, b.name);
  },
});

/** Which tiles to show. */
export const SHOWS = Object.freeze({
  all: () => true,
  /** Tiles with an alert not acknowledged. */
  alerts: (s) => inAlert(s),
  /** Stations that are not offline. */
  online: (s) => s.state !== 'offline',
  /** Stations whose device is not ok or is warm. */
  device: (s) => s.summary !== null && deviceHealth(s.summary.device).level !== 'ok',
});

/**
 * The tiles to show, in order: `stations` (a `dashboard` message's) kept by `show` (a key of
 * `SHOWS`) and by `text` (words that must all appear, in any case, in the station's name, scene,
 * trainee or exercise), sorted by `sort` (a key of `SORTS`).
 */
export function arrange(stations, { sort = 'alerts', show = 'all', text = '' } = {}) {
  const words = text.toLowerCase().split(/\s+/).filter(Boolean);
  const keep = SHOWS[show] ?? SHOWS.all;
  const matches = (s) => {
    if (words.length === 0) return true;
    const hay = [s.name, s.scene, s.summary?.trainee ?? '', s.summary?.exercise?.name ?? ''].join(' ').toLowerCase();
    return words.every((w) => hay.includes(w));
  };
  return stations.filter((s) => keep(s) && matches(s)).sort(SORTS[sort] ?? SORTS.alerts);
}

/** How the page starts: alerts first, every station, no filter, full tiles. */
export const DEFAULT_VIEW = Object.freeze({ sort: 'alerts', show: 'all', text: '', compact: false });

/** Where the browser keeps the view an instructor chose (localStorage: it outlives the tab). */
export const VIEW_STORAGE_KEY = 'softhaptic.dashboard.view';

/** The longest filter text kept: a filter is a few words. */
const MAX_FILTER_CHARS = 200;

/**
 * The view kept by `viewToStored`, read back: each choice that is not one the page offers (an
 * older page's, an edited value) falls back to `DEFAULT_VIEW`'s, and text that is not JSON gives
 * the default view.
 */
export function viewFromStored(text) {
  let kept;
  try {
    kept = typeof text === 'string' ? JSON.parse(text) : null;
  } catch {
    kept = null;
  }
  if (kept === null || typeof kept !== 'object') return { ...DEFAULT_VIEW };
  const own = (table, key) => typeof key === 'string' && Object.hasOwn(table, key);
  return {
    sort: own(SORTS, kept.sort) ? kept.sort : DEFAULT_VIEW.sort,
    show: own(SHOWS, kept.show) ? kept.show : DEFAULT_VIEW.show,
    text: typeof kept.text === 'string' ? kept.text.slice(0, MAX_FILTER_CHARS) : DEFAULT_VIEW.text,
    compact: typeof kept.compact === 'boolean' ? kept.compact : DEFAULT_VIEW.compact,
  };
}

/** The text `viewFromStored` reads back. */
export function viewToStored(view) {
  const { sort, show, text, compact } = view;
  return JSON.stringify({ sort, show, text: text.slice(0, MAX_FILTER_CHARS), compact });
}

/**
 * Every alert of every station, the latest first: `{station, alert}`. A summary carries every
 * alert not acknowledged and the latest acknowledged ones, so the list is what the stations
 * still hold.
 */
export function alertList(stations) {
  const out = [];
  for (const s of stations) for (const alert of s.summary?.alerts ?? []) out.push({ station: s.name, alert });
  return out.sort((a, b) => b.alert.unix_ms - a.alert.unix_ms || compareNames(a.station, b.station));
}

/** A wall-clock time (Unix ms) as the lab's clock shows it, `HH:MM:SS` in the page's time zone. */
export function clockTime(unixMs) {
  const d = new Date(unixMs);
  return [d.getHours(), d.getMinutes(), d.getSeconds()].map((n) => String(n).padStart(2, '0')).join(':');
}

/** Whether the dashboard's connection may act on stations (`hello.role`). */
export function canAct(role) {
  return role === 'instructor';
}

/**
 * The actions a tile offers an instructor of `station` (none to an observer): `open` always (the
 * station's full view); `next`, `repeat` and `mark` on a station that is not offline; `repeat`
 * only once an exercise has run; `rearm` only when the device latched its force off.
 */
export function tileActions(station, role) {
  const actions = {
    open: true,
    next: false,
    repeat: false,
    stop: false,
    mark: false,
    rearm: false,
    acknowledge: false,
  };
  if (!canAct(role) || station.state === 'offline') return actions;
  const s = station.summary;
  actions.mark = true;
  actions.next = true;
  actions.repeat = s?.exercise != null;
  actions.stop = s?.exercise?.state === 'running';
  actions.rearm = s?.device.state === 'force_latched';
  actions.acknowledge = true;
  return actions;
}

/** The address of a station's full view on this hub (the viewer page). */
export function stationViewUrl(name) {
  return `/?station=${encodeURIComponent(name)}`;
}

/** What a tile's exercise line says: `2/5 Press and hold 2 N · attempt 2 · 12 s left`. */
export function exerciseLine(summary) {
  const e = summary?.exercise ?? null;
  if (e === null) return 'no exercise';
  const parts = [`${e.index + 1}/${e.count} ${e.name}`];
  if (e.attempt > 1) parts.push(`attempt ${e.attempt}`);
  if (e.state === 'running') parts.push(`${Math.ceil(e.remaining_s)} s left`);
  else parts.push(e.passed ? 'passed' : 'failed');
  return parts.join(' · ');
}

/** A force, N, with two significant decimals. */
export function newtons(f) {
  return `${f.toFixed(2)} N`;
}

/** What an `action_result` or a `refused` says to the instructor, in a line. */
export function resultLine(result) {
  if (result.type === 'refused') return `refused: ${result.reason}`;
  const name = result.action === 'rearm_device' ? 're-arm' : result.action;
  return result.done ? `${name}: done` : `${name}: ${result.reason ?? 'not done'}`;
}
