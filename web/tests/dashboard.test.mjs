// The dashboard's plain logic (src/dashboard-model.js) and its messages (src/protocol.js): the
// `dashboard` and `action_result` messages checked field by field, the `station_action` encoded
// as the shared vectors spell it, the force history kept from each summary's last second, the
// sparkline's geometry, which tiles are in alert, the order and filter, the alert list, what
// each role may do.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { fileURLToPath } from 'node:url';

import {
  activityOf,
  alertList,
  arrange,
  canAct,
  clockTime,
  dashboardSocketUrl,
  DEFAULT_VIEW,
  deviceHealth,
  exerciseLine,
  ForceHistory,
  HISTORY_S,
  inAlert,
  openAlerts,
  resultLine,
  sparkline,
  stationViewUrl,
  tileActions,
  viewFromStored,
  viewToStored,
} from '../src/dashboard-model.js';
import { decodeMessage, encodeStationAction, ProtocolError } from '../src/protocol.js';

const VECTORS = JSON.parse(
  readFileSync(fileURLToPath(new URL('../../proto/vectors/messages.json', import.meta.url)), 'utf8'),
);
const vector = (name) => {
  const v = VECTORS.find((x) => x.name === name);
  assert.ok(v, `the vectors hold ${name}`);
  return structuredClone(v.json);
};

/** The vector's `dashboard` message, with its live station's summary changed by `edit`. */
function dashboard(edit = () => {}) {
  const m = vector('dashboard');
  edit(m.stations[0].summary, m);
  return m;
}

/** A station of a `dashboard` message: the vector's live one, renamed and changed by `edit`. */
function station(name, edit = () => {}) {
  const s = structuredClone(vector('dashboard').stations[0]);
  s.name = name;
  s.summary.alerts = [];
  edit(s, s.summary);
  return s;
}

const alert = (id, kind, unixMs, acknowledged = null) => ({
  id,
  kind,
  time_ns: id * 1e9,
  unix_ms: unixMs,
  detail: `${kind} ${id}`,
  acknowledged,
});

// ----- the messages -----

test('the dashboard and action_result vectors decode', () => {
  const d = decodeMessage(JSON.stringify(vector('dashboard')));
  assert.equal(d.kind, 'message');
  assert.equal(d.message.stations.length, 2);
  assert.equal(d.message.stations[1].summary, null);
  const r = decodeMessage(JSON.stringify(vector('action_result')));
  assert.equal(r.message.done, false);
  assert.match(r.message.reason, /not latched/);
});

test('a dashboard message that breaks the contract is refused, naming the field and the value', () => {
  const refused = (edit, field, words) => {
    const text = JSON.stringify(dashboard(edit));
    assert.throws(
      () => decodeMessage(text),
      (e) => e instanceof ProtocolError && e.field === field && words.test(e.message),
      field,
    );
  };
  refused((s) => (s.force_n = [...s.force_n, 1, 1, 1, 1, 1, 1]), 'dashboard.stations[0].summary.force_n', /at most 10/);
  refused((s) => (s.force_n[2] = -1), 'dashboard.stations[0].summary.force_n[2]', /-1/);
  refused((s) => (s.force_n[0] = 'x'), 'dashboard.stations[0].summary.force_n[0]', /"x"/);
  refused((s) => (s.safe_force_n = 0), 'dashboard.stations[0].summary.safe_force_n', /> 0/);
  refused((s) => (s.device.state = 'melted'), 'dashboard.stations[0].summary.device.state', /"melted"/);
  refused((s) => (s.alerts[1].kind = 'fire'), 'dashboard.stations[0].summary.alerts[1].kind', /"fire"/);
  refused(
    (s) => (s.alerts[0].acknowledged = { by: 7 }),
    'dashboard.stations[0].summary.alerts[0].acknowledged.by',
    /7/,
  );
  refused(
    (s) => (s.alerts[0].detail = 'x'.repeat(201)),
    'dashboard.stations[0].summary.alerts[0].detail',
    /200 characters/,
  );
  refused((s) => (s.exercise.state = 'paused'), 'dashboard.stations[0].summary.exercise.state', /"paused"/);
  refused((s) => (s.exercise.passed = 'yes'), 'dashboard.stations[0].summary.exercise.passed', /"yes"/);
  refused((s) => (s.pushes = 1.5), 'dashboard.stations[0].summary.pushes', /1.5/);
  refused((s, m) => (m.stations[1].state = 'gone'), 'dashboard.stations[1].state', /"gone"/);
  refused((s, m) => (m.stations[1].viewers = -1), 'dashboard.stations[1].viewers', /-1/);
  refused((s, m) => (m.stations = {}), 'dashboard.stations', /array/);
  refused((s, m) => delete m.time_unix_ms, 'dashboard.time_unix_ms', /undefined/);
  const noTrainee = decodeMessage(JSON.stringify(dashboard((s) => (s.trainee = null))));
  assert.equal(noTrainee.message.stations[0].summary.trainee, null);
  assert.throws(
    () => decodeMessage(JSON.stringify({ ...vector('action_result'), done: 'no' })),
    (e) => e.field === 'action_result.done',
  );
});

