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
 * (Sneddon, α the half-angle between axis and flank). A model with the exact sphere streams
 * `exactSphereContactRadius` instead.
 */
export function contactRadius(tool, depthM) {
  const d = sanitise(depthM);
  if (tool.shape === 'sphere') return Math.sqrt(tool.radiusM * d);
  return (2 * d * tool.tanAlpha) / Math.PI;
}

/** Newton steps of `exactSphereContactRadius` (4 reach the last bits; 6 leave a margin). */
const EXACT_SPHERE_NEWTON_STEPS = 6;
/** From δ/R = 20 on, tanh of the root is 1 to the last bit: a = R exactly. */
const EXACT_SPHERE_SATURATED_DEPTH_OVER_RADIUS = 20;

/**
 * Contact radius a of Sneddon's exact sphere (not Hertz's paraboloid), what a contact streams
 * when its model uses the exact sphere: the root a ∈ [0, R) of δ = (a/2)·ln((R+a)/(R−a)), solved
 * for t = atanh(a/R) (t·tanh t = δ/R) by the same Newton steps as the Rust reference
 * (`proto::deformation::exact_sphere_contact_radius_m`). a ≈ √(Rδ) shallow, 0.834·R at δ = R,
 * → R deep; 0 for a non-finite or non-positive depth or radius, R for an infinite depth.
 */
export function exactSphereContactRadius(radiusM, depthM) {
  if (!(Number.isFinite(radiusM) && radiusM > 0) || Number.isNaN(depthM) || !(depthM > 0)) return 0;
  const s = depthM / radiusM;
  if (s >= EXACT_SPHERE_SATURATED_DEPTH_OVER_RADIUS) return radiusM;
  let t = Math.sqrt(s) * Math.sqrt(1 + s / 3);
  for (let k = 0; k < EXACT_SPHERE_NEWTON_STEPS; k++) {
    const tanhT = Math.tanh(t);
    // The slope tanh t + t·sech² t is > 0 for t > 0, and t stays > 0 from t₀ > 0.
    const slope = tanhT + t * (1 - tanhT * tanhT);
    t -= (t * tanhT - s) / slope;
  }
  return radiusM * Math.tanh(t);
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
 * `SurfaceFamily`): `{radius_exponent, radius_step_m, rows: [{depth_m, depression_m: [...],
 * radial_displacement_m?: [...]}]}`. Returns `{radiusExponent, radiusStepM, depths:
 * Float64Array, rows: Float64Array[], radial: Float64Array[], rowLateral: boolean[]}`: `rows[k]`
 * the depression samples Z_k, `radial[k]` the sideways samples U_k (zeros, of the row's length,
 * for a row without `radial_displacement_m` or with an empty one), `rowLateral[k]` whether U_k
 * has a nonzero sample. Throws naming the field, with the checks the Rust side makes (a server
 * only sends valid ones).
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
  const radial = [];
  const rowLateral = [];
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
    const u = radialFromJson(row.radial_displacement_m, z.length, step, `surface.rows[${i}].radial_displacement_m`);
    radial.push(u);
    rowLateral.push(u.some((x) => x !== 0));
    return Float64Array.from(z);
  });
  return { radiusExponent: exponent, radiusStepM: step, depths, rows, radial, rowLateral };
}

/**
 * A row's `radial_displacement_m` (proto/WIRE.md, `fem`): absent or empty is no sideways motion
 * (zeros); otherwise as many finite samples as the row's depression, the first and the last 0,
 * and the drawn radius j·Δ + U[j] strictly increasing (the surface does not fold over itself).
 */
function radialFromJson(u, length, step, field) {
  // null is refused, as the Rust reader refuses it: only an absent field has a default.
  if (u === undefined || (Array.isArray(u) && u.length === 0)) return new Float64Array(length);
  if (!Array.isArray(u) || u.length !== length) {
    const got = Array.isArray(u) ? u.length : JSON.stringify(u);
    throw new Error(`${field} must hold as many samples as depression_m (${length}), got ${got}`);
  }
  const show = (x) => (typeof x === 'number' ? String(x) : JSON.stringify(x));
  for (let j = 0; j < length; j++) {
    if (!Number.isFinite(u[j])) throw new Error(`${field}[${j}] must be finite, got ${show(u[j])}`);
  }
  for (const j of [0, length - 1]) {
    if (u[j] !== 0) {
      throw new Error(
        `${field}[${j}] must be 0 (the axis and the unmoved surface beyond the table do not move sideways), got ${u[j]}`,
      );
    }
  }
  for (let j = 1; j < length; j++) {
    if (!(j * step + u[j] > (j - 1) * step + u[j - 1])) {
      throw new Error(
        `${field}[${j}] = ${u[j]} folds the surface over itself: the displaced radius j·Δ + u[j] must increase with j`,
      );
    }
  }
  return Float64Array.from(u);
}

