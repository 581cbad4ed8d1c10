// The playout buffer: clock estimation, interpolation between frames, contact onset, gaps and
// device clock resets.
import { test } from 'node:test';
import assert from 'node:assert/strict';

import { PlayoutBuffer, RenderedContact, flagBits, slerp } from '../src/interpolation.js';
import { CONTACT_FLAGS } from '../src/protocol.js';
import { contact } from './fixtures.mjs';

/** A 50 Hz contact frame at device time `ms`. */
function frame(ms, over = {}) {
  return contact({ seq: Math.round(ms / 20), tick: ms, time_ns: Math.round(ms * 1e6), ...over });
}

const near = (a, b, tol = 1e-9) => Math.abs(a - b) <= tol;

test('draws the playout delay behind the device clock, interpolating between frames', () => {
  const buf = new PlayoutBuffer({ delayMs: 50 });
  // Device time 1000 ms arrives at local 5000 ms, one frame every 20 ms, no jitter.
  for (let k = 0; k <= 10; k++) {
    buf.push(frame(1000 + 20 * k, { depth_m: 0.001 * k, force_n: [0, k, 0] }), 5000 + 20 * k);
  }
  const out = new RenderedContact();
  // Local 5200 = device 1200 now; drawn at 1150, between frames 7 (1140) and 8 (1160).
  buf.sample(5200, out);
  assert.ok(out.valid && !out.stale);
  assert.ok(near(out.deviceTimeMs, 1150));
  assert.ok(near(out.depthM, 0.0075), `depth ${out.depthM}`);
  assert.ok(near(out.force[1], 7.5));
  assert.ok(near(out.forceMagnitudeN, 7.5));
  assert.ok(near(out.lateMs, -50));
});

test('jittered arrivals do not move the render clock backwards', () => {
  const buf = new PlayoutBuffer({ delayMs: 50 });
  const out = new RenderedContact();
  let lastT = -Infinity;
  let seed = 7;
  const rand = () => (seed = (seed * 1103515245 + 12345) >>> 0) / 2 ** 32;
  for (let k = 0; k < 200; k++) {
    const arrival = 20 * k + 15 * rand(); // up to 15 ms of network jitter
    buf.push(frame(20 * k), arrival);
    // Sample at 60 Hz between arrivals.
    const now = arrival + 1;
    buf.sample(now, out);
    assert.ok(out.deviceTimeMs >= lastT - 1, `render time went back at frame ${k}: ${out.deviceTimeMs} < ${lastT}`);
    lastT = out.deviceTimeMs;
    // The render time stays within [delay − jitter, delay] behind the newest frame.
    assert.ok(out.lateMs <= -50 + 20 + 1e-9, `lateMs ${out.lateMs}`);
  }
});

test('a device clock slower than the browser clock (loaded host) is followed, never stale', () => {
  // The device ticks late: 15 ms of device time per 20 ms of local time, frames every 20 ms.
  const buf = new PlayoutBuffer({ delayMs: 50 });
  const out = new RenderedContact();
  let last = -Infinity;
  for (let k = 0; k < 500; k++) {
    buf.push(frame(15 * k), 20 * k);
    for (const dt of [0, 7, 14]) {
      buf.sample(20 * k + dt, out);
      assert.ok(out.deviceTimeMs >= last, 'never backwards');
      last = out.deviceTimeMs;
      if (k > 20) {
        assert.ok(!out.stale, `stale at frame ${k}`);
        // Within one clock window's drift (10 frames × 5 ms) of the intended delay.
        assert.ok(out.lateMs <= -50 + 50 + 14 + 1e-9, `lateMs ${out.lateMs} at frame ${k}`);
      }
    }
  }
});

test('tool orientation is slerped along the shorter arc', () => {
  const buf = new PlayoutBuffer({ delayMs: 0 });
  const half = Math.SQRT1_2;
  // 0° and 90° about y; the second given with a negated sign (same rotation).
  buf.push(frame(0, { tip_in_world: { position_m: [0, 0, 0], orientation: [0, 0, 0, 1] } }), 0);
  buf.push(frame(20, { tip_in_world: { position_m: [0.02, 0, 0], orientation: [0, -half, 0, -half] } }), 20);
  const out = new RenderedContact();
  buf.sample(10, out); // render time 10 → half way
  const angle =
    2 *
    Math.atan2(Math.hypot(out.orientation[0], out.orientation[1], out.orientation[2]), Math.abs(out.orientation[3]));
  assert.ok(near(angle, Math.PI / 4, 1e-9), `angle ${angle}`);
  assert.ok(near(out.position[0], 0.01));
  const q = new Float64Array(4);
  slerp(new Float64Array([0, 0, 0, 1, 0, 0, 0, 1]), 0, 4, 0.3, q);
  assert.deepEqual([...q], [0, 0, 0, 1]);
});

test('contact onset: the dimple grows from zero with the in-contact frame geometry', () => {
  const buf = new PlayoutBuffer({ delayMs: 0 });
  buf.push(
    frame(0, {
      in_contact: false,
      depth_m: 0,
      normal: [0, 1, 0],
      contact_point_m: [0, 0, 0],
      deformed_radius_m: 0,
      flags: [],
    }),
    0,
  );
  buf.push(
    frame(20, {
      in_contact: true,
      depth_m: 0.002,
      normal: [1, 0, 0],
      contact_point_m: [0.1, 0, 0],
      deformed_radius_m: 0.015,
    }),
    20,
  );
  const out = new RenderedContact();
  buf.sample(5, out);
  assert.ok(out.inContact);
  assert.ok(near(out.depthM, 0.0005));
  assert.deepEqual([...out.normal], [1, 0, 0]);
  assert.deepEqual([...out.point], [0.1, 0, 0]);
  assert.equal(out.deformedRadiusM, 0.015);
  // Flags come from the nearer frame.
  assert.equal(out.flags, 0);
  buf.sample(15, out);
  assert.equal(out.flags, flagBits(['ramping', 'beyond_valid_depth']));
});