test('station actions are encoded exactly as the shared vectors spell them', () => {
  for (const name of [
    'station_action_acknowledge',
    'station_action_exercise',
    'station_action_mark',
    'station_action_rearm',
  ]) {
    const v = vector(name);
    assert.deepEqual(JSON.parse(encodeStationAction(v.station, v.action)), v, name);
    // A page → hub message is not one the page receives: ignored, not refused.
    assert.equal(decodeMessage(JSON.stringify(v)).kind, 'unknown');
  }
  // A note is trimmed and extra fields do not leave the page.
  assert.deepEqual(JSON.parse(encodeStationAction('d', { kind: 'mark', note: '  grip ', extra: 1 })).action, {
    kind: 'mark',
    note: 'grip',
  });
});

test('a station action the hub would refuse never leaves the page', () => {
  const refused = (station, action, field) =>
    assert.throws(
      () => encodeStationAction(station, action),
      (e) => e instanceof ProtocolError && e.field === field,
    );
  refused('', { kind: 'rearm_device' }, 'station_action.station');
  refused('d', { kind: 'mark', note: '   ' }, 'station_action.action.note');
  refused('d', { kind: 'mark', note: 'é'.repeat(281) }, 'station_action.action.note');
  assert.doesNotThrow(() => encodeStationAction('d', { kind: 'mark', note: 'é'.repeat(280) }));
  refused('d', { kind: 'exercise', control: 'skip' }, 'station_action.action.control');
  refused('d', { kind: 'acknowledge', alert: -1 }, 'station_action.action.alert');
  refused('d', { kind: 'acknowledge', alert: '2' }, 'station_action.action.alert');
  refused('d', { kind: 'reboot' }, 'station_action.action.kind');
});

// ----- the force history -----

const summaryWith = (forceN, extra = {}) => ({ ...vector('dashboard').stations[0].summary, force_n: forceN, ...extra });

test('the history places each second of samples before the message that carried it', () => {
  const h = new ForceHistory({ historyS: 2 });
  assert.deepEqual(h.values(), []);
  assert.equal(h.push(summaryWith([1, 2, 3, 4, 5, 6, 7, 8, 9, 10]), 10_000), true);
  const v = h.values();
  assert.equal(v.length, 20);
  // Slots 9 901 … 10 000 hold the ten samples, the second before them none.
  assert.deepEqual(v.slice(10), [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]);
  assert.deepEqual(v.slice(0, 10), new Array(10).fill(null));
  // The next second follows; fewer samples (fewer frames) end at the message.
  h.push(summaryWith([0.5, 0.25], { pushes: 4 }), 11_000);
  const w = h.values();
  assert.deepEqual(w.slice(0, 10), [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]);
  assert.deepEqual(w.slice(10), [null, null, null, null, null, null, null, null, 0.5, 0.25]);
  assert.equal(h.max(), 10);
});

test('overlapping seconds keep the larger force; a repeated summary is not added twice', () => {
  const h = new ForceHistory({ historyS: 2 });
  h.push(summaryWith([1, 1, 1, 1, 1, 1, 1, 1, 1, 3]), 10_000);
  // 0.5 s later: five slots overlap.
  h.push(summaryWith([2, 2, 2, 2, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5], { pushes: 9 }), 10_500);
  const v = h.values();
  assert.deepEqual(v.slice(-15), [1, 1, 1, 1, 1, 2, 2, 2, 2, 3, 0.5, 0.5, 0.5, 0.5, 0.5]);
  // The same summary again a second later: the hub resent the station's latest heartbeat.
  const same = summaryWith([2, 2, 2, 2, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5], { pushes: 9 });
  assert.equal(h.push(same, 11_500), false);
  const w = h.values();
  assert.deepEqual(w.slice(-10), new Array(10).fill(null), 'the repeat adds nothing; the clock moved on');
});

