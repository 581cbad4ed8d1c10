// The viewer's side of the WebSocket protocol (proto/WIRE.md): decoding and validating the
// server's messages and encoding the messages a viewer sends (`auth`, `replay_control`, `mark`,
// and the dashboard's `station_action`).
// The connection that carries them (URL, token, reconnection) is connection.js.
//
// Messages keep their wire names (snake_case, SI units in the names) so that what the viewer
// reads can be compared with the contract line by line. A message that breaks the contract is
// an error naming the field and the value; the connection that sent it is closed and opened
// again. An unknown message type is ignored and counted, so a newer server can add messages.

import { toolFromJson } from './deformation.js';

/** The protocol version this viewer speaks (proto/WIRE.md); `hello` and `scene` must carry it. */
export const PROTOCOL_VERSION = 1;

/** The contact flags the contract defines, in its snake_case spelling. */
export const CONTACT_FLAGS = Object.freeze([
  'saturated',
  'stiffness_capped',
  'beyond_valid_depth',
  'beyond_valid_inclination',
  'device_fault',
  'ramping',
  'passivity_damping',
  'degenerate_normal',
  'continuous_force_limited',
  'pushed_through',
  'motors_warm',
  'outside_workspace',
  'late_tick_limited',
]);

/**
 * The haptic device's states a `stats` message names (`DeviceStatus` in proto/src/wire/mod.rs), with
 * what the viewer shows for each: words a trainee understands, not a driver's code.
 */
export const DEVICE_STATUS_MESSAGES = Object.freeze({
  ok: 'device ok',
  disconnected: 'device disconnected',
  not_answering: 'device not answering',
  force_disabled: 'device force output disabled',
  needs_calibration: 'device needs calibration: put the stylus in its inkwell',
  overrun: 'device tick overran: force skipped',
  driver_error: 'device driver error',
  force_latched:
    'device force output latched off after repeated force trips: an instructor must re-arm it (or restart the server)',
  failed: 'device servo tick failed: no force until the server restarts',
  needs_calibration_reset: 'device needs calibration: hold the stylus at its reset position and press its button',
  calibration_updating: 'device updating its calibration: force resumes when it is done',
});

/**
 * What the viewer shows for a device state when the device is input only (a SpaceMouse,
 * `hello.force_feedback` false): it has no motors, so only its connection can fail.
 */
export function deviceStatusMessage(status, forceFeedback) {
  if (!forceFeedback && status === 'disconnected') return 'input device disconnected';
  if (!forceFeedback && status === 'ok') return 'input device ok';
  return DEVICE_STATUS_MESSAGES[status];
}

/**
 * Why a stretch of a replayed recording has no ticks (`replay.gaps[].cause`): the loop lost
 * them, or the file did (damage the reader skipped).
 */
export const GAP_CAUSES = Object.freeze(['lost_ticks', 'damaged']);

/** A message that breaks the contract; `field` is its dotted path. */
export class ProtocolError extends Error {
  constructor(field, message) {
    super(`${field}: ${message}`);
    this.name = 'ProtocolError';
    this.field = field;
  }
}

function show(value) {
  const s = JSON.stringify(value);
  if (s === undefined) return String(value);
  return s.length > 80 ? `${s.slice(0, 77)}...` : s;
}

function object(value, field) {
  if (value === null || typeof value !== 'object' || Array.isArray(value)) {
    throw new ProtocolError(field, `expected an object, got ${show(value)}`);
  }
  return value;
}

function finite(value, field) {
  if (typeof value !== 'number' || !Number.isFinite(value)) {
    throw new ProtocolError(field, `expected a finite number, got ${show(value)}`);
  }
  return value;
}

function nonNegative(value, field) {
  if (finite(value, field) < 0) throw new ProtocolError(field, `expected a number ≥ 0, got ${show(value)}`);
  return value;
}

function positive(value, field) {
  if (!(finite(value, field) > 0)) throw new ProtocolError(field, `expected a number > 0, got ${show(value)}`);
  return value;
}

/** A u64 on the wire; JSON numbers beyond 2^53 lose precision but stay ordered. */
function count(value, field) {
  if (typeof value !== 'number' || !Number.isInteger(value) || value < 0) {
    throw new ProtocolError(field, `expected a non-negative integer, got ${show(value)}`);
  }
  return value;
}

function string(value, field) {
  if (typeof value !== 'string') throw new ProtocolError(field, `expected a string, got ${show(value)}`);
  return value;
}

function boolean(value, field) {
  if (typeof value !== 'boolean') throw new ProtocolError(field, `expected true or false, got ${show(value)}`);
  return value;
}

function vector(value, length, field) {
  if (!Array.isArray(value) || value.length !== length) {
    throw new ProtocolError(field, `expected an array of ${length} numbers, got ${show(value)}`);
  }
  for (let i = 0; i < length; i++) finite(value[i], `${field}[${i}]`);
  return value;
}

