// The deformation profile against the shared vectors written by the Rust reference, against
// the wire contract's definition, and MeshDeformer on real grids. Long (over 700 lines) because
// both profiles, the paper's and the FEM's, are checked those same three ways with shared helpers.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { fileURLToPath } from 'node:url';

import { MeshDeformer } from '../src/deformer.js';
import {
  contactRadius,
  depression,
  depressionAt,
  exactSphereContactRadius,
  profileSetup,
  profileTable,
  stiffenSurface,
  stiffenedDeformedRadius,
  surfaceDepressionAt,
  surfaceFamilyFromJson,
  surfaceRadialDisplacementAt,
  surfaceSetup,
  surfaceTable,
  surfaceTableAt,
  surfaceTableRadialAt,
  toolFromJson,
  toolShape,
} from '../src/deformation.js';
import { flatGrid } from '../src/mesh.js';

const VECTORS = fileURLToPath(new URL('../../proto/vectors/deformation.json', import.meta.url));
const SURFACE_VECTORS = fileURLToPath(new URL('../../proto/vectors/surface_profile.json', import.meta.url));
const MM = 1e-3;
const sphere = toolFromJson({ shape: 'sphere', radius_m: 10 * MM });
const cone = toolFromJson({ shape: 'cone', half_angle_rad: Math.PI / 4, radius_m: 10 * MM });

/** Equal within 1e-9 relative (and 1e-15 m absolute for values that should be zero). */
function close(actual, expected, what) {
  const tol = 1e-9 * Math.abs(expected) + 1e-15;
  assert.ok(Math.abs(actual - expected) <= tol, `${what}: got ${actual}, expected ${expected}`);
}

/** JSON cannot carry NaN or ±∞; the vectors may spell them as strings. */
function num(x) {
  if (x === 'NaN' || x === 'nan') return NaN;
  if (x === 'inf' || x === 'Infinity' || x === '+inf') return Infinity;
  if (x === '-inf' || x === '-Infinity') return -Infinity;
  return x;
}

test('profile equals the Rust reference on every shared vector', () => {
  const vectors = JSON.parse(readFileSync(VECTORS, 'utf8'));
  const list = Array.isArray(vectors) ? vectors : vectors.vectors;
  assert.ok(Array.isArray(list) && list.length >= 10, 'the vector file holds a list of cases');
  for (const [i, v] of list.entries()) {
    const z = depression(
      toolShape(v.tool),
      num(v.depth_m),
      num(v.contact_radius_m),
      num(v.deformed_radius_m),
      num(v.r_m),
    );
    close(z, num(v.depression_m), `vector ${i} ${JSON.stringify(v)}`);
  }
});

test("the exact sphere's contact radius equals the Rust reference on every sphere vector", () => {
  const list = JSON.parse(readFileSync(VECTORS, 'utf8'));
  const spheres = list.filter((v) => v.tool.shape === 'sphere');
  assert.ok(spheres.length > 0 && spheres.every((v) => typeof v.exact_sphere_contact_radius_m === 'number'));
  for (const [i, v] of spheres.entries()) {
    const a = exactSphereContactRadius(v.tool.radius_m, num(v.depth_m));
    close(a, v.exact_sphere_contact_radius_m, `sphere vector ${i} ${JSON.stringify(v)}`);
  }
  // The cases reach past δ = R, where the exact sphere's contact is still narrower than the tool.
  assert.ok(
    spheres.some((v) => num(v.depth_m) >= v.tool.radius_m && v.exact_sphere_contact_radius_m < 0.9 * v.tool.radius_m),
  );
});

test("the exact sphere's contact radius solves its law, is Hertz's when shallow and stays inside the tool", () => {
  const R = 10 * MM;
  // δ = (a/2)·ln((R+a)/(R−a)), written with log1p so that it is accurate for a ≪ R.
  const depthOf = (a) => 0.5 * a * Math.log1p((2 * a) / (R - a));
  let last = 0;
  for (let k = 1; k <= 200; k++) {
    const d = 0.1 * MM * k;
    const a = exactSphereContactRadius(R, d);
    assert.ok(a > last && a < Math.sqrt(R * d) && a < R, `δ = ${d}: a = ${a}`);
    if (a < 0.999 * R) close(depthOf(a), d, `δ = ${d}`);
    last = a;
  }
  close(exactSphereContactRadius(R, R), 0.8335565596 * R, 'δ = R');
  assert.ok(Math.abs(exactSphereContactRadius(R, 1e-6 * R) / Math.sqrt(R * 1e-6 * R) - 1) < 1e-6);
  for (const d of [0, -MM, NaN, -Infinity]) assert.equal(exactSphereContactRadius(R, d), 0);
  for (const r of [0, -R, NaN, Infinity]) assert.equal(exactSphereContactRadius(r, MM), 0);
  assert.equal(exactSphereContactRadius(R, Infinity), R);
});

test('centre of the contact is pressed by the full depth', () => {
  for (const d of [1e-9, 0.5 * MM, 3 * MM, 9 * MM]) {
    close(depression(sphere, d, contactRadius(sphere, d), 30 * MM, 0), d, `sphere δ=${d}`);
    close(depression(cone, d, contactRadius(cone, d), 30 * MM, 0), d, `cone δ=${d}`);
  }
});

test('inside the contact the surface follows the tool', () => {
  const d = 4 * MM;
  const a = contactRadius(sphere, d);
  close(a, Math.sqrt(10 * MM * d), 'Hertz contact radius');
  for (let k = 0; k < 20; k++) {
    const r = (a * k) / 20;
    const expected = d - (10 * MM - Math.sqrt((10 * MM) ** 2 - r * r));
    close(depression(sphere, d, a, 30 * MM, r), expected, `sphere r=${r}`);
  }
  const ac = contactRadius(cone, d);
  close(ac, (2 * d) / Math.PI, 'Sneddon contact radius at 45°');
  for (let k = 0; k < 20; k++) {
    const r = (ac * k) / 20;
    close(depression(cone, d, ac, 30 * MM, r), d - r, `cone r=${r}`);
  }
});

