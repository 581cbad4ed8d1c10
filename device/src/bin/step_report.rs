//! Times one haptic step on the paper's timing surfaces and prints it beside the paper's Table 1.
//!
//! `cargo run --release -p softhaptic-device --features tools --bin step-report`
//!
//! The step is [`timing_step_force_n`]: collision query, contact law and damping along the
//! normal, with a 10 mm sphere 5 mm into a flat 0.1 m grid, the tip circling 1 mm around the
//! centre (the same set-up as `benches/haptic_step.rs`), and last the same press into the top
//! of the liver's haptic mesh. For each surface and collision mode the report times 101 batches
//! of steps (each about 0.5 ms long) and prints the median of the batch means and the fastest
//! batch mean. On a shared machine another process preempting a batch inflates that batch only:
//! the median shows the typical cost under the current load, the fastest batch the cost of the
//! code itself. The figures are measurements, never pass/fail criteria.
//!
//! A second table times the contact model: one evaluation of the force (the paper's law, and
//! the default scene's combined model: exact sphere, hyperelastic fit, curvature), the bisection
//! for the stiffness cap's depth δ*, and a whole tick ([`HapticWorld::step`]: collision with the
//! curvature, the model, every safety layer) pressing and sliding on the liver, where the
//! curvature under the tool changes from tick to tick.

use std::hint::black_box;
use std::time::{Duration, Instant};

use glam::DQuat;
use glam::DVec3;
use softhaptic_device::collision::{Collider, CollisionMode, timing_step_force_n};
use softhaptic_device::device::{DeviceLimits, DeviceSample};
use softhaptic_device::force::ForceConfig;
use softhaptic_device::liver;
use softhaptic_device::mesh::HapticMesh;
use softhaptic_device::model::{ForceModel, LocalGeometry};
use softhaptic_device::world::HapticWorld;
use softhaptic_proto::{Material, ModelSpec, Pose, ToolShape};

/// Vertices per side and the paper's mean step time (ms, Intel i7-2600, 2011; Table 1), or
/// `None` for the sizes past the paper's.
const SIZES: [(usize, Option<f64>); 9] = [
    (40, Some(0.154)),
    (50, Some(0.231)),
    (60, Some(0.325)),
    (70, Some(0.426)),
    (80, Some(0.551)),
    (90, Some(0.696)),
    (100, Some(0.856)),
    (316, None),
    (1000, None),
];

/// Batches timed per configuration.
const BATCHES: usize = 101;

/// Target length of one batch: short, so that most batches escape preemption by other processes.
const BATCH_TIME: Duration = Duration::from_micros(500);

/// Step time of one configuration, in microseconds.
#[derive(Clone, Copy)]
struct Timing {
    median_us: f64,
    best_us: f64,
}

struct Bench {
    tool: ToolShape,
    material: Material,
    velocity_m_s: DVec3,
    path: Vec<Pose>,
}

impl Bench {
    fn run(&self, collider: &mut Collider, path: &[Pose], steps: usize, start: usize) -> DVec3 {
        let mut sum = DVec3::ZERO;
        for k in 0..steps {
            let pose = &path[(start + k) % path.len()];
            sum += timing_step_force_n(
                collider,
                &self.tool,
                &self.material,
                black_box(pose),
                self.velocity_m_s,
                5.0,
            );
        }
        sum
    }

    /// Median and minimum over batches of the mean step time.
    fn time(&self, collider: &mut Collider, path: &[Pose]) -> Timing {
        // Warm up, and size the batches from a first estimate.
        let probe = Instant::now();
        let mut probe_steps = 0;
        while probe.elapsed() < Duration::from_millis(50) {
            black_box(self.run(collider, path, 16, probe_steps));
            probe_steps += 16;
        }
        let per_step = probe.elapsed().as_secs_f64() / probe_steps as f64;
        let steps = ((BATCH_TIME.as_secs_f64() / per_step) as usize).max(1);
        let mut means_us: Vec<f64> = (0..BATCHES)
            .map(|b| {
                let t = Instant::now();
                black_box(self.run(collider, path, steps, b * steps));
                t.elapsed().as_secs_f64() * 1e6 / steps as f64
            })
            .collect();
        means_us.sort_by(f64::total_cmp);
        Timing {
            median_us: means_us[BATCHES / 2],
            best_us: means_us[0],
        }
    }

    /// Times both collision modes on one mesh; returns the build time (ms) too.
    fn time_modes(&self, mesh: HapticMesh, path: &[Pose]) -> (f64, Timing, Timing) {
        let built = Instant::now();
        let mut collider = Collider::new(mesh, CollisionMode::Continuous);
        let build_ms = built.elapsed().as_secs_f64() * 1e3;
        let continuous = self.time(&mut collider, path);
        collider.set_mode(CollisionMode::PaperVertices);
        let paper_mode = self.time(&mut collider, path);
        (build_ms, continuous, paper_mode)
    }
}

