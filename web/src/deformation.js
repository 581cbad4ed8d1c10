// The deformation profiles of proto/WIRE.md ("Deformation profile") and their application to a
// render mesh: `paper`, the Bézier profile of the seed paper's §3.3, and `fem`, the FEM surface
// the calibration tabulated (carried in the scene's calibration table as `surface`).
//
// `depression(...)` and `surfaceDepression(...)` are the exact profiles the wire contract
// defines (the Rust reference in `proto` computes the same numbers; the shared vectors in
// proto/vectors/deformation.json and surface_profile.json keep the two identical).
// `MeshDeformer` moves the vertices of a render mesh around a contact: it keeps a uniform spatial
// grid over the rest positions so that a frame visits only the cells near the contact, restores
// the vertices it moved the frame before, writes analytic normals for the moved vertices, and
// allocates nothing after construction. The `fem` profile reaches far (to where the FEM block's
// surface settles, tens of millimetres), so a frame may move most of a 100 000-vertex mesh: it
// is drawn from a radial table of the profile (`surfaceTable`, proto's `SurfaceTable`) sampled
// once per frame, one lookup per vertex.

/** Non-finite or negative inputs count as zero (profile step 1). */
function sanitise(x) {
  return Number.isFinite(x) && x > 0 ? x : 0;
}

/**
 * The numeric form of a tool description (`{"shape":"sphere","radius_m"}` or
 * `{"shape":"cone","half_angle_rad","radius_m"}`), without refusing anything: a tool that
 * `toolError` would refuse is marked `valid: false` and deforms nothing, as in the Rust
 * reference, so no input can produce NaN.
 */
export function toolShape(tool) {
  const shape = tool && tool.shape === 'cone' ? 'cone' : 'sphere';
  const radiusM = tool ? tool.radius_m : NaN;
  const halfAngleRad = shape === 'cone' ? tool.half_angle_rad : 0;
  const tanAlpha = shape === 'cone' ? Math.tan(halfAngleRad) : 0;
  return { shape, radiusM, halfAngleRad, tanAlpha, valid: toolError(tool) === null };
}

/** Why a tool description cannot be used (field and value), or null when it can. */
export function toolError(tool) {
  if (tool === null || typeof tool !== 'object') return `tool must be an object, got ${JSON.stringify(tool)}`;
  if (tool.shape !== 'sphere' && tool.shape !== 'cone') {
    return `tool.shape must be "sphere" or "cone", got ${JSON.stringify(tool.shape)}`;
  }
  const radius = tool.radius_m;
  if (!(typeof radius === 'number' && Number.isFinite(radius) && radius > 0)) {
    return `tool.radius_m must be finite and > 0, got ${JSON.stringify(radius)}`;
  }
  if (tool.shape === 'cone') {
    const alpha = tool.half_angle_rad;
    if (!(typeof alpha === 'number' && Number.isFinite(alpha) && alpha > 0 && alpha < Math.PI / 2)) {
      return `tool.half_angle_rad must be finite and in (0, π/2), got ${JSON.stringify(alpha)}`;
    }
  }
  return null;
}

/** `toolShape` for a description that must be valid (a scene's tool); throws naming the field. */
export function toolFromJson(tool) {
  const error = toolError(tool);
  if (error !== null) throw new Error(error);
  return toolShape(tool);
}

/**
 * Contact radius a of the closed-form laws: √(Rδ) for a sphere (Hertz), 2δ·tanα/π for a cone
 * (Sneddon, α the half-angle between axis and flank).
 */
export function contactRadius(tool, depthM) {
  const d = sanitise(depthM);
  if (tool.shape === 'sphere') return Math.sqrt(tool.radiusM * d);
  return (2 * d * tool.tanAlpha) / Math.PI;
}

/** Depth of the tool surface below its tip plane at radial distance r (profile step 2). */
function toolHeight(tool, r) {
  if (tool.shape === 'sphere') {
    const R = tool.radiusM;
    return R - Math.sqrt(Math.max(0, R * R - r * r));
  }
  return r / tool.tanAlpha;
}

/**
 * The cross-section of the deformed surface for one contact: everything `depression` needs
 * that does not depend on r. Computed once per frame, not once per vertex.
 * Returns `out` (a plain object reused by the caller) so nothing is allocated per frame.
 */