test('the history forgets what is older than its window, and a silent station scrolls on', () => {
  const h = new ForceHistory();
  assert.equal(h.slots, HISTORY_S * 10);
  h.push(summaryWith([5]), 1_000_000);
  assert.equal(h.max(), 5);
  h.advance(1_000_000 + (HISTORY_S - 1) * 1000);
  assert.equal(h.values()[0], null);
  assert.ok(h.values().includes(5));
  h.advance(1_000_000 + HISTORY_S * 1000);
  assert.ok(!h.values().includes(5));
  assert.equal(h.max(), 0);
  assert.equal(h.bySlot.size, 0);
});

test('the sparkline fits the force, keeps the safe force in view near it, and marks what lies above', () => {
  const s = sparkline([0, 1, null, 3], 2, 300, 30);
  assert.equal(s.points.length, 4);
  assert.deepEqual(
    s.points.map(([x]) => x),
    [0, 100, 200, 300],
  );
  // Scale: the larger of 1.1 × the largest (3.3 N) and the safe force's 2.3 N.
  assert.ok(Math.abs(s.scaleN - 3.3) < 1e-12);
  assert.ok(Math.abs(s.safeY - (30 - (2 / 3.3) * 30)) < 1e-9);
  assert.equal(s.points[0][1], 30, 'zero force at the bottom');
  assert.equal(s.points[2][1], 30, 'a missing sample drawn at zero');
  assert.equal(s.points[3][1], 30 - (3 / 3.3) * 30);
  assert.deepEqual(s.above, [3]);
  // Below the safe force and within three times it: the safe line stays in view.
  const quiet = sparkline([0.5, 1], 2, 100, 30);
  assert.ok(Math.abs(quiet.scaleN - 2.3) < 1e-12);
  assert.ok(quiet.safeY > 0 && quiet.safeY < 30);
  assert.deepEqual(quiet.above, []);
  // A press of 1 N under a safe force of 50 N keeps its shape; the safe line is off the plot.
  const far = sparkline([0, 1], 50, 100, 30);
  assert.equal(far.scaleN, 3);
  assert.equal(far.safeY, null);
  assert.ok(far.points[1][1] < 25, 'the press fills the plot');
  // No force at all: the safe force near the top.
  const idle = sparkline([null, 0], 2, 100, 30);
  assert.ok(Math.abs(idle.safeY - (30 - 30 / 1.15)) < 1e-9);
});

// ----- tiles -----

test('a tile is in alert while its station has an alert nobody acknowledged', () => {
  const m = vector('dashboard');
  assert.equal(inAlert(m.stations[0]), true);
  assert.deepEqual(
    openAlerts(m.stations[0]).map((a) => a.id),
    [2],
  );
  assert.equal(inAlert(m.stations[1]), false, 'no summary, no alert');
  m.stations[0].summary.alerts[1].acknowledged = { by: 'instructor at 127.0.0.1:1 on a hub', unix_ms: 1 };
  assert.equal(inAlert(m.stations[0]), false);
});

test('a tile says what its station is doing', () => {
  const words = (edit) => activityOf(station('d', edit)).words;
  assert.equal(words(), 'exercise running');
  assert.equal(
    words((s, sum) => Object.assign(sum.exercise, { state: 'ended', passed: true })),
    'passed',
  );
  assert.equal(
    words((s, sum) => Object.assign(sum.exercise, { state: 'ended', passed: false })),
    'failed',
  );
  assert.equal(
    words((s, sum) => (sum.exercise = null)),
    'in contact',
  );
  assert.equal(
    words((s, sum) => Object.assign(sum, { exercise: null, in_contact: false })),
    'idle',
  );
  // A device down is said in place of idle or contact, not over an exercise's state; a device
  // that needs calibration or runs warm is the device line's warning alone.
  const down = (state) => (s, sum) => {
    sum.exercise = null;
    sum.device.state = state;
  };
  assert.deepEqual(activityOf(station('d', down('disconnected'))), { words: 'device fault', level: 'bad' });
  assert.equal(words(down('force_latched')), 'device fault');
  assert.equal(words(down('needs_calibration')), 'in contact');
  assert.equal(
    words((s, sum) => (sum.device.state = 'disconnected')),
    'exercise running',
  );
  assert.equal(
    words((s) => (s.state = 'offline')),
    'offline',
  );
  assert.equal(
    words((s) => (s.summary = null)),
    'live, no summary',
  );
  assert.equal(exerciseLine(station('d').summary), '1/2 Press and hold 2 N · 13 s left');
  assert.equal(
    exerciseLine({
      exercise: { name: 'Trace', index: 1, count: 2, attempt: 2, state: 'ended', remaining_s: 0, passed: false },
    }),
    '2/2 Trace · attempt 2 · failed',
  );
  assert.equal(exerciseLine({ exercise: null }), 'no exercise');
});

