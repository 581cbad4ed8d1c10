// A playout buffer for the 50 Hz contact frames.
//
// Frames arrive over the network with jitter, at 50 Hz, while the screen refreshes at 60 Hz or
// more. Drawing each frame as it arrives would stutter; instead the viewer draws the state at a
// fixed delay behind the device's clock ("playout delay", 50 ms = 2.5 frame periods by default)
// and interpolates between the two frames around that instant.
//
// The device clock is estimated from the frames' `time_ns` and their local arrival times: over
// the last few frames (200 ms), the one that arrived earliest relative to its stamp sets the
// offset between the clocks. A window rather than an all-time maximum, because the device clock
// may run at another rate than the browser's (a loaded host ticks late and its device time falls
// behind); the render time never moves backwards, so a falling offset slows the playout down for
// a moment instead of replaying.
//
// A replay may run the device clock at another rate than ours (`speed`), and pausing, seeking or
// changing speed breaks the relation between the two clocks: `restartClock(rate)` says so, and
// the offset is then taken from the frames that arrive afterwards only.
//
// Storage is a fixed ring of numbers; pushing and sampling allocate nothing.

import { CONTACT_FLAGS } from './protocol.js';

// Layout of one frame in the ring.
const T = 0; // device time, ms
const SEQ = 1;
const IN_CONTACT = 2;
const DEPTH = 3;
const A = 4; // contact radius
const RD = 5; // deformed radius
const NORMAL = 6; // 3
const POINT = 9; // 3
const POS = 12; // 3
const QUAT = 15; // 4, [x,y,z,w]
const FORCE = 19; // 3
const FLAGS = 22; // bit i = CONTACT_FLAGS[i]
const ARRIVAL = 23; // local ms
const CLOCK = 24; // device ms − rate × local arrival ms
const RATIO = 25; // the inclusions' force ratio at the contact (1 without)
const GUIDED = 26; // 1 when the frame carries guidance
const GUIDE_FORCE = 27; // 3
const GUIDE_TARGET = 30; // 3
const GUIDE_PROGRESS = 33;
const GUIDE_GAIN = 34;
const GUIDE_EFFECTIVE_GAIN = 35;
const GUIDE_ENGAGED = 36;
const GUIDE_PASS = 37;
const STRIDE = 38;

/** Bitmask of a frame's flag names, bit i for `CONTACT_FLAGS[i]`. */
export function flagBits(flags) {
  let bits = 0;
  for (let i = 0; i < flags.length; i++) {
    const k = CONTACT_FLAGS.indexOf(flags[i]);
    if (k >= 0) bits |= 1 << k;
  }
  return bits;
}

/** The interpolated state the viewer draws; one instance, rewritten by `sample`. */
export class RenderedContact {
  constructor() {
    this.valid = false;
    this.deviceTimeMs = 0;
    this.seq = 0;
    this.inContact = false;
    this.depthM = 0;
    this.contactRadiusM = 0;
    this.deformedRadiusM = 0;
    /** The inclusions' force ratio at the contact (`inclusion_force_ratio`; 1 without them). */
    this.inclusionForceRatio = 1;
    this.normal = new Float64Array([0, 1, 0]);
    this.point = new Float64Array(3);
    this.position = new Float64Array(3);
    this.orientation = new Float64Array([0, 0, 0, 1]);
    this.force = new Float64Array(3);
    this.forceMagnitudeN = 0;
    this.flags = 0;
    /** How far the render time is past the newest frame (ms); > 0 means frames are late. */
    this.lateMs = 0;
    /** True when the newest frame is older than the buffer's `staleAfterMs`. */
    this.stale = true;
    /** Whether the frame carries guidance along an expert's path (`contact.guide`). */
    this.guided = false;
    /** The guiding force, N, and its target on the expert's path (where the expert's tool was). */
    this.guideForce = new Float64Array(3);
    this.guideTarget = new Float64Array(3);
    this.guideProgress = 0;
    this.guideGain = 0;
    this.guideEffectiveGain = 0;
    this.guideEngaged = false;
    /** Passes along the path completed before this one. */
    this.guidePass = 0;
  }
}

function lerp(a, b, s) {
  return a + (b - a) * s;
}