test('flank lies on the quadratic Bézier through P0, P1, P2', () => {
  const d = 4 * MM;
  const a = contactRadius(sphere, d);
  const R = 10 * MM;
  const rd = 30 * MM;
  const p = profileSetup(sphere, d, a, rd);
  const z0 = d - (R - Math.sqrt(R * R - a * a));
  const slope = a / Math.sqrt(R * R - a * a);
  close(p.z0, z0, 'z0');
  close(p.r1, a + z0 / slope, 'r1 where the tool tangent meets the surface');
  for (let k = 0; k <= 10; k++) {
    const t = k / 10;
    const r = (1 - t) ** 2 * a + 2 * t * (1 - t) * p.r1 + t * t * rd;
    const z = (1 - t) ** 2 * z0;
    assert.ok(Math.abs(depressionAt(p, r) - z) < 1e-12, `t=${t}`);
  }
  // Leaves P0 along the tool's tangent.
  const h = 1e-9;
  const slopeOut = (depressionAt(p, a) - depressionAt(p, a + h)) / h;
  assert.ok(Math.abs(slopeOut / slope - 1) < 1e-3, `slope ${slopeOut} vs tool ${slope}`);
});

test('nothing moves at or beyond the deformed radius', () => {
  const d = 4 * MM;
  for (const r of [30 * MM, 30.0001 * MM, 1, 1e300]) {
    assert.equal(depression(sphere, d, contactRadius(sphere, d), 30 * MM, r), 0);
  }
  assert.ok(depression(sphere, d, contactRadius(sphere, d), 30 * MM, 29.9 * MM) > 0);
});

test('degenerate inputs have the contract answers', () => {
  for (const d of [0, -1, NaN, Infinity]) assert.equal(depression(sphere, d, 1 * MM, 20 * MM, 0), 0, `δ=${d}`);
  const d = 2 * MM;
  const a = contactRadius(sphere, d);
  // NaN or negative r behaves as r = 0.
  assert.equal(depression(sphere, d, a, 20 * MM, NaN), depression(sphere, d, a, 20 * MM, 0));
  assert.equal(depression(sphere, d, a, 20 * MM, -5), depression(sphere, d, a, 20 * MM, 0));
  // Zero contact radius: horizontal tool slope, r1 = R_d.
  const p = profileSetup(sphere, d, 0, 20 * MM);
  assert.equal(p.r1, 20 * MM);
  assert.equal(depressionAt(p, 0), d);
  // R_d inside the contact is lifted to a_eff + z0.
  const q = profileSetup(sphere, 4 * MM, contactRadius(sphere, 4 * MM), 0.1 * MM);
  close(q.rdEff, q.aEff + q.z0, 'R_d_eff');
  // Contact wider than the tool: a_eff = R, vertical tangent, r1 = a_eff.
  const w = profileSetup(sphere, 15 * MM, contactRadius(sphere, 15 * MM), 60 * MM);
  assert.equal(w.aEff, 10 * MM);
  close(w.z0, 5 * MM, 'z0 past the tool radius');
  assert.equal(w.r1, 10 * MM);
  // An invalid tool deforms nothing.
  assert.equal(depression(toolShape({ shape: 'sphere', radius_m: -1 }), d, a, 20 * MM, 0), 0);
  assert.throws(() => toolFromJson({ shape: 'cone', half_angle_rad: Math.PI / 2, radius_m: 0.01 }), /half_angle_rad/);
});

test('profile is finite, bounded by δ, monotone and continuous over a sweep of inputs', () => {
  for (const tool of [sphere, cone]) {
    for (const dmm of [0.01, 0.5, 2, 4.3, 7, 12]) {
      for (const rdmm of [0, 1, 5, 20, 60]) {
        const d = dmm * MM;
        const p = profileSetup(tool, d, contactRadius(tool, d), rdmm * MM);
        const n = 4000;
        const rMax = p.rdEff * 1.2;
        const step = rMax / n;
        // No step exceeds what the steepest slope allows: the tool's at the contact rim, or
        // the flank's at P0, z0 / (r1 − a) (the flank's slope only decreases toward R_d).
        const rim = tool.shape === 'sphere' ? p.aEff / Math.sqrt((10 * MM) ** 2 - p.aEff ** 2) : 1 / tool.tanAlpha;
        const maxSlope = Math.max(rim, p.r1 > p.aEff ? p.z0 / (p.r1 - p.aEff) : 0);
        let prev = depressionAt(p, 0);
        for (let k = 1; k <= n; k++) {
          const z = depressionAt(p, (rMax * k) / n);
          assert.ok(Number.isFinite(z) && z >= 0 && z <= d, `${tool.shape} δ=${dmm}mm R_d=${rdmm}mm`);
          assert.ok(z <= prev + 1e-15, 'monotone in r');
          if (Number.isFinite(maxSlope)) {
            assert.ok(prev - z <= maxSlope * step * 1.01 + 1e-15, `jump at r=${(rMax * k) / n}, δ=${dmm}mm`);
          }
          prev = z;
        }
      }
    }
  }
});

/** Brute-force reference: which vertices move and where, straight from the contract. */
function bruteForce(rest, contact, tool) {
  const p = profileSetup(tool, contact.depthM, contact.contactRadiusM, contact.deformedRadiusM);
  const [nx, ny, nz] = contact.normal;
  const out = new Map();
  for (let i = 0; i < rest.length / 3; i++) {
    const vx = rest[3 * i] - contact.point[0];
    const vy = rest[3 * i + 1] - contact.point[1];
    const vz = rest[3 * i + 2] - contact.point[2];
    const ax = vx * nx + vy * ny + vz * nz;
    if (Math.abs(ax) > p.rdEff) continue;
    const r = Math.hypot(vx - ax * nx, vy - ax * ny, vz - ax * nz);
    const z = depressionAt(p, r);
    if (z > 0) out.set(i, z);
  }
  return out;
}