function pose(value, field) {
  object(value, field);
  vector(value.position_m, 3, `${field}.position_m`);
  const q = vector(value.orientation, 4, `${field}.orientation`);
  const norm = Math.hypot(q[0], q[1], q[2], q[3]);
  if (!(Math.abs(norm - 1) < 1e-3)) {
    throw new ProtocolError(
      `${field}.orientation`,
      `expected a unit quaternion [x,y,z,w], got ${show(q)} (norm ${norm})`,
    );
  }
  return value;
}

function version(value, field) {
  if (value !== PROTOCOL_VERSION) {
    throw new ProtocolError(field, `this viewer speaks protocol ${PROTOCOL_VERSION}, the server sent ${show(value)}`);
  }
  return value;
}

/**
 * What a connection may do (`hello.role`): an `instructor` also moves a replay's shared timeline
 * (and later issues' instructor-only actions); an `observer` only watches.
 */
export const ROLES = Object.freeze(['instructor', 'observer']);

/** What the server serves (`hello.mode`): a `live` session or the `replay` of a recording. */
export const MODES = Object.freeze(['live', 'replay']);

/**
 * The roles of servers before roles and tokens, which sent no `mode`: every connection was a
 * `viewer` of a live session, or a `replay` viewer that anyone could control.
 */
const LEGACY_ROLES = Object.freeze({
  viewer: { role: 'observer', mode: 'live' },
  replay: { role: 'instructor', mode: 'replay' },
});

function validateHello(m) {
  version(m.protocol_version, 'hello.protocol_version');
  string(m.session_id, 'hello.session_id');
  string(m.server, 'hello.server');
  string(m.role, 'hello.role');
  if (m.force_feedback !== undefined) boolean(m.force_feedback, 'hello.force_feedback');
  if (m.accepts_marks !== undefined) boolean(m.accepts_marks, 'hello.accepts_marks');
  if (m.mode === undefined) {
    if (!ROLES.includes(m.role) && !Object.hasOwn(LEGACY_ROLES, m.role)) {
      throw new ProtocolError('hello.role', `unknown role ${show(m.role)} (known: ${ROLES.join(', ')})`);
    }
  } else {
    if (!MODES.includes(m.mode)) {
      throw new ProtocolError('hello.mode', `unknown mode ${show(m.mode)} (known: ${MODES.join(', ')})`);
    }
    if (!ROLES.includes(m.role)) {
      throw new ProtocolError('hello.role', `unknown role ${show(m.role)} (known: ${ROLES.join(', ')})`);
    }
  }
  return m;
}

/**
 * Whether the trainee feels the force (`hello.force_feedback`): false for an input-only device,
 * whose force is computed and shown but not rendered. Servers before the field: true.
 */
export function forceFeedbackOf(hello) {
  return hello.force_feedback ?? true;
}

/**
 * Whether the server takes instructors' marks (`hello.accepts_marks`, sent only when false): a
 * teaching lab's hub relays a station's stream, can neither time nor record a mark, and refuses
 * them. Without the field, a page on a hub (`onHub`: it shows a station through a hub) offers
 * none, since a hub older than the field refuses them too; any other server takes them.
 */
export function marksAcceptedOf(hello, onHub) {
  return hello.accepts_marks ?? !onHub;
}

/**
 * The role and mode of a validated `hello`: `{role, mode}`, with `role` one of `ROLES` and
 * `mode` one of `MODES`. A `hello` without `mode` (servers before roles) is read through its
 * old role: `viewer` watches a live session, `replay` controls a replay.
 */
export function accessOf(hello) {
  if (hello.mode === undefined && Object.hasOwn(LEGACY_ROLES, hello.role)) return { ...LEGACY_ROLES[hello.role] };
  return { role: hello.role, mode: hello.mode ?? 'live' };
}

function validateCalibration(c, field) {
  object(c, field);
  if (c.format !== 'softhaptic-calibration') {
    throw new ProtocolError(`${field}.format`, `expected "softhaptic-calibration", got ${show(c.format)}`);
  }
  count(c.version, `${field}.version`);
  string(c.source, `${field}.source`);
  nonNegative(c.threshold_m, `${field}.threshold_m`);
  if (!Array.isArray(c.rows)) throw new ProtocolError(`${field}.rows`, `expected an array, got ${show(c.rows)}`);
  c.rows.forEach((row, i) => {
    object(row, `${field}.rows[${i}]`);
    nonNegative(row.depth_m, `${field}.rows[${i}].depth_m`);
    nonNegative(row.deformed_radius_m, `${field}.rows[${i}].deformed_radius_m`);
  });
  const fit = object(c.fit, `${field}.fit`);
  nonNegative(fit.breakpoint_m, `${field}.fit.breakpoint_m`);
  vector(fit.linear, 2, `${field}.fit.linear`);
  vector(fit.quadratic, 3, `${field}.fit.quadratic`);
  return c;
}

