//! Verification of the FEM before the experiments: Hertz on a large block, the surface profile
//! against the half-space, the patch tests, and the small-deformation formulation against
//! Sneddon's exact sphere and cone on a deep block, under mesh refinement.

use serde::Serialize;
use softhaptic_device::law;
use softhaptic_device::model::LocalGeometry;
use softhaptic_proto::{Material, ModelSpec, ToolShape};

use super::{
    Body, ExperimentError, MATERIAL, MM, Mode, Resolution, RunCache, RunSpec, depths, force_tools,
    max_contact_radius_m,
};
use crate::analytic;
use crate::element::{Constitutive, LawKind};
use crate::indenter::IndenterShape;
use crate::mesh::{self, BlockSpec, Symmetry};
use crate::models::{RuntimeModel, layer};
use crate::solver::{ContactModel, SolveError, SolverOptions};

/// One verification figure.
#[derive(Debug, Clone, Serialize)]
pub struct HertzCheck {
    pub indenter: String,
    pub fine_cell_m: f64,
    pub dofs: usize,
    pub fem_n: f64,
    pub hertz_n: f64,
    /// FEM / Hertz − 1, percent.
    pub error_vs_hertz_percent: f64,
    /// FEM against the runtime's law corrected for the block depth (bonded layer) and, for the
    /// sphere, for the exact sphere shape, percent.
    pub error_vs_corrected_percent: f64,
    /// Largest |FEM − half-space| surface depression for a < r < 4a, relative to δ, percent.
    pub profile_error_percent: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct VerificationStudy {
    pub depth_over_radius: f64,
    pub block_over_radius: f64,
    pub checks: Vec<HertzCheck>,
    /// The patch tests: each law at ν = 0.33 and at ν = 0.49.
    pub patch_test: Vec<PatchTest>,
    /// The small-deformation formulation against Sneddon on a deep block, per tool.
    pub sneddon: Vec<SneddonCheck>,
    /// The neo-Hookean law against Sneddon's exact sphere at small depths on the deep block, at
    /// ν = 0.33 and 0.49.
    pub neo_hookean: Vec<NeoHookeanPoint>,
}

/// The neo-Hookean FEM at one small depth of the 6 mm sphere on the deep block, beside the
/// small-deformation FEM of the same mesh and Sneddon's exact sphere: where the strain is small
/// the hyperelastic law must reduce to linear elasticity, at ν = 0.49 as at 0.33, so a locking or
/// otherwise wrong nearly incompressible neo-Hookean element would show here as a departure
/// beyond the law's own small stiffening (Lin et al.'s incompressible ratio beside it).
#[derive(Debug, Clone, Serialize)]
pub struct NeoHookeanPoint {
    pub poisson_ratio: f64,
    pub depth_m: f64,
    pub mesh: SneddonMesh,
    pub dofs: usize,
    pub sneddon_n: f64,
    pub small_deformation_n: f64,
    pub neo_hookean_n: f64,
    /// Lin et al.'s incompressible neo-Hookean sphere over Hertz at this depth.
    pub lin_et_al_over_hertz: f64,
}

impl NeoHookeanPoint {
    /// Neo-Hookean FEM / Sneddon − 1, percent.
    pub fn error_percent(&self) -> f64 {
        100.0 * (self.neo_hookean_n / self.sneddon_n - 1.0)
    }

