// The deformation profiles of proto/WIRE.md ("Deformation profile") and their application to a
// render mesh: `paper`, the Bézier profile of the seed paper's §3.3, and `fem`, the FEM surface
// the calibration tabulated (carried in the scene's calibration table as `surface`).
//
// `depression(...)` and `surfaceDepression(...)` are the exact profiles the wire contract
// defines (the Rust reference in `proto` computes the same numbers; the shared vectors in
// proto/vectors/deformation.json and surface_profile.json keep the two identical).
// `deformer.js` applies them to a render mesh.

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
export function evaluateAt(p, r, out) {
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