/** One scaled row of a prepared `fem` profile (see `surfaceSetup`). */
function surfaceTerm(family, index, weight, d, term) {
  const row = family.rows[index];
  term.row = row;
  term.radial = family.radial[index];
  term.lateral = family.rowLateral[index];
  term.amplitude = (weight * d) / family.depths[index];
  term.indexPerM = Math.pow(family.depths[index] / d, family.radiusExponent) / family.radiusStepM;
  term.reachM = (row.length - 1) / term.indexPerM;
}

/**
 * Over a stiffer inclusion the surface around the tool dents less (docs/physics.md, "The drawn
 * surface over an inclusion"): with `forceRatio` the inclusions' force ratio at the contact (the
 * frame's `inclusion_force_ratio`, 1 away from them), the paper's profile reaches
 * a + (R_d − a) / ratio instead of R_d. Under the tool the surface still follows the tool.
 */
export function stiffenedDeformedRadius(contactRadiusM, deformedRadiusM, forceRatio) {
  if (!(forceRatio > 1)) return deformedRadiusM;
  const a = Math.min(contactRadiusM, deformedRadiusM);
  return a + (deformedRadiusM - a) / forceRatio;
}

/**
 * The same for the `fem` profile set up by `surfaceSetup`: its rows' amplitudes (z and u) divided
 * by `forceRatio`; inside the footprint the surface is still never above the tool (the table
 * applies that after the rows). Returns `p`.
 */
export function stiffenSurface(p, forceRatio) {
  if (forceRatio > 1) {
    p.t0.amplitude /= forceRatio;
    p.t1.amplitude /= forceRatio;
  }
  return p;
}

/**
 * The `fem` profile of `tool` (from `toolShape`) pressed `depthM` deep (proto/WIRE.md, steps 1–2):
 * the one or two rows to blend, each with its amplitude (weight·δ/δ_k) and its samples per metre
 * ((δ_k/δ)^p / Δ), the tool's footprint (inside it the drawn surface is never above the tool)
 * and the reach beyond which nothing moves; `lateral` is whether a row used moves the surface
 * sideways. An invalid tool draws nothing. Writes into `out`, allocating nothing once `out` has
 * been used.
 */
export function surfaceSetup(family, tool, depthM, out = {}) {
  const d = tool.valid ? sanitise(depthM) : 0;
  out.tool = tool;
  out.isSphere = tool.shape === 'sphere';
  out.depthM = d;
  out.footprintM = 0;
  out.t0 ??= { row: null, radial: null, lateral: false, amplitude: 0, indexPerM: 0, reachM: 0 };
  out.t1 ??= { row: null, radial: null, lateral: false, amplitude: 0, indexPerM: 0, reachM: 0 };
  out.t0.amplitude = out.t1.amplitude = 0;
  out.t0.reachM = out.t1.reachM = 0;
  out.t0.lateral = out.t1.lateral = false;
  out.reachM = 0;
  out.lateral = false;
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
  out.lateral = (out.t0.amplitude !== 0 && out.t0.lateral) || (out.t1.amplitude !== 0 && out.t1.lateral);
  return out;
}

/**
 * One row's contribution at radius r ≥ 0: its samples (`t.row` for z, `t.radial` for u)
 * interpolated at x = r·indexPerM, times its amplitude; 0 from the row's last sample on.
 */
function surfaceTermAt(t, samples, r) {
  if (t.amplitude === 0) return 0;
  const x = r * t.indexPerM;
  if (!(x < samples.length - 1)) return 0;
  const j = Math.floor(x);
  const f = x - j;
  return t.amplitude * (samples[j] + f * (samples[j + 1] - samples[j]));
}

/**
 * Depression z(r), 0 ≤ z ≤ δ, for a profile prepared by `surfaceSetup` (proto/WIRE.md, step 3): the
 * rows' blend, never above the tool where the point drawn for r lies, at radius ρ = max(0, r +
 * u(r)) (between the FEM's nodes the rows are straight chords, which the curved tool would
 * otherwise poke through).
 */