    /// Neo-Hookean / small-deformation FEM on the same mesh − 1, percent: the hyperelastic
    /// law's own departure, the mesh's error cancelled.
    pub fn over_linear_percent(&self) -> f64 {
        100.0 * (self.neo_hookean_n / self.small_deformation_n - 1.0)
    }
}

/// Depths of the neo-Hookean deep-block check, where δ/R ≤ 1/6 keeps the sphere's strain small.
pub fn neo_hookean_depths(mode: Mode) -> Vec<f64> {
    match mode {
        Mode::Quick => vec![1.0 * MM],
        Mode::Full => vec![0.5 * MM, 1.0 * MM],
    }
}

/// The mesh of the neo-Hookean deep-block check: the middle one of the convergence table (its
/// tangent is factorised every Newton iteration, so the finest would cost as much as the rest
/// of the verification); the small-deformation run of the same mesh cancels its error.
pub fn neo_hookean_mesh(mode: Mode) -> SneddonMesh {
    let meshes = sneddon_meshes(mode);
    meshes[meshes.len() / 2]
}

/// The neo-Hookean run and the small-deformation run of the 6 mm sphere at `depth_m` on the deep
/// block; the neo-Hookean one in two load steps (Newton's starting point).
pub fn neo_hookean_runs_at(depth_m: f64, mesh: SneddonMesh, material: &Material) -> [RunSpec; 2] {
    let [(name, tool), _] = force_tools();
    let size = SNEDDON_BLOCK_OVER_CONTACT_RADIUS * max_contact_radius_m(&tool, depth_m);
    [
        sneddon_run(name, &tool, depth_m, mesh, material),
        contact_scaled_run(
            format!("deep block {name}"),
            [size, size, size],
            &tool,
            depth_m,
            mesh,
            LawKind::NeoHookean,
            material,
            2,
        ),
    ]
}

/// The materials of the neo-Hookean check: the paper's and the nearly incompressible one.
fn neo_hookean_materials() -> Vec<Material> {
    let mut out = vec![MATERIAL];
    out.extend(material_with_poisson(NEARLY_INCOMPRESSIBLE_POISSON).ok());
    out
}

/// Every run of the neo-Hookean deep-block check.
pub fn neo_hookean_runs(mode: Mode) -> Vec<RunSpec> {
    let mut out = Vec::new();
    for material in neo_hookean_materials() {
        for d in neo_hookean_depths(mode) {
            out.extend(neo_hookean_runs_at(d, neo_hookean_mesh(mode), &material));
        }
    }
    out
}

/// The neo-Hookean deep-block check of one depth and material, from the finished runs.
pub fn neo_hookean_point(
    cache: &RunCache,
    depth_m: f64,
    mesh: SneddonMesh,
    material: &Material,
) -> Result<NeoHookeanPoint, ExperimentError> {
    let study = "verify (neo-Hookean)";
    let [(_, tool), _] = force_tools();
    let [linear, neo_hookean] = neo_hookean_runs_at(depth_m, mesh, material);
    let linear = cache.get(study, &linear)?;
    let neo_hookean = cache.get(study, &neo_hookean)?;
    let radius_m = tool.radius_m();
    Ok(NeoHookeanPoint {
        poisson_ratio: material.poisson_ratio(),
        depth_m,
        mesh,
        dofs: neo_hookean.dofs,
        sneddon_n: sneddon_force_n(&tool, material, depth_m),
        small_deformation_n: linear.normal_force_at_n(depth_m),
        neo_hookean_n: neo_hookean.normal_force_at_n(depth_m),
        lin_et_al_over_hertz: analytic::lin_neo_hookean_sphere_force_n(material, radius_m, depth_m)
            / law::hertz_force_n(material, radius_m, depth_m),
    })
}

/// One patch test: the largest nodal error relative to the largest displacement.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct PatchTest {
    pub law: LawKind,
    pub poisson_ratio: f64,
    pub error: f64,
}

/// Mesh of the deep-block check at one depth, relative to that depth's contact radius a: the
/// cell edge is a / `cells_per_contact_radius` over 1.5 a laterally and a in depth, then
/// `coarse_cells` cells grow geometrically to the block's faces.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SneddonMesh {
    pub name: &'static str,
    pub cells_per_contact_radius: f64,
    pub coarse_cells: usize,
}

/// Size of the deep block (a cube, bottom clamped, sides free) in contact radii of each depth.
/// The bonded-layer correction's first term, 0.9 a/h at ν = 0.33, bounds the finite size's
/// stiffening by about +0.9% at this size; the finest mesh lands within +0.4% of Sneddon, so
/// the block is a half-space to that accuracy.
pub const SNEDDON_BLOCK_OVER_CONTACT_RADIUS: f64 = 100.0;