test('device health: a fault is bad, calibration and warm motors a warning, ticks told', () => {
  const health = (d) => deviceHealth({ state: 'ok', fault_ticks: 0, lost_ticks: 0, motors_warm: false, ...d });
  assert.deepEqual(health({}), { level: 'ok', words: 'ok', needsCalibration: false, latched: false });
  assert.equal(health({ lost_ticks: 3 }).words, 'ok · 3 lost ticks');
  assert.equal(health({ lost_ticks: 3 }).level, 'ok');
  assert.equal(health({ motors_warm: true }).level, 'warn');
  const latched = health({ state: 'force_latched', fault_ticks: 40 });
  assert.equal(latched.level, 'bad');
  assert.equal(latched.latched, true);
  assert.equal(latched.words, 'force latched off · 40 fault ticks');
  for (const state of ['needs_calibration', 'needs_calibration_reset', 'calibration_updating']) {
    assert.equal(health({ state }).level, 'warn', state);
    assert.equal(health({ state }).needsCalibration, true, state);
  }
  assert.equal(health({ state: 'disconnected' }).level, 'bad');
});

test('tiles sort with alerts first (the oldest first), names in human order, and filter', () => {
  const stations = [
    station('desk-10'),
    station('desk-2', (s, sum) => (sum.alerts = [alert(1, 'device_fault', 5000)])),
    station('desk-1', (s, sum) => Object.assign(sum, { trainee: 'zoe', peak_force_n: 4 })),
    station('desk-3', (s, sum) => (sum.alerts = [alert(1, 'above_safe_force', 3000)])),
    station('desk-4', (s, sum) => (sum.alerts = [alert(1, 'above_safe_force', 1000, { by: 'x', unix_ms: 2 })])),
    { ...station('lab-b'), state: 'offline', summary: null },
  ];
  const names = (opts) => arrange(stations, opts).map((s) => s.name);
  assert.deepEqual(names({}), ['desk-3', 'desk-2', 'desk-1', 'desk-4', 'desk-10', 'lab-b']);
  assert.deepEqual(names({ sort: 'name' }), ['desk-1', 'desk-2', 'desk-3', 'desk-4', 'desk-10', 'lab-b']);
  assert.deepEqual(names({ sort: 'peak' }).slice(0, 1), ['desk-1']);
  assert.deepEqual(names({ sort: 'peak' }).at(-1), 'lab-b');
  assert.deepEqual(names({ sort: 'trainee' }).slice(-2), ['desk-1', 'lab-b'], 'ana before zoe, none last');
  assert.deepEqual(names({ show: 'alerts' }), ['desk-3', 'desk-2']);
  assert.deepEqual(names({ show: 'online', sort: 'name' }), ['desk-1', 'desk-2', 'desk-3', 'desk-4', 'desk-10']);
  assert.deepEqual(names({ text: 'ZOE' }), ['desk-1']);
  assert.deepEqual(names({ text: 'cone' }), [], 'words from the scene');
  assert.deepEqual(names({ text: 'desk  press' }).length, 5, 'every word, name and exercise');
  assert.deepEqual(names({ text: 'lab-b' }), ['lab-b']);
  const faulty = station('desk-9', (s, sum) => (sum.device.state = 'disconnected'));
  assert.deepEqual(
    arrange([...stations, faulty], { show: 'device' }).map((s) => s.name),
    ['desk-9'],
  );
  // Sorting leaves the message's list as it was.
  assert.equal(stations[0].name, 'desk-10');
});

