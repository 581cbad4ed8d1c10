// The panels: the info panel (connection, role, contact, material, device, contact model), the
// flags, the haptic loop's and the trainee's figures, this viewer's own, and the instructors'
// marks list. Text is written only when it changes; `updatePanels` runs four times a second.
import { CONTACT_FLAGS, deviceStatusMessage } from './protocol.js';
import { PLAYOUT_DELAY_MS, buffer, dom, frameTimes, rendered, state, timings, view } from './context.js';

/**
 * Flags that mean the force is not what the model says (shown in red rather than amber);
 * `pushed_through`: a hand has pushed the tool past what the collision measures and the contact
 * is held on the side it entered, which an instructor should see at once; `motors_warm`: the
 * device's motors are hot and the force is held to its continuous rating.
 */
const SEVERE_FLAGS = new Set(['device_fault', 'saturated', 'degenerate_normal', 'pushed_through', 'motors_warm']);

/** The elements the page's modules use, by id. */
const DOM_IDS = [
  'view',
  'webgl-message',
  'conn-state',
  'contact-state',
  'conn-error',
  'v-depth',
  'v-rd',
  'v-force',
  'v-material',
  'v-device',
  'guide-row',
  'v-guide',
  'v-model',
  'model-details',
  'm-corrections',
  'm-depth',
  'm-inclination',
  'm-source',
  'mode',
  'feedback',
  'role',
  'token-prompt',
  'token-prompt-detail',
  'token-input',
  'token-connect',
  'token-prompt-note',
  'replay-hint',
  'replay-refused',
  'replay-panel',
  'replay-play',
  'replay-speed',
  'replay-scrubber',
  'replay-time',
  'replay-file',
  'replay-gaps',
  'map-toggle',
  'map-scale',
  'section-toggle',
  'section-key',
  'mark-form',
  'mark-note',
  'rearm-device',
  'mark-list',
  't-peak',
  't-above',
  't-contact',
  't-path',
  't-pushes',
  't-jerk',
  't-flags',
  'stations-panel',
  'stations-list',
  'flags',
  's-rate',
  's-jitter',
  's-compute',
  's-overruns',
  's-viewers',
  's-device',
  'w-rx',
  'w-fps',
  'w-deform',
  'w-moved',
  'w-delay',
  'force-plot',
  'exercise-panel',
  'ex-progress',
  'ex-name',
  'ex-instructions',
  'ex-target',
  'ex-countdown',
  'ex-result',
  'ex-verdict',
  'ex-ended',
  'ex-marks',
  'ex-next-in',
  'ex-controls',
  'ex-next',
  'ex-repeat',
  'ex-stop',
  'ex-refused',
];

/** Finds the page's elements and makes the flag chips. */
export function bindPanels() {
  for (const id of DOM_IDS) {
    dom[id] = document.getElementById(id);
  }
  dom.flagChips = CONTACT_FLAGS.map((name) => {
    const chip = document.createElement('span');
    chip.className = 'flag';
    chip.textContent = name.replaceAll('_', ' ');
    chip.title = name;
    dom.flags.appendChild(chip);
    return chip;
  });
  dom['w-delay'].textContent = `${PLAYOUT_DELAY_MS} ms`;
}

export function setText(el, text) {
  if (el.textContent !== text) el.textContent = text;
}

export function setBadge(el, text, kind) {
  setText(el, text);
  const cls = `badge ${kind}`;
  if (el.className !== cls) el.className = cls;
}

export function showConnectionState(s, detail) {
  const kind = s === 'open' ? 'ok' : s === 'connecting' || s === 'pick a station' ? 'warn' : 'bad';
  let text = s;
  if (s === 'reconnecting' && detail) text = `reconnecting in ${(detail.delayMs / 1000).toFixed(1)} s`;
  else if (s === 'unauthorized') text = detail?.reason === 'token_refused' ? 'token refused' : 'needs token';
  setBadge(dom['conn-state'], text, kind);
}

export function formatPa(pa) {
  if (pa >= 1e9) return `${(pa / 1e9).toPrecision(3)} GPa`;
  if (pa >= 1e6) return `${(pa / 1e6).toPrecision(3)} MPa`;
  if (pa >= 1e3) return `${(pa / 1e3).toPrecision(3)} kPa`;
  return `${pa.toPrecision(3)} Pa`;
}