/// The meshes of the deep-block check, coarsest first.
pub fn sneddon_meshes(mode: Mode) -> &'static [SneddonMesh] {
    const COARSE: SneddonMesh = SneddonMesh {
        name: "a/2",
        cells_per_contact_radius: 2.0,
        coarse_cells: 6,
    };
    const MEDIUM: SneddonMesh = SneddonMesh {
        name: "a/3",
        cells_per_contact_radius: 3.0,
        coarse_cells: 8,
    };
    const FINE: SneddonMesh = SneddonMesh {
        name: "a/4",
        cells_per_contact_radius: 4.0,
        coarse_cells: 10,
    };
    const ROUGH: SneddonMesh = SneddonMesh {
        name: "a/1.5",
        cells_per_contact_radius: 1.5,
        coarse_cells: 5,
    };
    match mode {
        Mode::Quick => &[ROUGH, COARSE],
        Mode::Full => &[COARSE, MEDIUM, FINE],
    }
}

/// Depths of the deep-block check: to δ = R of the 6 mm tools.
pub fn sneddon_depths(mode: Mode) -> Vec<f64> {
    match mode {
        Mode::Quick => depths(2.0, 6.0, 4.0),
        Mode::Full => depths(1.0, 6.0, 1.0),
    }
}

/// Sneddon's closed form for `tool` on the half-space of `material`: the exact sphere, or the
/// cone.
pub fn sneddon_force_n(tool: &ToolShape, material: &Material, depth_m: f64) -> f64 {
    match *tool {
        ToolShape::Sphere { radius_m } => {
            analytic::exact_sphere_force_n(material, radius_m, depth_m)
        }
        ToolShape::Cone { .. } => law::contact_force_n(tool, material, depth_m),
    }
}

/// Poisson's ratio of the nearly incompressible checks (soft tissue: 0.45–0.49).
pub const NEARLY_INCOMPRESSIBLE_POISSON: f64 = 0.49;

/// The paper's soft material with Poisson's ratio `poisson_ratio` instead of 0.33.
pub fn material_with_poisson(poisson_ratio: f64) -> Result<Material, ExperimentError> {
    Material::new(MATERIAL.youngs_modulus_pa(), poisson_ratio).map_err(|e| ExperimentError::Data {
        study: "material".to_owned(),
        reason: format!("ν = {poisson_ratio}: {e}"),
    })
}

/// " ν = 0.49" for a material other than the paper's, nothing for the paper's (its run labels
/// stay as they were).
pub fn poisson_tag(material: &Material) -> String {
    if material.poisson_ratio() == MATERIAL.poisson_ratio() {
        String::new()
    } else {
        format!(", ν = {:.2}", material.poisson_ratio())
    }
}

/// One deep-block run: `tool` pressed to `depth_m` in one step (the problem is linear apart
/// from the active set, so there is no load path to follow), on a mesh scaled to that depth's
/// contact radius. Scaling the mesh with a keeps the relative resolution the same at every depth,
/// which one mesh cannot do for the cone: its contact radius grows sixfold from 1 to 6 mm.
pub fn sneddon_run(
    name: &str,
    tool: &ToolShape,
    depth_m: f64,
    mesh: SneddonMesh,
    material: &Material,
) -> RunSpec {
    let size = SNEDDON_BLOCK_OVER_CONTACT_RADIUS * max_contact_radius_m(tool, depth_m);
    contact_scaled_run(
        format!("deep block {name}"),
        [size, size, size],
        tool,
        depth_m,
        mesh,
        LawKind::LinearSmallDeformation,
        material,
        1,
    )
}