function pressAt(x, z, depthM, rdM, normal = [0, 1, 0]) {
  return {
    inContact: true,
    depthM,
    contactRadiusM: contactRadius(sphere, depthM),
    deformedRadiusM: rdM,
    point: [x, 0, z],
    normal,
  };
}

test('applyDeformation moves exactly the vertices within R_d, by the profile', () => {
  const grid = flatGrid(100, 0.2);
  const out = Float32Array.from(grid.positions);
  const normals = Float32Array.from(grid.normals);
  const deformer = new MeshDeformer(grid.positions, grid.normals, { cellSizeM: 0.004 });
  const contact = pressAt(0.013, -0.021, 3 * MM, 18 * MM);
  deformer.apply(out, normals, contact, sphere);
  const expected = bruteForce(grid.positions, contact, sphere);
  assert.ok(expected.size > 50, `a press moves many vertices (${expected.size})`);
  assert.equal(deformer.movedCount, expected.size);
  for (let i = 0; i < deformer.vertexCount; i++) {
    const dy = grid.positions[3 * i + 1] - out[3 * i + 1];
    const z = expected.get(i) ?? 0;
    assert.ok(Math.abs(dy - z) < 1e-7, `vertex ${i}: moved ${dy}, profile ${z}`);
    assert.equal(out[3 * i], grid.positions[3 * i], 'a flat press moves along −n only');
    if (z === 0) assert.equal(out[3 * i + 1], grid.positions[3 * i + 1], `vertex ${i} outside R_d moved`);
  }
  // The vertex nearest the axis sinks by about δ.
  let best = 0;
  let bestR = Infinity;
  for (let i = 0; i < deformer.vertexCount; i++) {
    const r = Math.hypot(grid.positions[3 * i] - 0.013, grid.positions[3 * i + 2] + 0.021);
    if (r < bestR) [best, bestR] = [i, r];
  }
  const sunk = grid.positions[3 * best + 1] - out[3 * best + 1];
  assert.ok(Math.abs(sunk - depression(sphere, 3 * MM, contactRadius(sphere, 3 * MM), 18 * MM, bestR)) < 1e-7);
  assert.ok(sunk > 0.9 * 3 * MM, `vertex under the tool sank ${sunk}`);
  // Normals of moved vertices stay unit and tilt toward the axis on the flank.
  for (const i of expected.keys()) {
    const len = Math.hypot(normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]);
    assert.ok(Math.abs(len - 1) < 1e-5);
  }
});

test("the paper profile's table, which the vertex shader draws, follows the exact profile", () => {
  for (const [tool, name] of [
    [sphere, 'sphere'],
    [cone, 'cone'],
  ]) {
    for (const depthMm of [0.5, 1, 3, 6, 9]) {
      const d = depthMm * MM;
      const p = profileSetup(tool, d, contactRadius(tool, d), 2.5 * d + 2 * MM, {});
      const table = profileTable(p, {});
      assert.equal(table.reachM, p.rdEff, `${name} ${depthMm} mm: the table reaches R_d,eff`);
      assert.ok(
        table.u.every((u) => u === 0),
        'the Bézier moves nothing sideways',
      );
      let worst = 0;
      for (let k = 0; k <= 20000; k++) {
        const r = (k / 20000) * 1.02 * p.rdEff;
        worst = Math.max(worst, Math.abs(surfaceTableAt(table, r) - depressionAt(p, r)));
      }
      assert.ok(worst < 0.5e-6, `${name} ${depthMm} mm: worst ${worst} m from the exact profile`);
    }
  }
  // Nothing pressed: a table of zero reach, which draws the rest shape.
  const none = profileTable(profileSetup(sphere, 0, 0, 0, {}), {});
  assert.equal(none.reachM, 0);
  assert.equal(surfaceTableAt(none, 0), 0);
});

test('the previous dimple is restored when the contact moves or ends', () => {
  const grid = flatGrid(60, 0.1);
  const out = Float32Array.from(grid.positions);
  const normals = Float32Array.from(grid.normals);
  const deformer = new MeshDeformer(grid.positions, grid.normals);
  deformer.apply(out, normals, pressAt(-0.02, 0, 4 * MM, 15 * MM), sphere);
  const first = deformer.movedCount;
  assert.ok(first > 0);
  const touched = deformer.apply(out, normals, pressAt(0.02, 0, 4 * MM, 15 * MM), sphere);
  assert.equal(touched, first + deformer.movedCount, 'disjoint dimples: restored + moved are both listed');
  const expected = bruteForce(grid.positions, pressAt(0.02, 0, 4 * MM, 15 * MM), sphere);
  for (let i = 0; i < deformer.vertexCount; i++) {
    const dy = grid.positions[3 * i + 1] - out[3 * i + 1];
    assert.ok(Math.abs(dy - (expected.get(i) ?? 0)) < 1e-7, `vertex ${i}`);
  }
  deformer.apply(out, normals, { inContact: false }, sphere);
  assert.deepEqual(out, grid.positions, 'out of contact, every vertex is back at rest');
  assert.deepEqual(normals, grid.normals, 'and so is every normal');
  assert.equal(deformer.movedCount, 0);
});