/** Contact frames by device time: `push` each on arrival, `sample` once per animation frame. */
export class PlayoutBuffer {
  /**
   * @param {{capacity?: number, delayMs?: number, maxGapMs?: number, staleAfterMs?: number,
   *   clockWindow?: number}} [options]
   *   `delayMs`: how far behind the estimated device time to draw (40–60 ms suits 50 Hz);
   *   `maxGapMs`: two frames further apart than this are not interpolated (the older one is held);
   *   `staleAfterMs`: past the newest frame by more than this, the state is marked stale;
   *   `clockWindow`: how many recent frames the clock offset is taken from.
   */
  constructor({ capacity = 64, delayMs = 50, maxGapMs = 250, staleAfterMs = 250, clockWindow = 10 } = {}) {
    this.capacity = capacity;
    this.delayMs = delayMs;
    this.maxGapMs = maxGapMs;
    this.staleAfterMs = staleAfterMs;
    this.clockWindow = Math.max(1, Math.min(clockWindow, capacity));
    this.data = new Float64Array(capacity * STRIDE);
    this.head = 0; // index of the next write
    this.count = 0;
    this.offsetMs = 0; // device ms − rate × local ms
    this.lastRenderMs = -Infinity;
    /** Device ms per local ms: 1 live, the replay speed in a replay. */
    this.rate = 1;
    /** Frames pushed since the clock (re)started; only they set the offset. */
    this.sinceClockStart = 0;
    /** Times the clock was restarted (replay play, seek or speed change). */
    this.clockRestarts = 0;
    /** Times the device clock went backwards (server or device restarted) and the buffer reset. */
    this.resets = 0;
    this.duplicates = 0;
  }

  /** Forgets every frame (new session, reconnection, device clock reset). */
  reset() {
    this.head = 0;
    this.count = 0;
    this.lastRenderMs = -Infinity;
    this.sinceClockStart = 0;
  }

  /**
   * The device clock now runs at `rate` device ms per local ms and its relation to ours is
   * unknown (a replay resumed, jumped or changed speed). Frames are kept, so the newest one stays
   * drawn, held as if it were the render time now, until frames of the new run arrive; the next
   * frame sets the offset afresh.
   */
  restartClock(nowMs, rate = this.rate) {
    if (!(rate > 0 && Number.isFinite(rate))) throw new RangeError(`rate must be finite and > 0, got ${rate}`);
    this.rate = rate;
    this.sinceClockStart = 0;
    this.clockRestarts++;
    this.lastRenderMs = -Infinity;
    if (this.count > 0) this.offsetMs = this.newestTimeMs() - rate * (nowMs - this.delayMs);
  }