export function profileSetup(tool, depthM, contactRadiusM, deformedRadiusM, out = {}) {
  const delta = tool.valid ? sanitise(depthM) : 0;
  const a = sanitise(contactRadiusM);
  const rd = sanitise(deformedRadiusM);
  out.tool = tool;
  out.isSphere = tool.shape === 'sphere';
  out.depthM = delta;
  if (delta === 0) {
    // Nothing is pressed: no region, nothing moves.
    out.aEff = out.z0 = out.rdEff = out.r1 = out.A = out.B = 0;
    return out;
  }
  const R = tool.radiusM;
  // Step 2: the contact cannot be wider than the tool.
  const aEff = Math.min(a, R);
  // Step 3: depth of the rim of the contact circle, and a deformed region wide enough to hold
  // the Bézier flank (so R_d ≤ a never leaves a step in the surface).
  const z0 = Math.max(0, delta - toolHeight(tool, aEff));
  const rdEff = Math.max(rd, aEff + z0);
  // Step 4: P1 is where the tool's tangent at the rim meets the undeformed surface.
  let slope;
  if (tool.shape === 'sphere') {
    const rest = R * R - aEff * aEff;
    slope = rest > 0 ? aEff / Math.sqrt(rest) : Infinity;
  } else {
    slope = 1 / tool.tanAlpha;
  }
  let r1;
  if (slope === Infinity || z0 === 0) r1 = aEff;
  else if (slope === 0) r1 = rdEff;
  else r1 = aEff + z0 / slope;
  r1 = Math.min(Math.max(r1, aEff), rdEff);
  if (!Number.isFinite(r1)) r1 = aEff;
  out.aEff = aEff;
  out.z0 = z0;
  out.rdEff = rdEff;
  out.r1 = r1;
  out.A = aEff - 2 * r1 + rdEff;
  out.B = 2 * (r1 - aEff);
  return out;
}

/** Bézier parameter t ∈ [0,1] of the flank point at radial distance r (profile step 5). */
function flankParameter(p, r) {
  const C = p.aEff - r;
  const q = p.B + Math.sqrt(Math.max(0, p.B * p.B - 4 * p.A * C));
  let t = q > 0 ? (-2 * C) / q : (r - p.aEff) / (p.rdEff - p.aEff);
  if (!(t >= 0)) t = 0; // also catches NaN from a zero-width flank
  if (t > 1) t = 1;
  return t;
}

/** Depression z(r) ≥ 0 for a profile prepared by `profileSetup`. */
export function depressionAt(p, rRaw) {
  const r = sanitise(rRaw);
  if (p.depthM === 0) return 0;
  if (r < p.aEff) return Math.max(0, p.depthM - toolHeight(p.tool, r));
  if (r < p.rdEff) {
    const s = 1 - flankParameter(p, r);
    return s * s * p.z0;
  }
  return 0;
}

const scratchProfile = {};

/**
 * The wire contract's deformation profile: how far (m) the surface at radial distance r from
 * the contact axis is pushed along −n. `tool` is the result of `toolFromJson`.
 */
export function depression(tool, depthM, contactRadiusM, deformedRadiusM, rM) {
  profileSetup(tool, depthM, contactRadiusM, deformedRadiusM, scratchProfile);
  return depressionAt(scratchProfile, rM);
}

/**
 * Depression and normal in one pass (what `apply` needs per vertex), for a finite r ≥ 0:
 * `out[0]` = z(r), the same number as `depressionAt`; `out[1]`, `out[2]` = the axial and radial
 * components of the deformed surface's normal, which is ∝ out[1]·n + out[2]·e_r (e_r points away
 * from the axis). Under the tool it is the tool surface's normal; on the flank it is
 * perpendicular to the Bézier curve's tangent (dr/dt, −dz/dt), so shading is continuous at r = a
 * and at r = R_d, where it turns back into the rest normal.
 */
