// The replay timeline's pure parts: decoding the `replay` status, encoding `replay_control`,
// extrapolating the position between statuses, the time format; and the timeline panel driven
// through stand-ins of its controls (what it sends on play, speed and a scrubber release, what
// an observer's panel shows and does not send, how a refused control is shown).
import { test } from 'node:test';
import assert from 'node:assert/strict';

import { ViewerConnection } from '../src/connection.js';
import { ProtocolError, decodeMessage, encodeReplayControl } from '../src/protocol.js';
import { PlayoutBuffer, RenderedContact } from '../src/interpolation.js';
import {
  ReplayClock,
  ReplayTimeline,
  aboveSafeMarkers,
  formatReplayTime,
  gapMarkers,
  markMarkers,
} from '../src/replay.js';
import { contact, hello } from './fixtures.mjs';

/** A status as `softhaptic replay` sends it (proto `ReplayStatus`). */
function status(over = {}) {
  return { type: 'replay', duration_s: 2.98, time_s: 0, paused: true, speed: 1, file: 'sphere-press.mcap', ...over };
}

const near = (a, b, tol = 1e-9) => Math.abs(a - b) <= tol;

test('a replay status decodes, and one that breaks the contract is refused with the field', () => {
  const decoded = decodeMessage(JSON.stringify(status({ time_s: 1.25, paused: false, speed: 2 })));
  assert.equal(decoded.kind, 'message');
  assert.deepEqual(decoded.message, status({ time_s: 1.25, paused: false, speed: 2 }));
  const cases = [
    [status({ duration_s: -1 }), /replay.duration_s: expected a number ≥ 0/],
    [status({ time_s: 'soon' }), /replay.time_s: expected a finite number, got "soon"/],
    [status({ paused: 'yes' }), /replay.paused: expected true or false/],
    [status({ speed: 0 }), /replay.speed: expected a number > 0, got 0/],
    [status({ file: null }), /replay.file: expected a string/],
  ];
  for (const [m, pattern] of cases) {
    assert.throws(
      () => decodeMessage(JSON.stringify(m)),
      (e) => e instanceof ProtocolError && pattern.test(e.message),
      JSON.stringify(m),
    );
  }
  const withoutPaused = status();
  delete withoutPaused.paused;
  assert.throws(() => decodeMessage(JSON.stringify(withoutPaused)), /replay.paused/);
});

test('replay controls encode as the server parses them, and what it would refuse is not sent', () => {
  assert.equal(encodeReplayControl('pause'), '{"type":"replay_control","action":"pause"}');
  assert.equal(encodeReplayControl('play', { speed: 2 }), '{"type":"replay_control","action":"play","speed":2}');
  assert.equal(encodeReplayControl('seek', { timeS: 1.5 }), '{"type":"replay_control","action":"seek","time_s":1.5}');
  assert.equal(
    encodeReplayControl('pause', { speed: 0.25 }),
    '{"type":"replay_control","action":"pause","speed":0.25}',
  );
  assert.throws(() => encodeReplayControl('rewind'), /replay_control.action: expected one of pause, play, seek/);
  assert.throws(() => encodeReplayControl('seek'), /replay_control.time_s: seek needs a time/);
  assert.throws(() => encodeReplayControl('seek', { timeS: -0.1 }), /replay_control.time_s: expected a number ≥ 0/);
  assert.throws(() => encodeReplayControl('seek', { timeS: NaN }), /replay_control.time_s/);
  assert.throws(
    () => encodeReplayControl('play', { speed: 1000 }),
    /replay_control.speed: expected a speed in \[0.01, 100\]/,
  );
  assert.throws(() => encodeReplayControl('play', { speed: 0.001 }), /replay_control.speed/);
  assert.doesNotThrow(() => encodeReplayControl('play', { speed: 0.01 }));
  assert.doesNotThrow(() => encodeReplayControl('play', { speed: 100 }));
});