/** A duration given in µs, in µs below 10 ms and in ms above, so the panel stays narrow. */
export function formatUs(us) {
  if (us >= 10000) return `${(us / 1000).toFixed(0)} ms`;
  if (us >= 100) return `${us.toFixed(0)} µs`;
  return `${us.toFixed(1)} µs`;
}

export function median(t) {
  if (t.count === 0) return NaN;
  const sorted = t.sorted.subarray(0, t.count);
  sorted.set(t.ms.subarray(0, t.count));
  sorted.sort();
  return sorted[t.count >> 1];
}

export function fps() {
  if (frameTimes.count < 2) return 0;
  const n = frameTimes.ms.length;
  const newest = frameTimes.ms[(frameTimes.head - 1 + n) % n];
  const oldest = frameTimes.ms[(frameTimes.head - frameTimes.count + n) % n];
  return newest > oldest ? ((frameTimes.count - 1) * 1000) / (newest - oldest) : 0;
}

export function showRole(role) {
  state.role = role;
  setBadge(dom.role, role ?? '—', role === 'instructor' ? 'active' : '');
  dom.role.title =
    role === 'instructor'
      ? 'instructor: watches, and moves a replay for everyone'
      : role === 'observer'
        ? 'observer: watches; the instructor moves a replay'
        : '';
}

/** Whether the trainee feels the force: an input-only device (a SpaceMouse) renders none. */
export function showForceFeedback(felt) {
  state.forceFeedback = felt;
  setBadge(dom.feedback, felt ? 'felt' : 'not felt', felt ? '' : 'warn');
  dom.feedback.title = felt
    ? 'the haptic device renders the force to the trainee'
    : 'input-only device (SpaceMouse): the force is computed, shown and recorded, but the trainee does not feel it';
}

/** The active contact model in the info panel: its label, and on expanding, its limits. */
export function showContactModel(model) {
  state.contactModel = model;
  dom['v-model'].textContent = model.label;
  const corrections = model.corrections.length
    ? model.corrections.map((c) => c.replaceAll('_', ' ')).join(', ')
    : "none: the paper's law";
  const depth = model.validDepthM === null ? 'not stated' : `${(model.validDepthM * 1e3).toFixed(1)} mm`;
  const inclination =
    model.validInclinationRad === null
      ? 'not stated'
      : `${((model.validInclinationRad * 180) / Math.PI).toFixed(1)}° (${model.validInclinationRad.toFixed(2)} rad)`;
  const source = model.limitsSource ?? 'not stated by this server';
  dom['m-corrections'].textContent = corrections;
  dom['m-depth'].textContent = depth;
  dom['m-inclination'].textContent = inclination;
  dom['m-source'].textContent = source;
  // The same on hover, for a glance without expanding.
  dom['model-details'].title =
    `corrections: ${corrections}\nvalid to depth ${depth}, inclination ${inclination}\nlimits from: ${source}\n` +
    'beyond them the flags "beyond valid depth" and "beyond valid inclination" light up';
}

export function setMode(replay) {
  setText(dom.mode, replay ? 'replay' : 'live view');
}

/** Lists a mark (its time and note) under the mark form. */
export function listMark(m) {
  const item = document.createElement('li');
  item.value = m.id;
  item.dataset.mark = String(m.id);
  item.textContent = `${(m.time_ns / 1e9).toFixed(1)} s: ${m.note}`;
  dom['mark-list'].append(item);
}