function evaluateAt(p, r, out) {
  if (r < p.aEff) {
    if (p.isSphere) {
      const R = p.tool.radiusM;
      const root = Math.sqrt(Math.max(0, R * R - r * r));
      const z = p.depthM - (R - root);
      if (z > 0) {
        out[0] = z;
        out[1] = root;
        out[2] = -r;
        return out;
      }
    } else {
      const z = p.depthM - r / p.tool.tanAlpha;
      if (z > 0) {
        out[0] = z;
        out[1] = p.tool.tanAlpha;
        out[2] = -1;
        return out;
      }
    }
    out[0] = 0;
    out[1] = 1;
    out[2] = 0;
    return out;
  }
  if (r < p.rdEff) {
    const t = flankParameter(p, r);
    const s = 1 - t;
    out[0] = s * s * p.z0;
    const drdt = 2 * s * (p.r1 - p.aEff) + 2 * t * (p.rdEff - p.r1);
    const dzdt = -2 * s * p.z0;
    if (drdt === 0 && dzdt === 0) {
      out[1] = 1;
      out[2] = 0;
    } else {
      out[1] = drdt;
      out[2] = dzdt;
    }
    return out;
  }
  out[0] = 0;
  out[1] = 1;
  out[2] = 0;
  return out;
}

// ----- the `fem` profile: the calibration's tabulated FEM surface -----

/**
 * The `fem` profile's family from the calibration table's `surface` object (proto
 * `SurfaceFamily`): `{radius_exponent, radius_step_m, rows: [{depth_m, depression_m: [...]}]}`.
 * Returns `{radiusExponent, radiusStepM, depths: Float64Array, rows: Float64Array[]}`, or throws
 * naming the field, with the checks the Rust side makes (a server only sends valid ones).
 */
export function surfaceFamilyFromJson(json) {
  if (json === null || typeof json !== 'object')
    throw new Error(`surface must be an object, got ${JSON.stringify(json)}`);
  const exponent = json.radius_exponent;
  if (!(Number.isFinite(exponent) && exponent > 0 && exponent <= 2)) {
    throw new Error(`surface.radius_exponent must be finite and in (0, 2], got ${JSON.stringify(exponent)}`);
  }
  const step = json.radius_step_m;
  if (!(Number.isFinite(step) && step > 0)) {
    throw new Error(`surface.radius_step_m must be finite and > 0, got ${JSON.stringify(step)}`);
  }
  if (!Array.isArray(json.rows) || json.rows.length === 0) throw new Error('surface.rows must not be empty');
  const depths = new Float64Array(json.rows.length);
  const rows = json.rows.map((row, i) => {
    const d = row?.depth_m;
    if (!(Number.isFinite(d) && d > 0) || (i > 0 && !(d > depths[i - 1]))) {
      throw new Error(`surface.rows[${i}].depth_m must be finite, > 0 and increasing, got ${JSON.stringify(d)}`);
    }
    depths[i] = d;
    const z = row.depression_m;
    if (!Array.isArray(z) || z.length < 2 || z[z.length - 1] !== 0 || !z.every((x) => Number.isFinite(x) && x >= 0)) {
      throw new Error(`surface.rows[${i}].depression_m must be ≥ 2 finite samples ≥ 0 ending at 0`);
    }
    return Float64Array.from(z);
  });
  return { radiusExponent: exponent, radiusStepM: step, depths, rows };
}

/** One scaled row of a prepared `fem` profile (see `surfaceSetup`). */
function surfaceTerm(family, index, weight, d, term) {
  const row = family.rows[index];
  term.row = row;
  term.amplitude = (weight * d) / family.depths[index];
  term.indexPerM = Math.pow(family.depths[index] / d, family.radiusExponent) / family.radiusStepM;
  term.reachM = (row.length - 1) / term.indexPerM;
}

/**
 * The `fem` profile of `tool` (from `toolShape`) pressed `depthM` deep (WIRE.md, steps 1–2):
 * the one or two rows to blend, each with its amplitude (weight·δ/δ_k) and its samples per metre
 * ((δ_k/δ)^p / Δ), the tool's footprint (inside it the drawn surface is never above the tool)
 * and the reach beyond which nothing moves. An invalid tool draws nothing. Writes into `out`,
 * allocating nothing once `out` has been used.
 */