/** A number ≥ 0 when present; absent or null means "not known". */
function optionalNonNegative(value, field) {
  if (value === undefined || value === null) return value;
  return nonNegative(value, field);
}

function validateContactModel(c, field) {
  object(c, field);
  string(c.label, `${field}.label`);
  if (c.corrections !== undefined) {
    if (!Array.isArray(c.corrections)) {
      throw new ProtocolError(`${field}.corrections`, `expected an array of names, got ${show(c.corrections)}`);
    }
    c.corrections.forEach((name, i) => string(name, `${field}.corrections[${i}]`));
  }
  if (c.spec !== undefined && c.spec !== null) object(c.spec, `${field}.spec`);
  optionalNonNegative(c.valid_depth_m, `${field}.valid_depth_m`);
  optionalNonNegative(c.valid_inclination_rad, `${field}.valid_inclination_rad`);
  if (c.limits_source !== undefined && c.limits_source !== null) string(c.limits_source, `${field}.limits_source`);
  return c;
}

function validateScene(m) {
  version(m.protocol_version, 'scene.protocol_version');
  try {
    toolFromJson(m.tool);
  } catch (e) {
    throw new ProtocolError('scene.tool', e.message);
  }
  const material = object(m.material, 'scene.material');
  positive(material.youngs_modulus_pa, 'scene.material.youngs_modulus_pa');
  const nu = finite(material.poisson_ratio, 'scene.material.poisson_ratio');
  if (!(nu >= 0 && nu < 0.5))
    throw new ProtocolError('scene.material.poisson_ratio', `expected a value in [0, 0.5), got ${nu}`);
  const model = object(m.model, 'scene.model');
  string(model.name, 'scene.model.name');
  nonNegative(model.valid_depth_m, 'scene.model.valid_depth_m');
  nonNegative(model.valid_inclination_rad, 'scene.model.valid_inclination_rad');
  validateCalibration(m.calibration, 'scene.calibration');
  if (!Array.isArray(m.render_meshes)) {
    throw new ProtocolError('scene.render_meshes', `expected an array, got ${show(m.render_meshes)}`);
  }
  m.render_meshes.forEach((mesh, i) => {
    const f = `scene.render_meshes[${i}]`;
    object(mesh, f);
    string(mesh.name, `${f}.name`);
    string(mesh.url, `${f}.url`);
    count(mesh.vertex_count, `${f}.vertex_count`);
    pose(mesh.object_in_world, `${f}.object_in_world`);
  });
  // Servers before the contact-model field, and their recordings, do not send it.
  if (m.contact_model !== undefined && m.contact_model !== null) {
    validateContactModel(m.contact_model, 'scene.contact_model');
  }
  const device = object(m.device, 'scene.device');
  string(device.name, 'scene.device.name');
  if (device.force_feedback !== undefined) boolean(device.force_feedback, 'scene.device.force_feedback');
  positive(device.peak_force_n, 'scene.device.peak_force_n');
  positive(device.continuous_force_n, 'scene.device.continuous_force_n');
  positive(device.max_stiffness_n_per_m, 'scene.device.max_stiffness_n_per_m');
  nonNegative(device.damping_n_s_per_m, 'scene.device.damping_n_s_per_m');
  positive(device.workspace_radius_m, 'scene.device.workspace_radius_m');
  if (m.guide !== undefined && m.guide !== null) validateGuidePath(m.guide, 'scene.guide');
  return m;
}

function validateContact(m) {
  count(m.seq, 'contact.seq');
  count(m.tick, 'contact.tick');
  count(m.time_ns, 'contact.time_ns');
  pose(m.tip_in_world, 'contact.tip_in_world');
  boolean(m.in_contact, 'contact.in_contact');
  nonNegative(m.depth_m, 'contact.depth_m');
  vector(m.normal, 3, 'contact.normal');
  vector(m.contact_point_m, 3, 'contact.contact_point_m');
  nonNegative(m.contact_radius_m, 'contact.contact_radius_m');
  nonNegative(m.deformed_radius_m, 'contact.deformed_radius_m');
  vector(m.force_n, 3, 'contact.force_n');
  if (!Array.isArray(m.flags)) throw new ProtocolError('contact.flags', `expected an array, got ${show(m.flags)}`);
  m.flags.forEach((flag, i) => {
    if (!CONTACT_FLAGS.includes(flag)) {
      throw new ProtocolError(`contact.flags[${i}]`, `unknown flag ${show(flag)} (known: ${CONTACT_FLAGS.join(', ')})`);
    }
  });
  count(m.dropped, 'contact.dropped');
  // Absent from servers and recordings that predate it (read it as 0).
  if (m.buttons !== undefined) count(m.buttons, 'contact.buttons');
  // Only in a session guided along an expert's path.
  if (m.guide !== undefined && m.guide !== null) validateGuideState(m.guide, 'contact.guide');
  // Only on an object with inclusions.
  if (m.inclusion_force_ratio !== undefined) positive(m.inclusion_force_ratio, 'contact.inclusion_force_ratio');
  return m;
}

