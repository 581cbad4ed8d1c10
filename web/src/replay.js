// The replay timeline: where a recording being replayed stands, and the controls that move it.
//
// The server (`softhaptic replay FILE`) sends a `replay` status (duration, position, paused,
// speed) about once a second and after every control. Between two statuses the position is
// extrapolated from the last one: position + speed × elapsed while playing, held while paused,
// so the time shown advances smoothly at display rate. The viewer moves the replay with
// `replay_control` messages (pause, play, seek, speed; see proto/WIRE.md, "Replay").
//
// `ReplayClock` and `formatReplayTime` are plain computations (unit-tested); `ReplayTimeline`
// binds them to the page's controls. `ReplayTimeline.frame()` runs every animation frame and
// allocates nothing: it writes numbers into the scrubber and rebuilds the time text only when
// the tenths of a second it shows change, at most twenty times a second whatever the speed.
//
// Only an instructor moves the replay, for everyone watching it. An observer's timeline shows
// the same position and follows every move, but its play button and speed selector are hidden
// and its scrubber disabled (`setControllable(false)`), and it sends nothing. Should a control
// be refused all the same (the server is the authority: a role can change on reconnection), the
// server's reason is shown beside the controls for a few seconds.

import { encodeReplayControl } from './protocol.js';

/**
 * A status whose position differs from the extrapolated one by more than this many seconds of
 * wall-clock time (times the speed) is a jump (a seek), not the drift between two clocks.
 */
const JUMP_TOLERANCE_WALL_S = 0.25;

/** How long a refused control's reason stays beside the controls. */
const REFUSED_SHOWN_MS = 4000;

/** How far (recording seconds) a status may be from the extrapolation and still be the same run. */
function seekTolerance(speed) {
  return JUMP_TOLERANCE_WALL_S * Math.max(1, speed);
}

/**
 * The marks of a recording's stretches without ticks (`replay.gaps`) on a timeline of
 * `durationS`: left edge and width in percent of the track (a gap too short to see still gets
 * the track's thinnest mark, in CSS), the cause, and a title in words.
 */
export function gapMarkers(gaps, durationS) {
  if (!Array.isArray(gaps) || !(durationS > 0)) return [];
  return gaps.map((g) => {
    const start = Math.min(Math.max(g.start_s / durationS, 0), 1);
    const end = Math.min(Math.max(g.end_s / durationS, start), 1);
    const what = g.cause === 'damaged' ? 'not in the file (damaged)' : 'lost by the loop';
    const ticks = g.ticks === 1 ? '1 tick' : `${g.ticks} ticks`;
    return {
      leftPct: start * 100,
      widthPct: (end - start) * 100,
      cause: g.cause,
      title: `${ticks} ${what} at ${formatReplayTime(g.start_s)}`,
    };
  });
}

/**
 * The marks of the stretches where the force was above the safe force (`replay.above_safe`), in
 * the form of `gapMarkers`.
 */
export function aboveSafeMarkers(spans, durationS) {
  if (!Array.isArray(spans) || !(durationS > 0)) return [];
  return spans.map((s) => {
    const start = Math.min(Math.max(s.start_s / durationS, 0), 1);
    const end = Math.min(Math.max(s.end_s / durationS, start), 1);
    const lasted = Math.max(0, s.end_s - s.start_s);
    return {
      leftPct: start * 100,
      widthPct: (end - start) * 100,
      cause: 'above_safe',
      title: `above the safe force for ${lasted.toFixed(2)} s at ${formatReplayTime(s.start_s)}`,
    };
  });
}

/** The instructors' marks (`replay.marks`) on the timeline, in the form of `gapMarkers`. */
export function markMarkers(marks, durationS) {
  if (!Array.isArray(marks) || !(durationS > 0)) return [];
  return marks.map((m) => ({
    leftPct: Math.min(Math.max(m.time_s / durationS, 0), 1) * 100,
    widthPct: 0,
    cause: 'mark',
    title: `mark ${m.id} at ${formatReplayTime(m.time_s)}: ${m.note}`,
  }));
}

/** Where a replay stands, from its last status; all times in seconds of recording time. */
export class ReplayClock {
  constructor() {
    /** True once a status arrived. */
    this.known = false;
    this.durationS = 0;
    /** Position at local time `anchorMs`. */
    this.anchorS = 0;
    this.anchorMs = 0;
    this.paused = true;
    this.speed = 1;
    this.file = '';
    /** Statuses taken. */
    this.statuses = 0;
  }