test('the position is extrapolated from the last status while playing and held while paused', () => {
  const clock = new ReplayClock();
  assert.equal(clock.known, false);
  assert.equal(clock.positionS(1000), 0);
  // Playing at 2× from 1.0 s, received at local 10 000 ms.
  clock.update(status({ time_s: 1.0, paused: false, speed: 2 }), 10000);
  assert.ok(near(clock.positionS(10000), 1.0));
  assert.ok(near(clock.positionS(10250), 1.5));
  assert.ok(near(clock.positionS(10500), 2.0));
  // Never past the end, never before the start.
  assert.equal(clock.positionS(20000), 2.98);
  assert.equal(clock.positionS(0), 0);
  // Paused at 1.2 s: held whatever the time.
  clock.update(status({ time_s: 1.2, paused: true, speed: 2 }), 11000);
  assert.equal(clock.positionS(11000), 1.2);
  assert.equal(clock.positionS(99000), 1.2);
  assert.equal(clock.statuses, 2);
  assert.equal(clock.file, 'sphere-press.mcap');
  clock.reset();
  assert.equal(clock.known, false);
  assert.equal(clock.positionS(99000), 0);
});

test('a status reports a break of the time axis on play, seek and speed change, not on drift', () => {
  const clock = new ReplayClock();
  assert.equal(clock.update(status(), 0), true, 'the first status');
  assert.equal(clock.update(status(), 1000), false, 'paused, same place');
  assert.equal(clock.update(status({ paused: false }), 1500), true, 'play after pause');
  // One second later the periodic status says 1.02 s: 20 ms of drift between the clocks.
  assert.equal(clock.update(status({ paused: false, time_s: 1.02 }), 2500), false, 'drift');
  assert.equal(clock.update(status({ paused: false, time_s: 0.3 }), 2600), true, 'seek backwards');
  assert.equal(clock.update(status({ paused: false, time_s: 2.5 }), 2700), true, 'seek forwards');
  assert.equal(clock.update(status({ paused: true, time_s: 2.52 }), 2720), false, 'pause holds the frames');
  assert.equal(clock.update(status({ paused: true, time_s: 2.52, speed: 4 }), 2800), true, 'speed change');
  // At 4× a status a little late by the network is still the same run (tolerance scales).
  clock.update(status({ paused: false, time_s: 0, speed: 4 }), 3000);
  assert.equal(clock.update(status({ paused: false, time_s: 2.4, speed: 4 }), 3500), false);
});

test('a status a little behind the extrapolation never makes the shown time step back', () => {
  const clock = new ReplayClock();
  clock.update(status({ time_s: 1, paused: false, speed: 0.5 }), 0);
  // One second later the extrapolation says 1.5 s; the server's status, sent a moment earlier,
  // says 1.45 s: the same run (within the tolerance), so the time shown holds at 1.5 s.
  assert.ok(near(clock.positionS(1000), 1.5));
  assert.equal(clock.update(status({ time_s: 1.45, paused: false, speed: 0.5 }), 1000), false);
  assert.ok(near(clock.positionS(1000), 1.5));
  assert.ok(clock.positionS(1100) > 1.5);
  // A status ahead of the extrapolation is taken as it is.
  clock.update(status({ time_s: 1.6, paused: false, speed: 0.5 }), 1100);
  assert.ok(near(clock.positionS(1100), 1.6));
  // A real jump back (a seek by another viewer) is taken, and reported as a break.
  assert.equal(clock.update(status({ time_s: 0.2, paused: false, speed: 0.5 }), 1200), true);
  assert.ok(near(clock.positionS(1200), 0.2));
  // Paused, the server's position is the truth.
  clock.update(status({ time_s: 0.9, paused: true, speed: 0.5 }), 1300);
  assert.ok(near(clock.positionS(5000), 0.9));
});

test('times read as m:ss.s, truncated to the tenth', () => {
  assert.equal(formatReplayTime(0), '0:00.0');
  assert.equal(formatReplayTime(2.98), '0:02.9');
  assert.equal(formatReplayTime(3), '0:03.0');
  assert.equal(formatReplayTime(0.3), '0:00.3');
  assert.equal(formatReplayTime(61.25), '1:01.2');
  assert.equal(formatReplayTime(600), '10:00.0');
  assert.equal(formatReplayTime(-1), '0:00.0');
  assert.equal(formatReplayTime(NaN), '—');
});