/** A gain in [0, 1]. */
function unit(value, field) {
  const v = finite(value, field);
  if (!(v >= 0 && v <= 1)) throw new ProtocolError(field, `expected a value in [0, 1], got ${v}`);
  return v;
}

/** One frame's guidance: the pull, the target on the expert's path, how far along, the gains. */
function validateGuideState(g, field) {
  object(g, field);
  vector(g.force_n, 3, `${field}.force_n`);
  vector(g.target_m, 3, `${field}.target_m`);
  unit(g.progress, `${field}.progress`);
  unit(g.gain, `${field}.gain`);
  unit(g.effective_gain, `${field}.effective_gain`);
  boolean(g.engaged, `${field}.engaged`);
  // Absent from recordings made before passes were counted.
  if (g.pass !== undefined) count(g.pass, `${field}.pass`);
  return g;
}

/**
 * How the guidance's gain is set: `fixed` (one gain), `as_needed` (fading with the error) or
 * `schedule` (a gain per pass along the path).
 */
export const GUIDE_GAIN_MODES = ['fixed', 'as_needed', 'schedule'];

/** The expert's path in a `scene` message (`scene.guide`). */
function validateGuidePath(g, field) {
  object(g, field);
  string(g.source, `${field}.source`);
  if (!Array.isArray(g.path_m) || g.path_m.length < 2) {
    throw new ProtocolError(`${field}.path_m`, `expected an array of at least 2 points, got ${show(g.path_m)}`);
  }
  g.path_m.forEach((p, i) => vector(p, 3, `${field}.path_m[${i}]`));
  positive(g.length_m, `${field}.length_m`);
  positive(g.max_force_n, `${field}.max_force_n`);
  const gain = object(g.gain, `${field}.gain`);
  if (!GUIDE_GAIN_MODES.includes(gain.mode)) {
    throw new ProtocolError(
      `${field}.gain.mode`,
      `unknown mode ${show(gain.mode)} (known: ${GUIDE_GAIN_MODES.join(', ')})`,
    );
  }
  return g;
}

function validateStats(m) {
  finite(m.loop_rate_hz, 'stats.loop_rate_hz');
  const period = object(m.period_error_us, 'stats.period_error_us');
  for (const k of ['p50', 'p99', 'p999', 'max']) finite(period[k], `stats.period_error_us.${k}`);
  count(m.overruns, 'stats.overruns');
  count(m.standby_ticks, 'stats.standby_ticks');
  const compute = object(m.compute_us, 'stats.compute_us');
  for (const k of ['p50', 'p99', 'max']) finite(compute[k], `stats.compute_us.${k}`);
  count(m.viewers, 'stats.viewers');
  count(m.dropped_frames, 'stats.dropped_frames');
  // Absent from servers and recordings that predate it (read it as `ok`).
  if (m.device !== undefined && !Object.hasOwn(DEVICE_STATUS_MESSAGES, m.device)) {
    throw new ProtocolError(
      'stats.device',
      `unknown device state ${show(m.device)} (known: ${Object.keys(DEVICE_STATUS_MESSAGES).join(', ')})`,
    );
  }
  return m;
}

function validateReplay(m) {
  nonNegative(m.duration_s, 'replay.duration_s');
  nonNegative(m.time_s, 'replay.time_s');
  boolean(m.paused, 'replay.paused');
  positive(m.speed, 'replay.speed');
  string(m.file, 'replay.file');
  if (m.marks !== undefined) {
    if (!Array.isArray(m.marks)) throw new ProtocolError('replay.marks', `expected an array, got ${show(m.marks)}`);
    m.marks.forEach((k, i) => {
      object(k, `replay.marks[${i}]`);
      count(k.id, `replay.marks[${i}].id`);
      nonNegative(k.time_s, `replay.marks[${i}].time_s`);
      string(k.note, `replay.marks[${i}].note`);
    });
  }
  if (m.above_safe !== undefined) {
    if (!Array.isArray(m.above_safe)) {
      throw new ProtocolError('replay.above_safe', `expected an array, got ${show(m.above_safe)}`);
    }
    m.above_safe.forEach((s, i) => {
      object(s, `replay.above_safe[${i}]`);
      nonNegative(s.start_s, `replay.above_safe[${i}].start_s`);
      nonNegative(s.end_s, `replay.above_safe[${i}].end_s`);
    });
  }
  if (m.gaps !== undefined) {
    if (!Array.isArray(m.gaps)) throw new ProtocolError('replay.gaps', `expected an array, got ${show(m.gaps)}`);
    m.gaps.forEach((g, i) => {
      const field = `replay.gaps[${i}]`;
      object(g, field);
      nonNegative(g.start_s, `${field}.start_s`);
      nonNegative(g.end_s, `${field}.end_s`);
      if (g.end_s < g.start_s) throw new ProtocolError(`${field}.end_s`, `before start_s (${g.start_s})`);
      count(g.ticks, `${field}.ticks`);
      if (!GAP_CAUSES.includes(g.cause)) {
        throw new ProtocolError(`${field}.cause`, `unknown cause ${show(g.cause)} (known: ${GAP_CAUSES.join(', ')})`);
      }
    });
  }
  return m;
}

