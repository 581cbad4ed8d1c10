// Messages as the wire contract (proto/WIRE.md) spells them, shared by the unit tests.

export const hello = {
  type: 'hello',
  protocol_version: 1,
  session_id: 's-1',
  role: 'instructor',
  mode: 'live',
  server: 'softhaptic 0.1.0',
};

/** `hello` as servers before roles and tokens sent it: no `mode`, the role `viewer` or `replay`. */
export const legacyHello = {
  type: 'hello',
  protocol_version: 1,
  session_id: 's-1',
  role: 'viewer',
  server: 'softhaptic 0.1.0',
};

export const scene = {
  type: 'scene',
  protocol_version: 1,
  tool: { shape: 'sphere', radius_m: 0.01 },
  material: { youngs_modulus_pa: 50000, poisson_ratio: 0.33 },
  model: { name: 'hertz', valid_depth_m: 0.0043, valid_inclination_rad: 0.38 },
  calibration: {
    format: 'softhaptic-calibration',
    version: 1,
    source: 'half_space',
    description: 'test',
    tool: { shape: 'sphere', radius_m: 0.01 },
    material: { youngs_modulus_pa: 50000, poisson_ratio: 0.33 },
    threshold_m: 0.0005,
    rows: [{ depth_m: 0.0005, deformed_radius_m: 0.0123 }],
    fit: { breakpoint_m: 0.007, linear: [0.01, 2.5], quadratic: [0.01, 2.5, 0] },
  },
  render_meshes: [
    {
      name: 'liver',
      url: '/meshes/liver.bin',
      vertex_count: 100000,
      object_in_world: { position_m: [0, 0, 0], orientation: [0, 0, 0, 1] },
    },
  ],
  device: {
    name: 'simulated PHANTOM Desktop',
    peak_force_n: 7.9,
    continuous_force_n: 1.75,
    max_stiffness_n_per_m: 1000,
    damping_n_s_per_m: 5,
    workspace_radius_m: 0.1,
  },
};

/**
 * The scene's `contact_model` object (newer servers): a sphere with three corrections and limits
 * measured by the project's FEM.
 */
export const contactModel = {
  label: 'Hertz + exact sphere + curvature + neo-Hookean fit',
  corrections: ['exact_sphere', 'curvature', 'hyperelastic'],
  spec: { exact_sphere: true, curvature: true, thickness: null, hyperelastic: true, inclination: false },
  valid_depth_m: 0.0058,
  valid_inclination_rad: 0.38,
  limits_source: 'FEM (neo-Hookean block, 10 mm sphere), within 7 % of the reference force',
};

export function contact(overrides = {}) {
  return {
    type: 'contact',
    seq: 7,
    tick: 140,
    time_ns: 140_000_000,
    tip_in_world: { position_m: [0, 0.01, 0], orientation: [0, 0, 0, 1] },
    in_contact: true,
    depth_m: 0.002,
    normal: [0, 1, 0],
    contact_point_m: [0, 0.012, 0],
    contact_radius_m: 0.0045,
    deformed_radius_m: 0.015,
    force_n: [0, 1.2, 0],
    flags: ['ramping', 'beyond_valid_depth'],
    dropped: 0,
    ...overrides,
  };
}

export const stats = {
  type: 'stats',
  loop_rate_hz: 1000.2,
  period_error_us: { p50: 2, p99: 15, p999: 40, max: 80 },
  overruns: 0,
  standby_ticks: 0,
  compute_us: { p50: 5, p99: 12, max: 30 },
  viewers: 1,
  dropped_frames: 0,
};
