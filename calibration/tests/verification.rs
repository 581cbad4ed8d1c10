//! Verification of the FEM before any experiment: patch tests, invariance, contact against the
//! closed-form half-space solutions. Meshes are small enough for a debug build.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use softhaptic_calibration::element::{Constitutive, LawKind};
use softhaptic_calibration::experiments::MATERIAL;
use softhaptic_calibration::indenter::{Indenter, IndenterShape};
use softhaptic_calibration::mesh::{self, BlockSpec, Symmetry};
use softhaptic_calibration::solver::{ContactModel, SolverOptions, deformed_radius_m};
use softhaptic_calibration::sparse::{FillOrdering, StiffnessPattern};
use softhaptic_device::model::{ForceModel, LocalGeometry};
use softhaptic_proto::{LayerSpec, Material, ModelSpec};

fn patch_mesh() -> mesh::TetMesh {
    // A graded, non-uniform block so the elements differ in size and shape.
    let spec = BlockSpec {
        size_m: [0.04, 0.03, 0.02],
        fine_cell_m: 0.004,
        fine_radius_m: 0.006,
        fine_depth_m: 0.006,
        coarse_cells_lateral: 2,
        coarse_cells_depth: 2,
        symmetry: Symmetry::Full,
    };
    let mut m = mesh::block(&spec).unwrap();
    m.fixed.iter_mut().for_each(|f| *f = 0);
    m
}