test('normals are blended and renormalised; opposite normals fall back to the nearer frame', () => {
  const buf = new PlayoutBuffer({ delayMs: 0 });
  buf.push(frame(0, { normal: [0, 1, 0] }), 0);
  buf.push(frame(20, { normal: [1, 0, 0] }), 20);
  buf.push(frame(40, { normal: [-1, 0, 0] }), 40);
  const out = new RenderedContact();
  buf.sample(10, out);
  assert.ok(near(out.normal[0], Math.SQRT1_2) && near(out.normal[1], Math.SQRT1_2));
  buf.sample(31, out);
  assert.deepEqual([...out.normal], [-1, 0, 0]);
});

test('a long gap is held, not interpolated across, and marked stale when nothing arrives', () => {
  const buf = new PlayoutBuffer({ delayMs: 50, maxGapMs: 250, staleAfterMs: 250 });
  buf.push(frame(0, { depth_m: 0.001 }), 100);
  buf.push(frame(1000, { depth_m: 0.003 }), 1100);
  const out = new RenderedContact();
  buf.sample(600, out); // render time 500, between frames 1 s apart
  assert.equal(out.depthM, 0.001, 'held at the older frame');
  buf.sample(1100 + 50 + 300, out); // 300 ms past the newest frame
  assert.equal(out.depthM, 0.003);
  assert.ok(out.stale);
  assert.ok(near(out.lateMs, 300));
});

test('a device clock that goes backwards resets the buffer', () => {
  const buf = new PlayoutBuffer({ delayMs: 50 });
  for (let k = 0; k < 20; k++) buf.push(frame(5000 + 20 * k, { depth_m: 0.001 }), 100 + 20 * k);
  buf.push(frame(5000 + 19 * 20), 600); // duplicate
  assert.equal(buf.duplicates, 1);
  // Server restarted: device time starts again at 0.
  buf.push(frame(0, { depth_m: 0.004 }), 1000);
  assert.equal(buf.resets, 1);
  assert.equal(buf.count, 1);
  const out = new RenderedContact();
  buf.sample(1000, out);
  assert.equal(out.depthM, 0.004, 'only the new run is drawn');
  buf.push(frame(20, { depth_m: 0.006 }), 1020);
  buf.sample(1020 + 40, out); // render time 10 + ... = device 10 → between 0 and 20
  assert.ok(near(out.depthM, 0.005), `${out.depthM}`);
});

test('the ring keeps the newest frames and counts arrivals per second', () => {
  const buf = new PlayoutBuffer({ capacity: 8, delayMs: 0 });
  for (let k = 0; k < 100; k++) buf.push(frame(20 * k, { depth_m: k * 1e-5 }), 20 * k);
  assert.equal(buf.count, 8);
  assert.equal(buf.newestTimeMs(), 20 * 99);
  assert.equal(buf.arrivalsSince(20 * 99, 100), 6); // arrivals at 1880 … 1980
  const out = new RenderedContact();
  buf.sample(0, out); // far before the oldest frame kept
  assert.ok(near(out.depthM, 92e-5));
});

test('an empty buffer draws nothing', () => {
  const out = new RenderedContact();
  new PlayoutBuffer().sample(0, out);
  assert.equal(out.valid, false);
  assert.equal(out.inContact, false);
});

test('flag names map to bits in contract order', () => {
  assert.equal(flagBits(['saturated']), 1);
  assert.equal(flagBits(['continuous_force_limited']), 1 << 8);
  assert.equal(flagBits(['pushed_through']), 1 << 9);
  assert.equal(flagBits(['motors_warm']), 1 << 10);
  assert.equal(flagBits(['outside_workspace']), 1 << 11);
  assert.equal(flagBits([...CONTACT_FLAGS]), (1 << CONTACT_FLAGS.length) - 1);
});

test('guidance blends between guided frames and is absent from unguided ones', () => {
  const guide = (k) => ({
    force_n: [0.1 * k, 0, 0],
    target_m: [0.001 * k, 0.05, 0],
    progress: 0.05 * k,
    gain: 0.5,
    effective_gain: 0.5,
    engaged: true,
  });
  const buf = new PlayoutBuffer({ delayMs: 50 });
  for (let k = 0; k <= 10; k++) buf.push(frame(1000 + 20 * k, { guide: guide(k) }), 5000 + 20 * k);
  const out = new RenderedContact();
  // Drawn at device 1150: half way between frames 7 and 8.
  buf.sample(5200, out);
  assert.ok(out.guided && out.guideEngaged);
  assert.ok(near(out.guideForce[0], 0.75), `force ${out.guideForce[0]}`);
  assert.ok(near(out.guideTarget[0], 0.0075));
  assert.ok(near(out.guideProgress, 0.375));
  assert.equal(out.guideGain, 0.5);
  // A frame without guidance (a session without a guide) reads as unguided.
  const plain = new PlayoutBuffer({ delayMs: 50 });
  for (let k = 0; k <= 10; k++) plain.push(frame(1000 + 20 * k), 5000 + 20 * k);
  plain.sample(5200, out);
  assert.ok(!out.guided);
  assert.equal(out.guideForce[0], 0);
});