  #slot(k) {
    // k = 0 is the oldest frame.
    return ((this.head - this.count + k + this.capacity) % this.capacity) * STRIDE;
  }

  /** Device time (ms) of the newest frame, or NaN when empty. */
  newestTimeMs() {
    return this.count === 0 ? NaN : this.data[this.#slot(this.count - 1) + T];
  }

  /** Number of frames that arrived in the last `windowMs` before `nowMs` (received rate). */
  arrivalsSince(nowMs, windowMs = 1000) {
    let n = 0;
    for (let k = this.count - 1; k >= 0; k--) {
      if (this.data[this.#slot(k) + ARRIVAL] < nowMs - windowMs) break;
      n++;
    }
    return n;
  }

  /** Adds a validated `contact` message that arrived at local time `arrivalMs`. */
  push(m, arrivalMs) {
    const t = m.time_ns / 1e6;
    if (this.count > 0) {
      const newest = this.newestTimeMs();
      if (t < newest) {
        // The device clock restarted: older frames describe another run.
        this.resets++;
        this.reset();
      } else if (t === newest) {
        this.duplicates++;
        return;
      }
    }
    const d = this.data;
    const o = this.head * STRIDE;
    d[o + T] = t;
    d[o + SEQ] = m.seq;
    d[o + IN_CONTACT] = m.in_contact ? 1 : 0;
    d[o + DEPTH] = m.depth_m;
    d[o + A] = m.contact_radius_m;
    d[o + RD] = m.deformed_radius_m;
    d[o + RATIO] = m.inclusion_force_ratio ?? 1;
    for (let i = 0; i < 3; i++) {
      d[o + NORMAL + i] = m.normal[i];
      d[o + POINT + i] = m.contact_point_m[i];
      d[o + POS + i] = m.tip_in_world.position_m[i];
      d[o + FORCE + i] = m.force_n[i];
    }
    for (let i = 0; i < 4; i++) d[o + QUAT + i] = m.tip_in_world.orientation[i];
    d[o + FLAGS] = flagBits(m.flags);
    const g = m.guide;
    d[o + GUIDED] = g ? 1 : 0;
    for (let i = 0; i < 3; i++) {
      d[o + GUIDE_FORCE + i] = g ? g.force_n[i] : 0;
      d[o + GUIDE_TARGET + i] = g ? g.target_m[i] : 0;
    }
    d[o + GUIDE_PROGRESS] = g ? g.progress : 0;
    d[o + GUIDE_GAIN] = g ? g.gain : 0;
    d[o + GUIDE_EFFECTIVE_GAIN] = g ? g.effective_gain : 0;
    d[o + GUIDE_ENGAGED] = g?.engaged ? 1 : 0;
    d[o + GUIDE_PASS] = g?.pass ?? 0;
    d[o + ARRIVAL] = arrivalMs;
    d[o + CLOCK] = t - this.rate * arrivalMs;
    this.head = (this.head + 1) % this.capacity;
    if (this.count < this.capacity) this.count++;
    this.sinceClockStart++;
    // The least-delayed recent frame (of the current clock run) sets the clock offset.
    let offset = -Infinity;
    const n = Math.min(this.count, this.clockWindow, this.sinceClockStart);
    for (let k = this.count - n; k < this.count; k++) offset = Math.max(offset, d[this.#slot(k) + CLOCK]);
    this.offsetMs = offset;
  }

  /** The device time the viewer draws at local time `nowMs` (the delay is local time). */
  renderTimeMs(nowMs) {
    return this.rate * (nowMs - this.delayMs) + this.offsetMs;
  }

  /** Writes the state to draw at local time `nowMs` into `out` (a `RenderedContact`). */
  sample(nowMs, out) {
    if (this.count === 0) {
      out.valid = false;
      out.inContact = false;
      out.stale = true;
      return out;
    }
    const d = this.data;
    // Monotonic: when the offset falls (device clock slower than ours), hold instead of replaying.
    const t = Math.max(this.renderTimeMs(nowMs), this.lastRenderMs);
    this.lastRenderMs = t;
    const newest = this.#slot(this.count - 1);
    const oldest = this.#slot(0);
    let a;
    let b;
    let s;
    if (t >= d[newest + T]) {
      a = b = newest;
      s = 0;
    } else if (t <= d[oldest + T]) {
      a = b = oldest;
      s = 0;
    } else {
      // Newest first: the render time is normally within the last few frames.
      let k = this.count - 2;
      while (k > 0 && d[this.#slot(k) + T] > t) k--;
      a = this.#slot(k);
      b = this.#slot(k + 1);
      const span = d[b + T] - d[a + T];
      s = span > this.maxGapMs ? 0 : (t - d[a + T]) / span;
    }
    this.#blend(a, b, s, out);
    out.valid = true;
    out.deviceTimeMs = s === 0 ? d[a + T] : t;
    out.lateMs = t - d[newest + T];
    out.stale = out.lateMs > this.staleAfterMs * this.rate;
    return out;
  }

  #blend(a, b, s, out) {
    const d = this.data;
    const ca = d[a + IN_CONTACT] === 1;
    const cb = d[b + IN_CONTACT] === 1;
    const near = s < 0.5 ? a : b;
    out.seq = d[near + SEQ];
    out.flags = d[near + FLAGS];
    for (let i = 0; i < 3; i++) {
      out.position[i] = lerp(d[a + POS + i], d[b + POS + i], s);
      out.force[i] = lerp(d[a + FORCE + i], d[b + FORCE + i], s);
    }
    out.forceMagnitudeN = Math.hypot(out.force[0], out.force[1], out.force[2]);
    // Guidance blends between two guided frames; otherwise the nearer frame's holds.
    const ga = d[a + GUIDED] === 1;
    const gb = d[b + GUIDED] === 1;
    const sGuide = ga && gb ? s : 0;
    const h0 = ga && gb ? a : near;
    const h1 = ga && gb ? b : near;
    out.guided = d[near + GUIDED] === 1;
    for (let i = 0; i < 3; i++) {
      out.guideForce[i] = lerp(d[h0 + GUIDE_FORCE + i], d[h1 + GUIDE_FORCE + i], sGuide);
      out.guideTarget[i] = lerp(d[h0 + GUIDE_TARGET + i], d[h1 + GUIDE_TARGET + i], sGuide);
    }
    out.guideProgress = lerp(d[h0 + GUIDE_PROGRESS], d[h1 + GUIDE_PROGRESS], sGuide);
    out.guideGain = d[near + GUIDE_GAIN];
    out.guideEffectiveGain = lerp(d[h0 + GUIDE_EFFECTIVE_GAIN], d[h1 + GUIDE_EFFECTIVE_GAIN], sGuide);
    out.guideEngaged = d[near + GUIDE_ENGAGED] === 1;
    out.guidePass = d[near + GUIDE_PASS];
    slerp(d, a + QUAT, b + QUAT, s, out.orientation);

    // Contact geometry: between two frames in contact everything blends; across the start or
    // end of a contact, the geometry is the in-contact frame's and the depth (and contact
    // radius) blend toward zero, so the dimple grows and vanishes smoothly.
    const depthA = ca ? d[a + DEPTH] : 0;
    const depthB = cb ? d[b + DEPTH] : 0;
    const radA = ca ? d[a + A] : 0;
    const radB = cb ? d[b + A] : 0;
    out.depthM = lerp(depthA, depthB, s);
    out.contactRadiusM = lerp(radA, radB, s);
    out.inContact = (ca || cb) && out.depthM > 0;
    const g0 = ca ? a : b;
    const g1 = cb ? b : a;
    const sg = ca && cb ? s : 0;
    out.deformedRadiusM = lerp(d[g0 + RD], d[g1 + RD], sg);
    out.inclusionForceRatio = lerp(d[g0 + RATIO], d[g1 + RATIO], sg);
    for (let i = 0; i < 3; i++) out.point[i] = lerp(d[g0 + POINT + i], d[g1 + POINT + i], sg);
    const nx = lerp(d[g0 + NORMAL], d[g1 + NORMAL], sg);
    const ny = lerp(d[g0 + NORMAL + 1], d[g1 + NORMAL + 1], sg);
    const nz = lerp(d[g0 + NORMAL + 2], d[g1 + NORMAL + 2], sg);
    const len = Math.sqrt(nx * nx + ny * ny + nz * nz);
    if (len > 1e-12) {
      out.normal[0] = nx / len;
      out.normal[1] = ny / len;
      out.normal[2] = nz / len;
    } else {
      // Opposite normals cancel half way: keep the nearer frame's.
      out.normal[0] = d[near + NORMAL];
      out.normal[1] = d[near + NORMAL + 1];
      out.normal[2] = d[near + NORMAL + 2];
    }
  }
}

/**
 * Spherical interpolation between quaternions stored at `d[i..i+4]` and `d[j..j+4]` ([x,y,z,w]),
 * along the shorter arc, written normalised into `out`.
 */
export function slerp(d, i, j, s, out) {
  let bx = d[j],
    by = d[j + 1],
    bz = d[j + 2],
    bw = d[j + 3];
  const ax = d[i],
    ay = d[i + 1],
    az = d[i + 2],
    aw = d[i + 3];
  let cos = ax * bx + ay * by + az * bz + aw * bw;
  if (cos < 0) {
    cos = -cos;
    bx = -bx;
    by = -by;
    bz = -bz;
    bw = -bw;
  }
  let wa;
  let wb;
  if (cos > 0.9995) {
    wa = 1 - s;
    wb = s;
  } else {
    const theta = Math.acos(cos);
    const sin = Math.sin(theta);
    wa = Math.sin((1 - s) * theta) / sin;
    wb = Math.sin(s * theta) / sin;
  }
  const x = wa * ax + wb * bx;
  const y = wa * ay + wb * by;
  const z = wa * az + wb * bz;
  const w = wa * aw + wb * bw;
  const n = Math.sqrt(x * x + y * y + z * z + w * w) || 1;
  out[0] = x / n;
  out[1] = y / n;
  out[2] = z / n;
  out[3] = w / n;
  return out;
}