  /** The position at local time `nowMs`: extrapolated while playing, never past the end. */
  positionS(nowMs) {
    if (!this.known) return 0;
    if (this.paused) return this.anchorS;
    const t = this.anchorS + (nowMs - this.anchorMs) * 1e-3 * this.speed;
    return Math.min(Math.max(t, 0), this.durationS);
  }

  /**
   * Takes a validated `replay` status received at local time `nowMs`. Returns true when the
   * replay's time axis broke continuity with what was extrapolated (the first status, play after
   * a pause, a speed change, a seek): the frames that follow must not be timed against the ones
   * before.
   */
  update(status, nowMs) {
    const expected = this.positionS(nowMs);
    const tolerance = seekTolerance(status.speed);
    const broke =
      !this.known ||
      (this.paused && !status.paused) ||
      this.speed !== status.speed ||
      Math.abs(status.time_s - expected) > tolerance;
    this.known = true;
    this.durationS = status.duration_s;
    // Within one run, a status slightly behind the extrapolation (it was sent a moment before it
    // arrived, or the two clocks differ) must not make the time shown step back: hold what is
    // shown and let the run continue from there. A real jump (beyond the tolerance) is taken.
    const held = !broke && !status.paused ? Math.max(status.time_s, expected) : status.time_s;
    this.anchorS = Math.min(held, status.duration_s);
    this.anchorMs = nowMs;
    this.paused = status.paused;
    this.speed = status.speed;
    this.file = status.file;
    this.statuses++;
    return broke;
  }

  /** Forgets the replay (the viewer now watches another session). */
  reset() {
    this.known = false;
    this.durationS = 0;
    this.anchorS = 0;
    this.paused = true;
    this.speed = 1;
    this.file = '';
  }
}

/** Seconds as `m:ss.s` (tenths, truncated so the display never runs ahead); `—` if not finite. */
export function formatReplayTime(seconds) {
  if (!Number.isFinite(seconds)) return '—';
  const tenths = Math.floor(Math.max(0, seconds) * 10 + 1e-6);
  const minutes = Math.floor(tenths / 600);
  const rest = tenths - minutes * 600;
  const s = Math.floor(rest / 10);
  return `${minutes}:${s < 10 ? '0' : ''}${s}.${rest % 10}`;
}

/** The speeds offered by the selector (any other speed the server reports is added to it). */
export const REPLAY_SPEEDS = Object.freeze([0.25, 0.5, 1, 2, 4]);

/** What the line under the controls says to each role. */
const HINTS = Object.freeze({
  instructor: 'drag the slider and release to jump',
  observer: 'the instructor moves the timeline',
});

/**
 * The timeline panel: play/pause button, speed selector, scrubber and time. Shown only while the
 * viewer watches a replay. `send(text)` sends one WebSocket text frame and returns whether it
 * could; `now()` is the local clock in ms. `hintText` (what the controls do) and `refusedText`
 * (a refused control's reason) are optional.
 */