test('the far side of a thin object never moves', () => {
  // Two parallel sheets 30 mm apart; pressing the top one with R_d = 20 mm must not pull the
  // bottom sheet, whose vertices lie within R_d of the axis but farther than R_d along it (the
  // contract moves a vertex only when |(v − c)·n| ≤ R_d_eff).
  const top = flatGrid(40, 0.1);
  const n = top.positions.length / 3;
  const rest = new Float32Array(n * 6);
  rest.set(top.positions);
  for (let i = 0; i < n; i++) {
    rest[3 * (n + i)] = top.positions[3 * i];
    rest[3 * (n + i) + 1] = -0.03; // 30 mm below: beyond R_d along the axis
    rest[3 * (n + i) + 2] = top.positions[3 * i + 2];
  }
  const out = Float32Array.from(rest);
  const deformer = new MeshDeformer(rest, null);
  deformer.apply(out, null, pressAt(0, 0, 5 * MM, 20 * MM), sphere);
  assert.ok(deformer.movedCount > 0);
  for (let i = n; i < 2 * n; i++) assert.equal(out[3 * i + 1], rest[3 * i + 1], `bottom vertex ${i - n}`);
});

test('a tilted contact on a scattered cloud matches the brute-force rule', () => {
  // Deterministic pseudo-random cloud, to exercise every grid cell boundary.
  let seed = 12345;
  const rand = () => (seed = (seed * 1103515245 + 12345) >>> 0) / 2 ** 32;
  const count = 20000;
  const rest = new Float32Array(count * 3);
  for (let i = 0; i < rest.length; i++) rest[i] = (rand() - 0.5) * 0.1;
  const out = Float32Array.from(rest);
  const deformer = new MeshDeformer(rest, null, { cellSizeM: 0.0037 });
  const len = Math.hypot(0.3, 1, -0.2);
  const contact = {
    inContact: true,
    depthM: 3 * MM,
    contactRadiusM: 2 * MM,
    deformedRadiusM: 12 * MM,
    point: [0.01, 0.0, -0.005],
    normal: [0.3 / len, 1 / len, -0.2 / len],
  };
  deformer.apply(out, null, contact, cone);
  const expected = bruteForce(rest, contact, cone);
  assert.equal(deformer.movedCount, expected.size);
  for (const [i, z] of expected) {
    const moved = Math.hypot(
      out[3 * i] - rest[3 * i],
      out[3 * i + 1] - rest[3 * i + 1],
      out[3 * i + 2] - rest[3 * i + 2],
    );
    assert.ok(Math.abs(moved - z) < 1e-7, `vertex ${i}`);
  }
});

test('non-finite contacts and meshes are handled without NaN', () => {
  const grid = flatGrid(20, 0.05);
  const out = Float32Array.from(grid.positions);
  const deformer = new MeshDeformer(grid.positions, grid.normals);
  deformer.apply(out, null, { ...pressAt(0, 0, 2 * MM, 10 * MM), normal: [0, 0, 0] }, sphere);
  deformer.apply(out, null, { ...pressAt(0, 0, 2 * MM, 10 * MM), point: [NaN, 0, 0] }, sphere);
  deformer.apply(out, null, pressAt(0, 0, NaN, 10 * MM), sphere);
  assert.deepEqual(out, grid.positions);
  const bad = Float32Array.from(grid.positions);
  bad[7] = NaN;
  assert.throws(() => new MeshDeformer(bad), /vertex 2 has a non-finite position/);
});

test('moved vertices get the normal of the deformed surface', () => {
  // On a flat sheet the deformed surface is y = −z(r); its normal is ∝ n + z′(r)·e_r.
  const grid = flatGrid(120, 0.1);
  const out = Float32Array.from(grid.positions);
  const normals = Float32Array.from(grid.normals);
  const deformer = new MeshDeformer(grid.positions, grid.normals);
  const contact = pressAt(0.0011, -0.0007, 4 * MM, 20 * MM);
  deformer.apply(out, normals, contact, sphere);
  const p = profileSetup(sphere, contact.depthM, contact.contactRadiusM, contact.deformedRadiusM);
  let checked = 0;
  for (let k = 0; k < deformer.movedCount; k++) {
    const i = deformer.moved[k];
    const ex = grid.positions[3 * i] - contact.point[0];
    const ez = grid.positions[3 * i + 2] - contact.point[2];
    const r = Math.hypot(ex, ez);
    const h = 1e-7;
    if (r < 2 * h || Math.abs(r - p.aEff) < 2 * h || r > p.rdEff - 2 * h) continue; // kinks
    const slope = (depressionAt(p, r + h) - depressionAt(p, r - h)) / (2 * h);
    const len = Math.hypot(1, slope);
    const expected = [(slope * ex) / r / len, 1 / len, (slope * ez) / r / len];
    const got = [normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]];
    const err = Math.hypot(got[0] - expected[0], got[1] - expected[1], got[2] - expected[2]);
    assert.ok(err < 1e-4, `vertex ${i} at r=${r}: normal ${got}, expected ${expected}`);
    checked++;
  }
  assert.ok(checked > 100, `${checked} normals checked`);
});

// ----- the `fem` profile -----

const surfaceVectors = JSON.parse(readFileSync(SURFACE_VECTORS, 'utf8'));
const families = surfaceVectors.families.map(surfaceFamilyFromJson);

