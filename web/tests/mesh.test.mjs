// The SHM1 render-mesh layout: round trip and the errors a broken file gets.
import { test } from 'node:test';
import assert from 'node:assert/strict';

import { MeshError, encodeRenderMesh, flatGrid, parseRenderMesh } from '../src/mesh.js';

test('a grid survives encoding and decoding, byte for byte', () => {
  const grid = flatGrid(5, 0.04);
  const mesh = parseRenderMesh(encodeRenderMesh(grid), 'grid', 25);
  assert.equal(mesh.vertexCount, 25);
  assert.equal(mesh.triangleCount, 32);
  assert.deepEqual(mesh.positions, grid.positions);
  assert.deepEqual(mesh.normals, grid.normals);
  assert.deepEqual(mesh.indices, grid.indices);
});

test('grid triangles are counter-clockwise seen from +y', () => {
  const { positions: p, indices } = flatGrid(4, 1);
  for (let t = 0; t < indices.length; t += 3) {
    const [a, b, c] = [indices[t], indices[t + 1], indices[t + 2]];
    const e1 = [p[3 * b] - p[3 * a], p[3 * b + 2] - p[3 * a + 2]];
    const e2 = [p[3 * c] - p[3 * a], p[3 * c + 2] - p[3 * a + 2]];
    // y component of e1 × e2 (x, z plane): z1·x2 − x1·z2.
    assert.ok(e1[1] * e2[0] - e1[0] * e2[1] > 0, `triangle ${t / 3}`);
  }
});

test('broken files are refused with the reason', () => {
  const good = encodeRenderMesh(flatGrid(3, 0.01));
  const cases = [
    [new ArrayBuffer(4), /shorter than the 12-byte header/],
    [good.slice(0, good.byteLength - 4), /bytes, but 9 vertices and 8 triangles need/],
  ];
  const badMagic = good.slice(0);
  new Uint8Array(badMagic)[0] = 0x58;
  cases.push([badMagic, /magic is "XHM1"/]);
  const badIndex = good.slice(0);
  new DataView(badIndex).setUint32(badIndex.byteLength - 4, 9, true);
  cases.push([badIndex, /triangle 7 index 9 ≥ vertex_count 9/]);
  const nanVertex = good.slice(0);
  new DataView(nanVertex).setFloat32(12 + 4 * 4, NaN, true);
  cases.push([nanVertex, /vertex 1 position\[1\] is NaN/]);
  const shortNormal = good.slice(0);
  new DataView(shortNormal).setFloat32(12 + 9 * 12 + 4, 0.5, true);
  cases.push([shortNormal, /normal of vertex 0 has length 0.5/]);
  for (const [buffer, pattern] of cases) {
    assert.throws(
      () => parseRenderMesh(buffer, 'liver'),
      (e) => e instanceof MeshError && /liver/.test(e.message) && pattern.test(e.message),
    );
  }
  assert.throws(() => parseRenderMesh(good, 'liver', 10), /vertex_count is 9, the scene says 10/);
});