/// Median and minimum over batches of the mean time of one call of `run(steps, start)`, which
/// runs `steps` calls starting at index `start` (batches sized as in [`Bench::time`]).
fn time_calls(mut run: impl FnMut(usize, usize) -> f64) -> Timing {
    let probe = Instant::now();
    let mut probe_steps = 0;
    while probe.elapsed() < Duration::from_millis(50) {
        black_box(run(16, probe_steps));
        probe_steps += 16;
    }
    let per_step = probe.elapsed().as_secs_f64() / probe_steps as f64;
    let steps = ((BATCH_TIME.as_secs_f64() / per_step) as usize).max(1);
    let mut start = probe_steps;
    let mut means_us: Vec<f64> = (0..BATCHES)
        .map(|_| {
            let t = Instant::now();
            black_box(run(steps, start));
            start += steps;
            t.elapsed().as_secs_f64() * 1e6 / steps as f64
        })
        .collect();
    means_us.sort_by(f64::total_cmp);
    Timing {
        median_us: means_us[BATCHES / 2],
        best_us: means_us[0],
    }
}

/// The default scene's combined model.
fn combined_spec() -> ModelSpec {
    ModelSpec {
        exact_sphere: true,
        curvature: true,
        hyperelastic: true,
        ..ModelSpec::PAPER
    }
}

/// Times the contact model alone and whole ticks on the liver, paper's law against the
/// combined model.
fn model_report(tool: ToolShape, material: Material) {
    let paper = ForceModel::paper(tool, material);
    // A constant spec valid for a sphere: cannot fail.
    let combined =
        ForceModel::new(tool, material, combined_spec()).expect("valid for a sphere tool");
    let depth_m = |k: usize| 1e-3 + 4e-3 * ((k % 97) as f64 / 97.0);
    let geometry = |k: usize| LocalGeometry {
        curvature_1_per_m: 10.0 + (k % 89) as f64 * 0.2,
        inclination_rad: 0.0,
    };
    let force = |model: &ForceModel| {
        time_calls(|steps, start| {
            (start..start + steps)
                .map(|k| model.force_n(black_box(depth_m(k)), &geometry(k)))
                .sum()
        })
    };
    let k_max = DeviceLimits::PHANTOM_DESKTOP.max_stiffness_n_per_m;
    let cap = |model: &ForceModel| {
        time_calls(|steps, start| {
            (start..start + steps)
                .map(|k| model.depth_at_stiffness_m(black_box(k_max), &geometry(k)))
                .sum()
        })
    };

    // Whole ticks: the tip 2–4 mm deep at the top of the right lobe, sliding ±10 mm across it
    // and back over 4 s, so the curvature under the tool keeps changing.
    let top = liver::top_contact();
    let orientation = DQuat::from_rotation_arc(DVec3::Y, top.normal);
    let along = top.normal.any_orthonormal_vector();
    let sample = |k: usize| {
        let phase = k as f64 * std::f64::consts::TAU / 4000.0;
        DeviceSample {
            time_ns: k as u64 * 1_000_000,
            tip_in_world: Pose {
                position_m: top.point_m + along * (0.01 * phase.sin())
                    - top.normal * (0.003 + 0.001 * (3.0 * phase).cos()),
                orientation,
            },
            tip_velocity_m_s: DVec3::ZERO,
            buttons: 0,
            flags: softhaptic_proto::ContactFlags::empty(),
        }
    };
    let tick = |spec: ModelSpec| {
        let model = ForceModel::new(tool, material, spec).expect("valid for a sphere tool");
        let mut world = HapticWorld::with_model(
            Collider::new(liver::haptic_mesh(), CollisionMode::Continuous),
            Pose::IDENTITY,
            model,
            ForceConfig::for_tool(&tool),
            DeviceLimits::PHANTOM_DESKTOP,
        );
        time_calls(|steps, start| {
            (start..start + steps)
                .map(|k| world.step(Ok(black_box(sample(k)))).force_n.y)
                .sum()
        })
    };

    println!();
    println!(
        "Contact model, 10 mm sphere, 50 kPa; µs per call, median and fastest of {BATCHES} batch means."
    );
    println!("Combined = the default scene's model: exact sphere + hyperelastic fit + curvature.");
    println!();
    println!(
        "{:<50} {:>9} {:>9} {:>9} {:>9}",
        "", "paper", "", "combined", ""
    );
    println!(
        "{:<50} {:>9} {:>9} {:>9} {:>9}",
        "", "median", "best", "median", "best"
    );
    let line = |name: &str, p: Timing, c: Timing| {
        println!(
            "{name:<50} {:>9.4} {:>9.4} {:>9.4} {:>9.4}",
            p.median_us, p.best_us, c.median_us, c.best_us
        );
    };
    line(
        "force F(δ; geometry), one evaluation",
        force(&paper),
        force(&combined),
    );
    line(
        "stiffness-cap depth δ* (closed form / bisection)",
        cap(&paper),
        cap(&combined),
    );
    line(
        "whole tick on the liver, pressing and sliding",
        tick(ModelSpec::PAPER),
        tick(combined_spec()),
    );
}