test('the fem profile and its drawn table equal the Rust reference on every shared vector', () => {
  assert.ok(surfaceVectors.cases.length > 100, 'the vector file holds the cases');
  // A vector file written before sideways motion has neither a family with it nor the cases'
  // radial fields, and then every family draws u = 0; once a family has it, every case must
  // carry both (a missing one compares as NaN and fails).
  const sideways = families.some((f) => f.rowLateral.some(Boolean));
  const radial = (x) => (x === undefined ? (sideways ? NaN : 0) : x);
  let movedSideways = 0;
  for (const [i, c] of surfaceVectors.cases.entries()) {
    const p = surfaceSetup(families[c.family], toolShape(c.tool), num(c.depth_m));
    const table = surfaceTable(p);
    const r = num(c.r_m);
    close(surfaceTableAt(table, r), c.table_depression_m, `case ${i} table ${JSON.stringify(c)}`);
    close(p.reachM, c.reach_m, `case ${i} reach`);
    close(surfaceDepressionAt(p, r), c.depression_m, `case ${i} ${JSON.stringify(c)}`);
    const u = surfaceRadialDisplacementAt(p, r);
    close(u, radial(c.radial_displacement_m), `case ${i} radial ${JSON.stringify(c)}`);
    close(surfaceTableRadialAt(table, r), radial(c.table_radial_displacement_m), `case ${i} table radial`);
    if (u !== 0) movedSideways++;
  }
  if (sideways) assert.ok(movedSideways > 10, `${movedSideways} cases move sideways`);
});

test('over a stiffer inclusion the drawn surface dents less around the tool, never above it under', () => {
  const c = surfaceVectors.cases.find((x) => num(x.depth_m) > 0.003 && x.tool.shape === 'sphere');
  const tool = toolShape(c.tool);
  const d = num(c.depth_m);
  const plain = surfaceTable(surfaceSetup(families[c.family], tool, d), {});
  const p = surfaceSetup(families[c.family], tool, d, {});
  const footprint = p.footprintM;
  const stiff = surfaceTable(stiffenSurface(p, 2), {});
  let beyond = 0;
  for (let k = 0; k <= 200; k++) {
    const r = (k / 200) * plain.reachM;
    const z0 = surfaceTableAt(plain, r);
    const z1 = surfaceTableAt(stiff, r);
    assert.ok(z1 <= z0 + 1e-12, `r ${r}: ${z1} deeper than ${z0}`);
    if (r > footprint * 1.2 && z0 > 1e-6) {
      // Halved beyond the tool (the table's interpolation keeps it within a sample's step).
      assert.ok(Math.abs(z1 - z0 / 2) < 1e-3 * d + 1e-9, `r ${r}: ${z1} vs ${z0 / 2}`);
      beyond++;
    }
  }
  assert.ok(beyond > 10, `${beyond} radii beyond the tool`);
  // Under the tool's tip the surface still follows the tool.
  close(surfaceTableAt(stiff, 0), d, 'at the tip');
  // A ratio of 1 (or none) changes nothing; the paper's profile reaches less far.
  assert.equal(stiffenedDeformedRadius(0.003, 0.012, 1), 0.012);
  close(stiffenedDeformedRadius(0.003, 0.012, 3), 0.006, 'R_d over a ratio of 3');
});

/** `json` (a surface family's JSON) with every row moved sideways by `radial(z, j, n)`. */
function withRadial(json, radial) {
  const rows = json.rows.map((row) => {
    const n = row.depression_m.length;
    return { ...row, radial_displacement_m: row.depression_m.map((z, j) => radial(z, j, n)) };
  });
  return { ...json, rows };
}

/** A family of the shared vectors moved towards the axis by up to a tenth of its depression. */
function lateralJson(index = 0) {
  return withRadial(surfaceVectors.families[index], (z, j, n) => (-0.1 * z * j) / (n - 1));
}

test('a row moves the surface sideways by its radial_displacement_m, scaled like its depression', () => {
  const MM2 = 2 * MM;
  // One row 4 mm deep, samples 2 mm apart (the Rust reference's example, fem.rs).
  const family = surfaceFamilyFromJson({
    radius_exponent: 0.5,
    radius_step_m: MM2,
    rows: [
      {
        depth_m: 4 * MM,
        depression_m: [4 * MM, 3 * MM, 1 * MM, 0],
        radial_displacement_m: [0, -0.5 * MM, 0.3 * MM, 0],
      },
    ],
  });
  // A slender cone never bounds the row: the row itself, both ways.
  const slender = toolFromJson({ shape: 'cone', half_angle_rad: 0.1, radius_m: 10 * MM });
  const p = surfaceSetup(family, slender, 4 * MM);
  assert.equal(p.lateral, true);
  for (const [rMm, zMm, uMm] of [
    [0, 4, 0],
    [1, 3.5, -0.25],
    [3, 2, -0.1],
    [6, 0, 0],
    [7, 0, 0],
  ]) {
    close(surfaceDepressionAt(p, rMm * MM), zMm * MM, `z(${rMm} mm)`);
    close(surfaceRadialDisplacementAt(p, rMm * MM), uMm * MM, `u(${rMm} mm)`);
  }
  // r is sanitised as everywhere: NaN, negative and infinite radii are the axis.
  for (const r of [NaN, -1, Infinity]) assert.equal(surfaceRadialDisplacementAt(p, r), 0);
  // Twice as deep: depression ×2, radius ×√2, sideways motion ×2.
  close(surfaceRadialDisplacementAt(surfaceSetup(family, slender, 8 * MM), 2 * MM * Math.SQRT2), -1 * MM, 'u at 8 mm');
  // Nothing pressed, nothing moves.
  assert.equal(surfaceRadialDisplacementAt(surfaceSetup(family, slender, 0), 1 * MM), 0);
  // A ball: the point of undeformed radius r is drawn at r + u and held at or below the ball
  // there, not at r (where the ball is 0.2 mm lower).
  const ball = surfaceSetup(family, sphere, 4 * MM);
  const atDrawn = 4 * MM - (10 * MM - Math.sqrt((10 * MM) ** 2 - (1.5 * MM) ** 2));
  close(surfaceDepressionAt(ball, 2 * MM), Math.max(3 * MM, atDrawn), 'z held under the ball where it is drawn');
  assert.ok(surfaceDepressionAt(ball, 2 * MM) > 4 * MM - (10 * MM - Math.sqrt((10 * MM) ** 2 - (2 * MM) ** 2)) + 1e-5);
  // Its table follows both within the table's sampling, and says it moves something sideways.
  const table = surfaceTable(ball);
  assert.equal(table.lateral, true);
  assert.equal(table.u.length, table.z.length);
  assert.equal(table.u[table.u.length - 1], 0);
  for (let k = 0; k <= 60; k++) {
    const r = (6 * MM * k) / 60;
    assert.ok(Math.abs(surfaceTableAt(table, r) - surfaceDepressionAt(ball, r)) < 2e-6, `table z at ${r}`);
    assert.ok(
      Math.abs(surfaceTableRadialAt(table, r) - surfaceRadialDisplacementAt(ball, r)) < 1e-6,
      `table u at ${r}`,
    );
  }
  // Reused for a family without sideways motion, the same table draws none.
  surfaceTable(surfaceSetup(families[0], sphere, 3 * MM), table);
  assert.equal(table.lateral, false);
  assert.ok(table.u.every((u) => u === 0));
  // Absent and empty both mean no sideways motion, and draw the same numbers; null is refused
  // (as by the Rust reader).
  const plain = surfaceVectors.families[0];
  const rowsWith = (u) => ({ ...plain, rows: plain.rows.map((row) => ({ ...row, radial_displacement_m: u })) });
  assert.throws(() => surfaceFamilyFromJson(rowsWith(null)), /rows\[0\]\.radial_displacement_m.*got null/);
  for (const [v, json] of [plain, rowsWith([]), withRadial(plain, () => 0)].entries()) {
    const f = surfaceFamilyFromJson(json);
    const q = surfaceSetup(f, sphere, 3 * MM);
    assert.equal(q.lateral, false, `variant ${v}`);
    const t = surfaceTable(q);
    assert.equal(t.lateral, false);
    for (let k = 0; k <= 40; k++) {
      const r = (q.reachM * k) / 40;
      assert.equal(surfaceRadialDisplacementAt(q, r), 0);
      assert.equal(surfaceTableRadialAt(t, r), 0);
      assert.equal(surfaceDepressionAt(q, r), surfaceDepressionAt(surfaceSetup(families[0], sphere, 3 * MM), r));
    }
  }
});