/** A request of this viewer that the server did not carry out (an observer's replay control). */
function validateRefused(m) {
  string(m.request, 'refused.request');
  string(m.reason, 'refused.reason');
  return m;
}

/** `mark`: an instructor's note on the session, maybe at a point of the object. */
function validateMark(m) {
  count(m.id, 'mark.id');
  count(m.time_ns, 'mark.time_ns');
  string(m.note, 'mark.note');
  if (m.point_m !== null) vector(m.point_m, 3, 'mark.point_m');
  return m;
}

/** Longest note of a mark, characters (`MARK_NOTE_MAX_CHARS` in proto/src/wire/mod.rs). */
export const MARK_NOTE_MAX_CHARS = 280;

/**
 * The `add_mark` an instructor sends: `note` (trimmed, 1 … 280 characters) and an optional
 * world point. Throws `ProtocolError` for what the server would refuse.
 */
export function encodeMark(note, pointM = null) {
  const text = String(note ?? '').trim();
  if (text.length === 0) throw new ProtocolError('add_mark.note', 'a mark needs a note');
  if ([...text].length > MARK_NOTE_MAX_CHARS) {
    throw new ProtocolError('add_mark.note', `at most ${MARK_NOTE_MAX_CHARS} characters`);
  }
  const m = { type: 'add_mark', note: text };
  if (pointM !== null) {
    vector(pointM, 3, 'add_mark.point_m');
    m.point_m = [...pointM];
  }
  return JSON.stringify(m);
}

/**
 * The `rearm_device` an instructor sends to re-arm a device whose force output latched off after
 * repeated force trips (`stats.device` `force_latched`).
 */
export function encodeRearm() {
  return JSON.stringify({ type: 'rearm_device' });
}

/** `metrics`: the trainee's metrics, computed by the server from every 1 kHz tick. */
function validateMetrics(m) {
  for (const f of [
    'peak_force_n',
    'peak_force_time_s',
    'time_above_safe_s',
    'time_in_contact_s',
    'path_length_in_contact_m',
    'mean_squared_jerk_m2_s6',
  ]) {
    nonNegative(m[f], `metrics.${f}`);
  }
  positive(m.safe_force_n, 'metrics.safe_force_n');
  count(m.pushes, 'metrics.pushes');
  count(m.device_fault_ticks, 'metrics.device_fault_ticks');
  count(m.ticks, 'metrics.ticks');
  object(m.flags_raised, 'metrics.flags_raised');
  for (const [name, n] of Object.entries(m.flags_raised)) count(n, `metrics.flags_raised.${name}`);
  if (m.final !== undefined) boolean(m.final, 'metrics.final');
  return m;
}

const EXERCISE_STATES = ['running', 'ended'];
const EXERCISE_KINDS = ['press', 'trace', 'palpation', 'follow'];

/**
 * `exercise`: the exercise a station runs for its trainee and where the attempt stands (the
 * task in the world frame for drawing, the time left, the result once ended).
 */
