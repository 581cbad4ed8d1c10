// The force plot's sample window (drawing itself is checked in the browser test).
import { test } from 'node:test';
import assert from 'node:assert/strict';

import { ForcePlot } from '../src/forceplot.js';

function visible(plot) {
  const out = [];
  plot.forEachVisible((t, f) => out.push([t, f]));
  return out;
}

test('keeps the last five seconds of samples, oldest first', () => {
  const plot = new ForcePlot(null, { windowMs: 5000, capacity: 512 });
  for (let k = 0; k <= 400; k++) plot.push(20 * k, k / 100); // 8 s at 50 Hz
  const seen = visible(plot);
  assert.equal(seen.length, 251); // 3000 ms … 8000 ms
  assert.deepEqual(seen[0], [3000, 1.5]);
  assert.deepEqual(seen.at(-1), [8000, 4]);
});

test('the ring overwrites the oldest samples when full', () => {
  const plot = new ForcePlot(null, { windowMs: 1e9, capacity: 8 });
  for (let k = 0; k < 20; k++) plot.push(k, k);
  assert.deepEqual(
    visible(plot).map(([t]) => t),
    [12, 13, 14, 15, 16, 17, 18, 19],
  );
});

test('a replay sought backwards keeps what it had played before the new position', () => {
  const plot = new ForcePlot(null, { windowMs: 5000 });
  for (let k = 0; k <= 500; k++) plot.push(20 * k, k); // 0 … 10 s
  plot.push(6000, -1); // sought back to 6 s
  const seen = visible(plot);
  assert.deepEqual(seen.at(-1), [6000, -1]);
  assert.deepEqual(seen.at(-2), [5980, 299], 'the samples before 6 s stay');
  assert.deepEqual(seen[0], [1000, 50], 'five seconds of them');
  assert.equal(seen.length, 251);
  // Playing on from there replaces what was dropped, in order.
  plot.push(6020, 301);
  assert.deepEqual(visible(plot).slice(-3), [
    [5980, 299],
    [6000, -1],
    [6020, 301],
  ]);
});

test('a clock back to before every sample starts a new trace', () => {
  const plot = new ForcePlot(null);
  plot.push(1000, 1);
  plot.push(1020, 2);
  plot.push(10, 3);
  assert.deepEqual(visible(plot), [[10, 3]]);
  plot.push(10, 4); // the same time again replaces the sample
  assert.deepEqual(visible(plot), [[10, 4]]);
  plot.reset();
  assert.deepEqual(visible(plot), []);
});

test('the visible window of a long history is found from the newest sample', () => {
  const plot = new ForcePlot(null, { windowMs: 100 });
  for (let k = 0; k < 30000; k++) plot.push(k, 1);
  const seen = visible(plot);
  assert.equal(seen.length, 101);
  assert.equal(seen[0][0], 29899);
});