test('a malformed surface family is refused naming the field', () => {
  const good = surfaceVectors.families[0];
  assert.throws(() => surfaceFamilyFromJson({ ...good, radius_exponent: 0 }), /radius_exponent/);
  assert.throws(() => surfaceFamilyFromJson({ ...good, radius_step_m: -1 }), /radius_step_m/);
  assert.throws(() => surfaceFamilyFromJson({ ...good, rows: [] }), /rows must not be empty/);
  const open = { ...good, rows: [{ depth_m: 0.001, depression_m: [0.001, 0.0005] }] };
  assert.throws(() => surfaceFamilyFromJson(open), /rows\[0\]\.depression_m/);
  const unordered = { ...good, rows: [good.rows[1], good.rows[0]] };
  assert.throws(() => surfaceFamilyFromJson(unordered), /rows\[1\]\.depth_m/);
});

test('a malformed radial_displacement_m is refused naming the field', () => {
  const good = surfaceVectors.families[0];
  const last = good.rows.length - 1;
  /** `good` with row `last`'s radial_displacement_m replaced by `edit(valid U)`. */
  const bad = (edit) => {
    const rows = lateralJson().rows.map((row, k) =>
      k === last ? { ...row, radial_displacement_m: edit([...row.radial_displacement_m]) } : row,
    );
    return { ...good, rows };
  };
  const field = new RegExp(`surface\\.rows\\[${last}\\]\\.radial_displacement_m`);
  // The valid one, unedited, is accepted.
  assert.ok(surfaceFamilyFromJson(bad((u) => u)).rowLateral.every(Boolean));
  const refused = (edit, what) =>
    assert.throws(
      () => surfaceFamilyFromJson(bad(edit)),
      (e) => field.test(e.message) && what.test(e.message),
      `${what}`,
    );
  refused((u) => u.slice(1), /as many samples as depression_m/);
  refused((u) => [...u, 0], /as many samples as depression_m/);
  refused(() => 'sideways', /as many samples as depression_m/);
  refused(() => ({ 0: 0 }), /as many samples as depression_m/);
  refused((u) => ((u[3] = NaN), u), /\[3\] must be finite, got NaN/);
  refused((u) => ((u[3] = Infinity), u), /\[3\] must be finite/);
  refused((u) => ((u[2] = null), u), /\[2\] must be finite, got null/);
  refused((u) => ((u[1] = '0'), u), /\[1\] must be finite/);
  refused((u) => ((u[0] = 1e-9), u), /\[0\] must be 0/);
  refused(
    (u) => ((u[u.length - 1] = -1e-9), u),
    new RegExp(`\\[${good.rows[last].depression_m.length - 1}\\] must be 0`),
  );
  // Folding: sample 5 drawn just inside sample 4, then well inside it.
  const step = good.radius_step_m;
  refused((u) => ((u[5] = u[4] - 1.000001 * step), u), /\[5\] = .* folds the surface over itself/);
  refused((u) => ((u[5] = u[4] - 1.5 * step), u), /\[5\] = .* folds/);
  // Just short of folding is accepted.
  assert.ok(surfaceFamilyFromJson(bad((u) => ((u[5] = u[4] - 0.999 * step), u))));
  // The row named is the one at fault.
  const first = { ...good, rows: good.rows.map((row, k) => (k === 0 ? { ...row, radial_displacement_m: [0] } : row)) };
  assert.throws(() => surfaceFamilyFromJson(first), /surface\.rows\[0\]\.radial_displacement_m/);
});