test('the playout buffer follows a replay at another speed, and restarts its clock on resume', () => {
  const buf = new PlayoutBuffer({ delayMs: 50 });
  const out = new RenderedContact();
  const frame = (ms) => contact({ seq: ms / 20, tick: ms, time_ns: ms * 1e6, depth_m: ms * 1e-6 });
  // 2×: a frame (20 ms of device time) every 10 ms of local time.
  buf.restartClock(0, 2);
  for (let k = 0; k <= 20; k++) buf.push(frame(20 * k), 1000 + 10 * k);
  // Local 1200 = device 400 (newest); drawn 50 local ms = 100 device ms behind.
  buf.sample(1200, out);
  assert.ok(near(out.deviceTimeMs, 300), `drawn at ${out.deviceTimeMs}`);
  assert.ok(!out.stale);
  // 5 ms later (local), 10 ms later (device): between frames, interpolated.
  buf.sample(1205, out);
  assert.ok(near(out.deviceTimeMs, 310) && near(out.depthM, 310e-6), `${out.deviceTimeMs} ${out.depthM}`);

  // Paused for 10 s at device 400: the newest frame stays drawn (stale, no new frames).
  buf.sample(11200, out);
  assert.ok(out.valid && near(out.deviceTimeMs, 400));
  // Resumed at 1×: without a restart the render clock would run 10 s ahead of the frames.
  buf.restartClock(11200, 1);
  buf.sample(11200, out);
  assert.ok(near(out.deviceTimeMs, 400), 'the newest frame is held until new ones arrive');
  for (let k = 1; k <= 5; k++) buf.push(frame(400 + 20 * k), 11200 + 20 * k);
  // Local 11300: newest device 500 arrived at 11300; drawn at 450, interpolated, not stale.
  buf.sample(11300, out);
  assert.ok(near(out.deviceTimeMs, 450), `drawn at ${out.deviceTimeMs}`);
  assert.ok(!out.stale);
  assert.equal(buf.clockRestarts, 2);
  assert.throws(() => buf.restartClock(0, 0), /rate must be finite and > 0/);
});

test('the connection sends text frames only while open', () => {
  const sent = [];
  class Socket {
    constructor() {
      Socket.last = this;
    }
    send(text) {
      sent.push(text);
    }
    close() {}
  }
  const conn = new ViewerConnection({ url: 'ws://host/ws', WebSocketImpl: Socket, warn: () => {} });
  assert.equal(conn.send('x'), false, 'not started');
  conn.start();
  assert.equal(conn.send('x'), false, 'still connecting');
  Socket.last.onopen({});
  Socket.last.onmessage({ data: JSON.stringify(hello) });
  assert.equal(conn.send(encodeReplayControl('pause')), true);
  assert.deepEqual(sent, ['{"type":"replay_control","action":"pause"}']);
  assert.equal(conn.stats.sent, 1);
  conn.stop();
  assert.equal(conn.send('x'), false, 'stopped');
});

/** Just enough of a document for the timeline panel: option elements and pointer releases. */
const fakeDocument = {
  listeners: {},
  createElement: () => new FakeElement(),
  addEventListener(type, fn) {
    (this.listeners[type] ??= []).push(fn);
  },
  fire(type) {
    for (const fn of this.listeners[type] ?? []) fn({ type });
  },
};

/** Just enough of a DOM element for the timeline panel. */
class FakeElement {
  constructor(props = {}) {
    this.listeners = {};
    this.hidden = false;
    this.textContent = '';
    this.title = '';
    this.dataset = {};
    this.value = '';
    this.max = '0';
    this.valueAsNumber = 0;
    this.options = [];
    Object.assign(this, props);
  }
  get ownerDocument() {
    return fakeDocument;
  }
  appendChild(child) {
    this.options.push(child);
  }
  addEventListener(type, fn) {
    (this.listeners[type] ??= []).push(fn);
  }
  fire(type) {
    for (const fn of this.listeners[type] ?? []) fn({ type });
  }
}