function validateExercise(m) {
  string(m.trainee, 'exercise.trainee');
  count(m.index, 'exercise.index');
  count(m.count, 'exercise.count');
  count(m.attempt, 'exercise.attempt');
  if (!EXERCISE_STATES.includes(m.state)) {
    throw new ProtocolError('exercise.state', `expected one of ${EXERCISE_STATES.join(', ')}, got ${show(m.state)}`);
  }
  count(m.time_ns, 'exercise.time_ns');
  nonNegative(m.remaining_s, 'exercise.remaining_s');
  if (m.next_in_s !== null) nonNegative(m.next_in_s, 'exercise.next_in_s');
  const e = object(m.exercise, 'exercise.exercise');
  string(e.name, 'exercise.exercise.name');
  string(e.instructions, 'exercise.exercise.instructions');
  positive(e.time_limit_s, 'exercise.exercise.time_limit_s');
  const task = object(e.task, 'exercise.exercise.task');
  if (!EXERCISE_KINDS.includes(task.kind)) {
    throw new ProtocolError(
      'exercise.exercise.task.kind',
      `expected one of ${EXERCISE_KINDS.join(', ')}, got ${show(task.kind)}`,
    );
  }
  if (task.kind === 'press') {
    vector(task.site_m, 3, 'exercise.exercise.task.site_m');
    vector(task.normal, 3, 'exercise.exercise.task.normal');
    positive(task.site_radius_m, 'exercise.exercise.task.site_radius_m');
  } else if (task.kind === 'palpation') {
    vector(task.area_centre_m, 3, 'exercise.exercise.task.area_centre_m');
    vector(task.normal, 3, 'exercise.exercise.task.normal');
    positive(task.area_radius_m, 'exercise.exercise.task.area_radius_m');
  } else if (task.kind === 'follow') {
    // The path is the guide's, in the scene message.
    string(task.expert, 'exercise.exercise.task.expert');
  } else {
    if (!Array.isArray(task.path_m) || task.path_m.length < 2) {
      throw new ProtocolError('exercise.exercise.task.path_m', 'expected a path of at least 2 points');
    }
    task.path_m.forEach((p, i) => vector(p, 3, `exercise.exercise.task.path_m[${i}]`));
    vector(task.normal, 3, 'exercise.exercise.task.normal');
  }
  if (m.result !== null) {
    const r = object(m.result, 'exercise.result');
    boolean(r.passed, 'exercise.result.passed');
    object(r.score, 'exercise.result.score');
    if (!Array.isArray(r.marks)) throw new ProtocolError('exercise.result.marks', 'expected a list');
  }
  return m;
}

/**
 * `inclusions`: where a palpation scene's stiffer inclusions are (world frame), sent only to the
 * viewers allowed to see them: instructors while an attempt runs, everyone once it has ended
 * (`revealed`).
 */
function validateInclusions(m) {
  boolean(m.revealed, 'inclusions.revealed');
  if (m.exercise_index !== null) count(m.exercise_index, 'inclusions.exercise_index');
  if (m.attempt !== null) count(m.attempt, 'inclusions.attempt');
  if (!Array.isArray(m.inclusions)) throw new ProtocolError('inclusions.inclusions', 'expected a list');
  m.inclusions.forEach((inc, i) => {
    const at = `inclusions.inclusions[${i}]`;
    object(inc, at);
    vector(inc.centre_m, 3, `${at}.centre_m`);
    positive(inc.radius_m, `${at}.radius_m`);
    positive(inc.stiffness_ratio, `${at}.stiffness_ratio`);
    nonNegative(inc.centre_depth_m, `${at}.centre_depth_m`);
  });
  return m;
}

/** What an instructor may ask of a station's exercises (`ExerciseAction`). */
export const EXERCISE_ACTIONS = Object.freeze(['next', 'repeat', 'stop']);

/** The `exercise_control` an instructor sends: start the next exercise, repeat or stop one. */
export function encodeExerciseControl(action) {
  if (!EXERCISE_ACTIONS.includes(action)) {
    throw new ProtocolError(
      'exercise_control.action',
      `expected one of ${EXERCISE_ACTIONS.join(', ')}, got ${show(action)}`,
    );
  }
  return JSON.stringify({ type: 'exercise_control', action });
}

/** Why a station raised an alert (`AlertKind` in proto/src/wire/dashboard.rs). */
export const ALERT_KINDS = Object.freeze(['above_safe_force', 'device_fault', 'needs_calibration', 'exercise_failed']);

/** A station's state as a hub lists it (`/api/stations`, `dashboard.stations[].state`). */
export const STATION_STATES = Object.freeze(['live', 'idle', 'offline']);

/** Largest force samples a summary carries: one per 100 ms of the last second. */
export const FORCE_SAMPLES_PER_S = 10;

/** Longest alert detail, characters (`MAX_ALERT_DETAIL_CHARS`). */
export const MAX_ALERT_DETAIL_CHARS = 200;

function nullable(value, field, check) {
  return value === null ? null : check(value, field);
}

function list(value, field) {
  if (!Array.isArray(value)) throw new ProtocolError(field, `expected an array, got ${show(value)}`);
  return value;
}

function oneOf(value, known, field, what) {
  if (!known.includes(value)) {
    throw new ProtocolError(field, `unknown ${what} ${show(value)} (known: ${known.join(', ')})`);
  }
  return value;
}

function validateAlert(a, field) {
  object(a, field);
  count(a.id, `${field}.id`);
  oneOf(a.kind, ALERT_KINDS, `${field}.kind`, 'alert kind');
  count(a.time_ns, `${field}.time_ns`);
  count(a.unix_ms, `${field}.unix_ms`);
  string(a.detail, `${field}.detail`);
  if ([...a.detail].length > MAX_ALERT_DETAIL_CHARS) {
    throw new ProtocolError(`${field}.detail`, `longer than ${MAX_ALERT_DETAIL_CHARS} characters`);
  }
  nullable(a.acknowledged, `${field}.acknowledged`, (ack, f) => {
    object(ack, f);
    string(ack.by, `${f}.by`);
    count(ack.unix_ms, `${f}.unix_ms`);
    return ack;
  });
  return a;
}