export function surfaceDepressionAt(p, rRaw) {
  if (p.depthM === 0) return 0;
  const r = sanitise(rRaw);
  const t0 = p.t0,
    t1 = p.t1;
  let z = surfaceTermAt(t0, t0.row, r) + surfaceTermAt(t1, t1.row, r);
  const u = surfaceTermAt(t0, t0.radial, r) + surfaceTermAt(t1, t1.radial, r);
  const rho = Math.max(0, r + u);
  if (rho < p.footprintM) z = Math.max(z, p.depthM - toolHeight(p.tool, rho));
  return Math.min(Math.max(z, 0), p.depthM);
}

/**
 * Sideways displacement u(r) (m, away from the axis; negative: towards it) of the surface point
 * at undeformed radius r, for a profile prepared by `surfaceSetup` (proto/WIRE.md, step 3): the rows'
 * blend, not clamped. 0 when nothing is pressed, at and beyond the rows' reach, and for rows
 * without `radial_displacement_m`.
 */
export function surfaceRadialDisplacementAt(p, rRaw) {
  if (p.depthM === 0) return 0;
  const r = sanitise(rRaw);
  return surfaceTermAt(p.t0, p.t0.radial, r) + surfaceTermAt(p.t1, p.t1.radial, r);
}

const scratchSurface = {};

/** The `fem` profile's depression (m) at radial distance r for a family, a tool and a depth. */
export function surfaceDepression(family, tool, depthM, rM) {
  return surfaceDepressionAt(surfaceSetup(family, tool, depthM, scratchSurface), rM);
}

/** The `fem` profile's sideways displacement (m) at radial distance r for a family, a tool and a depth. */
export function surfaceRadialDisplacement(family, tool, depthM, rM) {
  return surfaceRadialDisplacementAt(surfaceSetup(family, tool, depthM, scratchSurface), rM);
}

/**
 * Intervals of a `fem` profile's radial table (`surfaceTable`, proto's
 * `SURFACE_TABLE_INTERVALS`): the profile sampled at 4097 radii from the axis to its reach.
 * Interpolated linearly it stays within 2 µm of the profile for the repository's tables (it
 * misses the rows' kinks between two samples, so the error falls with the interval), and
 * sampling it once per update costs about what 4 000 vertices cost.
 */
export const SURFACE_TABLE_INTERVALS = 4096;

/**
 * The `fem` profile prepared by `surfaceSetup`, sampled once per update for the render mesh
 * (proto's `SurfaceTable`): `z[k]` = z(k·reach / N) and `u[k]` = u(k·reach / N) for k = 0 … N
 * (N = SURFACE_TABLE_INTERVALS; `z[N]` and `u[N]` are 0, the profile's values at its reach);
 * `lateral` is false when every `u[k]` is 0 (no row used moves the surface sideways), so that a
 * reader can skip them. Each vertex then costs one lookup instead of a blend of two rows bounded
 * by the tool. Writes into `out` (its arrays are allocated once). A profile that draws nothing
 * gives a table with `reachM` 0.
 */