export function surfaceSetup(family, tool, depthM, out = {}) {
  const d = tool.valid ? sanitise(depthM) : 0;
  out.tool = tool;
  out.isSphere = tool.shape === 'sphere';
  out.depthM = d;
  out.footprintM = 0;
  out.t0 ??= { row: null, amplitude: 0, indexPerM: 0, reachM: 0 };
  out.t1 ??= { row: null, amplitude: 0, indexPerM: 0, reachM: 0 };
  out.t0.amplitude = out.t1.amplitude = 0;
  out.t0.reachM = out.t1.reachM = 0;
  out.reachM = 0;
  if (d === 0) return out;
  const depths = family.depths;
  const last = depths.length - 1;
  let k, w;
  if (d <= depths[0]) {
    k = 0;
    w = 0;
  } else if (d >= depths[last]) {
    k = last;
    w = 0;
  } else {
    k = 0;
    while (depths[k + 1] <= d) k++;
    w = (d - depths[k]) / (depths[k + 1] - depths[k]);
  }
  // Where the tool reaches below the undeformed surface: r with δ − h_tool(r) > 0.
  const R = tool.radiusM;
  if (out.isSphere) out.footprintM = d < R ? Math.sqrt(d * (2 * R - d)) : R;
  else out.footprintM = Math.min(d * tool.tanAlpha, R);
  surfaceTerm(family, k, 1 - w, d, out.t0);
  if (w > 0) surfaceTerm(family, k + 1, w, d, out.t1);
  out.reachM = Math.max(out.footprintM, out.t0.reachM, out.t1.reachM);
  return out;
}

/** One row's contribution at radius r ≥ 0: its interpolated sample times its amplitude. */
function surfaceTermAt(t, r) {
  if (t.amplitude === 0) return 0;
  const z = t.row;
  const u = r * t.indexPerM;
  if (!(u < z.length - 1)) return 0;
  const j = Math.floor(u);
  const f = u - j;
  return t.amplitude * (z[j] + f * (z[j + 1] - z[j]));
}

/**
 * Depression z(r), 0 ≤ z ≤ δ, for a profile prepared by `surfaceSetup` (WIRE.md, step 3): the
 * rows' blend, never above the tool (between the FEM's nodes the rows are straight chords, which
 * the curved tool would otherwise poke through).
 */
export function surfaceDepressionAt(p, rRaw) {
  if (p.depthM === 0) return 0;
  const r = sanitise(rRaw);
  let z = surfaceTermAt(p.t0, r) + surfaceTermAt(p.t1, r);
  if (r < p.footprintM) z = Math.max(z, p.depthM - toolHeight(p.tool, r));
  return Math.min(Math.max(z, 0), p.depthM);
}

const scratchSurface = {};

/** The `fem` profile's depression (m) at radial distance r for a family, a tool and a depth. */
export function surfaceDepression(family, tool, depthM, rM) {
  return surfaceDepressionAt(surfaceSetup(family, tool, depthM, scratchSurface), rM);
}

/**
 * Intervals of a `fem` profile's radial table (`surfaceTable`, proto's
 * `SURFACE_TABLE_INTERVALS`): the profile sampled at 4097 radii from the axis to its reach.
 * Interpolated linearly it stays within 1.1 µm of the profile for the repository's tables (it
 * misses the rows' kinks between two samples, so the error falls with the interval), and
 * sampling it once per update costs about what 4 000 vertices cost.
 */
export const SURFACE_TABLE_INTERVALS = 4096;

/**
 * The `fem` profile prepared by `surfaceSetup`, sampled once per update for the render mesh
 * (proto's `SurfaceTable`): `z[k]` = z(k·reach / N) for k = 0 … N (N = SURFACE_TABLE_INTERVALS;
 * `z[N]` is 0, the profile's value at its reach). Each vertex then costs one lookup instead of
 * a blend of two rows bounded by the tool. Writes into `out` (its array is allocated once). A
 * profile that draws nothing gives a table with `reachM` 0.
 */
export function surfaceTable(p, out = {}) {
  const n = SURFACE_TABLE_INTERVALS;
  if (!(out.z instanceof Float64Array)) out.z = new Float64Array(n + 1);
  const table = out.z;
  const reach = p.depthM === 0 ? 0 : p.reachM;
  out.reachM = reach;
  out.samplesPerM = reach > 0 ? n / reach : 0;
  if (reach === 0) {
    table.fill(0);
    return out;
  }
  // `surfaceDepressionAt` at r = k·step, with the rows and the tool read into locals once (the
  // stores into the table would otherwise make the engine load them again for every sample).
  const step = reach / n;
  const d = p.depthM;
  const footprint = p.footprintM;
  const tool = p.tool;
  const a0 = p.t0.amplitude,
    a1 = p.t1.amplitude;
  const s0 = p.t0.indexPerM,
    s1 = p.t1.indexPerM;
  const z0 = p.t0.row,
    z1 = a1 === 0 ? z0 : p.t1.row;
  const last0 = z0.length - 1,
    last1 = z1.length - 1;
  for (let k = 0; k < n; k++) {
    const r = k * step;
    let z = 0;
    const u0 = r * s0;
    if (a0 !== 0 && u0 < last0) {
      const j = Math.floor(u0);
      z += a0 * (z0[j] + (u0 - j) * (z0[j + 1] - z0[j]));
    }
    const u1 = r * s1;
    if (a1 !== 0 && u1 < last1) {
      const j = Math.floor(u1);
      z += a1 * (z1[j] + (u1 - j) * (z1[j + 1] - z1[j]));
    }
    if (r < footprint) z = Math.max(z, d - toolHeight(tool, r));
    table[k] = Math.min(Math.max(z, 0), d);
  }
  table[n] = 0;
  return out;
}