export class ReplayTimeline {
  constructor({
    panel,
    playButton,
    speedSelect,
    scrubber,
    timeText,
    fileText,
    hintText = null,
    refusedText = null,
    gapLayer = null,
    send,
    now = () => performance.now(),
  }) {
    this.el = { panel, playButton, speedSelect, scrubber, timeText, fileText, hintText, refusedText, gapLayer };
    /** The gaps drawn on the track (the status's, as JSON: redrawn only when they change). */
    this.gapsKey = '';
    this.gapsShown = [];
    this.send = send;
    this.now = now;
    this.clock = new ReplayClock();
    this.visible = false;
    /** False for an observer: the controls are hidden or disabled and nothing is sent. */
    this.controllable = true;
    /** When the refused control's reason is hidden again (local ms); 0 while none is shown. */
    this.refusedUntilMs = 0;
    /** Reasons of refused controls, newest last, the last 10 (browser tests). */
    this.refusals = [];
    /** True while the user holds the scrubber: frames do not move it under the pointer. */
    this.dragging = false;
    /** The position asked for by the last seek, shown until the server's status answers. */
    this.pendingSeekS = null;
    this.pendingUntilMs = 0;
    this.shownTenths = -1;
    this.shownDurationTenths = -1;
    this.lastTextMs = -Infinity;
    /** Controls sent and statuses received, newest last, the last 50 of each (browser tests). */
    this.sent = [];
    this.statusLog = [];
    /** Statuses received in all, so that a test can tell which of the log's arrived since. */
    this.statusesReceived = 0;
    this.lastStatus = null;

    playButton.addEventListener('click', () => this.#togglePlay());
    speedSelect.addEventListener('change', () => this.#setSpeed(Number(speedSelect.value)));
    // A disabled scrubber (an observer's) may still see pointer events: it never starts a drag.
    scrubber.addEventListener('pointerdown', () => {
      if (this.controllable) this.dragging = true;
    });
    scrubber.addEventListener('input', () => {
      if (!this.controllable) return;
      this.dragging = true;
      this.#showTime(scrubber.valueAsNumber, this.now(), true);
    });
    // `change` fires when the scrubber is released (or moved with the keyboard): seek then.
    scrubber.addEventListener('change', () => {
      this.dragging = false;
      if (this.controllable) this.#seek(scrubber.valueAsNumber);
    });
    // A press on the thumb that does not move it ends without `change`: the release anywhere
    // ends the drag (`change`, when it comes, follows the release in the same task).
    const release = () => {
      this.dragging = false;
    };
    scrubber.ownerDocument.addEventListener('pointerup', release);
    scrubber.addEventListener('pointercancel', release);
  }

  /**
   * Takes a `replay` status received at `nowMs`; shows the panel. Returns true when the replay's
   * time axis broke continuity (see `ReplayClock.update`).
   */
  onStatus(status, nowMs) {
    const broke = this.clock.update(status, nowMs);
    this.lastStatus = status;
    if (this.statusLog.length >= 50) this.statusLog.shift();
    this.statusLog.push(status);
    this.statusesReceived += 1;
    // A periodic status may overtake the answer to a seek; only the answer ends the wait.
    if (this.pendingSeekS !== null && Math.abs(status.time_s - this.pendingSeekS) <= seekTolerance(status.speed)) {
      this.pendingSeekS = null;
    }
    const { playButton, scrubber, fileText } = this.el;
    this.show();
    if (scrubber.max !== String(status.duration_s)) scrubber.max = String(status.duration_s);
    const label = status.paused ? 'play' : 'pause';
    if (playButton.dataset.action !== label) {
      playButton.dataset.action = label;
      playButton.textContent = status.paused ? '▶ play' : '❚❚ pause';
      playButton.title = status.paused ? 'play the recording' : 'pause the replay';
    }
    this.#showSpeed(status.speed);
    if (fileText.textContent !== status.file) fileText.textContent = status.file;
    this.#showGaps(status.gaps ?? [], status.above_safe ?? [], status.marks ?? [], status.duration_s);
    this.shownTenths = -1; // redraw the text now
    this.frame(nowMs);
    return broke;
  }

  /** Marks the stretches without ticks on the track, when they changed. */
  #showGaps(gaps, aboveSafe, marks, durationS) {
    const key = JSON.stringify([gaps, aboveSafe, marks, durationS]);
    if (key === this.gapsKey) return;
    this.gapsKey = key;
    this.gapsShown = [
      ...aboveSafeMarkers(aboveSafe, durationS),
      ...gapMarkers(gaps, durationS),
      ...markMarkers(marks, durationS),
    ];
    const layer = this.el.gapLayer;
    if (!layer) return;
    const doc = layer.ownerDocument;
    layer.replaceChildren(
      ...this.gapsShown.map((m) => {
        const mark = doc.createElement('div');
        mark.className = `replay-gap ${m.cause}`;
        mark.style.left = `${m.leftPct}%`;
        mark.style.width = `${m.widthPct}%`;
        mark.title = m.title;
        return mark;
      }),
    );
  }

  /** Shows the panel before the first status (the server's `hello` said it serves a replay). */
  show() {
    if (this.visible) return;
    this.visible = true;
    this.el.panel.hidden = false;
    this.shownTenths = -1;
  }

  /**
   * Gives (true: an instructor) or takes away (false: an observer) the controls: the play button
   * and the speed selector are hidden, the scrubber only shows the position, nothing is sent.
   */
  setControllable(on) {
    const { playButton, speedSelect, scrubber, hintText } = this.el;
    this.controllable = Boolean(on);
    playButton.hidden = !this.controllable;
    speedSelect.hidden = !this.controllable;
    scrubber.disabled = !this.controllable;
    if (hintText) hintText.textContent = this.controllable ? HINTS.instructor : HINTS.observer;
    if (!this.controllable) {
      this.dragging = false;
      this.pendingSeekS = null;
    }
  }

  /**
   * Shows why the server refused a control (`refused.reason`), received at `nowMs`, beside the
   * controls for a few seconds; a seek it refused is no longer shown as pending.
   */
  showRefused(reason, nowMs) {
    if (this.refusals.length >= 10) this.refusals.shift();
    this.refusals.push(reason);
    this.pendingSeekS = null;
    this.refusedUntilMs = nowMs + REFUSED_SHOWN_MS;
    const text = this.el.refusedText;
    if (!text) return;
    text.textContent = `refused: ${reason}`;
    text.hidden = false;
  }

  /** Hides the panel and forgets the replay (the viewer now watches another session). */
  hide() {
    this.visible = false;
    this.el.panel.hidden = true;
    this.clock.reset();
    this.lastStatus = null;
    this.pendingSeekS = null;
  }

  /** The position shown at `nowMs`: a seek waiting for its answer, else the clock's. */
  positionS(nowMs) {
    if (this.pendingSeekS !== null && nowMs < this.pendingUntilMs) return this.pendingSeekS;
    return this.clock.positionS(nowMs);
  }

  /** Once per animation frame: moves the scrubber and the time. Allocates nothing. */
  frame(nowMs) {
    if (this.refusedUntilMs !== 0 && nowMs >= this.refusedUntilMs) {
      this.refusedUntilMs = 0;
      if (this.el.refusedText) this.el.refusedText.hidden = true;
    }
    if (!this.visible || this.dragging) return;
    const t = this.positionS(nowMs);
    const scrubber = this.el.scrubber;
    // The scrubber's step is 0.01 s: it rounds what it is given, so compare at that grain.
    if (Math.abs(scrubber.valueAsNumber - t) > 0.006) scrubber.valueAsNumber = t;
    this.#showTime(t, nowMs, false);
  }

  #showTime(t, nowMs, force) {
    const tenths = Math.floor(t * 10 + 1e-6);
    const durationTenths = Math.floor(this.clock.durationS * 10 + 1e-6);
    if (tenths === this.shownTenths && durationTenths === this.shownDurationTenths) return;
    // The text is rebuilt at most twenty times a second, however fast the replay runs.
    if (!force && this.shownTenths >= 0 && nowMs - this.lastTextMs < 50) return;
    this.shownTenths = tenths;
    this.shownDurationTenths = durationTenths;
    this.lastTextMs = nowMs;
    this.el.timeText.textContent = `${formatReplayTime(t)} / ${formatReplayTime(this.clock.durationS)}`;
  }