function timelinePanel(sendResult = true) {
  const sent = [];
  let now = 0;
  const el = {
    panel: new FakeElement({ hidden: true }),
    playButton: new FakeElement(),
    speedSelect: new FakeElement({ value: '1', options: ['0.25', '0.5', '1', '2', '4'].map((value) => ({ value })) }),
    scrubber: new FakeElement(),
    timeText: new FakeElement(),
    fileText: new FakeElement(),
    hintText: new FakeElement(),
    refusedText: new FakeElement({ hidden: true }),
  };
  const timeline = new ReplayTimeline({
    ...el,
    send: (text) => {
      sent.push(JSON.parse(text));
      return sendResult;
    },
    now: () => now,
  });
  return { timeline, el, sent, setNow: (ms) => (now = ms) };
}

test('the timeline panel appears with the first status and shows the duration', () => {
  const { timeline, el } = timelinePanel();
  assert.equal(el.panel.hidden, true);
  timeline.frame(0);
  assert.equal(el.timeText.textContent, '', 'nothing drawn while hidden');
  timeline.onStatus(status(), 0);
  assert.equal(el.panel.hidden, false);
  assert.equal(el.scrubber.max, '2.98');
  assert.equal(el.timeText.textContent, '0:00.0 / 0:02.9');
  assert.equal(el.playButton.dataset.action, 'play');
  assert.equal(el.fileText.textContent, 'sphere-press.mcap');
  timeline.hide();
  assert.equal(el.panel.hidden, true);
  assert.equal(timeline.clock.known, false);
});

test('the scrubber follows the extrapolated position, and the text changes once per tenth, not per frame', () => {
  const { timeline, el } = timelinePanel();
  timeline.onStatus(status({ paused: false, time_s: 0.5 }), 1000);
  timeline.frame(1016);
  assert.ok(near(el.scrubber.valueAsNumber, 0.516));
  timeline.frame(1250);
  assert.ok(near(el.scrubber.valueAsNumber, 0.75));
  assert.equal(el.timeText.textContent, '0:00.7 / 0:02.9');
  // 60 frames over one second: the text is rebuilt once per tenth, not per frame.
  let changes = 0;
  let last = el.timeText.textContent;
  for (let k = 1; k <= 60; k++) {
    timeline.frame(1250 + (1000 * k) / 60);
    if (el.timeText.textContent !== last) changes++;
    last = el.timeText.textContent;
  }
  assert.equal(changes, 10, `${changes} text changes`);
  assert.equal(el.timeText.textContent, '0:01.7 / 0:02.9');
  // At 10× the tenths change every frame; the text still changes at most every 50 ms.
  timeline.onStatus(status({ paused: false, time_s: 0, speed: 10 }), 3000);
  changes = 0;
  for (let k = 1; k <= 12; k++) {
    timeline.frame(3000 + (1000 * k) / 60);
    if (el.timeText.textContent !== last) changes++;
    last = el.timeText.textContent;
  }
  assert.ok(changes <= 5, `${changes} text changes in 200 ms at 10×`);
  // A speed the selector does not offer is added to it.
  assert.equal(el.speedSelect.value, '10');
  assert.ok(el.speedSelect.options.some((o) => o.value === '10' && o.textContent === '10×'));
});

test('play, pause, speed and a scrubber release send the controls the server expects', () => {
  const { timeline, el, sent, setNow } = timelinePanel();
  timeline.onStatus(status(), 0);
  el.playButton.fire('click');
  assert.deepEqual(sent.at(-1), { type: 'replay_control', action: 'play' });
  timeline.onStatus(status({ paused: false }), 10);
  assert.equal(el.playButton.dataset.action, 'pause');
  el.playButton.fire('click');
  assert.deepEqual(sent.at(-1), { type: 'replay_control', action: 'pause' });
  // A speed chosen while paused keeps the replay paused.
  timeline.onStatus(status({ paused: true, time_s: 0.4 }), 20);
  el.speedSelect.value = '0.5';
  el.speedSelect.fire('change');
  assert.deepEqual(sent.at(-1), { type: 'replay_control', action: 'pause', speed: 0.5 });

  // Dragging does not seek and the frames do not move the thumb; the release seeks.
  setNow(100);
  el.scrubber.fire('pointerdown');
  el.scrubber.valueAsNumber = 2.25;
  el.scrubber.fire('input');
  assert.equal(el.timeText.textContent, '0:02.2 / 0:02.9', 'the time follows the thumb');
  timeline.frame(100);
  assert.equal(el.scrubber.valueAsNumber, 2.25);
  assert.equal(sent.length, 3, 'no seek while dragging');
  el.scrubber.fire('change');
  assert.deepEqual(sent.at(-1), { type: 'replay_control', action: 'seek', time_s: 2.25 });
  // Until the server answers, the asked position is shown, even if a periodic status
  // (still at the old place) overtakes the answer.
  timeline.onStatus(status({ paused: true, time_s: 0.4 }), 150);
  assert.equal(timeline.positionS(160), 2.25);
  timeline.onStatus(status({ paused: true, time_s: 2.25 }), 200);
  assert.equal(timeline.pendingSeekS, null);
  assert.equal(timeline.positionS(300), 2.25);
  assert.deepEqual(
    timeline.sent.map((c) => c.action),
    ['play', 'pause', 'pause', 'seek'],
  );
});