/** What a station says of its trainee, exercise and device once a second (`StationSummary`). */
function validateSummary(s, field) {
  object(s, field);
  nullable(s.trainee, `${field}.trainee`, string);
  nullable(s.exercise, `${field}.exercise`, (e, f) => {
    object(e, f);
    string(e.name, `${f}.name`);
    count(e.index, `${f}.index`);
    count(e.count, `${f}.count`);
    count(e.attempt, `${f}.attempt`);
    oneOf(e.state, EXERCISE_STATES, `${f}.state`, 'exercise state');
    nonNegative(e.remaining_s, `${f}.remaining_s`);
    nullable(e.passed, `${f}.passed`, boolean);
    return e;
  });
  boolean(s.in_contact, `${field}.in_contact`);
  list(s.force_n, `${field}.force_n`);
  if (s.force_n.length > FORCE_SAMPLES_PER_S) {
    throw new ProtocolError(`${field}.force_n`, `at most ${FORCE_SAMPLES_PER_S} samples, got ${s.force_n.length}`);
  }
  s.force_n.forEach((f, i) => nonNegative(f, `${field}.force_n[${i}]`));
  positive(s.safe_force_n, `${field}.safe_force_n`);
  nonNegative(s.peak_force_n, `${field}.peak_force_n`);
  nonNegative(s.time_above_safe_s, `${field}.time_above_safe_s`);
  nonNegative(s.time_in_contact_s, `${field}.time_in_contact_s`);
  count(s.pushes, `${field}.pushes`);
  const d = object(s.device, `${field}.device`);
  oneOf(d.state, Object.keys(DEVICE_STATUS_MESSAGES), `${field}.device.state`, 'device state');
  count(d.fault_ticks, `${field}.device.fault_ticks`);
  count(d.lost_ticks, `${field}.device.lost_ticks`);
  boolean(d.motors_warm, `${field}.device.motors_warm`);
  list(s.alerts, `${field}.alerts`).forEach((a, i) => validateAlert(a, `${field}.alerts[${i}]`));
  return s;
}

/** `dashboard`: the hub's view of every station, about once a second, to its dashboard pages. */
function validateDashboard(m) {
  count(m.time_unix_ms, 'dashboard.time_unix_ms');
  list(m.stations, 'dashboard.stations').forEach((s, i) => {
    const field = `dashboard.stations[${i}]`;
    object(s, field);
    string(s.name, `${field}.name`);
    string(s.scene, `${field}.scene`);
    oneOf(s.state, STATION_STATES, `${field}.state`, 'station state');
    count(s.viewers, `${field}.viewers`);
    count(s.hub_viewers, `${field}.hub_viewers`);
    nullable(s.summary, `${field}.summary`, validateSummary);
  });
  return m;
}

/** `action_result`: a station's answer to an instructor's `station_action`. */
function validateActionResult(m) {
  string(m.station, 'action_result.station');
  string(m.action, 'action_result.action');
  boolean(m.done, 'action_result.done');
  nullable(m.reason, 'action_result.reason', string);
  return m;
}

/** What an instructor may ask of a station from the dashboard (`StationAction`). */
export const STATION_ACTIONS = Object.freeze(['acknowledge', 'exercise', 'mark', 'rearm_device']);

/**
 * The `station_action` a dashboard sends: `action` is `{kind: 'acknowledge', alert}`,
 * `{kind: 'exercise', control}` (`next`, `repeat`, `stop`), `{kind: 'mark', note}` (trimmed, 1 …
 * 280 characters) or `{kind: 'rearm_device'}`. Throws `ProtocolError` for what the hub would
 * refuse, so a bad action never leaves the page.
 */
export function encodeStationAction(station, action) {
  string(station, 'station_action.station');
  if (station.length === 0) throw new ProtocolError('station_action.station', 'expected a station name');
  object(action, 'station_action.action');
  let encoded;
  switch (action.kind) {
    case 'acknowledge':
      encoded = { kind: 'acknowledge', alert: count(action.alert, 'station_action.action.alert') };
      break;
    case 'exercise':
      encoded = {
        kind: 'exercise',
        control: oneOf(action.control, EXERCISE_ACTIONS, 'station_action.action.control', 'control'),
      };
      break;
    case 'mark': {
      const note = String(action.note ?? '').trim();
      if (note.length === 0) throw new ProtocolError('station_action.action.note', 'a mark needs a note');
      if ([...note].length > MARK_NOTE_MAX_CHARS) {
        throw new ProtocolError('station_action.action.note', `at most ${MARK_NOTE_MAX_CHARS} characters`);
      }
      encoded = { kind: 'mark', note };
      break;
    }
    case 'rearm_device':
      encoded = { kind: 'rearm_device' };
      break;
    default:
      oneOf(action.kind, STATION_ACTIONS, 'station_action.action.kind', 'action');
  }
  return JSON.stringify({ type: 'station_action', station, action: encoded });
}

