//! The runtime contact models as the calibration measures them: each is the very
//! `softhaptic_device::model::ForceModel` the 1 kHz loop runs, built from a `ModelSpec`, so what
//! the report measures is what the loop computes. This module names them, times one force
//! evaluation, and scores forces against an FEM reference.

use std::time::Instant;

use serde::Serialize;
use softhaptic_device::model::{ForceModel, LocalGeometry};
use softhaptic_proto::{LayerSpec, Material, ModelError, ModelSpec, ToolShape};

/// A runtime model under test.
#[derive(Debug, Clone)]
pub struct RuntimeModel {
    pub tool: ToolShape,
    pub spec: ModelSpec,
    model: ForceModel,
}

impl RuntimeModel {
    pub fn new(tool: ToolShape, material: Material, spec: ModelSpec) -> Result<Self, ModelError> {
        Ok(RuntimeModel {
            tool,
            spec,
            model: ForceModel::new(tool, material, spec)?,
        })
    }

    /// The name the report uses (the scene vocabulary's label).
    pub fn name(&self) -> String {
        self.spec.label(&self.tool)
    }

    /// Force along the contact normal at `depth_m`.
    pub fn force_n(&self, depth_m: f64, geometry: &LocalGeometry) -> f64 {
        self.model.force_n(depth_m, geometry)
    }

    /// Forces at each of `depths_m`.
    pub fn forces_n(&self, depths_m: &[f64], geometry: &LocalGeometry) -> Vec<f64> {
        depths_m
            .iter()
            .map(|&d| self.force_n(d, geometry))
            .collect()
    }

    /// Median wall time of one `force_n` evaluation, nanoseconds (see [`time_per_call_ns`]).
    pub fn nanoseconds_per_evaluation(&self, geometry: &LocalGeometry, max_depth_m: f64) -> f64 {
        time_per_call_ns(|d| self.model.force_n(d, geometry), max_depth_m)
    }
}

/// Batches of calls timed for [`time_per_call_ns`].
pub const TIMING_BATCHES: usize = 31;
/// Calls per timed batch.
pub const CALLS_PER_BATCH: usize = 20_000;

/// Median over [`TIMING_BATCHES`] batches of the mean wall time of one call of `f`, in
/// nanoseconds. The calls cycle through 64 depths spread over (0, `max_depth_m`] and the
/// results are summed and passed through `black_box`, so neither the input nor the work can be
/// hoisted out of the loop. The median discards the batches a busy machine interrupted.
pub fn time_per_call_ns(f: impl Fn(f64) -> f64, max_depth_m: f64) -> f64 {
    let inputs: Vec<f64> = (1..=64).map(|i| max_depth_m * i as f64 / 64.0).collect();
    let mut per_call = Vec::with_capacity(TIMING_BATCHES);
    let mut sink = 0.0;
    // One untimed batch warms caches and branch predictors.
    for batch in 0..=TIMING_BATCHES {
        let start = Instant::now();
        for i in 0..CALLS_PER_BATCH {
            sink += f(std::hint::black_box(inputs[i & 63]));
        }
        let ns = start.elapsed().as_secs_f64() * 1e9 / CALLS_PER_BATCH as f64;
        if batch > 0 {
            per_call.push(ns);
        }
    }
    std::hint::black_box(sink);
    crate::experiments::median(&per_call)
}

/// Errors of forces against a reference at the same depths, percent, signed (model above the
/// reference is positive).
#[derive(Debug, Clone, Serialize)]
pub struct ErrorCurve {
    /// The paper's eq. 9 (and eq. 6) form: (f_a − f_f) / max f_f.
    pub eq9_percent: Vec<f64>,
    /// Pointwise: (f_a − f_f) / f_f.
    pub relative_percent: Vec<f64>,
}

impl ErrorCurve {
    pub fn new(forces_n: &[f64], reference_n: &[f64]) -> Self {
        let f_max = reference_n
            .iter()
            .copied()
            .filter(|f| f.is_finite())
            .fold(0.0_f64, f64::max)
            .max(f64::MIN_POSITIVE);
        ErrorCurve {
            eq9_percent: forces_n
                .iter()
                .zip(reference_n)
                .map(|(f, r)| 100.0 * (f - r) / f_max)
                .collect(),
            relative_percent: forces_n
                .iter()
                .zip(reference_n)
                .map(|(f, r)| 100.0 * (f - r) / r)
                .collect(),
        }
    }