  #showSpeed(speed) {
    const select = this.el.speedSelect;
    const value = String(speed);
    if (select.value === value) return;
    if (![...select.options].some((o) => o.value === value)) {
      const option = select.ownerDocument.createElement('option');
      option.value = value;
      option.textContent = `${speed}×`;
      select.appendChild(option);
    }
    select.value = value;
  }

  #control(action, options) {
    if (!this.controllable) return false;
    let text;
    try {
      text = encodeReplayControl(action, options);
    } catch (e) {
      console.warn(`softhaptic: replay control not sent: ${e.message}`);
      return false;
    }
    const ok = this.send(text);
    if (ok) {
      if (this.sent.length >= 50) this.sent.shift();
      this.sent.push(JSON.parse(text));
    }
    return ok;
  }

  #togglePlay() {
    this.#control(this.clock.paused ? 'play' : 'pause');
  }

  #setSpeed(speed) {
    // The speed goes with the action that keeps the current state.
    this.#control(this.clock.paused ? 'pause' : 'play', { speed });
  }

  #seek(timeS) {
    if (!Number.isFinite(timeS)) return;
    if (this.#control('seek', { timeS: Math.max(0, timeS) })) {
      this.pendingSeekS = timeS;
      // Without an answer within a second (a lost connection), the clock's position returns.
      this.pendingUntilMs = this.now() + 1000;
    }
  }
}