/// `tool` pressed to `depth_m` in `steps` equal load steps into a block of `size_m` (quarter
/// model, bottom clamped, sides free) meshed with `mesh` scaled to that depth's contact radius;
/// labelled `label` followed by the depth, the mesh, the law when it is not the
/// small-deformation one and ν when it is not the paper's.
#[allow(clippy::too_many_arguments)] // each is one independent property of the run
pub fn contact_scaled_run(
    label: String,
    size_m: [f64; 3],
    tool: &ToolShape,
    depth_m: f64,
    mesh: SneddonMesh,
    law: LawKind,
    material: &Material,
    steps: usize,
) -> RunSpec {
    let a = max_contact_radius_m(tool, depth_m);
    let cell = a / mesh.cells_per_contact_radius;
    let steps = steps.max(1);
    let law_tag = if law == LawKind::LinearSmallDeformation {
        String::new()
    } else {
        format!(", {}", law.name())
    };
    RunSpec {
        label: format!(
            "{label} δ = {:.1} mm, cells {}{law_tag}{}",
            depth_m / MM,
            mesh.name,
            poisson_tag(material)
        ),
        body: Body::Block(BlockSpec::graded(
            size_m,
            a,
            cell,
            mesh.coarse_cells,
            Symmetry::Quarter,
        )),
        indenter: IndenterShape::from(tool),
        law,
        material: *material,
        resolution: Resolution {
            name: mesh.name,
            fine_cell_m: cell,
            coarse_cells: mesh.coarse_cells,
        },
        depths_m: (1..=steps)
            .map(|k| depth_m * k as f64 / steps as f64)
            .collect(),
        tilt_rad: 0.0,
    }
}

/// The deep-block runs of every tool, depth and mesh.
pub fn sneddon_runs(meshes: &[SneddonMesh], depths_m: &[f64], material: &Material) -> Vec<RunSpec> {
    let mut out = Vec::new();
    for (name, tool) in force_tools() {
        for &mesh in meshes {
            for &d in depths_m {
                out.push(sneddon_run(name, &tool, d, mesh, material));
            }
        }
    }
    out
}

/// The small-deformation FEM against Sneddon at one depth, on every mesh.
#[derive(Debug, Clone, Serialize)]
pub struct SneddonPoint {
    pub depth_m: f64,
    pub sneddon_n: f64,
    /// FEM force per mesh, coarsest first.
    pub fem_n: Vec<f64>,
    /// Unknowns per mesh.
    pub dofs: Vec<usize>,
    /// FEM / Sneddon − 1 per mesh, percent.
    pub error_percent: Vec<f64>,
}

/// The deep-block check of one tool.
#[derive(Debug, Clone, Serialize)]
pub struct SneddonCheck {
    pub tool_name: String,
    pub tool: ToolShape,
    pub material: Material,
    pub meshes: Vec<SneddonMesh>,
    pub points: Vec<SneddonPoint>,
}

impl SneddonCheck {
    /// Largest |FEM / Sneddon − 1| over the depths on the finest mesh, percent.
    pub fn worst_finest_error_percent(&self) -> f64 {
        self.points
            .iter()
            .filter_map(|p| p.error_percent.last())
            .fold(0.0_f64, |m, e| m.max(e.abs()))
    }
}

/// The small-deformation formulation against Sneddon's exact sphere and cone on the deep block,
/// from the finished runs of [`sneddon_runs`] with the same meshes and depths.
pub fn sneddon_checks(
    cache: &RunCache,
    meshes: &[SneddonMesh],
    depths_m: &[f64],
    material: &Material,
) -> Result<Vec<SneddonCheck>, ExperimentError> {
    let study = "verify (Sneddon)";
    let mut out = Vec::new();
    for (name, tool) in force_tools() {
        let mut points = Vec::new();
        for &d in depths_m {
            let sneddon_n = sneddon_force_n(&tool, material, d);
            let mut fem_n = Vec::new();
            let mut dofs = Vec::new();
            for &mesh in meshes {
                let run = cache.get(study, &sneddon_run(name, &tool, d, mesh, material))?;
                fem_n.push(run.normal_force_at_n(d));
                dofs.push(run.dofs);
            }
            let error_percent = fem_n
                .iter()
                .map(|f| 100.0 * (f / sneddon_n - 1.0))
                .collect();
            points.push(SneddonPoint {
                depth_m: d,
                sneddon_n,
                fem_n,
                dofs,
                error_percent,
            });
        }
        out.push(SneddonCheck {
            tool_name: name.to_owned(),
            tool,
            material: *material,
            meshes: meshes.to_vec(),
            points,
        });
    }
    Ok(out)
}

const RADIUS_M: f64 = 0.01;
const DEPTH_OVER_RADIUS: f64 = 0.2;
const BLOCK_OVER_RADIUS: f64 = 20.0;

fn cells(mode: Mode) -> &'static [f64] {
    match mode {
        Mode::Quick => &[5.0 * MM, 3.0 * MM],
        Mode::Full => &[2.0 * MM, 1.25 * MM],
    }
}