const VALIDATORS = {
  hello: validateHello,
  scene: validateScene,
  contact: validateContact,
  stats: validateStats,
  metrics: validateMetrics,
  mark: validateMark,
  replay: validateReplay,
  refused: validateRefused,
  exercise: validateExercise,
  inclusions: validateInclusions,
  dashboard: validateDashboard,
  action_result: validateActionResult,
};

/**
 * Encodes the `auth` message (viewer → server) that presents a token: the first message on
 * every connection of a viewer that has one. A server without tokens ignores it.
 */
export function encodeAuth(token) {
  if (typeof token !== 'string' || token.length === 0) {
    throw new ProtocolError('auth.token', 'expected a non-empty token');
  }
  return JSON.stringify({ type: 'auth', token });
}

/** Slowest and fastest replay speeds the server accepts (`ReplayControl::SPEED_RANGE`). */
export const REPLAY_SPEED_RANGE = Object.freeze([0.01, 100]);

const REPLAY_ACTIONS = ['pause', 'play', 'seek'];

/**
 * Encodes a `replay_control` message (viewer → server): `action` is `pause`, `play` or `seek`;
 * `timeS` (seconds from the recording's start) is required by `seek`; `speed` (1 = real time)
 * may go with any action and is kept by the server when absent. Throws `ProtocolError` for
 * what the server would refuse (and close the connection for), so a bad control never leaves.
 */
export function encodeReplayControl(action, { timeS, speed } = {}) {
  if (!REPLAY_ACTIONS.includes(action)) {
    throw new ProtocolError(
      'replay_control.action',
      `expected one of ${REPLAY_ACTIONS.join(', ')}, got ${show(action)}`,
    );
  }
  const message = { type: 'replay_control', action };
  if (action === 'seek' && timeS === undefined) {
    throw new ProtocolError('replay_control.time_s', 'seek needs a time');
  }
  if (timeS !== undefined) message.time_s = nonNegative(timeS, 'replay_control.time_s');
  if (speed !== undefined) {
    const [lo, hi] = REPLAY_SPEED_RANGE;
    if (!(finite(speed, 'replay_control.speed') >= lo && speed <= hi)) {
      throw new ProtocolError('replay_control.speed', `expected a speed in [${lo}, ${hi}], got ${show(speed)}`);
    }
    message.speed = speed;
  }
  return JSON.stringify(message);
}

/** Wire names of the paper's laws, as the contact-model labels spell them. */
const LAW_LABELS = { hertz: 'Hertz', sneddon_cone: 'Sneddon cone' };

/**
 * The active contact model of a validated scene, for display: `{label, corrections,
 * validDepthM, validInclinationRad, limitsSource, spec}`. From `contact_model` when the server
 * sends it; otherwise (older servers and recordings) from `model`, which names the paper's law
 * and its validity bounds but not where they come from (`limitsSource` null).
 */
export function contactModelOf(scene) {
  const c = scene.contact_model;
  if (c !== undefined && c !== null) {
    return {
      label: c.label,
      corrections: c.corrections ?? [],
      validDepthM: c.valid_depth_m ?? null,
      validInclinationRad: c.valid_inclination_rad ?? null,
      limitsSource: c.limits_source ?? null,
      spec: c.spec ?? null,
    };
  }
  return {
    label: LAW_LABELS[scene.model.name] ?? scene.model.name,
    corrections: [],
    validDepthM: scene.model.valid_depth_m,
    validInclinationRad: scene.model.valid_inclination_rad,
    limitsSource: null,
    spec: null,
  };
}

/**
 * Validates an already parsed message. Returns it (known type) or `null` (unknown type, to be
 * ignored and counted); throws `ProtocolError` for a message that breaks the contract.
 */
export function validateMessage(message) {
  object(message, 'message');
  const type = string(message.type, 'message.type');
  const validate = VALIDATORS[type];
  if (!validate) return null;
  return validate(message);
}

/**
 * Decodes one WebSocket text frame: `{kind: 'message', message}` for a known type,
 * `{kind: 'unknown', type}` for an unknown one; throws `ProtocolError` when the frame is not
 * JSON or breaks the contract.
 */
export function decodeMessage(text) {
  if (typeof text !== 'string') throw new ProtocolError('frame', 'expected a text frame');
  let parsed;
  try {
    parsed = JSON.parse(text);
  } catch (e) {
    throw new ProtocolError('frame', `not JSON (${e.message}): ${show(text)}`);
  }
  const message = validateMessage(parsed);
  if (message === null) return { kind: 'unknown', type: parsed.type };
  return { kind: 'message', message };
}