fn boundary_nodes(m: &mesh::TetMesh) -> Vec<usize> {
    let mut lo = [f64::MAX; 3];
    let mut hi = [f64::MIN; 3];
    for p in &m.nodes_m {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (0..m.node_count())
        .filter(|&i| {
            let p = m.nodes_m[i];
            (0..3).any(|k| (p[k] - lo[k]).abs() < 1e-12 || (p[k] - hi[k]).abs() < 1e-12)
        })
        .collect()
}

/// Patch test: a linear displacement field imposed on the boundary must be reproduced exactly
/// at every interior node (constant strain), for the linear law at small strain and for the
/// neo-Hookean law at finite strain (a homogeneous deformation is an exact solution of both).
#[test]
fn patch_test_reproduces_constant_strain_exactly() {
    let grad = [
        [2e-3, 1e-3, -5e-4],
        [3e-4, -1.5e-3, 8e-4],
        [-7e-4, 6e-4, 1e-3],
    ];
    for (kind, scale) in [
        (LawKind::LinearDeformedContact, 1.0),
        (LawKind::NeoHookean, 1.0),
        (LawKind::NeoHookean, 40.0),
    ] {
        let m = patch_mesh();
        let boundary = boundary_nodes(&m);
        let field = |p: [f64; 3]| -> [f64; 3] {
            std::array::from_fn(|i| (0..3).map(|j| scale * grad[i][j] * p[j]).sum())
        };
        let targets: Vec<(usize, [f64; 3])> =
            boundary.iter().map(|&i| (i, field(m.nodes_m[i]))).collect();
        let nodes = m.nodes_m.clone();
        let interior = m.node_count() - boundary.len();
        assert!(
            interior > 50,
            "the patch needs interior nodes, got {interior}"
        );
        let mut model = ContactModel::new(
            m,
            Constitutive::new(kind, &Material::PAPER_SOFT),
            SolverOptions::default(),
        )
        .unwrap();
        model.solve_prescribed(&targets).unwrap();
        let u = model.displacements_m();
        let mut worst = 0.0_f64;
        let mut biggest = 0.0_f64;
        for (i, p) in nodes.iter().enumerate() {
            let exact = field(*p);
            for k in 0..3 {
                worst = worst.max((u[i][k] - exact[k]).abs());
                biggest = biggest.max(exact[k].abs());
            }
        }
        assert!(
            worst <= 1e-9 * biggest,
            "{kind:?} ×{scale}: interior error {worst:e} m for displacements up to {biggest:e} m"
        );
    }
}

/// With the displacement imposed and no body force, the static displacement field does not
/// depend on E at fixed ν: the R_d tables for 50 kPa and 1.5 MPa are one solve (and the force
/// scales with E).
#[test]
fn displacement_field_is_independent_of_youngs_modulus() {
    let spec = BlockSpec::graded([0.06, 0.06, 0.03], 0.004, 0.004, 2, Symmetry::Quarter);
    let shape = IndenterShape::Sphere { radius_m: 0.01 };
    let mut results = Vec::new();
    for material in [Material::PAPER_SOFT, Material::PAPER_STIFF] {
        let mut model = ContactModel::new(
            mesh::block(&spec).unwrap(),
            Constitutive::new(LawKind::NeoHookean, &material),
            SolverOptions::default(),
        )
        .unwrap();
        let eq = model
            .follow(
                &|d| Indenter::vertical(shape, d),
                0.0,
                &[0.002, 0.004],
                |_, _, _, _| {},
            )
            .unwrap();
        results.push((eq[1].force_on_tool_n[2], model.displacements_m().to_vec()));
    }
    let ratio = results[1].0 / results[0].0;
    assert!((ratio / 30.0 - 1.0).abs() < 1e-6, "force ratio {ratio}");
    let worst = results[0]
        .1
        .iter()
        .zip(&results[1].1)
        .flat_map(|(a, b)| (0..3).map(move |k| (a[k] - b[k]).abs()))
        .fold(0.0_f64, f64::max);
    assert!(worst < 1e-9, "displacements differ by {worst:e} m");
}

/// Hertz at δ = 0.2 R on a block 20 R wide and deep. The sphere's FEM force must be within 3%
/// of F = (4/3) E* √R δ^{3/2}. Hertz's own shape, the paraboloid, removes the sphere's
/// deviation (−2% at this depth, docs/physics.md): its force must be within 3% of Hertz corrected
/// for the block's finite depth (Dimitriadis' bonded factor, +2%), and the surface outside the
/// contact must follow Johnson's half-space profile.
#[test]
fn indentation_matches_hertz_and_half_space_profile() {
    let r = 0.01_f64;
    let depth = 0.2 * r;
    let a = (r * depth).sqrt();
    let size = 20.0 * r;
    let spec = BlockSpec::graded([size, size, size], a, 0.002, 5, Symmetry::Quarter);
    let material = Material::PAPER_SOFT;
    let mut model = ContactModel::new(
        mesh::block(&spec).unwrap(),
        Constitutive::new(LawKind::LinearDeformedContact, &material),
        SolverOptions::default(),
    )
    .unwrap();
    let hertz = softhaptic_device::law::hertz_force_n(&material, r, depth);
    let eq = model
        .solve(
            &Indenter::vertical(IndenterShape::Sphere { radius_m: r }, depth),
            0,
            depth,
        )
        .unwrap();
    let err = eq.force_on_tool_n[2] / hertz - 1.0;
    assert!(
        err.abs() < 0.03,
        "sphere: FEM {} N vs Hertz {hertz} N ({:+.2}%)",
        eq.force_on_tool_n[2],
        100.0 * err
    );
    model.reset();
    let eq = model
        .solve(
            &Indenter::vertical(IndenterShape::Paraboloid { radius_m: r }, depth),
            0,
            depth,
        )
        .unwrap();
    // The runtime's bonded-layer correction (Dimitriadis) for the block's finite depth.
    let layered = ForceModel::new(
        softhaptic_proto::ToolShape::Sphere { radius_m: r },
        material,
        ModelSpec {
            thickness: Some(LayerSpec {
                thickness_m: size,
                bonded: true,
            }),
            ..ModelSpec::PAPER
        },
    )
    .unwrap()
    .force_n(depth, &LocalGeometry::FLAT);
    let layer = layered / hertz;
    let err = eq.force_on_tool_n[2] / (hertz * layer) - 1.0;
    assert!(
        err.abs() < 0.03,
        "paraboloid: FEM {} N vs Hertz × layer factor {} N ({:+.2}%)",
        eq.force_on_tool_n[2],
        hertz * layer,
        100.0 * err
    );
    // Profile between 1.5 a and 4 a against Johnson's formula (docs/physics.md).
    let tool = softhaptic_proto::ToolShape::Sphere { radius_m: r };
    let profile = model.surface_profile();
    let mut checked = 0;
    for &(radius, depression) in &profile {
        if radius > 1.5 * a && radius < 4.0 * a {
            let exact =
                softhaptic_proto::calibration::half_space_depression_m(&tool, depth, radius);
            assert!(
                (depression - exact).abs() < 0.05 * depth,
                "r = {radius}: FEM {depression} m, half-space {exact} m"
            );
            checked += 1;
        }
    }
    assert!(checked >= 3, "only {checked} profile nodes in range");
    // The centre sinks by exactly δ (the contact constraint holds there).
    assert!((profile[0].1 - depth).abs() < 1e-7);
    // R_d on the profile is where the depression crosses the threshold.
    let rd = deformed_radius_m(&profile, 0.25 * depth);
    let exact_rd =
        softhaptic_proto::calibration::half_space_deformed_radius_m(&tool, depth, 0.25 * depth);
    assert!(
        (rd / exact_rd - 1.0).abs() < 0.1,
        "R_d {rd} vs half-space {exact_rd}"
    );
}

/// Mesh convergence: refining the contact zone moves the Hertz force toward the analytical
/// value (the FEM is stiffer on coarser meshes, as a displacement-based method must be).
#[test]
fn refinement_converges_toward_hertz_from_above() {
    let r = 0.01_f64;
    let depth = 0.1 * r;
    let a = (r * depth).sqrt();
    let material = Material::PAPER_SOFT;
    let hertz = softhaptic_device::law::hertz_force_n(&material, r, depth);
    let mut errors = Vec::new();
    for cell in [0.004, 0.002] {
        let spec = BlockSpec::graded(
            [16.0 * r, 16.0 * r, 16.0 * r],
            a,
            cell,
            4,
            Symmetry::Quarter,
        );
        let mut model = ContactModel::new(
            mesh::block(&spec).unwrap(),
            Constitutive::new(LawKind::LinearDeformedContact, &material),
            SolverOptions::default(),
        )
        .unwrap();
        let eq = model
            .solve(
                &Indenter::vertical(IndenterShape::Paraboloid { radius_m: r }, depth),
                0,
                depth,
            )
            .unwrap();
        errors.push(eq.force_on_tool_n[2] / hertz - 1.0);
    }
    assert!(errors[0] > errors[1], "errors {errors:?} do not decrease");
    assert!(errors[1] > -0.02, "fine mesh softer than Hertz: {errors:?}");
}

/// The quarter model with its symmetry planes must give the whole block's force: the full
/// (unmirrored) block, meshed without any symmetry plane, agrees to the discretisation error
/// (its tetrahedra are split along one diagonal direction, so the two meshes differ), and its
/// lateral force vanishes.
#[test]
fn quarter_and_full_models_agree() {
    let r = 0.01_f64;
    let depth = 0.002;
    let a = (r * depth).sqrt();
    let material = Material::PAPER_SOFT;
    let mut forces = Vec::new();
    for symmetry in [Symmetry::Quarter, Symmetry::Full] {
        let spec = BlockSpec::graded([0.06, 0.06, 0.03], a, 0.004, 2, symmetry);
        let mut model = ContactModel::new(
            mesh::block(&spec).unwrap(),
            Constitutive::new(LawKind::LinearDeformedContact, &material),
            SolverOptions::default(),
        )
        .unwrap();
        let eq = model
            .solve(
                &Indenter::vertical(IndenterShape::Sphere { radius_m: r }, depth),
                0,
                depth,
            )
            .unwrap();
        forces.push(eq.force_on_tool_n);
    }
    assert!(
        (forces[0][2] / forces[1][2] - 1.0).abs() < 0.03,
        "{forces:?}"
    );
    assert!(forces[1][0].abs() < 0.01 * forces[1][2] && forces[1][1].abs() < 0.01 * forces[1][2]);
}

/// The nested-dissection ordering is a permutation of every node, and the factorisation it
/// orders solves the same system as minimum degree's, to rounding.
#[test]
fn nested_dissection_solves_the_same_system_as_minimum_degree() {
    let spec = BlockSpec::graded([0.06, 0.06, 0.03], 0.004, 0.004, 2, Symmetry::Quarter);
    let mesh = mesh::block(&spec).unwrap();
    let dims = mesh.grid_nodes.unwrap();
    let mut order = softhaptic_calibration::sparse::nested_dissection_order(dims);
    assert_eq!(order.len(), mesh.node_count());
    order.sort_unstable();
    assert!(order.iter().enumerate().all(|(i, &n)| i == n));
    // An SPD matrix on the mesh's pattern: a stiffness-like Laplacian plus a diagonal shift.
    let nd = StiffnessPattern::with_ordering(&mesh, FillOrdering::NestedDissection).unwrap();
    let md = StiffnessPattern::with_ordering(&mesh, FillOrdering::MinimumDegree).unwrap();
    assert!(
        nd.factor_entries() < md.factor_entries(),
        "nested dissection {} vs minimum degree {} factor entries",
        nd.factor_entries(),
        md.factor_entries()
    );
    let mut values = nd.zero_values();
    for (k, v) in values.iter_mut().enumerate() {
        *v = -1e-3 * (1.0 + (k % 7) as f64);
    }
    for dof in 0..nd.size() {
        nd.set_diagonal(&mut values, dof, 10.0);
    }
    let b: Vec<f64> = (0..nd.size())
        .map(|i| ((i * 37) % 11) as f64 - 5.0)
        .collect();
    let mut x_nd = b.clone();
    nd.factorise(&values).unwrap().solve_in_place(&mut x_nd);
    let mut x_md = b.clone();
    md.factorise(&values).unwrap().solve_in_place(&mut x_md);
    let scale = x_md.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    let worst = x_nd
        .iter()
        .zip(&x_md)
        .fold(0.0_f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(
        worst <= 1e-10 * scale,
        "solutions differ by {worst:e} (scale {scale:e})"
    );
    // And it is the solution: K x = b.
    let mut kx = vec![0.0; nd.size()];
    nd.multiply(&values, &x_nd, &mut kx);
    let residual = kx
        .iter()
        .zip(&b)
        .fold(0.0_f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(residual < 1e-9, "residual {residual:e}");
}

/// The small-deformation formulation is the textbook linear contact problem, so on a block deep
/// enough to stand for the half-space it must give Sneddon's closed forms: the exact sphere and
/// the cone, within 2% at every depth from 1 mm to δ = R = 6 mm. The coarse meshes of the
/// report's convergence table (cells of a/2); the finer ones come within 0.5%.
#[test]
fn small_deformation_matches_sneddon_on_a_deep_block() {
    use softhaptic_calibration::experiments::verification::{
        SneddonMesh, sneddon_checks, sneddon_runs,
    };
    use softhaptic_calibration::experiments::{RunCache, depths};
    let meshes = [SneddonMesh {
        name: "a/2",
        cells_per_contact_radius: 2.0,
        coarse_cells: 6,
    }];
    let depths_m = depths(1.0, 6.0, 1.0);
    let mut cache = RunCache::new(2);
    cache
        .ensure(&sneddon_runs(&meshes, &depths_m, &MATERIAL))
        .unwrap();
    let checks = sneddon_checks(&cache, &meshes, &depths_m, &MATERIAL).unwrap();
    assert_eq!(checks.len(), 2);
    for check in &checks {
        assert_eq!(check.points.len(), 6);
        for p in &check.points {
            let err = p.error_percent[0];
            assert!(
                err.abs() < 2.0,
                "{} at δ = {} mm: FEM {} N, Sneddon {} N ({err:+.2}%)",
                check.tool_name,
                p.depth_m * 1e3,
                p.fem_n[0],
                p.sneddon_n
            );
        }
    }
}

/// Refining the deep-block mesh moves the small-deformation force toward Sneddon from above, as
/// a displacement-based method must; the deformed-surface formulation, at the same depth on the
/// same mesh, falls below it (the symptom the small-deformation mode removes).
#[test]
fn small_deformation_converges_to_sneddon_from_above() {
    use softhaptic_calibration::experiments::verification::{
        SneddonMesh, sneddon_force_n, sneddon_run,
    };
    use softhaptic_calibration::experiments::{RunCache, run_indentation};
    let tool = softhaptic_proto::ToolShape::Cone {
        half_angle_rad: std::f64::consts::FRAC_PI_4,
        radius_m: 0.006,
    };
    let depth = 0.004;
    let exact = sneddon_force_n(&tool, &MATERIAL, depth);
    let meshes = [
        SneddonMesh {
            name: "a/1.5",
            cells_per_contact_radius: 1.5,
            coarse_cells: 5,
        },
        SneddonMesh {
            name: "a/2",
            cells_per_contact_radius: 2.0,
            coarse_cells: 6,
        },
    ];
    let specs: Vec<_> = meshes
        .iter()
        .map(|&m| sneddon_run("cone", &tool, depth, m, &MATERIAL))
        .collect();
    let mut cache = RunCache::new(2);
    cache.ensure(&specs).unwrap();
    let errors: Vec<f64> = specs
        .iter()
        .map(|s| cache.get("test", s).unwrap().normal_force_at_n(depth) / exact - 1.0)
        .collect();
    assert!(
        errors[0] > errors[1] && errors[1] > 0.0,
        "errors {errors:?} do not decrease toward Sneddon from above"
    );
    // The deformed-surface formulation on the finer mesh, loaded in 1 mm steps.
    let mut deformed = specs[1].clone();
    deformed.law = LawKind::LinearDeformedContact;
    deformed.depths_m = vec![0.001, 0.002, 0.003, 0.004];
    let run = run_indentation(&deformed, &indicatif::ProgressBar::hidden()).unwrap();
    let ratio = run.normal_force_at_n(depth) / exact;
    assert!(
        ratio < 1.0 + errors[1] - 0.02,
        "deformed-surface formulation {ratio:.3} × Sneddon, small deformation {:.3}",
        1.0 + errors[1]
    );
}

/// At ν = 0.49 (bulk modulus 25 times the shear modulus) both laws still reproduce a constant
/// strain exactly: the patch test does not see locking, but an element that failed it could not
/// converge at all.
#[test]
fn patch_test_holds_at_nearly_incompressible_poisson_ratio() {
    use softhaptic_calibration::experiments::verification::{
        NEARLY_INCOMPRESSIBLE_POISSON, material_with_poisson, patch_test_error,
    };
    let material = material_with_poisson(NEARLY_INCOMPRESSIBLE_POISSON).unwrap();
    for law in [LawKind::LinearDeformedContact, LawKind::NeoHookean] {
        let err = patch_test_error(law, &material).unwrap();
        assert!(err < 1e-10, "{}: {err:e}", law.name());
    }
}

/// At ν = 0.49 the 10-node tetrahedra do not lock: on the coarse deep-block mesh (cells of a/2)
/// the small-deformation FEM stays within 4% of Sneddon (the report's finer meshes come within
/// 1%), stiff by a few percent as a displacement method is, not by the tens of percent of a
/// locking element.
#[test]
fn small_deformation_matches_sneddon_at_nearly_incompressible_poisson_ratio() {
    use softhaptic_calibration::experiments::verification::{
        NEARLY_INCOMPRESSIBLE_POISSON, SneddonMesh, material_with_poisson, sneddon_checks,
        sneddon_runs,
    };
    use softhaptic_calibration::experiments::{RunCache, depths};
    let material = material_with_poisson(NEARLY_INCOMPRESSIBLE_POISSON).unwrap();
    let meshes = [SneddonMesh {
        name: "a/2",
        cells_per_contact_radius: 2.0,
        coarse_cells: 6,
    }];
    let depths_m = depths(2.0, 6.0, 2.0);
    let mut cache = RunCache::new(2);
    cache
        .ensure(&sneddon_runs(&meshes, &depths_m, &material))
        .unwrap();
    for check in sneddon_checks(&cache, &meshes, &depths_m, &material).unwrap() {
        for p in &check.points {
            let err = p.error_percent[0];
            assert!(
                (0.0..4.0).contains(&err),
                "{} at δ = {} mm, ν = 0.49: {err:+.2}%",
                check.tool_name,
                p.depth_m * 1e3
            );
        }
    }
}

/// On the paper's 30 mm bonded layer the small-deformation FEM must sit above Sneddon's
/// half-space by the bonded-layer factor the runtime applies, also at small depths: there the
/// §4.3 mesh's 1.5 mm cells are wider than the cone's contact (0.64 mm at δ = 1 mm) and put the
/// cone below the half-space, which a bonded layer cannot be; the report's layer check solves
/// those depths again on meshes scaled to the contact (cells of a/4), and these are those runs.
#[test]
fn small_depths_on_the_bonded_layer_meet_the_layer_factor_on_a_contact_scaled_mesh() {
    use softhaptic_calibration::experiments::force::{
        layer_closed_form_n, layer_refined_mesh, layer_refined_run,
    };
    use softhaptic_calibration::experiments::verification::sneddon_force_n;
    use softhaptic_calibration::experiments::{Mode, RunCache, force_tools};
    // The report's mesh is a/4; a/3 (within 0.6% of Sneddon on the deep block) keeps the test
    // to seconds. δ = 1 mm, the depth the §4.3 mesh gets most wrong.
    assert_eq!(layer_refined_mesh(Mode::Full).name, "a/4");
    let depths_m = [0.001];
    let mesh = softhaptic_calibration::experiments::verification::SneddonMesh {
        name: "a/3",
        cells_per_contact_radius: 3.0,
        coarse_cells: 8,
    };
    let mut specs = Vec::new();
    for (name, tool) in force_tools() {
        for d in depths_m {
            specs.push((name, tool, d, layer_refined_run(name, &tool, d, mesh)));
        }
    }
    let mut cache = RunCache::new(2);
    let runs: Vec<_> = specs.iter().map(|s| s.3.clone()).collect();
    cache.ensure(&runs).unwrap();
    for (name, tool, d, spec) in &specs {
        let fem = cache.get("test", spec).unwrap().normal_force_at_n(*d);
        let half_space = sneddon_force_n(tool, &MATERIAL, *d);
        let layer = layer_closed_form_n(name, tool, &[*d]).unwrap()[0];
        let error = 100.0 * (fem / layer - 1.0);
        assert!(
            fem > half_space && error.abs() < 2.0,
            "{name} at δ = {} mm: FEM {fem} N, half-space {half_space} N (× {:.3}), layer \
             closed form {layer} N ({error:+.2}%)",
            d * 1e3,
            fem / half_space
        );
    }
}

/// Where the strain is small the neo-Hookean law comes down to linear elasticity, so on the deep
/// block at δ = 1 mm (δ/R = 1/6) it must land near Sneddon's exact sphere at ν = 0.49 as at
/// 0.33: within 5% on the coarse mesh (cells of a/2), where the small-deformation FEM of the same
/// mesh is 1–3% stiff and the neo-Hookean law adds a few percent of its own stiffening (Lin et
/// al.'s incompressible sphere: 1 + 0.2 a/R + … over Hertz). An element that locked at ν = 0.49
/// would come out tens of percent stiff; a wrong volumetric term, off at any depth.
#[test]
fn neo_hookean_meets_sneddon_at_small_depth_at_nearly_incompressible_poisson_ratio() {
    use softhaptic_calibration::experiments::RunCache;
    use softhaptic_calibration::experiments::verification::{
        NEARLY_INCOMPRESSIBLE_POISSON, SneddonMesh, material_with_poisson, neo_hookean_point,
        neo_hookean_runs_at,
    };
    let mesh = SneddonMesh {
        name: "a/2",
        cells_per_contact_radius: 2.0,
        coarse_cells: 6,
    };
    let depth_m = 0.001;
    let materials = [
        MATERIAL,
        material_with_poisson(NEARLY_INCOMPRESSIBLE_POISSON).unwrap(),
    ];
    let mut runs = Vec::new();
    for material in &materials {
        runs.extend(neo_hookean_runs_at(depth_m, mesh, material));
    }
    let mut cache = RunCache::new(2);
    cache.ensure(&runs).unwrap();
    let points: Vec<_> = materials
        .iter()
        .map(|m| neo_hookean_point(&cache, depth_m, mesh, m).unwrap())
        .collect();
    let describe = |p: &softhaptic_calibration::experiments::verification::NeoHookeanPoint| {
        format!(
            "ν = {}: neo-Hookean {} N, Sneddon {} N ({:+.2}%), small deformation {} N ({:+.2}%)",
            p.poisson_ratio,
            p.neo_hookean_n,
            p.sneddon_n,
            p.error_percent(),
            p.small_deformation_n,
            p.over_linear_percent()
        )
    };
    for p in &points {
        assert!(
            p.error_percent().abs() < 5.0 && p.over_linear_percent().abs() < 5.0,
            "{}",
            describe(p)
        );
    }
}