fn shapes() -> [(&'static str, IndenterShape); 2] {
    [
        ("sphere", IndenterShape::Sphere { radius_m: RADIUS_M }),
        (
            "paraboloid",
            IndenterShape::Paraboloid { radius_m: RADIUS_M },
        ),
    ]
}

fn check_run(cell_m: f64, name: &str, shape: IndenterShape) -> RunSpec {
    let depth = DEPTH_OVER_RADIUS * RADIUS_M;
    let a = (RADIUS_M * depth).sqrt();
    let size = BLOCK_OVER_RADIUS * RADIUS_M;
    RunSpec {
        label: format!("verification {name} {:.2} mm cells", cell_m / MM),
        body: Body::Block(BlockSpec::graded(
            [size, size, size],
            a,
            cell_m,
            5,
            Symmetry::Quarter,
        )),
        indenter: shape,
        law: LawKind::LinearDeformedContact,
        material: MATERIAL,
        resolution: Resolution {
            name: "verification",
            fine_cell_m: cell_m,
            coarse_cells: 5,
        },
        depths_m: vec![depth],
        tilt_rad: 0.0,
    }
}

/// The runs: sphere and paraboloid, two mesh sizes; the deep-block Sneddon runs.
pub fn verification_runs(mode: Mode) -> Vec<RunSpec> {
    let mut out = Vec::new();
    for &cell in cells(mode) {
        for (name, shape) in shapes() {
            out.push(check_run(cell, name, shape));
        }
    }
    out.extend(sneddon_runs(
        sneddon_meshes(mode),
        &sneddon_depths(mode),
        &MATERIAL,
    ));
    if let Ok(nearly_incompressible) = material_with_poisson(NEARLY_INCOMPRESSIBLE_POISSON) {
        out.extend(sneddon_runs(
            sneddon_meshes(mode),
            &sneddon_depths(mode),
            &nearly_incompressible,
        ));
    }
    out.extend(neo_hookean_runs(mode));
    out
}

/// The verification figures quoted in the report: Hertz at δ = 0.2 R on a block 20 R wide and
/// deep (sphere and paraboloid, two mesh sizes), the surface profile against Johnson's
/// half-space formula, the patch test of both laws, and the small-deformation formulation
/// against Sneddon on the deep block.
pub fn verification(mode: Mode, cache: &RunCache) -> Result<VerificationStudy, ExperimentError> {
    let study = "verify";
    let depth = DEPTH_OVER_RADIUS * RADIUS_M;
    let a = (RADIUS_M * depth).sqrt();
    let size = BLOCK_OVER_RADIUS * RADIUS_M;
    let tool = ToolShape::Sphere { radius_m: RADIUS_M };
    let hertz = law::hertz_force_n(&MATERIAL, RADIUS_M, depth);
    // The runtime's corrections for the block's finite depth, and for the sphere's shape.
    let corrected = |exact_sphere: bool| -> Result<f64, ExperimentError> {
        let spec = ModelSpec {
            exact_sphere,
            thickness: layer(size, true),
            ..ModelSpec::PAPER
        };
        Ok(RuntimeModel::new(tool, MATERIAL, spec)
            .map_err(|source| ExperimentError::Model {
                run: study.to_owned(),
                source,
            })?
            .force_n(depth, &LocalGeometry::FLAT))
    };
    let mut checks = Vec::new();
    for &cell in cells(mode) {
        for (name, shape) in shapes() {
            let run = cache.get(study, &check_run(cell, name, shape))?;
            let fem = run.forces_n.first().map(|f| f[2]).unwrap_or(f64::NAN);
            let reference = corrected(matches!(shape, IndenterShape::Sphere { .. }))?;
            let profile_error = run
                .final_profile_m
                .iter()
                .filter(|(radius, _)| *radius > a && *radius < 4.0 * a)
                .map(|&(radius, d)| {
                    (d - softhaptic_proto::calibration::half_space_depression_m(
                        &tool, depth, radius,
                    ))
                    .abs()
                })
                .fold(0.0_f64, f64::max);
            checks.push(HertzCheck {
                indenter: name.to_owned(),
                fine_cell_m: cell,
                dofs: run.dofs,
                fem_n: fem,
                hertz_n: hertz,
                error_vs_hertz_percent: 100.0 * (fem / hertz - 1.0),
                error_vs_corrected_percent: 100.0 * (fem / reference - 1.0),
                profile_error_percent: 100.0 * profile_error / depth,
            });
        }
    }
    let nearly_incompressible = material_with_poisson(NEARLY_INCOMPRESSIBLE_POISSON)?;
    let mut patch_test = Vec::new();
    for material in [MATERIAL, nearly_incompressible] {
        for law in [LawKind::LinearDeformedContact, LawKind::NeoHookean] {
            patch_test.push(PatchTest {
                law,
                poisson_ratio: material.poisson_ratio(),
                error: patch_test_error(law, &material).map_err(|source| {
                    ExperimentError::Solve {
                        run: format!("patch test {}{}", law.name(), poisson_tag(&material)),
                        source,
                    }
                })?,
            });
        }
    }
    let mut sneddon = Vec::new();
    for material in [MATERIAL, nearly_incompressible] {
        sneddon.extend(sneddon_checks(
            cache,
            sneddon_meshes(mode),
            &sneddon_depths(mode),
            &material,
        )?);
    }
    let mut neo_hookean = Vec::new();
    for material in neo_hookean_materials() {
        for d in neo_hookean_depths(mode) {
            neo_hookean.push(neo_hookean_point(
                cache,
                d,
                neo_hookean_mesh(mode),
                &material,
            )?);
        }
    }
    Ok(VerificationStudy {
        depth_over_radius: DEPTH_OVER_RADIUS,
        block_over_radius: BLOCK_OVER_RADIUS,
        checks,
        patch_test,
        sneddon,
        neo_hookean,
    })
}

/// Imposes u = G·X (G a constant displacement gradient, 5% strain for the neo-Hookean law) on
/// the boundary of a graded block and returns the largest interior error relative to the
/// largest displacement.
pub fn patch_test_error(kind: LawKind, material: &Material) -> Result<f64, SolveError> {
    let spec = BlockSpec {
        size_m: [0.04, 0.03, 0.02],
        fine_cell_m: 0.004,
        fine_radius_m: 0.006,
        fine_depth_m: 0.006,
        coarse_cells_lateral: 2,
        coarse_cells_depth: 2,
        symmetry: Symmetry::Full,
    };
    let Ok(mut m) = mesh::block(&spec) else {
        return Ok(f64::NAN);
    };
    m.fixed.iter_mut().for_each(|f| *f = 0);
    let scale = if kind == LawKind::NeoHookean {
        25.0
    } else {
        1.0
    };
    let grad = [
        [2e-3, 1e-3, -5e-4],
        [3e-4, -1.5e-3, 8e-4],
        [-7e-4, 6e-4, 1e-3],
    ];
    let field = |p: [f64; 3]| -> [f64; 3] {
        std::array::from_fn(|i| (0..3).map(|j| scale * grad[i][j] * p[j]).sum())
    };
    let mut lo = [f64::MAX; 3];
    let mut hi = [f64::MIN; 3];
    for p in &m.nodes_m {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let targets: Vec<(usize, [f64; 3])> = m
        .nodes_m
        .iter()
        .enumerate()
        .filter(|(_, p)| {
            (0..3).any(|k| (p[k] - lo[k]).abs() < 1e-12 || (p[k] - hi[k]).abs() < 1e-12)
        })
        .map(|(i, p)| (i, field(*p)))
        .collect();
    let nodes = m.nodes_m.clone();
    let mut model = ContactModel::new(
        m,
        Constitutive::new(kind, material),
        SolverOptions::default(),
    )?;
    model.solve_prescribed(&targets)?;
    let mut worst = 0.0_f64;
    let mut biggest = 0.0_f64;
    for (u, p) in model.displacements_m().iter().zip(&nodes) {
        let exact = field(*p);
        for k in 0..3 {
            worst = worst.max((u[k] - exact[k]).abs());
            biggest = biggest.max(exact[k].abs());
        }
    }
    Ok(worst / biggest.max(f64::MIN_POSITIVE))
}
