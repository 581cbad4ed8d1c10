//! One contact-force evaluation, `ForceModel::force_n`, per model combination: the paper's law,
//! each correction alone, and the best combined model, for the §4.3 sphere (R = 6 mm) and 45°
//! cone on the 30 mm block, E = 50 kPa, ν = 0.33.
//!
//! `cargo bench -p softhaptic-device --bench force_model`. The calibration report's
//! speed-accuracy table (`softhaptic-calibrate speed-accuracy`) times the same evaluations with a
//! plain timing loop and puts them beside their force error; issue 6's budget is 1 µs per
//! evaluation. The depth cycles through 64 values up to 6 mm so that no evaluation repeats the
//! previous one; the curvature and inclination models get a curved, tilted contact.

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use softhaptic_device::model::{ForceModel, LocalGeometry};
use softhaptic_proto::{LayerSpec, Material, ModelSpec, ToolShape};

const LAYER: Option<LayerSpec> = Some(LayerSpec {
    thickness_m: 0.03,
    bonded: true,
});

/// (name, spec, geometry) of every benchmarked model of one tool.
fn models(sphere: bool) -> Vec<(&'static str, ModelSpec, LocalGeometry)> {
    let flat = LocalGeometry::FLAT;
    let curved = LocalGeometry {
        curvature_1_per_m: 1.0 / 0.05,
        inclination_rad: 0.0,
    };
    let tilted = LocalGeometry {
        curvature_1_per_m: 0.0,
        inclination_rad: 10f64.to_radians(),
    };
    let paper = ModelSpec::PAPER;
    let mut out = vec![
        ("paper", paper, flat),
        (
            "curvature",
            ModelSpec {
                curvature: true,
                ..paper
            },
            curved,
        ),
        (
            "bonded_layer",
            ModelSpec {
                thickness: LAYER,
                ..paper
            },
            flat,
        ),
        (
            "hyperelastic",
            ModelSpec {
                hyperelastic: true,
                ..paper
            },
            flat,
        ),
    ];
    if sphere {
        out.extend([
            (
                "exact_sphere",
                ModelSpec {
                    exact_sphere: true,
                    ..paper
                },
                flat,
            ),
            (
                "sliding_layer",
                ModelSpec {
                    thickness: Some(LayerSpec {
                        thickness_m: 0.03,
                        bonded: false,
                    }),
                    ..paper
                },
                flat,
            ),
            (
                "best_combined",
                ModelSpec {
                    exact_sphere: true,
                    thickness: LAYER,
                    hyperelastic: true,
                    ..paper
                },
                flat,
            ),
            (
                "best_combined_curved",
                ModelSpec {
                    exact_sphere: true,
                    curvature: true,
                    hyperelastic: true,
                    ..paper
                },
                curved,
            ),
        ]);
    } else {
        out.extend([
            (
                "inclination",
                ModelSpec {
                    inclination: true,
                    ..paper
                },
                tilted,
            ),
            (
                "best_combined",
                ModelSpec {
                    thickness: LAYER,
                    hyperelastic: true,
                    ..paper
                },
                flat,
            ),
            (
                "best_combined_curved_tilted",
                ModelSpec {
                    curvature: true,
                    hyperelastic: true,
                    inclination: true,
                    ..paper
                },
                LocalGeometry {
                    curvature_1_per_m: curved.curvature_1_per_m,
                    inclination_rad: tilted.inclination_rad,
                },
            ),
        ]);
    }
    out
}

fn force_model(c: &mut Criterion) {
    let material = Material::PAPER_SOFT;
    let depths: Vec<f64> = (1..=64).map(|i| 0.006 * i as f64 / 64.0).collect();
    let mut group = c.benchmark_group("force_model");
    group
        .sample_size(30)
        .warm_up_time(Duration::from_millis(200))
        .measurement_time(Duration::from_millis(600));
    for (tool_name, tool) in [
        ("sphere6", ToolShape::Sphere { radius_m: 0.006 }),
        (
            "cone45",
            ToolShape::Cone {
                half_angle_rad: std::f64::consts::FRAC_PI_4,
                radius_m: 0.006,
            },
        ),
    ] {
        for (name, spec, geometry) in models(matches!(tool, ToolShape::Sphere { .. })) {
            let model = ForceModel::new(tool, material, spec)
                .expect("every benchmarked combination is valid for its tool");
            let mut k = 0usize;
            group.bench_function(format!("{tool_name}/{name}"), |b| {
                b.iter(|| {
                    k = (k + 1) & 63;
                    black_box(model.force_n(black_box(depths[k]), black_box(&geometry)))
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, force_model);
criterion_main!(benches);