    /// Largest |eq. 9 error|, percent.
    pub fn max_eq9_percent(&self) -> f64 {
        self.eq9_percent.iter().fold(0.0_f64, |m, e| m.max(e.abs()))
    }

    /// Largest |pointwise error|, percent.
    pub fn max_relative_percent(&self) -> f64 {
        self.relative_percent
            .iter()
            .fold(0.0_f64, |m, e| m.max(e.abs()))
    }
}

/// A bonded or sliding layer of `thickness_m`.
pub fn layer(thickness_m: f64, bonded: bool) -> Option<LayerSpec> {
    Some(LayerSpec {
        thickness_m,
        bonded,
    })
}

/// The models of the speed-accuracy table for a sphere on a layer of `thickness_m`: the paper's
/// law, each correction alone, and the combinations; the last one is the best combined model.
pub fn sphere_specs(thickness_m: f64) -> Vec<ModelSpec> {
    let base = ModelSpec::PAPER;
    vec![
        base,
        ModelSpec {
            exact_sphere: true,
            ..base
        },
        ModelSpec {
            thickness: layer(thickness_m, true),
            ..base
        },
        ModelSpec {
            thickness: layer(thickness_m, false),
            ..base
        },
        ModelSpec {
            hyperelastic: true,
            ..base
        },
        ModelSpec {
            exact_sphere: true,
            thickness: layer(thickness_m, true),
            ..base
        },
        best_combined_sphere(thickness_m),
    ]
}

/// The best combined sphere model on a bonded layer: exact sphere, layer and neo-Hookean fit.
pub fn best_combined_sphere(thickness_m: f64) -> ModelSpec {
    ModelSpec {
        exact_sphere: true,
        thickness: layer(thickness_m, true),
        hyperelastic: true,
        ..ModelSpec::PAPER
    }
}

/// The models of the speed-accuracy table for a cone on a bonded layer of `thickness_m`.
pub fn cone_specs(thickness_m: f64) -> Vec<ModelSpec> {
    let base = ModelSpec::PAPER;
    vec![
        base,
        ModelSpec {
            thickness: layer(thickness_m, true),
            ..base
        },
        ModelSpec {
            hyperelastic: true,
            ..base
        },
        ModelSpec {
            thickness: layer(thickness_m, true),
            hyperelastic: true,
            ..base
        },
    ]
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn errors_follow_eq9_and_pointwise_definitions() {
        let e = ErrorCurve::new(&[1.1, 2.0, 3.6], &[1.0, 2.0, 4.0]);
        assert!((e.eq9_percent[0] - 2.5).abs() < 1e-12);
        assert!((e.eq9_percent[2] + 10.0).abs() < 1e-12);
        assert!((e.relative_percent[0] - 10.0).abs() < 1e-12);
        assert!((e.max_eq9_percent() - 10.0).abs() < 1e-12);
        assert!((e.max_relative_percent() - 10.0).abs() < 1e-12);
    }

    #[test]
    fn every_listed_model_is_accepted_by_the_runtime() {
        let m = Material::PAPER_SOFT;
        let sphere = ToolShape::Sphere { radius_m: 0.006 };
        let cone = ToolShape::Cone {
            half_angle_rad: std::f64::consts::FRAC_PI_4,
            radius_m: 0.006,
        };
        for spec in sphere_specs(0.03) {
            RuntimeModel::new(sphere, m, spec).unwrap();
        }
        for spec in cone_specs(0.03) {
            RuntimeModel::new(cone, m, spec).unwrap();
        }
        let paper = RuntimeModel::new(sphere, m, ModelSpec::PAPER).unwrap();
        let hertz = softhaptic_device::law::hertz_force_n(&m, 0.006, 0.002);
        assert_eq!(paper.force_n(0.002, &LocalGeometry::FLAT), hertz);
        let ns = paper.nanoseconds_per_evaluation(&LocalGeometry::FLAT, 0.006);
        assert!(ns.is_finite() && ns > 0.0);
    }
}