export function surfaceTable(p, out = {}) {
  const n = SURFACE_TABLE_INTERVALS;
  if (!(out.z instanceof Float64Array)) out.z = new Float64Array(n + 1);
  if (!(out.u instanceof Float64Array)) out.u = new Float64Array(n + 1);
  const table = out.z;
  const tableU = out.u;
  const reach = p.depthM === 0 ? 0 : p.reachM;
  out.reachM = reach;
  out.samplesPerM = reach > 0 ? n / reach : 0;
  // u stays all 0 from one table to the next while nothing moves sideways: filled only when
  // the table before it did move something.
  if (out.lateral !== false) tableU.fill(0);
  out.lateral = false;
  if (reach === 0) {
    table.fill(0);
    return out;
  }
  // `surfaceDepressionAt` and `surfaceRadialDisplacementAt` at r = k·step, with the rows and the
  // tool read into locals once (the stores into the table would otherwise make the engine load
  // them again for every sample).
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
  if (!p.lateral) {
    for (let k = 0; k < n; k++) {
      const r = k * step;
      let z = 0;
      const x0 = r * s0;
      if (a0 !== 0 && x0 < last0) {
        const j = Math.floor(x0);
        z += a0 * (z0[j] + (x0 - j) * (z0[j + 1] - z0[j]));
      }
      const x1 = r * s1;
      if (a1 !== 0 && x1 < last1) {
        const j = Math.floor(x1);
        z += a1 * (z1[j] + (x1 - j) * (z1[j + 1] - z1[j]));
      }
      if (r < footprint) z = Math.max(z, d - toolHeight(tool, r));
      table[k] = Math.min(Math.max(z, 0), d);
    }
    table[n] = 0;
    return out;
  }
  const u0 = p.t0.radial,
    u1 = a1 === 0 ? u0 : p.t1.radial;
  for (let k = 0; k < n; k++) {
    const r = k * step;
    let z = 0,
      u = 0;
    const x0 = r * s0;
    if (a0 !== 0 && x0 < last0) {
      const j = Math.floor(x0);
      const f = x0 - j;
      z += a0 * (z0[j] + f * (z0[j + 1] - z0[j]));
      u += a0 * (u0[j] + f * (u0[j + 1] - u0[j]));
    }
    const x1 = r * s1;
    if (a1 !== 0 && x1 < last1) {
      const j = Math.floor(x1);
      const f = x1 - j;
      z += a1 * (z1[j] + f * (z1[j + 1] - z1[j]));
      u += a1 * (u1[j] + f * (u1[j + 1] - u1[j]));
    }
    // The tool bounds the surface where the point drawn for r lies: at radius r + u.
    const rho = Math.max(0, r + u);
    if (rho < footprint) z = Math.max(z, d - toolHeight(tool, rho));
    table[k] = Math.min(Math.max(z, 0), d);
    tableU[k] = u;
  }
  table[n] = 0;
  tableU[n] = 0;
  out.lateral = true;
  return out;
}

/** The drawn value at radial distance r of one of a `surfaceTable`'s sample arrays. */
function surfaceTableSample(table, samples, rRaw) {
  const r = sanitise(rRaw);
  if (!(r < table.reachM)) return 0;
  const x = r * table.samplesPerM;
  // x < N in exact arithmetic; the last interval also takes a product that rounds up to N.
  const j = Math.min(Math.floor(x), SURFACE_TABLE_INTERVALS - 1);
  return samples[j] + (x - j) * (samples[j + 1] - samples[j]);
}

/**
 * The drawn depression at radial distance r from a `surfaceTable`: linear between its samples,
 * 0 at and beyond the reach; r sanitised as everywhere (a NaN radius is the axis).
 */
export function surfaceTableAt(table, rRaw) {
  return surfaceTableSample(table, table.z, rRaw);
}

/**
 * The drawn sideways displacement at radial distance r from a `surfaceTable` (away from the
 * axis; negative: towards it): linear between its samples, 0 at and beyond the reach.
 */
export function surfaceTableRadialAt(table, rRaw) {
  return surfaceTableSample(table, table.u, rRaw);
}

/**
 * The `paper` profile prepared by `profileSetup`, sampled like `surfaceTable` for the vertex
 * shader (`shaderdeform.js`): `z[k]` = z(k·R_d_eff / N) for k = 0 … N, `u` all 0 (the Bézier
 * moves nothing sideways), `reachM` = R_d_eff. Linear between samples it stays within 0.2 µm
 * of the exact profile, whose slope is continuous at a and at R_d; only a sphere pressed to its
 * equator (δ ≥ R), whose wall at r = R is vertical, differs there by the wall's drop within one
 * sample interval (0.15 mm at δ = R = 10 mm). Writes into `out`.
 */
export function profileTable(p, out = {}) {
  const n = SURFACE_TABLE_INTERVALS;
  if (!(out.z instanceof Float64Array)) out.z = new Float64Array(n + 1);
  if (!(out.u instanceof Float64Array)) out.u = new Float64Array(n + 1);
  if (out.lateral !== false) out.u.fill(0);
  out.lateral = false;
  const reach = p.depthM === 0 ? 0 : p.rdEff;
  out.reachM = reach;
  out.samplesPerM = reach > 0 ? n / reach : 0;
  if (reach === 0) {
    out.z.fill(0);
    return out;
  }
  const step = reach / n;
  for (let k = 0; k < n; k++) out.z[k] = depressionAt(p, k * step);
  out.z[n] = 0;
  return out;
}