/** Writes every panel's figures from the latest state (four times a second). */
export function updatePanels({ connection, timeline, guideView }) {
  const error = connection.lastError ?? state.loadError;
  setText(dom['conn-error'], error ?? '');
  const replayPaused = timeline.visible && timeline.clock.known && timeline.clock.paused;
  if (!rendered.valid) setBadge(dom['contact-state'], replayPaused ? 'paused' : 'no data', '');
  else if (replayPaused) setBadge(dom['contact-state'], rendered.inContact ? 'in contact, paused' : 'free, paused', '');
  else if (rendered.stale) setBadge(dom['contact-state'], 'stale', 'warn');
  else if (rendered.inContact) setBadge(dom['contact-state'], 'in contact', 'active');
  else setBadge(dom['contact-state'], 'free', 'ok');
  if (rendered.valid) {
    setText(dom['v-depth'], `${(rendered.depthM * 1e3).toFixed(2)} mm`);
    setText(dom['v-rd'], rendered.inContact ? `${(rendered.deformedRadiusM * 1e3).toFixed(1)} mm` : '—');
    setText(dom['v-force'], `${rendered.forceMagnitudeN.toFixed(2)} N`);
  }
  const guidance = guideView?.summary(rendered);
  if (guidance) setText(dom['v-guide'], guidance);
  for (let i = 0; i < CONTACT_FLAGS.length; i++) {
    const on = rendered.valid && (rendered.flags & (1 << i)) !== 0;
    const cls = on ? (SEVERE_FLAGS.has(CONTACT_FLAGS[i]) ? 'flag on severe' : 'flag on') : 'flag';
    if (dom.flagChips[i].className !== cls) dom.flagChips[i].className = cls;
  }
  const s = state.lastStats;
  if (s) {
    setText(dom['s-rate'], `${s.loop_rate_hz.toFixed(1)} Hz`);
    setText(dom['s-jitter'], `${formatUs(s.period_error_us.p99)}, ${formatUs(s.period_error_us.max)}`);
    setText(dom['s-compute'], formatUs(s.compute_us.p99));
    setText(dom['s-overruns'], `${s.overruns} / ${s.standby_ticks}`);
    setText(dom['s-viewers'], `${s.viewers} / ${s.dropped_frames}`);
    const device = s.device ?? 'ok';
    setText(dom['s-device'], deviceStatusMessage(device, state.forceFeedback));
    const deviceClass = device === 'ok' ? '' : 'severe';
    if (dom['s-device'].className !== deviceClass) dom['s-device'].className = deviceClass;
    // Only an instructor of a live session may re-arm a latched force output.
    const rearmable = device === 'force_latched' && state.role === 'instructor' && state.mode === 'live';
    if (dom['rearm-device'].hidden === rearmable) dom['rearm-device'].hidden = !rearmable;
  }
  const m = state.lastMetrics;
  if (m) {
    setText(dom['t-peak'], `${m.peak_force_n.toFixed(2)} N at ${m.peak_force_time_s.toFixed(1)} s`);
    setText(dom['t-above'], `${m.time_above_safe_s.toFixed(2)} s over ${m.safe_force_n} N`);
    const above = m.time_above_safe_s > 0 ? 'severe' : '';
    if (dom['t-above'].className !== above) dom['t-above'].className = above;
    setText(dom['t-contact'], `${m.time_in_contact_s.toFixed(1)} s`);
    setText(dom['t-path'], `${(m.path_length_in_contact_m * 1e3).toFixed(1)} mm`);
    setText(dom['t-pushes'], String(m.pushes));
    setText(dom['t-jerk'], `${m.mean_squared_jerk_m2_s6.toExponential(2)} m²/s⁶`);
    const flags = Object.values(m.flags_raised).reduce((a, b) => a + b, 0);
    setText(dom['t-flags'], `${m.device_fault_ticks} / ${flags}`);
  }
  setText(dom['w-rx'], `${buffer.arrivalsSince(performance.now())} /s`);
  const gl = view.renderer === null ? ' (no WebGL)' : view.software ? ' (software GL)' : '';
  setText(dom['w-fps'], `${fps().toFixed(0)} fps${gl}`);
  const med = median(timings);
  const where = state.deformation === 'gpu' ? ' (GPU)' : ' (CPU)';
  setText(dom['w-deform'], Number.isNaN(med) ? '—' : `${med.toFixed(2)} ms${where}`);
  // The vertex shader does not count what it moves.
  setText(dom['w-moved'], timings.moved === null ? 'in the shader' : String(timings.moved));
}

/** The names of the flags set in `bits`. */
export function flagNames(bits) {
  return CONTACT_FLAGS.filter((_, i) => (bits & (1 << i)) !== 0);
}