test('the alert list holds every station’s alerts, the latest first', () => {
  const stations = [
    station(
      'desk-1',
      (s, sum) => (sum.alerts = [alert(1, 'above_safe_force', 1000), alert(2, 'exercise_failed', 4000)]),
    ),
    station('desk-2', (s, sum) => (sum.alerts = [alert(1, 'device_fault', 2000, { by: 'i', unix_ms: 3000 })])),
    { ...station('desk-3'), summary: null },
  ];
  assert.deepEqual(
    alertList(stations).map((e) => [e.station, e.alert.id]),
    [
      ['desk-1', 2],
      ['desk-2', 1],
      ['desk-1', 1],
    ],
  );
  assert.equal(clockTime(new Date(2026, 0, 1, 9, 5, 7).getTime()), '09:05:07');
});

test('only an instructor acts; re-arm only for a latched device; offline stations take nothing', () => {
  const s = station('desk-1');
  assert.equal(canAct('instructor'), true);
  assert.equal(canAct('observer'), false);
  assert.equal(canAct(null), false);
  const observer = tileActions(s, 'observer');
  assert.equal(observer.open, true, 'an observer may open the full view');
  for (const a of ['next', 'repeat', 'stop', 'mark', 'rearm', 'acknowledge']) assert.equal(observer[a], false, a);
  const instructor = tileActions(s, 'instructor');
  assert.deepEqual(
    { ...instructor },
    { open: true, next: true, repeat: true, stop: true, mark: true, rearm: false, acknowledge: true },
  );
  const latched = station('desk-1', (x, sum) => (sum.device.state = 'force_latched'));
  assert.equal(tileActions(latched, 'instructor').rearm, true);
  const noExercise = station('desk-1', (x, sum) => (sum.exercise = null));
  assert.equal(tileActions(noExercise, 'instructor').repeat, false);
  assert.equal(tileActions(noExercise, 'instructor').next, true);
  const offline = { ...station('desk-1'), state: 'offline' };
  assert.equal(tileActions(offline, 'instructor').mark, false);
});

test('the page’s addresses and the answers it shows', () => {
  assert.equal(dashboardSocketUrl({ protocol: 'https:', host: 'lab:8090' }), 'wss://lab:8090/ws?dashboard');
  assert.equal(dashboardSocketUrl({ protocol: 'http:', host: '127.0.0.1:1' }), 'ws://127.0.0.1:1/ws?dashboard');
  assert.equal(stationViewUrl('desk-1'), '/?station=desk-1');
  assert.equal(
    resultLine(vector('action_result')),
    're-arm: the device’s force output is not latched off'.replace('’', "'"),
  );
  assert.equal(resultLine({ type: 'action_result', action: 'mark', done: true, reason: null }), 'mark: done');
  assert.equal(
    resultLine({ type: 'refused', request: 'station_action', reason: 'observers cannot act' }),
    'refused: observers cannot act',
  );
});

test('the chosen view is kept and read back; what the page does not offer falls back to the default', () => {
  const chosen = { sort: 'peak', show: 'device', text: 'desk 2', compact: true };
  assert.deepEqual(viewFromStored(viewToStored(chosen)), chosen);
  // Nothing kept yet, or text that is not a view.
  assert.deepEqual(viewFromStored(null), DEFAULT_VIEW);
  assert.deepEqual(viewFromStored('{not json'), DEFAULT_VIEW);
  assert.deepEqual(viewFromStored('"peak"'), DEFAULT_VIEW);
  // One bad choice loses only itself: a sort no page offers, a prototype's key, a wrong type.
  assert.deepEqual(viewFromStored(JSON.stringify({ ...chosen, sort: 'weight' })), { ...chosen, sort: 'alerts' });
  assert.deepEqual(viewFromStored(JSON.stringify({ ...chosen, show: 'toString' })), { ...chosen, show: 'all' });
  assert.deepEqual(viewFromStored(JSON.stringify({ ...chosen, compact: 'yes', text: 7 })), {
    ...chosen,
    compact: false,
    text: '',
  });
  // A filter is a few words: a pasted page is cut, not kept whole.
  assert.equal(viewFromStored(JSON.stringify({ text: 'x'.repeat(10000) })).text.length, 200);
});
