// The section view's cut of the undeformed mesh (src/section.js): segments where they belong,
// none of zero length, and a buffer that grows once and is then reused.
import { test } from 'node:test';
import assert from 'node:assert/strict';

import { cutMesh, segmentBuffer } from '../src/section.js';

/** A flat grid of n × n squares on y = 0 over [0, 1]², two triangles each. */
function grid(n) {
  const positions = [];
  for (let j = 0; j <= n; j++) for (let i = 0; i <= n; i++) positions.push(i / n, 0, j / n);
  const indices = [];
  for (let j = 0; j < n; j++) {
    for (let i = 0; i < n; i++) {
      const a = j * (n + 1) + i;
      indices.push(a, a + 1, a + n + 1, a + 1, a + n + 2, a + n + 1);
    }
  }
  return { positions: Float32Array.from(positions), indices: Uint32Array.from(indices) };
}

/** The segments of `out` as [[x0, y0, z0], [x1, y1, z1]] pairs. */
function segmentsOf(out) {
  const s = [];
  for (let k = 0; k < out.segments; k++) {
    const p = out.positions.subarray(6 * k, 6 * k + 6);
    s.push([
      [p[0], p[1], p[2]],
      [p[3], p[4], p[5]],
    ]);
  }
  return s;
}

test('a plane across a flat grid cuts it along a line of the plane, edge to edge', () => {
  const { positions, indices } = grid(10);
  const distances = new Float32Array(positions.length / 3);
  const out = segmentBuffer(4);
  // x = 0.35: between grid lines, so every square of one column is cut, each triangle once.
  const n = cutMesh(positions, indices, [1, 0, 0], -0.35, distances, out);
  assert.equal(n, 20);
  let length = 0;
  for (const [p, q] of segmentsOf(out)) {
    for (const point of [p, q]) {
      assert.ok(Math.abs(point[0] - 0.35) < 1e-6, `on the plane: ${point}`);
      assert.equal(point[1], 0);
    }
    length += Math.hypot(q[0] - p[0], q[1] - p[1], q[2] - p[2]);
  }
  // The segments make up the grid's whole width along z, with no overlap.
  assert.ok(Math.abs(length - 1) < 1e-5, `length ${length}`);
});

test('a plane through grid vertices gives no segment of zero length and covers the line once', () => {
  const { positions, indices } = grid(4);
  const distances = new Float32Array(positions.length / 3);
  const out = segmentBuffer();
  cutMesh(positions, indices, [1, 0, 0], -0.5, distances, out);
  let length = 0;
  for (const [p, q] of segmentsOf(out)) {
    const l = Math.hypot(q[0] - p[0], q[1] - p[1], q[2] - p[2]);
    assert.ok(l > 1e-9, 'no degenerate segment');
    length += l;
  }
  assert.ok(Math.abs(length - 1) < 1e-5, `length ${length}`);
});

test('a plane that misses the mesh cuts nothing', () => {
  const { positions, indices } = grid(4);
  const out = segmentBuffer();
  assert.equal(cutMesh(positions, indices, [0, 1, 0], -0.01, new Float32Array(25), out), 0);
  assert.equal(out.segments, 0);
});

test('the buffer grows when a cut needs more room, then is reused as it is', () => {
  const { positions, indices } = grid(50);
  const distances = new Float32Array(positions.length / 3);
  const out = segmentBuffer(1);
  cutMesh(positions, indices, [0, 0, 1], -0.51, distances, out);
  assert.equal(out.segments, 100);
  const grown = out.positions;
  assert.ok(grown.length >= 600);
  cutMesh(positions, indices, [1, 0, 0], -0.27, distances, out);
  assert.equal(out.segments, 100);
  assert.equal(out.positions, grown, 'no new allocation for a cut that fits');
});

test('too few distances for the vertices is refused, not written out of bounds', () => {
  const { positions, indices } = grid(2);
  assert.throws(() => cutMesh(positions, indices, [1, 0, 0], 0, new Float32Array(3), segmentBuffer()), /distances/);
});