test('a seek that cannot be sent is not shown as pending', () => {
  const { timeline, el } = timelinePanel(false);
  timeline.onStatus(status({ time_s: 1 }), 0);
  el.scrubber.valueAsNumber = 2;
  el.scrubber.fire('change');
  assert.equal(timeline.pendingSeekS, null);
  assert.equal(timeline.positionS(10), 1);
  assert.deepEqual(timeline.sent, []);
});

test('a press on the thumb released without moving it ends the drag', () => {
  const { timeline, el, sent } = timelinePanel();
  timeline.onStatus(status({ paused: false, time_s: 1 }), 0);
  el.scrubber.fire('pointerdown');
  timeline.frame(500);
  assert.equal(el.scrubber.valueAsNumber, 1, 'held while pressed');
  fakeDocument.fire('pointerup'); // no input, no change: the value did not move
  assert.equal(timeline.dragging, false);
  timeline.frame(500);
  assert.ok(near(el.scrubber.valueAsNumber, 1.5), 'follows the replay again');
  assert.equal(sent.length, 0, 'nothing sent');
  assert.deepEqual(timeline.statusLog, [status({ paused: false, time_s: 1 })]);
});

test('an observer’s timeline follows the instructor’s moves but hides its controls and sends nothing', () => {
  const { timeline, el, sent } = timelinePanel();
  timeline.setControllable(false);
  assert.equal(el.playButton.hidden, true);
  assert.equal(el.speedSelect.hidden, true);
  assert.equal(el.scrubber.disabled, true, 'the scrubber only shows the position');
  assert.equal(el.hintText.textContent, 'the instructor moves the timeline');
  // The instructor plays from 0.5 s, then seeks back to 0.2 s: the observer's timeline follows.
  timeline.onStatus(status({ paused: false, time_s: 0.5 }), 0);
  timeline.frame(500);
  assert.ok(near(el.scrubber.valueAsNumber, 1.0));
  timeline.onStatus(status({ paused: false, time_s: 0.2 }), 600);
  timeline.frame(600);
  assert.ok(near(el.scrubber.valueAsNumber, 0.2));
  // Events that still reach the controls send nothing and start no drag.
  el.playButton.fire('click');
  el.speedSelect.value = '2';
  el.speedSelect.fire('change');
  el.scrubber.fire('pointerdown');
  assert.equal(timeline.dragging, false);
  el.scrubber.valueAsNumber = 2.5;
  el.scrubber.fire('input');
  el.scrubber.fire('change');
  assert.deepEqual(sent, []);
  assert.equal(timeline.pendingSeekS, null);
  timeline.frame(700);
  assert.ok(near(el.scrubber.valueAsNumber, 0.3), 'the thumb is put back where the replay is');
  // Given the controls back (an instructor's token), they work again.
  timeline.setControllable(true);
  assert.equal(el.playButton.hidden, false);
  assert.equal(el.scrubber.disabled, false);
  assert.equal(el.hintText.textContent, 'drag the slider and release to jump');
  el.playButton.fire('click');
  assert.deepEqual(sent, [{ type: 'replay_control', action: 'pause' }]);
});