/**
 * The drawn depression at radial distance r from a `surfaceTable`: linear between its samples,
 * 0 at and beyond the reach; r sanitised as everywhere (a NaN radius is the axis).
 */
export function surfaceTableAt(table, rRaw) {
  const r = sanitise(rRaw);
  if (!(r < table.reachM)) return 0;
  const u = r * table.samplesPerM;
  // u < N in exact arithmetic; the last interval also takes a product that rounds up to N.
  const j = Math.min(Math.floor(u), SURFACE_TABLE_INTERVALS - 1);
  const z = table.z;
  return z[j] + (u - j) * (z[j + 1] - z[j]);
}

/**
 * Deforms one render mesh in its object frame. Built once per mesh; `apply` is called each
 * animation frame and allocates nothing.
 */
export class MeshDeformer {
  /**
   * @param {Float32Array} restPositions xyz per vertex, object frame (m); not modified.
   * @param {Float32Array|null} restNormals unit xyz per vertex, or null when normals are not kept.
   * @param {{cellSizeM?: number, maxCells?: number}} [options] grid cell edge (default: the
   *   larger of 1/48 of the largest extent and what keeps the grid under `maxCells` cells).
   */
  constructor(restPositions, restNormals = null, options = {}) {
    if (!(restPositions instanceof Float32Array) || restPositions.length % 3 !== 0) {
      throw new Error('restPositions must be a Float32Array of xyz triples');
    }
    const n = restPositions.length / 3;
    if (
      restNormals !== null &&
      (!(restNormals instanceof Float32Array) || restNormals.length !== restPositions.length)
    ) {
      throw new Error(`restNormals must be a Float32Array of ${restPositions.length} values`);
    }
    this.vertexCount = n;
    this.restPositions = restPositions;
    this.restNormals = restNormals;

    let minX = Infinity,
      minY = Infinity,
      minZ = Infinity;
    let maxX = -Infinity,
      maxY = -Infinity,
      maxZ = -Infinity;
    for (let i = 0; i < n; i++) {
      const x = restPositions[3 * i],
        y = restPositions[3 * i + 1],
        z = restPositions[3 * i + 2];
      if (!(Number.isFinite(x) && Number.isFinite(y) && Number.isFinite(z))) {
        throw new Error(`vertex ${i} has a non-finite position (${x}, ${y}, ${z})`);
      }
      if (x < minX) minX = x;
      if (y < minY) minY = y;
      if (z < minZ) minZ = z;
      if (x > maxX) maxX = x;
      if (y > maxY) maxY = y;
      if (z > maxZ) maxZ = z;
    }
    if (n === 0) {
      minX = minY = minZ = 0;
      maxX = maxY = maxZ = 0;
    }
    const maxCells = options.maxCells ?? 1 << 20;
    const extent = Math.max(maxX - minX, maxY - minY, maxZ - minZ, 1e-9);
    let cell = options.cellSizeM ?? extent / 48;
    const cellsFor = (h) =>
      (Math.floor((maxX - minX) / h) + 1) * (Math.floor((maxY - minY) / h) + 1) * (Math.floor((maxZ - minZ) / h) + 1);
    while (cellsFor(cell) > maxCells) cell *= 1.25;
    this.cellSizeM = cell;
    this.origin = [minX, minY, minZ];
    this.dims = [
      Math.floor((maxX - minX) / cell) + 1,
      Math.floor((maxY - minY) / cell) + 1,
      Math.floor((maxZ - minZ) / cell) + 1,
    ];
    const cellCount = this.dims[0] * this.dims[1] * this.dims[2];
    // Compressed cell lists: the vertices of cell k are cellVertices[cellStart[k] .. cellStart[k+1]].
    const cellOf = new Uint32Array(n);
    this.cellStart = new Uint32Array(cellCount + 1);
    for (let i = 0; i < n; i++) {
      const k = this.#cellIndex(restPositions[3 * i], restPositions[3 * i + 1], restPositions[3 * i + 2]);
      cellOf[i] = k;
      this.cellStart[k + 1]++;
    }
    for (let k = 0; k < cellCount; k++) this.cellStart[k + 1] += this.cellStart[k];
    const fill = this.cellStart.slice(0, cellCount);
    this.cellVertices = new Uint32Array(n);
    for (let i = 0; i < n; i++) this.cellVertices[fill[cellOf[i]]++] = i;
    // The rest position and normal of each vertex again, in the cell lists' order and side by
    // side (x, y, z, nx, ny, nz): a frame reads them in one sweep through memory instead of
    // jumping between vertex indices in two arrays (8% less time per frame on a 100 000-vertex
    // grid, for 24 bytes per vertex).
    this.cellRest = new Float32Array(6 * n);
    for (let s = 0; s < n; s++) {
      const i = this.cellVertices[s];
      for (let c = 0; c < 3; c++) {
        this.cellRest[6 * s + c] = restPositions[3 * i + c];
        this.cellRest[6 * s + 3 + c] = restNormals === null ? 0 : restNormals[3 * i + c];
      }
    }

    // Per-frame bookkeeping, preallocated: the vertices written this frame, those it moved
    // first and then those it put back to rest (`written`), and the same list of the frame
    // before (`writtenSpare`; the two swap each frame), whose first entries are the vertices
    // to restore unless this frame moves them. A stamp marks the vertices moved this frame, so
    // that one moved in both frames is written once, not restored and then moved; it is a byte
    // (the frame number counts 1 … 255, and every stamp is cleared when it starts again at 1)
    // to keep down the memory each vertex costs per frame.
    this.written = new Int32Array(n);
    this.writtenSpare = new Int32Array(n);
    this.movedCount = 0;
    this.touchedCount = 0;
    this.stamp = new Uint8Array(n);
    this.frame = 0;
    this.profile = {};
    this.surfaceProfile = surfaceSetup(null, { valid: false }, 0, {});
    this.table = surfaceTable(this.surfaceProfile, {});
    this.evaluation = new Float64Array(3);
    this.lastVisitedCells = 0;
  }

