use softhaptic_calibration::element::{Constitutive, LawKind};
use softhaptic_calibration::experiments::{self, Resolution, block_mesh, placed_indenter};
use softhaptic_calibration::indenter::IndenterShape;
use softhaptic_calibration::mesh::Symmetry;
use softhaptic_calibration::solver::{ContactModel, SolverOptions};
use softhaptic_proto::{Material, ToolShape};
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args[1] == "fill" {
        fill();
        return;
    }
    if args[1] == "ball" {
        let law = if args[2] == "nh" {
            LawKind::NeoHookean
        } else {
            LawKind::Linear
        };
        ball(
            law,
            args[3].parse().unwrap(),
            args[4].parse().unwrap(),
            args.get(5).is_some(),
        );
        return;
    }
    let law = if args[1] == "nh" {
        LawKind::NeoHookean
    } else {
        LawKind::Linear
    };
    let reuse = args[2] == "reuse";
    let cell: f64 = args[3].parse().unwrap();
    let tool = if args.get(4).map(|s| s.as_str()) == Some("cone") {
        ToolShape::Cone {
            half_angle_rad: std::f64::consts::FRAC_PI_4,
            radius_m: 0.006,
        }
    } else {
        ToolShape::Sphere { radius_m: 0.006 }
    };
    let res = Resolution {
        name: "t",
        fine_cell_m: cell * 1e-3,
        coarse_cells: 4,
    };
    let ds: Vec<f64> = (1..=12).map(|i| i as f64 * 0.5e-3).collect();
    let mesh = block_mesh(
        "t",
        experiments::FORCE_BLOCK_M,
        &tool,
        0.006,
        res,
        Symmetry::Quarter,
    )
    .unwrap();
    let _ = reuse;
    let opts = SolverOptions::default();
    let mut model =
        ContactModel::new(mesh, Constitutive::new(law, &Material::PAPER_SOFT), opts).unwrap();
    let shape = IndenterShape::from(&tool);
    let t = Instant::now();
    let eqs = model
        .follow(
            &|d| placed_indenter(shape, d, 0.0),
            0.0,
            &ds,
            |_, _, _, _| {},
        )
        .unwrap();
    println!(
        "dofs {} time {:.2}s stats {}",
        model.dof_count(),
        t.elapsed().as_secs_f64(),
        0
    );
    for (d, e) in ds.iter().zip(&eqs) {
        print!(
            "{:.1}:{:.6} ({}) ",
            d * 1e3,
            e.force_on_tool_n[2],
            e.iterations
        );
    }
    println!();
}

#[allow(dead_code)]
pub fn fill() {
    use softhaptic_calibration::sparse::{FillOrdering, StiffnessPattern};
    for (cell, tool) in [(1.5, "sphere"), (2.0, "sphere"), (1.5, "cone")] {
        let tool = if tool == "cone" {
            ToolShape::Cone {
                half_angle_rad: std::f64::consts::FRAC_PI_4,
                radius_m: 0.006,
            }
        } else {
            ToolShape::Sphere { radius_m: 0.006 }
        };
        let res = Resolution {
            name: "t",
            fine_cell_m: cell * 1e-3,
            coarse_cells: 4,
        };
        let mesh = block_mesh(
            "t",
            experiments::FORCE_BLOCK_M,
            &tool,
            0.006,
            res,
            Symmetry::Quarter,
        )
        .unwrap();
        for ord in [FillOrdering::MinimumDegree, FillOrdering::NestedDissection] {
            let t = Instant::now();
            let p = StiffnessPattern::with_ordering(&mesh, ord).unwrap();
            let ts = t.elapsed().as_secs_f64();
            let mut v = p.zero_values();
            for x in v.iter_mut() {
                *x = 1e-3;
            }
            for d in 0..p.size() {
                p.set_diagonal(&mut v, d, 1e3);
            }
            let t = Instant::now();
            let f = p.factorise(&v).unwrap();
            let tf = t.elapsed().as_secs_f64();
            let mut b = vec![1.0; p.size()];
            let t = Instant::now();
            f.solve_in_place(&mut b);
            let tsol = t.elapsed().as_secs_f64();
            let mut y = vec![0.0; p.size()];
            let t = Instant::now();
            p.multiply(&v, &b, &mut y);
            let tm = t.elapsed().as_secs_f64();
            println!(
                "cell {cell} n {} {:?}: L {} symbolic {:.3}s factor {:.3}s solve {:.4}s matvec {:.4}s",
                p.size(),
                ord,
                p.factor_entries(),
                ts,
                tf,
                tsol,
                tm
            );
        }
    }
}

#[allow(dead_code)]
pub fn ball(law: LawKind, r0: f64, cell: f64, cone: bool) {
    use softhaptic_calibration::mesh::{self, BallSpec};
    let tool = if cone {
        ToolShape::Cone {
            half_angle_rad: std::f64::consts::FRAC_PI_4,
            radius_m: 0.01,
        }
    } else {
        ToolShape::Sphere { radius_m: 0.01 }
    };
    let a: f64 = if cone { 0.00637 } else { 0.01 };
    let mesh = mesh::quarter_ball(&BallSpec {
        radius_m: r0,
        fine_cell_m: cell * 1e-3,
        fine_radius_m: (1.5 * a).min(0.6 * r0),
        coarse_cells: 5,
    })
    .unwrap();
    let ds: Vec<f64> = (1..=10).map(|i| i as f64 * 1e-3).collect();
    let mut model = ContactModel::new(
        mesh,
        Constitutive::new(law, &Material::PAPER_SOFT),
        SolverOptions::default(),
    )
    .unwrap();
    let shape = IndenterShape::from(&tool);
    let t = Instant::now();
    let eqs = model
        .follow(
            &|d| placed_indenter(shape, d, 0.0),
            0.0,
            &ds,
            |_, _, _, _| {},
        )
        .unwrap();
    println!(
        "ball r0 {r0} cell {cell} dofs {} time {:.2}s",
        model.dof_count(),
        t.elapsed().as_secs_f64()
    );
    for (d, e) in ds.iter().zip(&eqs) {
        print!(
            "{:.1}:{:.4} ({}) ",
            d * 1e3,
            e.force_on_tool_n[2],
            e.iterations
        );
    }
    println!();
}