test('a refused control’s reason shows beside the controls for a few seconds and ends a pending seek', () => {
  const { timeline, el, setNow } = timelinePanel();
  timeline.onStatus(status({ time_s: 1 }), 0);
  setNow(100);
  el.scrubber.valueAsNumber = 2;
  el.scrubber.fire('change');
  assert.equal(timeline.positionS(150), 2, 'the seek is shown while it waits for its answer');
  timeline.showRefused('observers cannot control the replay', 200);
  assert.equal(el.refusedText.hidden, false);
  assert.equal(el.refusedText.textContent, 'refused: observers cannot control the replay');
  assert.equal(timeline.positionS(250), 1, 'the replay did not move');
  assert.deepEqual(timeline.refusals, ['observers cannot control the replay']);
  timeline.frame(4100);
  assert.equal(el.refusedText.hidden, false);
  timeline.frame(4200);
  assert.equal(el.refusedText.hidden, true);
  assert.equal(timeline.refusedUntilMs, 0);
});

test('gaps are marked where they are on the track, in words', () => {
  const gaps = [
    { start_s: 3.25, end_s: 3.272, ticks: 22, cause: 'lost_ticks' },
    { start_s: 7, end_s: 8, ticks: 1000, cause: 'damaged' },
    { start_s: 12, end_s: 14, ticks: 1, cause: 'lost_ticks' },
  ];
  const marks = gapMarkers(gaps, 12.5);
  assert.equal(marks.length, 3);
  assert.ok(Math.abs(marks[0].leftPct - 26) < 1e-9);
  assert.ok(Math.abs(marks[0].widthPct - 0.176) < 1e-9);
  assert.equal(marks[0].title, '22 ticks lost by the loop at 0:03.2');
  assert.equal(marks[1].cause, 'damaged');
  assert.equal(marks[1].title, '1000 ticks not in the file (damaged) at 0:07.0');
  // Past the end: held on the track.
  assert.ok(Math.abs(marks[2].leftPct - 96) < 1e-9 && Math.abs(marks[2].widthPct - 4) < 1e-9);
  assert.equal(marks[2].title.startsWith('1 tick '), true);
  assert.deepEqual(gapMarkers([], 10), []);
  assert.deepEqual(gapMarkers(gaps, 0), []);
  assert.deepEqual(gapMarkers(undefined, 10), []);
});

test('a status with gaps decodes and one with a broken gap is refused by field', () => {
  const base = { type: 'replay', duration_s: 10, time_s: 0, paused: true, speed: 1, file: 'a.mcap' };
  const ok = decodeMessage(JSON.stringify({ ...base, gaps: [{ start_s: 1, end_s: 2, ticks: 3, cause: 'damaged' }] }));
  assert.equal(ok.message.gaps.length, 1);
  for (const [gap, field] of [
    [{ start_s: 2, end_s: 1, ticks: 3, cause: 'damaged' }, 'replay.gaps[0].end_s'],
    [{ start_s: 1, end_s: 2, ticks: 3, cause: 'gremlins' }, 'replay.gaps[0].cause'],
    [{ start_s: 1, end_s: 2, ticks: -1, cause: 'damaged' }, 'replay.gaps[0].ticks'],
  ]) {
    assert.throws(
      () => decodeMessage(JSON.stringify({ ...base, gaps: [gap] })),
      (e) => e instanceof ProtocolError && e.field === field,
      field,
    );
  }
});

test('stretches above the safe force are marked with how long they lasted', () => {
  const [m] = aboveSafeMarkers([{ start_s: 2.5, end_s: 3.0 }], 10);
  assert.equal(m.cause, 'above_safe');
  assert.ok(Math.abs(m.leftPct - 25) < 1e-9 && Math.abs(m.widthPct - 5) < 1e-9);
  assert.equal(m.title, 'above the safe force for 0.50 s at 0:02.5');
  assert.deepEqual(aboveSafeMarkers(undefined, 10), []);
});

test("the instructors' marks are placed on the timeline with their notes", () => {
  const [m] = markMarkers([{ id: 3, time_s: 5, note: 'too deep' }], 20);
  assert.equal(m.cause, 'mark');
  assert.ok(Math.abs(m.leftPct - 25) < 1e-9);
  assert.equal(m.title, 'mark 3 at 0:05.0: too deep');
  assert.deepEqual(markMarkers(null, 20), []);
});