  #cellIndex(x, y, z) {
    const [nx, ny, nz] = this.dims;
    const h = this.cellSizeM;
    const ix = Math.min(nx - 1, Math.max(0, Math.floor((x - this.origin[0]) / h)));
    const iy = Math.min(ny - 1, Math.max(0, Math.floor((y - this.origin[1]) / h)));
    const iz = Math.min(nz - 1, Math.max(0, Math.floor((z - this.origin[2]) / h)));
    return (iz * ny + iy) * nx + ix;
  }

  /** The vertices the last `apply` moved: `moved[0 .. movedCount]`. */
  get moved() {
    return this.written;
  }

  /** The vertices the last `apply` wrote, moved or restored: `touched[0 .. touchedCount]`. */
  get touched() {
    return this.written;
  }

  /**
   * Deforms `positionsOut` (and `normalsOut`, when given) for one contact, in the object frame.
   *
   * `contact`: `{inContact, depthM, contactRadiusM, deformedRadiusM, point: [x,y,z], normal:
   * [x,y,z]}` with point and normal already in the mesh's object frame; `tool` from
   * `toolFromJson`; `surface` the `fem` profile's family (`surfaceFamilyFromJson`) to draw it,
   * or null for the paper's Bézier. A vertex v moves by −n·z(r) when r is inside the profile's
   * reach (R_d_eff for the paper's) and |(v − c)·n| is too (the far side never moves); the
   * vertices moved by the previous call and not by this one go back to rest.
   *
   * Returns the number of vertices written (moved or restored); their indices are
   * `this.touched[0 .. count]`, for partial normal or buffer updates.
   */
  apply(positionsOut, normalsOut, contact, tool, surface = null) {
    this.frame = this.frame === 255 ? 1 : this.frame + 1;
    if (this.frame === 1) this.stamp.fill(0);
    const previous = this.written;
    const previousCount = this.movedCount;
    this.written = this.writtenSpare;
    this.writtenSpare = previous;
    this.movedCount = 0;
    this.touchedCount = 0;
    this.lastVisitedCells = 0;
    this.#move(positionsOut, normalsOut, contact, tool, surface);
    // Then back to rest every vertex moved the frame before and not this one (the stamp marks
    // the ones moved this frame).
    const rest = this.restPositions;
    const restN = normalsOut ? this.restNormals : null;
    const stamp = this.stamp;
    const frame = this.frame;
    const written = this.written;
    let count = this.movedCount;
    for (let m = 0; m < previousCount; m++) {
      const i = previous[m];
      if (stamp[i] === frame) continue;
      const j = 3 * i;
      positionsOut[j] = rest[j];
      positionsOut[j + 1] = rest[j + 1];
      positionsOut[j + 2] = rest[j + 2];
      if (restN !== null) {
        normalsOut[j] = restN[j];
        normalsOut[j + 1] = restN[j + 1];
        normalsOut[j + 2] = restN[j + 2];
      }
      written[count++] = i;
    }
    this.touchedCount = count;
    return count;
  }

  /** The moving half of `apply`: writes and lists the vertices the contact moves this frame. */
  #move(positionsOut, normalsOut, contact, tool, surface) {
    if (!contact || !contact.inContact) return;

    const fem = surface !== null;
    let reach;
    if (fem) {
      const p = surfaceSetup(surface, tool, contact.depthM, this.surfaceProfile);
      if (p.depthM === 0) return;
      reach = p.reachM;
    } else {
      const p = profileSetup(tool, contact.depthM, contact.contactRadiusM, contact.deformedRadiusM, this.profile);
      if (p.depthM === 0) return;
      reach = p.rdEff;
    }
    if (!(reach > 0)) return;
    let nx = contact.normal[0],
      ny = contact.normal[1],
      nz = contact.normal[2];
    const nLen = Math.sqrt(nx * nx + ny * ny + nz * nz);
    if (!(nLen > 0 && Number.isFinite(nLen))) return;
    nx /= nLen;
    ny /= nLen;
    nz /= nLen;
    const cx = contact.point[0],
      cy = contact.point[1],
      cz = contact.point[2];
    if (!(Number.isFinite(cx) && Number.isFinite(cy) && Number.isFinite(cz))) return;
    if (fem) surfaceTable(this.surfaceProfile, this.table);

    // A vertex that may move is u = h·n + e with |h| < reach and |e| < reach; along axis i that
    // is at most reach·(|n_i| + √(1 − n_i²)) from c (reach·√2 at worst, reach along n's own
    // axis and across it), so only the cells of that box are visited.
    const h = this.cellSizeM;
    const origin = this.origin;
    const dims = this.dims;
    const dx = dims[0],
      dy = dims[1],
      dz = dims[2];
    const bx = reach * (Math.abs(nx) + Math.sqrt(Math.max(0, 1 - nx * nx)));
    const by = reach * (Math.abs(ny) + Math.sqrt(Math.max(0, 1 - ny * ny)));
    const bz = reach * (Math.abs(nz) + Math.sqrt(Math.max(0, 1 - nz * nz)));
    const ix0 = Math.max(0, Math.floor((cx - bx - origin[0]) / h));
    const iy0 = Math.max(0, Math.floor((cy - by - origin[1]) / h));
    const iz0 = Math.max(0, Math.floor((cz - bz - origin[2]) / h));
    const ix1 = Math.min(dx - 1, Math.floor((cx + bx - origin[0]) / h));
    const iy1 = Math.min(dy - 1, Math.floor((cy + by - origin[1]) / h));
    const iz1 = Math.min(dz - 1, Math.floor((cz + bz - origin[2]) / h));
    if (ix0 > ix1 || iy0 > iy1 || iz0 > iz1) return;

    // The hot loop reads everything from locals: a property of `this` or of the profile would
    // be loaded again for every vertex, since the stores in the loop could have changed it.
    const restN = normalsOut ? this.restNormals : null;
    const cellStart = this.cellStart;
    const cellVertices = this.cellVertices;
    const cellRest = this.cellRest;
    const moved = this.written;
    const stamp = this.stamp;
    const frame = this.frame;
    let movedCount = 0;
    const reach2 = reach * reach;
    // `fem`: the radial table of this update; `paper`: its exact profile, per vertex.
    const tableZ = this.table.z;
    const samplesPerM = this.table.samplesPerM;
    const lastInterval = SURFACE_TABLE_INTERVALS - 1;
    const p = this.profile;
    const ev = this.evaluation;
    // A cell whose bounding sphere lies beyond the reach, radially or along n, holds no vertex
    // that moves: skipped whole (a quarter of the box's cells when the reach circle fits it).
    // The sphere is taken 0.1% wider than the cell's, far above the rounding of the test.
    const halfDiagonal = 0.5 * Math.sqrt(3) * h * 1.001;
    const cellReach = reach + halfDiagonal;
    const cellReach2 = cellReach * cellReach;
    let visited = 0;
    for (let iz = iz0; iz <= iz1; iz++) {
      const wz = origin[2] + (iz + 0.5) * h - cz;
      for (let iy = iy0; iy <= iy1; iy++) {
        const wy = origin[1] + (iy + 0.5) * h - cy;
        const row = (iz * dy + iy) * dx;
        for (let ix = ix0; ix <= ix1; ix++) {
          const wx = origin[0] + (ix + 0.5) * h - cx;
          const cellAxial = wx * nx + wy * ny + wz * nz;
          if (cellAxial > cellReach || cellAxial < -cellReach) continue;
          const cellR2 = wx * wx + wy * wy + wz * wz - cellAxial * cellAxial;
          if (cellR2 >= cellReach2) continue;
          visited++;
          const end = cellStart[row + ix + 1];
          for (let s = cellStart[row + ix]; s < end; s++) {
            const i = cellVertices[s];
            const j = 3 * i;
            const q = 6 * s;
            const px = cellRest[q],
              py = cellRest[q + 1],
              pz = cellRest[q + 2];
            const vx = px - cx,
              vy = py - cy,
              vz = pz - cz;
            const axial = vx * nx + vy * ny + vz * nz;
            if (axial > reach || axial < -reach) continue;
            const ex = vx - axial * nx,
              ey = vy - axial * ny,
              ez = vz - axial * nz;
            const r2 = ex * ex + ey * ey + ez * ez;
            if (r2 >= reach2) continue;
            const r = Math.sqrt(r2);
            // z and the normal's axial and radial components (normal ∝ a·n + b·e_r).
            let z, a, b;
            if (fem) {
              const u = r * samplesPerM;
              // u ≥ 0, so truncation is the floor; u < N but for rounding.
              let k = u | 0;
              if (k > lastInterval) k = lastInterval;
              const z0 = tableZ[k];
              const rise = tableZ[k + 1] - z0;
              z = z0 + (u - k) * rise;
              // Perpendicular to the drawn surface: the slope of the table interval r lies in.
              a = 1;
              b = rise * samplesPerM;
            } else {
              evaluateAt(p, r, ev);
              z = ev[0];
              a = ev[1];
              b = ev[2];
            }
            if (!(z > 0)) continue;
            positionsOut[j] = px - nx * z;
            positionsOut[j + 1] = py - ny * z;
            positionsOut[j + 2] = pz - nz * z;
            if (restN !== null) {
              // Analytic normal: the profile's (axial, radial) components applied to the rest
              // normal and the radial direction, so curved objects keep their own shading.
              const rnx = cellRest[q + 3],
                rny = cellRest[q + 4],
                rnz = cellRest[q + 5];
              let ox = rnx * a,
                oy = rny * a,
                oz = rnz * a;
              if (r > 0) {
                const br = b / r;
                ox += ex * br;
                oy += ey * br;
                oz += ez * br;
              } else {
                ox = rnx;
                oy = rny;
                oz = rnz;
              }
              const len2 = ox * ox + oy * oy + oz * oz;
              if (len2 > 0) {
                const inv = 1 / Math.sqrt(len2);
                normalsOut[j] = ox * inv;
                normalsOut[j + 1] = oy * inv;
                normalsOut[j + 2] = oz * inv;
              }
            }
            // Each vertex lies in one cell, so it is met once: no need to check the stamp.
            moved[movedCount++] = i;
            stamp[i] = frame;
          }
        }
      }
    }
    this.movedCount = movedCount;
    this.lastVisitedCells = visited;
  }
}