test('the deformer draws the fem profile: every vertex within its reach, by its table', () => {
  const family = families[0];
  const grid = flatGrid(100, 0.2);
  const out = Float32Array.from(grid.positions);
  const normals = Float32Array.from(grid.normals);
  const deformer = new MeshDeformer(grid.positions, grid.normals, { cellSizeM: 0.004 });
  const contact = pressAt(0.013, -0.021, 3 * MM, 18 * MM);
  deformer.apply(out, normals, contact, sphere, family);
  const p = surfaceSetup(family, sphere, contact.depthM);
  const table = surfaceTable(p);
  assert.ok(p.reachM > 18 * MM, `the profile reaches past R_d (${p.reachM})`);
  let moved = 0;
  for (let i = 0; i < deformer.vertexCount; i++) {
    const r = Math.hypot(grid.positions[3 * i] - 0.013, grid.positions[3 * i + 2] + 0.021);
    const z = surfaceTableAt(table, r);
    const dy = grid.positions[3 * i + 1] - out[3 * i + 1];
    assert.ok(Math.abs(dy - z) < 1e-7, `vertex ${i} at r=${r}: moved ${dy}, table ${z}`);
    // The table is the profile to within a micrometre (proto checks the bound on the
    // repository's tables).
    const exact = r < p.reachM ? surfaceDepressionAt(p, r) : 0;
    assert.ok(Math.abs(dy - exact) < 1.1e-6, `vertex ${i} at r=${r}: moved ${dy}, profile ${exact}`);
    if (z > 0) moved++;
  }
  assert.equal(deformer.movedCount, moved);
  // Normals: unit, and ∝ n + z′(r)·e_r with z′ the slope of the table's interval that holds r,
  // so that they are perpendicular to the surface as drawn.
  let checked = 0;
  for (let k = 0; k < deformer.movedCount; k++) {
    const i = deformer.moved[k];
    const ex = grid.positions[3 * i] - 0.013;
    const ez = grid.positions[3 * i + 2] + 0.021;
    const r = Math.hypot(ex, ez);
    const j = Math.floor(r * table.samplesPerM);
    const slope = (table.z[j + 1] - table.z[j]) * table.samplesPerM;
    if (r < 1e-6) continue;
    const len = Math.hypot(1, slope);
    const expected = [(slope * ex) / r / len, 1 / len, (slope * ez) / r / len];
    const got = [normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]];
    const err = Math.hypot(got[0] - expected[0], got[1] - expected[1], got[2] - expected[2]);
    assert.ok(err < 1e-4, `vertex ${i} at r=${r}: normal ${got}, expected ${expected}`);
    checked++;
  }
  assert.ok(checked > 100, `${checked} normals checked`);
  // Switching back to the paper's profile restores what the fem profile moved beyond R_d.
  deformer.apply(out, normals, contact, sphere);
  for (let i = 0; i < deformer.vertexCount; i++) {
    const r = Math.hypot(grid.positions[3 * i] - 0.013, grid.positions[3 * i + 2] + 0.021);
    if (r >= 18 * MM) assert.equal(out[3 * i + 1], grid.positions[3 * i + 1], `vertex ${i} at r=${r}`);
  }
});