fn row(vertices: usize, triangles: usize, build_ms: f64, c: Timing, p: Timing, tail: &str) {
    println!(
        "{vertices:>9} {triangles:>9} {build_ms:>8.1} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {tail}",
        c.median_us, c.best_us, p.median_us, p.best_us
    );
}

/// Times one haptic step (collision, contact law, damping) on the paper's Table 1 surfaces and
/// beyond, in both collision modes, beside the paper's figures; then the contact model's costs.
/// Run it on a release build: `cargo run --release -p softhaptic-device --features tools --bin step-report`.
#[derive(clap::Parser)]
#[command(name = "step-report", version)]
struct Args {}

fn main() {
    use clap::Parser as _;
    Args::parse();
    // A report piped into `head` ends when the reader does, as other command-line tools do,
    // instead of panicking on the closed pipe.
    // SAFETY: restores the default action of one signal before any other thread exists.
    unsafe { libc::signal(libc::SIGPIPE, libc::SIG_DFL) };
    let bench = Bench {
        // A constant, valid radius: cannot fail.
        tool: ToolShape::sphere(0.01).expect("a 10 mm sphere is a valid tool"),
        material: Material::PAPER_SOFT,
        velocity_m_s: DVec3::new(0.01, -0.02, 0.0),
        path: (0..64)
            .map(|k| {
                let a = k as f64 / 64.0 * std::f64::consts::TAU;
                Pose::from_position(DVec3::new(0.001 * a.cos(), -0.005, 0.001 * a.sin()))
            })
            .collect(),
    };
    println!("One haptic step (collision + contact law + damping), 10 mm sphere 5 mm deep, flat");
    println!("0.1 m grids. Times in µs per step: median and fastest of {BATCHES} batch means.");
    println!("Paper: Table 1, mean ms, Intel i7-2600 (2011); ratios use our medians.");
    println!();
    println!(
        "{:>9} {:>9} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9} {:>11} {:>11}",
        "", "", "", "continuous", "", "paper mode", "", "paper", "paper/ours", "paper/ours"
    );
    println!(
        "{:>9} {:>9} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9} {:>11} {:>11}",
        "vertices",
        "triangles",
        "build ms",
        "median",
        "best",
        "median",
        "best",
        "mean ms",
        "continuous",
        "paper mode"
    );
    let mut at_10k = None;
    let mut at_1m = None;
    for (side, paper_ms) in SIZES {
        let mesh = HapticMesh::grid(side, 0.1);
        let (vertices, triangles) = (mesh.positions_m().len(), mesh.triangles().len());
        let (build_ms, c, p) = bench.time_modes(mesh, &bench.path);
        let tail = match paper_ms {
            Some(ms) => format!(
                "{ms:>9.3} {:>10.0}× {:>10.0}×",
                ms * 1e3 / c.median_us,
                ms * 1e3 / p.median_us
            ),
            None => format!("{:>9} {:>11} {:>11}", "—", "—", "—"),
        };
        row(vertices, triangles, build_ms, c, p, &tail);
        match side {
            100 => at_10k = Some((c, p)),
            1000 => at_1m = Some((c, p)),
            _ => {}
        }
    }
    // The scene's own object: the liver's haptic mesh, pressed 5 mm at its top along the normal.
    let top = liver::top_contact();
    let orientation = DQuat::from_rotation_arc(DVec3::Y, top.normal);
    let liver_path: Vec<Pose> = bench
        .path
        .iter()
        .map(|p| Pose {
            position_m: top.point_m + orientation * p.position_m,
            orientation,
        })
        .collect();
    let mesh = liver::haptic_mesh();
    let (vertices, triangles) = (mesh.positions_m().len(), mesh.triangles().len());
    let (build_ms, c, p) = bench.time_modes(mesh, &liver_path);
    row(
        vertices,
        triangles,
        build_ms,
        c,
        p,
        "  (the liver's haptic mesh)",
    );

    if let (Some((c10k, p10k)), Some((c1m, p1m))) = (at_10k, at_1m) {
        println!();
        println!(
            "growth 10⁶ / 10⁴ vertices (median, best): continuous {:.2}×, {:.2}×; paper mode {:.0}×, {:.0}× (the paper's times grow linearly)",
            c1m.median_us / c10k.median_us,
            c1m.best_us / c10k.best_us,
            p1m.median_us / p10k.median_us,
            p1m.best_us / p10k.best_us
        );
        println!(
            "goals: ≤ 10 µs at 10⁴ vertices (continuous median {:.3} µs); ≤ 4× from 10⁴ to 10⁶ vertices (continuous median {:.2}×)",
            c10k.median_us,
            c1m.median_us / c10k.median_us
        );
    }

    model_report(bench.tool, bench.material);
}
