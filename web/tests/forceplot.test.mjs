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

test('a device clock that goes backwards starts a new trace', () => {
  const plot = new ForcePlot(null);
  plot.push(1000, 1);
  plot.push(1020, 2);
  plot.push(10, 3);
  assert.deepEqual(visible(plot), [[10, 3]]);
  plot.reset();
  assert.deepEqual(visible(plot), []);
});