test('the deformer moves vertices sideways by the table and keeps normals perpendicular to the drawn surface', () => {
  const json = lateralJson(0);
  // The rule the family must satisfy (and surfaceFamilyFromJson checks): j·Δ + U[j] increasing.
  for (const row of json.rows) {
    const u = row.radial_displacement_m;
    for (let j = 1; j < u.length; j++)
      assert.ok(j * json.radius_step_m + u[j] > (j - 1) * json.radius_step_m + u[j - 1]);
  }
  const family = surfaceFamilyFromJson(json);
  const grid = flatGrid(100, 0.2);
  const out = Float32Array.from(grid.positions);
  const normals = Float32Array.from(grid.normals);
  const deformer = new MeshDeformer(grid.positions, grid.normals, { cellSizeM: 0.004 });
  const [cx, cz] = [0.013, -0.021];
  const contact = pressAt(cx, cz, 3 * MM, 18 * MM);
  deformer.apply(out, normals, contact, sphere, family);
  const p = surfaceSetup(family, sphere, contact.depthM);
  const table = surfaceTable(p);
  assert.equal(table.lateral, true);
  // Every vertex: rest − n·z + e_r·u, z and u read from the table (nothing beyond the reach).
  let moved = 0;
  let sideways = 0;
  for (let i = 0; i < deformer.vertexCount; i++) {
    const ex = grid.positions[3 * i] - cx;
    const ez = grid.positions[3 * i + 2] - cz;
    const r = Math.hypot(ex, ez);
    const z = surfaceTableAt(table, r);
    const u = surfaceTableRadialAt(table, r);
    const expected = [
      grid.positions[3 * i] + (r > 0 ? (ex / r) * u : 0),
      grid.positions[3 * i + 1] - z,
      grid.positions[3 * i + 2] + (r > 0 ? (ez / r) * u : 0),
    ];
    for (let c = 0; c < 3; c++) {
      assert.ok(
        Math.abs(out[3 * i + c] - expected[c]) < 1e-7,
        `vertex ${i} at r=${r}: ${c} is ${out[3 * i + c]}, expected ${expected[c]}`,
      );
    }
    // The table is the profile within its sampling, sideways too.
    const exact = r < p.reachM ? surfaceRadialDisplacementAt(p, r) : 0;
    assert.ok(Math.abs(u - exact) < 1.1e-6, `vertex ${i} at r=${r}: u ${u}, profile ${exact}`);
    if (z > 0 || u !== 0) moved++;
    if (Math.abs(u) > 1e-6) sideways++;
  }
  assert.equal(deformer.movedCount, moved);
  assert.ok(sideways > 1000, `${sideways} vertices moved sideways by more than 1 µm`);
  // Normals: unit, in the plane of n and e_r, and perpendicular to the drawn surface's radial
  // tangent d/dr [(r + u)·e_r − z·n], by central differences inside the table interval of r.
  const h = 1e-9;
  let checked = 0;
  for (let k = 0; k < deformer.movedCount; k++) {
    const i = deformer.moved[k];
    const ex = grid.positions[3 * i] - cx;
    const ez = grid.positions[3 * i + 2] - cz;
    const r = Math.hypot(ex, ez);
    // Only where r ± h lie in r's table interval (whose slopes the normal is made of).
    const interval = Math.floor(r * table.samplesPerM);
    const inside = (rr) => Math.floor(rr * table.samplesPerM) === interval;
    if (r < 1e-6 || !inside(r - h) || !inside(r + h)) continue;
    const dz = (surfaceTableAt(table, r + h) - surfaceTableAt(table, r - h)) / (2 * h);
    const du = (surfaceTableRadialAt(table, r + h) - surfaceTableRadialAt(table, r - h)) / (2 * h);
    // Radial tangent (in e_r, n components) and its unit vector in the grid's frame.
    const [tr, tn] = [1 + du, -dz];
    const len = Math.hypot(tr, tn);
    const tangent = [((tr / len) * ex) / r, tn / len, ((tr / len) * ez) / r];
    const got = [normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]];
    const dot = got[0] * tangent[0] + got[1] * tangent[1] + got[2] * tangent[2];
    assert.ok(Math.abs(dot) < 1e-5, `vertex ${i} at r=${r}: normal ${got} · tangent ${tangent} = ${dot}`);
    assert.ok(Math.abs(Math.hypot(...got) - 1) < 1e-5, `vertex ${i}: unit normal`);
    assert.ok(Math.abs(got[0] * ez - got[2] * ex) / r < 1e-6, `vertex ${i}: no azimuthal component`);
    assert.ok(got[1] > 0, `vertex ${i}: the normal points out of the surface`);
    checked++;
  }
  assert.ok(checked > 1000, `${checked} normals checked`);
  // The same family without its sideways motion, then the paper's profile: back where they draw
  // vertices, sideways motion and all (every x and z at rest beyond R_d for the paper's).
  deformer.apply(out, normals, contact, sphere, families[0]);
  const plain = surfaceTable(surfaceSetup(families[0], sphere, contact.depthM));
  for (let i = 0; i < deformer.vertexCount; i++) {
    assert.equal(out[3 * i], grid.positions[3 * i], `vertex ${i} x`);
    assert.equal(out[3 * i + 2], grid.positions[3 * i + 2], `vertex ${i} z`);
    const r = Math.hypot(grid.positions[3 * i] - cx, grid.positions[3 * i + 2] - cz);
    assert.ok(Math.abs(grid.positions[3 * i + 1] - out[3 * i + 1] - surfaceTableAt(plain, r)) < 1e-7, `vertex ${i} y`);
  }
  deformer.apply(out, normals, contact, sphere, family);
  deformer.apply(out, normals, contact, sphere);
  for (let i = 0; i < deformer.vertexCount; i++) {
    assert.equal(out[3 * i], grid.positions[3 * i], `vertex ${i} x`);
    assert.equal(out[3 * i + 2], grid.positions[3 * i + 2], `vertex ${i} z`);
  }
});

test('a press that slides writes every vertex of both dimples once, each where the new press puts it', () => {
  const grid = flatGrid(80, 0.1);
  const out = Float32Array.from(grid.positions);
  const normals = Float32Array.from(grid.normals);
  const deformer = new MeshDeformer(grid.positions, grid.normals);
  for (const surface of [null, families[0], surfaceFamilyFromJson(lateralJson(0))]) {
    deformer.apply(out, normals, pressAt(0, 0, 3 * MM, 12 * MM), sphere, surface);
    const before = new Set(deformer.moved.subarray(0, deformer.movedCount));
    const press = pressAt(0.001, 0, 3 * MM, 12 * MM);
    const touched = deformer.apply(out, normals, press, sphere, surface);
    const now = new Set(deformer.moved.subarray(0, deformer.movedCount));
    const list = deformer.touched.subarray(0, touched);
    assert.equal(new Set(list).size, touched, 'each vertex listed once');
    assert.equal(touched, new Set([...before, ...now]).size, 'the union of both dimples');
    const table = surface ? surfaceTable(surfaceSetup(surface, sphere, press.depthM)) : null;
    for (let i = 0; i < deformer.vertexCount; i++) {
      const ex = grid.positions[3 * i] - 0.001;
      const ez = grid.positions[3 * i + 2];
      const r = Math.hypot(ex, ez);
      const z = surface
        ? surfaceTableAt(table, r)
        : depression(sphere, press.depthM, press.contactRadiusM, press.deformedRadiusM, r);
      const u = surface && r > 0 ? surfaceTableRadialAt(table, r) : 0;
      const dy = grid.positions[3 * i + 1] - out[3 * i + 1];
      assert.ok(Math.abs(dy - z) < 1e-7, `${surface ? 'fem' : 'paper'} vertex ${i}: moved ${dy}, profile ${z}`);
      assert.ok(Math.abs(out[3 * i] - grid.positions[3 * i] - (u * ex) / (r || 1)) < 1e-7, `vertex ${i} x`);
      assert.ok(Math.abs(out[3 * i + 2] - grid.positions[3 * i + 2] - (u * ez) / (r || 1)) < 1e-7, `vertex ${i} z`);
      if (!now.has(i)) assert.equal(normals[3 * i + 1], grid.normals[3 * i + 1], `vertex ${i} normal restored`);
    }
    deformer.apply(out, normals, { inContact: false }, sphere, surface);
    assert.equal(deformer.movedCount, 0);
  }
});
