//! Static frictionless contact of a rigid indenter with an elastic body, solved by Newton's
//! method with an active set.
//!
//! One file because the Newton iteration and the active set share the assembled system and its
//! invariants; split, neither half reads on its own.
//!
//! # Contact enforcement
//! Every node on the contact surface that penetrates the indenter joins the active set. An active
//! node gets its own orthonormal frame whose first free axis is the indenter's normal at that
//! node (projected onto the components the symmetry planes leave free); in that frame the normal
//! displacement increment is prescribed so that the linearised gap closes exactly (constraint
//! elimination, no penalty: the constraint holds to the gap tolerance and the tangential
//! components stay free, i.e. frictionless). The indenter's force is the sum of the active nodes'
//! reactions. A node leaves the set when its reaction turns tensile. Nodes of quadratic elements
//! carry contact loads of alternating sign (a 6-node triangle under uniform pressure loads its
//! corners with zero), so a node that is released and then penetrates again within the same load
//! step is kept active for the rest of the step; the number of such nodes is reported.
//!
//! # Newton iterations
//! Each iteration evaluates the internal forces, updates the active set and solves for the
//! increment. The neo-Hookean law assembles the tangent in the node frames with constrained rows
//! and columns eliminated (the pattern never changes), factorises it (sparse Cholesky) and
//! solves. The linear laws' stiffness does not change, so it is factorised once per model,
//! without contact, and each iteration solves the contact as a small dense system on the
//! contacted nodes' columns of its inverse (`ContactModel::constant_stiffness_increment`): the
//! same increment to rounding, for two triangular solves instead of a factorisation. A
//! backtracking line search on the free residual keeps neo-Hookean iterates admissible (J > 0).
//! Converged when the free residual, the worst penetration and the tensile reactions are all
//! within tolerance.

use faer::Mat;
use faer::linalg::solvers::Solve;
use serde::Serialize;

use crate::element::{
    BadElement, Constitutive, ElementGeometry, Inverted, LawKind, element_response,
};
use crate::indenter::{Gap, Indenter};
use crate::mesh::TetMesh;
use crate::sparse::{Factor, LinearError, StiffnessPattern};

/// Tolerances and limits of the nonlinear solver.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct SolverOptions {
    /// Newton iterations allowed per load step.
    pub max_iterations: usize,
    /// Free residual allowed, relative to the largest reaction.
    pub residual_tolerance: f64,
    /// Penetration allowed, metres.
    pub gap_tolerance_m: f64,
    /// How many times a failing load step may be halved.
    pub max_bisections: usize,
}

impl Default for SolverOptions {
    fn default() -> Self {
        SolverOptions {
            max_iterations: 40,
            residual_tolerance: 1e-7,
            gap_tolerance_m: 1e-8,
            max_bisections: 6,
        }
    }
}

/// Why a solve failed. Every variant says where.
#[derive(Debug, thiserror::Error)]
pub enum SolveError {
    #[error("bad mesh: {0}")]
    Mesh(#[from] BadElement),
    #[error(transparent)]
    Linear(#[from] LinearError),
    #[error(
        "no convergence at load step {step} (indenter parameter {parameter:.6e}) after {iterations} Newton iterations: free residual {residual_n:.3e} N (tolerance {tolerance_n:.3e} N), worst penetration {penetration_m:.3e} m, tensile reaction {tensile_n:.3e} N"
    )]
    NoConvergence {
        step: usize,
        parameter: f64,
        iterations: usize,
        residual_n: f64,
        tolerance_n: f64,
        penetration_m: f64,
        tensile_n: f64,
    },
    #[error(
        "elements inverted at load step {step} (indenter parameter {parameter:.6e}) even with a step of 1/64: the neo-Hookean solution left J > 0"
    )]
    Inverted { step: usize, parameter: f64 },
}

/// The state after one converged load step.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Equilibrium {
    /// Force the body exerts on the indenter, whole object (symmetry applied), FEM frame.
    pub force_on_tool_n: [f64; 3],
    /// Nodes in contact in the modelled part.
    pub active_nodes: usize,
    /// Nodes kept active after alternating (see the module documentation).
    pub locked_nodes: usize,
    /// Newton iterations this step took.
    pub iterations: usize,
    /// Final free residual, N.
    pub residual_n: f64,
}

/// Per-node frame for the Newton system.
#[derive(Debug, Clone, Copy)]
struct NodeFrame {
    /// Columns of the rotation: `basis[c]` is the c-th local axis in the FEM frame.
    basis: [[f64; 3]; 3],
    rotated: bool,
    constrained: [bool; 3],
    prescribed: [f64; 3],
}

const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// A linear law's stiffness with the mesh's supports only (no contact), factorised once, and its
/// inverse between the unknowns of every node the contact has touched so far
/// (see [`ContactModel::constant_stiffness_increment`]).
struct ConstantStiffness {
    factor: Factor,
    /// Mean diagonal of the free unknowns: the contact multipliers' unit.
    scale: f64,
    /// Per node: its place in `nodes`, once it has one.
    slot: Vec<Option<usize>>,
    /// The nodes whose columns of K⁻¹ are known, in the order they came.
    nodes: Vec<usize>,
    /// (K⁻¹) between the unknowns of `nodes`, 3·len × 3·len, column-major.
    compliance: Vec<f64>,
}

impl ConstantStiffness {
    /// Entry of K⁻¹ between component `a` of node `i` and component `b` of node `j`, NaN unless
    /// both nodes were passed to [`ConstantStiffness::ensure`] (the caller's finiteness check
    /// then fails the solve).
    fn compliance(&self, i: usize, a: usize, j: usize, b: usize) -> f64 {
        let dim = 3 * self.nodes.len();
        let (Some(si), Some(sj)) = (self.slot[i], self.slot[j]) else {
            return f64::NAN;
        };
        self.compliance[3 * si + a + dim * (3 * sj + b)]
    }

    /// Computes the columns of K⁻¹ of the nodes not seen before, all in one solve, and extends
    /// the compliance between known nodes with them.
    fn ensure(&mut self, nodes: &[usize]) {
        let new: Vec<usize> = nodes
            .iter()
            .copied()
            .filter(|&i| self.slot[i].is_none())
            .collect();
        if new.is_empty() {
            return;
        }
        let n = self.slot.len();
        let mut columns = Mat::<f64>::zeros(3 * n, 3 * new.len());
        for (j, &i) in new.iter().enumerate() {
            for k in 0..3 {
                columns[(3 * i + k, 3 * j + k)] = 1.0;
            }
        }
        self.factor.solve_columns_in_place(columns.as_mut());
        let old = 3 * self.nodes.len();
        for &i in &new {
            self.slot[i] = Some(self.nodes.len());
            self.nodes.push(i);
        }
        let dim = 3 * self.nodes.len();
        let mut compliance = vec![0.0; dim * dim];
        for col in 0..old {
            compliance[dim * col..dim * col + old]
                .copy_from_slice(&self.compliance[old * col..old * (col + 1)]);
        }
        for c in 0..dim - old {
            for (s, &i) in self.nodes.iter().enumerate() {
                for k in 0..3 {
                    let v = columns[(3 * i + k, c)];
                    compliance[3 * s + k + dim * (old + c)] = v;
                    if 3 * s + k < old {
                        compliance[old + c + dim * (3 * s + k)] = v;
                    }
                }
            }
        }
        self.compliance = compliance;
    }
}

/// An elastic body meshed for contact, with its current displacement.
pub struct ContactModel {
    mesh: TetMesh,
    law: Constitutive,
    geometry: Vec<ElementGeometry>,
    pattern: StiffnessPattern,
    /// Nodal displacements, metres.
    u: Vec<[f64; 3]>,
    active: Vec<bool>,
    /// 1 for a node released once during the current load step (it may not be released again).
    toggles: Vec<u8>,
    options: SolverOptions,
    values: Vec<f64>,
    /// The last factor of a tangent, whose buffers the next factorisation reuses.
    factor: Option<Factor>,
    /// The linear laws' stiffness without contact, factorised once (built by the first solve).
    constant: Option<ConstantStiffness>,
    steps_done: usize,
    /// Per element, its modulus over the law's (empty: every element has the law's own). Both
    /// laws are linear in (μ, λ) at a fixed ν, so scaling the two scales the element's force
    /// and tangent exactly: how a stiffer inclusion is put inside the block.
    modulus_ratio: Vec<f64>,
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl ContactModel {
    /// Prepares geometry, sparsity pattern and symbolic factorisation.
    pub fn new(
        mesh: TetMesh,
        law: Constitutive,
        options: SolverOptions,
    ) -> Result<Self, SolveError> {
        let mut geometry = Vec::with_capacity(mesh.elements.len());
        for (i, e) in mesh.elements.iter().enumerate() {
            let x: [[f64; 3]; 10] = std::array::from_fn(|a| mesh.nodes_m[e[a] as usize]);
            geometry.push(ElementGeometry::new(i, &x)?);
        }
        let pattern = StiffnessPattern::new(&mesh)?;
        let n = mesh.node_count();
        let values = pattern.zero_values();
        Ok(ContactModel {
            u: vec![[0.0; 3]; n],
            active: vec![false; n],
            toggles: vec![0; n],
            mesh,
            law,
            geometry,
            pattern,
            options,
            values,
            factor: None,
            constant: None,
            steps_done: 0,
            modulus_ratio: Vec::new(),
        })
    }

    /// Gives each element `ratio(corners)` times the law's modulus (same ν), from its four
    /// corners in the FEM frame. Call before the first solve: the linear laws factorise their
    /// stiffness once.
    pub fn with_element_moduli(mut self, ratio: impl Fn([[f64; 3]; 4]) -> f64) -> Self {
        self.modulus_ratio = self
            .mesh
            .elements
            .iter()
            .map(|e| ratio(std::array::from_fn(|a| self.mesh.nodes_m[e[a] as usize])))
            .collect();
        self.constant = None;
        self
    }

    /// How many elements have a modulus other than the law's.
    pub fn stiffened_elements(&self) -> usize {
        self.modulus_ratio.iter().filter(|&&r| r != 1.0).count()
    }

    /// The law of element `index`, its modulus ratio applied.
    fn element_law(&self, index: usize) -> Constitutive {
        match self.modulus_ratio.get(index) {
            Some(&r) if r != 1.0 => Constitutive {
                mu_pa: self.law.mu_pa * r,
                lambda_pa: self.law.lambda_pa * r,
                ..self.law
            },
            _ => self.law,
        }
    }

    pub fn mesh(&self) -> &TetMesh {
        &self.mesh
    }

    pub fn law(&self) -> LawKind {
        self.law.kind
    }

    /// Current nodal displacements.
    pub fn displacements_m(&self) -> &[[f64; 3]] {
        &self.u
    }

    /// Unknowns of the linear system.
    pub fn dof_count(&self) -> usize {
        self.pattern.size()
    }

    /// Stored entries of the Cholesky factor of the stiffness matrix.
    pub fn factor_entries(&self) -> usize {
        self.pattern.factor_entries()
    }

    /// Stored entries of the stiffness matrix (lower triangle).
    pub fn stored_entries(&self) -> usize {
        self.pattern.stored_entries()
    }

    /// Resets to the undeformed state.
    pub fn reset(&mut self) {
        self.u.iter_mut().for_each(|v| *v = [0.0; 3]);
        self.active.iter_mut().for_each(|v| *v = false);
        self.toggles.iter_mut().for_each(|v| *v = 0);
    }

    /// Internal forces at displacement `u`; `Err` if an element is inverted.
    fn internal_forces(&self, u: &[[f64; 3]], out: &mut [[f64; 3]]) -> Result<(), Inverted> {
        out.iter_mut().for_each(|v| *v = [0.0; 3]);
        let mut f = [0.0; 30];
        for (index, (e, geom)) in self.mesh.elements.iter().zip(&self.geometry).enumerate() {
            let ue: [[f64; 3]; 10] = std::array::from_fn(|a| u[e[a] as usize]);
            element_response(&self.element_law(index), geom, &ue, &mut f, None)?;
            for a in 0..10 {
                let o = &mut out[e[a] as usize];
                for i in 0..3 {
                    o[i] += f[3 * a + i];
                }
            }
        }
        Ok(())
    }

    /// Frame of node `i` given the contact normal (if active) and the gap.
    fn frame(&self, i: usize, contact: Option<(f64, [f64; 3])>) -> NodeFrame {
        let fixed = self.mesh.fixed[i];
        let mut frame = NodeFrame {
            basis: IDENTITY,
            rotated: false,
            constrained: [fixed & 1 != 0, fixed & 2 != 0, fixed & 4 != 0],
            prescribed: [0.0; 3],
        };
        let Some((gap, normal)) = contact else {
            return frame;
        };
        let mut n_free = normal;
        for k in 0..3 {
            if frame.constrained[k] {
                n_free[k] = 0.0;
            }
        }
        let len = dot(n_free, n_free).sqrt();
        if len < 1e-6 {
            return frame;
        }
        let m = [n_free[0] / len, n_free[1] / len, n_free[2] / len];
        // Columns: fixed axes stay, the first free slot takes m, the rest is completed by
        // Gram–Schmidt over the free coordinate axes.
        let mut cols: Vec<([f64; 3], bool, f64)> = Vec::with_capacity(3);
        for k in 0..3 {
            if frame.constrained[k] {
                cols.push((IDENTITY[k], true, 0.0));
            }
        }
        cols.push((m, true, -gap / len));
        for k in 0..3 {
            if cols.len() == 3 {
                break;
            }
            if frame.constrained[k] {
                continue;
            }
            let mut v = IDENTITY[k];
            for (c, _, _) in &cols {
                let d = dot(v, *c);
                for j in 0..3 {
                    v[j] -= d * c[j];
                }
            }
            let l = dot(v, v).sqrt();
            if l > 0.3 {
                cols.push(([v[0] / l, v[1] / l, v[2] / l], false, 0.0));
            }
        }
        for (c, (v, constrained, value)) in cols.into_iter().enumerate() {
            frame.basis[c] = v;
            frame.constrained[c] = constrained;
            frame.prescribed[c] = value;
        }
        frame.rotated = true;
        frame
    }

    /// Free residual norm, worst tensile reaction and reaction scale for the given frames.
    fn residual_measures(&self, f_int: &[[f64; 3]], frames: &[NodeFrame]) -> (f64, f64) {
        let mut free2 = 0.0;
        let mut reaction_max = 0.0_f64;
        for (i, fr) in frames.iter().enumerate() {
            for c in 0..3 {
                let v = dot(fr.basis[c], f_int[i]);
                if fr.constrained[c] {
                    reaction_max = reaction_max.max(v.abs());
                } else {
                    free2 += v * v;
                }
            }
        }
        (free2.sqrt(), reaction_max)
    }

    /// Solves for equilibrium with the indenter at `indenter`, starting from the current state.
    /// `step` and `parameter` only label errors.
    pub fn solve(
        &mut self,
        indenter: &Indenter,
        step: usize,
        parameter: f64,
    ) -> Result<Equilibrium, SolveError> {
        let n = self.mesh.node_count();
        let opts = self.options;
        let mut f_int = vec![[0.0; 3]; n];
        let mut trial_f = vec![[0.0; 3]; n];
        let mut frames = vec![
            NodeFrame {
                basis: IDENTITY,
                rotated: false,
                constrained: [false; 3],
                prescribed: [0.0; 3],
            };
            n
        ];
        let mut rhs = vec![0.0; 3 * n];
        self.toggles.iter_mut().for_each(|t| *t = 0);
        let candidates = self.mesh.contact_candidates.clone();
        let mut last = (f64::INFINITY, 0.0, f64::INFINITY, 0.0);
        for iter in 0..=opts.max_iterations {
            if self.internal_forces(&self.u, &mut f_int).is_err() {
                return Err(SolveError::Inverted { step, parameter });
            }
            // Contact status.
            let mut changed = false;
            let mut worst_penetration = 0.0_f64;
            let mut worst_tensile = 0.0_f64;
            let mut max_pressure = 0.0_f64;
            let mut gaps = Vec::with_capacity(candidates.len());
            for &c in &candidates {
                let i = c as usize;
                let g = self.contact_gap(indenter, i);
                gaps.push(g);
                if self.active[i] {
                    let p = self.reaction(i, &f_int[i], g.normal);
                    max_pressure = max_pressure.max(p);
                }
            }
            let tensile_tol = 1e-6 * max_pressure.max(f64::MIN_POSITIVE);
            for (k, &c) in candidates.iter().enumerate() {
                let i = c as usize;
                let g = gaps[k];
                if self.active[i] {
                    worst_penetration = worst_penetration.max(g.distance_m.abs());
                    let p = self.reaction(i, &f_int[i], g.normal);
                    if p < -tensile_tol {
                        worst_tensile = worst_tensile.max(-p);
                        if self.toggles[i] == 0 {
                            self.active[i] = false;
                            self.toggles[i] = 1;
                            changed = true;
                        }
                    }
                } else if g.distance_m < -opts.gap_tolerance_m {
                    worst_penetration = worst_penetration.max(-g.distance_m);
                    self.active[i] = true;
                    changed = true;
                }
            }
            // Frames.
            for i in 0..n {
                frames[i] = self.frame(i, None);
            }
            let mut curvature_terms = Vec::new();
            for (k, &c) in candidates.iter().enumerate() {
                let i = c as usize;
                if self.active[i] {
                    frames[i] = self.frame(i, Some((gaps[k].distance_m, gaps[k].normal)));
                    let p = self.reaction(i, &f_int[i], gaps[k].normal).max(0.0);
                    // On the reference configuration the gap is linear in u: no curvature.
                    if p > 0.0 && !self.law.kind.contact_on_reference() {
                        let x = add(self.mesh.nodes_m[i], self.u[i]);
                        let dn = indenter.normal_derivative(x);
                        let block: [[f64; 3]; 3] =
                            std::array::from_fn(|r| std::array::from_fn(|q| -p * dn[r][q]));
                        curvature_terms.push((i, block));
                    }
                }
            }
            let (residual, reaction_max) = self.residual_measures(&f_int, &frames);
            let tolerance = opts.residual_tolerance * reaction_max.max(1e-12);
            last = (residual, tolerance, worst_penetration, worst_tensile);
            let converged = iter > 0
                && !changed
                && residual <= tolerance
                && worst_penetration <= opts.gap_tolerance_m;
            if converged {
                self.steps_done += 1;
                return Ok(self.equilibrium(indenter, &f_int, iter, residual));
            }
            if iter == opts.max_iterations {
                break;
            }
            // Assemble and solve.
            tracing::debug!(
                iter,
                residual,
                tolerance,
                worst_penetration,
                worst_tensile,
                changed,
                "newton iteration"
            );
            let du = self.increment(&frames, &curvature_terms, &f_int, &mut rhs)?;
            // Line search: the linear law takes the full step. The neo-Hookean one backtracks
            // only while elements invert or the free residual explodes: a milder criterion would
            // also scale down the prescribed contact increments and stall the gap closure.
            let mut alpha = 1.0;
            let mut accepted = false;
            let mut trial = self.u.clone();
            for _ in 0..7 {
                for i in 0..n {
                    for j in 0..3 {
                        trial[i][j] = self.u[i][j] + alpha * du[i][j];
                    }
                }
                if self.law.kind.small_strain() {
                    accepted = true;
                    break;
                }
                if self.internal_forces(&trial, &mut trial_f).is_ok() {
                    let (r_trial, _) = self.residual_measures(&trial_f, &frames);
                    let bound = 1e3 * residual.max(tolerance).max(reaction_max);
                    if r_trial.is_finite() && (r_trial <= bound || alpha <= 1.0 / 32.0) {
                        accepted = true;
                        break;
                    }
                }
                alpha *= 0.5;
            }
            if !accepted {
                return Err(SolveError::Inverted { step, parameter });
            }
            std::mem::swap(&mut self.u, &mut trial);
        }
        Err(SolveError::NoConvergence {
            step,
            parameter,
            iterations: opts.max_iterations,
            residual_n: last.0,
            tolerance_n: last.1,
            penetration_m: last.2,
            tensile_n: last.3,
        })
    }

    /// Internal (elastic) nodal forces at the current displacement; `None` if an element is
    /// inverted.
    pub fn internal_forces_n(&self) -> Option<Vec<[f64; 3]>> {
        let mut out = vec![[0.0; 3]; self.mesh.node_count()];
        self.internal_forces(&self.u, &mut out).ok()?;
        Some(out)
    }

    /// Solves without an indenter, the listed nodes held at the given displacements (and the
    /// mesh's own fixed components at zero). Returns the Newton iterations taken. Used by the
    /// patch test: with a linear displacement imposed on the boundary, the interior must follow
    /// it exactly.
    pub fn solve_prescribed(&mut self, targets: &[(usize, [f64; 3])]) -> Result<usize, SolveError> {
        let n = self.mesh.node_count();
        let mut f_int = vec![[0.0; 3]; n];
        let mut rhs = vec![0.0; 3 * n];
        let mut last = (f64::INFINITY, 0.0);
        for iter in 0..=self.options.max_iterations {
            if self.internal_forces(&self.u, &mut f_int).is_err() {
                return Err(SolveError::Inverted {
                    step: 0,
                    parameter: 0.0,
                });
            }
            let mut frames: Vec<NodeFrame> = (0..n).map(|i| self.frame(i, None)).collect();
            let mut worst_gap = 0.0_f64;
            for &(i, target) in targets {
                let fr = &mut frames[i];
                fr.constrained = [true; 3];
                for k in 0..3 {
                    fr.prescribed[k] = target[k] - self.u[i][k];
                    worst_gap = worst_gap.max(fr.prescribed[k].abs());
                }
            }
            let (residual, reaction_max) = self.residual_measures(&f_int, &frames);
            let tolerance = self.options.residual_tolerance * reaction_max.max(1e-12);
            last = (residual, tolerance);
            if iter > 0 && residual <= tolerance && worst_gap <= self.options.gap_tolerance_m {
                return Ok(iter);
            }
            if iter == self.options.max_iterations {
                break;
            }
            self.assemble(&frames, &[], &mut rhs);
            self.factorise_and_solve(&mut rhs)?;
            for i in 0..n {
                for k in 0..3 {
                    self.u[i][k] += rhs[3 * i + k];
                }
            }
        }
        Err(SolveError::NoConvergence {
            step: 0,
            parameter: 0.0,
            iterations: self.options.max_iterations,
            residual_n: last.0,
            tolerance_n: last.1,
            penetration_m: 0.0,
            tensile_n: 0.0,
        })
    }

    /// The Newton increment (FEM frame) for the node frames and indenter curvature of this
    /// iteration: for the linear laws through their constant stiffness
    /// ([`ContactModel::constant_stiffness_increment`]), otherwise by factorising the tangent.
    /// `rhs` is work space.
    fn increment(
        &mut self,
        frames: &[NodeFrame],
        curvature_terms: &[(usize, [[f64; 3]; 3])],
        f_int: &[[f64; 3]],
        rhs: &mut [f64],
    ) -> Result<Vec<[f64; 3]>, LinearError> {
        if self.law.kind.small_strain() {
            self.constant_stiffness_increment(frames, curvature_terms, f_int)
        } else {
            self.direct_increment(frames, curvature_terms, rhs)
        }
    }

    /// The increment from the tangent assembled in the node frames, constrained unknowns
    /// eliminated, factorised and solved.
    fn direct_increment(
        &mut self,
        frames: &[NodeFrame],
        curvature_terms: &[(usize, [[f64; 3]; 3])],
        rhs: &mut [f64],
    ) -> Result<Vec<[f64; 3]>, LinearError> {
        self.assemble(frames, curvature_terms, rhs);
        self.factorise_and_solve(rhs)?;
        Ok(frames
            .iter()
            .enumerate()
            .map(|(i, fr)| {
                let w = [rhs[3 * i], rhs[3 * i + 1], rhs[3 * i + 2]];
                if fr.rotated {
                    let mut v = [0.0; 3];
                    for c in 0..3 {
                        for j in 0..3 {
                            v[j] += fr.basis[c][j] * w[c];
                        }
                    }
                    v
                } else {
                    w
                }
            })
            .collect())
    }

    /// Factorises the assembled matrix into the buffers of the last factor and solves in place.
    fn factorise_and_solve(&mut self, rhs: &mut [f64]) -> Result<(), LinearError> {
        let factor = match self.factor.take() {
            Some(mut factor) => {
                self.pattern.refactorise(&mut factor, &self.values)?;
                factor
            }
            None => self.pattern.factorise(&self.values)?,
        };
        factor.solve_in_place(rhs);
        self.factor = Some(factor);
        Ok(())
    }

    /// The increment of a linear law, from its stiffness K without contact, factorised once per
    /// model, and the contact as a small dense system.
    ///
    /// A linear law's element matrices do not depend on the displacement, so from one Newton
    /// iteration to the next the tangent changes only at the nodes whose frame is rotated
    /// (contact) or carry the indenter's curvature. Factorising it anew every iteration, as the
    /// neo-Hookean law needs, spends most of a run recomputing a factor that did not change
    /// away from the contact. Instead, with E the unit vectors of those nodes' unknowns, the
    /// curvature H = E H_c Eᵀ, the contact constraints B_c Eᵀ Δu = g and their multipliers λ,
    /// the same increment solves (K + E H_c Eᵀ) Δu = r + E B_cᵀ λ: with y = Eᵀ Δu and
    /// Z = Eᵀ K⁻¹ E (kept by [`ConstantStiffness`], three columns per node, computed once),
    /// (I + Z H_c) y − Z B_cᵀ λ = Eᵀ K⁻¹ r and B_c y = g, then
    /// Δu = K⁻¹ (r + E (B_cᵀ λ − H_c y)). Two solves with the kept factor and a dense system
    /// of a few hundred unknowns replace a factorisation; the result is the direct one to
    /// rounding (a unit test compares them).
    fn constant_stiffness_increment(
        &mut self,
        frames: &[NodeFrame],
        curvature_terms: &[(usize, [[f64; 3]; 3])],
        f_int: &[[f64; 3]],
    ) -> Result<Vec<[f64; 3]>, LinearError> {
        let n = self.mesh.node_count();
        let mut constant = match self.constant.take() {
            Some(constant) => constant,
            None => self.constant_stiffness()?,
        };
        // The free residual: the supports' unknowns stay at zero.
        let mut r = vec![0.0; 3 * n];
        for (i, f) in f_int.iter().enumerate() {
            for k in 0..3 {
                if self.mesh.fixed[i] & (1 << k) == 0 {
                    r[3 * i + k] = -f[k];
                }
            }
        }
        // The nodes the contact touches, each with its constraints and curvature (FEM frame).
        let mut coupled: Vec<usize> = Vec::new();
        let mut constraints: Vec<(usize, [f64; 3], f64)> = Vec::new();
        let mut curvature: Vec<[[f64; 3]; 3]> = Vec::new();
        let mut local = vec![usize::MAX; n];
        for (i, fr) in frames.iter().enumerate() {
            if !fr.rotated {
                continue;
            }
            local[i] = coupled.len();
            coupled.push(i);
            curvature.push([[0.0; 3]; 3]);
            for c in 0..3 {
                let support = (0..3)
                    .any(|k| self.mesh.fixed[i] & (1 << k) != 0 && fr.basis[c] == IDENTITY[k]);
                if fr.constrained[c] && !support {
                    constraints.push((local[i], fr.basis[c], fr.prescribed[c]));
                }
            }
        }
        for (i, block) in curvature_terms {
            let fr = &frames[*i];
            if local[*i] == usize::MAX {
                local[*i] = coupled.len();
                coupled.push(*i);
                curvature.push([[0.0; 3]; 3]);
            }
            // As the assembly adds it: the lower triangle of the block in the node's free axes,
            // mirrored, rotated back to the FEM frame.
            let h = &mut curvature[local[*i]];
            for r_ax in 0..3 {
                for c_ax in 0..3 {
                    if fr.constrained[r_ax] || fr.constrained[c_ax] {
                        continue;
                    }
                    let (hi, lo) = (r_ax.max(c_ax), r_ax.min(c_ax));
                    let mut v = 0.0;
                    for a in 0..3 {
                        for b in 0..3 {
                            v += fr.basis[hi][a] * block[a][b] * fr.basis[lo][b];
                        }
                    }
                    for a in 0..3 {
                        for b in 0..3 {
                            h[a][b] += fr.basis[r_ax][a] * v * fr.basis[c_ax][b];
                        }
                    }
                }
            }
        }
        constant.ensure(&coupled);
        let mut x0 = r.clone();
        constant.factor.solve_in_place(&mut x0);
        let m = 3 * coupled.len();
        let size = m + constraints.len();
        let z =
            |a: usize, b: usize| constant.compliance(coupled[a / 3], a % 3, coupled[b / 3], b % 3);
        // Rows 0..m: (I + Z H_c) y − Z B_cᵀ λ = Eᵀ K⁻¹ r; rows m..: B_c y = g. The multipliers
        // are scaled by the mean stiffness so that every column is a displacement.
        let mut a = Mat::<f64>::zeros(size, size);
        let mut b = Mat::<f64>::zeros(size, 1);
        for row in 0..m {
            a[(row, row)] += 1.0;
            for col in 0..m {
                let node = col / 3;
                let mut v = 0.0;
                for t in 0..3 {
                    v += z(row, 3 * node + t) * curvature[node][t][col % 3];
                }
                a[(row, col)] += v;
            }
            b[(row, 0)] = x0[3 * coupled[row / 3] + row % 3];
        }
        for (l, &(node, dir, g)) in constraints.iter().enumerate() {
            for row in 0..m {
                let mut v = 0.0;
                for t in 0..3 {
                    v += z(row, 3 * node + t) * dir[t];
                }
                a[(row, m + l)] = -constant.scale * v;
            }
            for t in 0..3 {
                a[(m + l, 3 * node + t)] = dir[t];
            }
            b[(m + l, 0)] = g;
        }
        let solution = a.partial_piv_lu().solve(&b);
        let mut w = r;
        for (j, &i) in coupled.iter().enumerate() {
            let y = [
                solution[(3 * j, 0)],
                solution[(3 * j + 1, 0)],
                solution[(3 * j + 2, 0)],
            ];
            for k in 0..3 {
                w[3 * i + k] -= dot(curvature[j][k], y);
            }
        }
        for (l, &(node, dir, _)) in constraints.iter().enumerate() {
            let lambda = constant.scale * solution[(m + l, 0)];
            for k in 0..3 {
                w[3 * coupled[node] + k] += dir[k] * lambda;
            }
        }
        let finite = w.iter().all(|v| v.is_finite());
        if finite {
            constant.factor.solve_in_place(&mut w);
        }
        self.constant = Some(constant);
        if !finite {
            return Err(LinearError::NotPositiveDefinite(
                "the contact system is singular".into(),
            ));
        }
        Ok((0..n)
            .map(|i| [w[3 * i], w[3 * i + 1], w[3 * i + 2]])
            .collect())
    }

    /// Assembles and factorises the stiffness with the mesh's supports only.
    fn constant_stiffness(&mut self) -> Result<ConstantStiffness, LinearError> {
        let n = self.mesh.node_count();
        let frames: Vec<NodeFrame> = (0..n).map(|i| self.frame(i, None)).collect();
        let mut rhs = vec![0.0; 3 * n];
        self.assemble(&frames, &[], &mut rhs);
        let factor = self.pattern.factorise(&self.values)?;
        let (mut sum, mut count) = (0.0, 0usize);
        for (i, fr) in frames.iter().enumerate() {
            for c in 0..3 {
                if !fr.constrained[c] {
                    sum += self.pattern.diagonal(&self.values, 3 * i + c);
                    count += 1;
                }
            }
        }
        Ok(ConstantStiffness {
            factor,
            scale: if count > 0 && sum > 0.0 {
                sum / count as f64
            } else {
                1.0
            },
            slot: vec![None; n],
            nodes: Vec::new(),
            compliance: Vec::new(),
        })
    }

    /// Gap of contact candidate `i` and the direction its reaction acts along, as the
    /// formulation defines them: on the deformed surface, the current distance from the
    /// indenter and its normal there; on the reference configuration, the gap of the reference
    /// position along the body's surface normal (the tool's axis when it presses straight
    /// down), linearised in the displacement, g₀(X) + n·u (exact, the gap being linear in u),
    /// with the fixed direction n = −z.
    fn contact_gap(&self, indenter: &Indenter, i: usize) -> Gap {
        let x = self.mesh.nodes_m[i];
        if self.law.kind.contact_on_reference() {
            let g = indenter.surface_normal_gap(x);
            Gap {
                distance_m: g.distance_m + dot(g.normal, self.u[i]),
                normal: g.normal,
            }
        } else {
            indenter.gap(add(x, self.u[i]))
        }
    }

    /// Contact pressure (normal reaction) of node `i`, positive when pushing the body away.
    fn reaction(&self, i: usize, f: &[f64; 3], normal: [f64; 3]) -> f64 {
        let fixed = self.mesh.fixed[i];
        let mut n_free = normal;
        for (k, v) in n_free.iter_mut().enumerate() {
            if fixed & (1 << k) != 0 {
                *v = 0.0;
            }
        }
        let l2 = dot(n_free, n_free);
        if l2 < 1e-12 {
            return 0.0;
        }
        dot(*f, n_free) / l2
    }

    fn equilibrium(
        &self,
        indenter: &Indenter,
        f_int: &[[f64; 3]],
        iterations: usize,
        residual_n: f64,
    ) -> Equilibrium {
        let mut force = [0.0; 3];
        let mut active_nodes = 0;
        let mut locked_nodes = 0;
        for &c in &self.mesh.contact_candidates {
            let i = c as usize;
            if !self.active[i] {
                continue;
            }
            active_nodes += 1;
            if self.toggles[i] != 0 {
                locked_nodes += 1;
            }
            let g = self.contact_gap(indenter, i);
            let p = self.reaction(i, &f_int[i], g.normal);
            for k in 0..3 {
                force[k] -= p * g.normal[k];
            }
        }
        let factors = self.mesh.symmetry.factors();
        Equilibrium {
            force_on_tool_n: [
                force[0] * factors[0],
                force[1] * factors[1],
                force[2] * factors[2],
            ],
            active_nodes,
            locked_nodes,
            iterations,
            residual_n,
        }
    }

    /// Assembles the tangent and the right-hand side (−residual, prescribed increments) in the
    /// node frames, constrained unknowns eliminated.
    fn assemble(
        &mut self,
        frames: &[NodeFrame],
        curvature_terms: &[(usize, [[f64; 3]; 3])],
        rhs: &mut [f64],
    ) {
        self.values.iter_mut().for_each(|v| *v = 0.0);
        rhs.iter_mut().for_each(|v| *v = 0.0);
        let mut f = [0.0; 30];
        let mut k = [[0.0; 30]; 30];
        for (index, (e, geom)) in self.mesh.elements.iter().zip(&self.geometry).enumerate() {
            let ue: [[f64; 3]; 10] = std::array::from_fn(|a| self.u[e[a] as usize]);
            let law = self.element_law(index);
            // Inversion was ruled out by the force evaluation at this very state.
            if element_response(&law, geom, &ue, &mut f, Some(&mut k)).is_err() {
                continue;
            }
            // Rotate rows and columns of rotated nodes: K' = Qᵀ K Q, f' = Qᵀ f.
            for a in 0..10 {
                let fr = &frames[e[a] as usize];
                if !fr.rotated {
                    continue;
                }
                let fa = [f[3 * a], f[3 * a + 1], f[3 * a + 2]];
                for c in 0..3 {
                    f[3 * a + c] = dot(fr.basis[c], fa);
                }
                for col in 0..30 {
                    let ka = [k[3 * a][col], k[3 * a + 1][col], k[3 * a + 2][col]];
                    for c in 0..3 {
                        k[3 * a + c][col] = dot(fr.basis[c], ka);
                    }
                }
                for row in k.iter_mut() {
                    let ka = [row[3 * a], row[3 * a + 1], row[3 * a + 2]];
                    for c in 0..3 {
                        row[3 * a + c] = dot(fr.basis[c], ka);
                    }
                }
            }
            // Move prescribed increments to the right-hand side, then drop constrained rows
            // and columns.
            let mut presc = [0.0; 30];
            let mut cons = [false; 30];
            for a in 0..10 {
                let fr = &frames[e[a] as usize];
                for c in 0..3 {
                    cons[3 * a + c] = fr.constrained[c];
                    presc[3 * a + c] = if fr.constrained[c] {
                        fr.prescribed[c]
                    } else {
                        0.0
                    };
                }
            }
            for a in 0..10 {
                let node = e[a] as usize;
                for c in 0..3 {
                    let row = 3 * a + c;
                    if cons[row] {
                        continue;
                    }
                    let mut v = -f[row];
                    for col in 0..30 {
                        if cons[col] && presc[col] != 0.0 {
                            v -= k[row][col] * presc[col];
                        }
                    }
                    rhs[3 * node + c] += v;
                }
            }
            for row in 0..30 {
                for col in 0..30 {
                    if cons[row] || cons[col] {
                        k[row][col] = 0.0;
                    }
                }
            }
            self.pattern.add_element(&mut self.values, e, &k);
        }
        // Indenter curvature: −p dn/dx on the free (tangential) unknowns of each contact node.
        for (i, block) in curvature_terms {
            let fr = &frames[*i];
            for c in 0..3 {
                for r in c..3 {
                    if fr.constrained[r] || fr.constrained[c] {
                        continue;
                    }
                    let mut v = 0.0;
                    for a in 0..3 {
                        for b in 0..3 {
                            v += fr.basis[r][a] * block[a][b] * fr.basis[c][b];
                        }
                    }
                    self.pattern
                        .add_diagonal_block(&mut self.values, *i, r, c, v);
                }
            }
        }
        // Unit-scaled diagonal for constrained unknowns: the mean free diagonal keeps the
        // factorisation well conditioned.
        let mut sum = 0.0;
        let mut count = 0usize;
        for (i, fr) in frames.iter().enumerate() {
            for c in 0..3 {
                if !fr.constrained[c] {
                    sum += self.pattern.diagonal(&self.values, 3 * i + c);
                    count += 1;
                }
            }
        }
        let scale = if count > 0 && sum > 0.0 {
            sum / count as f64
        } else {
            1.0
        };
        for (i, fr) in frames.iter().enumerate() {
            for c in 0..3 {
                if fr.constrained[c] {
                    self.pattern
                        .set_diagonal(&mut self.values, 3 * i + c, scale);
                    rhs[3 * i + c] = scale * fr.prescribed[c];
                }
            }
        }
    }

    /// Follows a loading path: `indenter_at(s)` places the indenter for path parameter `s`
    /// (e.g. depth); each target is reached from the previous one, and a failing increment is
    /// halved up to `max_bisections` times before the error is returned.
    pub fn follow(
        &mut self,
        indenter_at: &dyn Fn(f64) -> Indenter,
        start: f64,
        targets: &[f64],
        mut on_step: impl FnMut(usize, f64, &Equilibrium, &ContactModel),
    ) -> Result<Vec<Equilibrium>, SolveError> {
        let mut out = Vec::with_capacity(targets.len());
        let mut s_prev = start;
        for (step, &target) in targets.iter().enumerate() {
            let mut pending = vec![target];
            let mut bisections = 0;
            let mut result = None;
            while let Some(&s) = pending.last() {
                let saved_u = self.u.clone();
                let saved_active = self.active.clone();
                match self.solve(&indenter_at(s), step, s) {
                    Ok(eq) => {
                        s_prev = s;
                        pending.pop();
                        if pending.is_empty() {
                            result = Some(eq);
                        }
                    }
                    Err(err) => {
                        self.u = saved_u;
                        self.active = saved_active;
                        if bisections >= self.options.max_bisections
                            || matches!(err, SolveError::Linear(_) | SolveError::Mesh(_))
                        {
                            return Err(err);
                        }
                        bisections += 1;
                        pending.push(0.5 * (s_prev + s));
                    }
                }
            }
            // `pending` ended with the target itself, so a result exists.
            if let Some(eq) = result {
                on_step(step, target, &eq, self);
                out.push(eq);
            }
        }
        Ok(out)
    }

    /// The top-surface profile along the `y = 0` line: (reference radius from the axis,
    /// depression = −u_z), ordered by radius.
    pub fn surface_profile(&self) -> Vec<(f64, f64)> {
        self.surface_motion()
            .iter()
            .map(|p| (p.radius_m, p.depression_m))
            .collect()
    }

    /// The top-surface motion along the `y = 0` line, ordered by reference radius: the
    /// depression of [`ContactModel::surface_profile`] and each node's radial displacement. The
    /// viewer moves its vertices along the surface normal only, so the radial part is what such
    /// a drawing leaves out.
    pub fn surface_motion(&self) -> Vec<SurfacePoint> {
        self.mesh
            .profile_nodes
            .iter()
            .map(|&i| {
                let i = i as usize;
                let x = self.mesh.nodes_m[i];
                let u = self.u[i];
                let radius_m = x[0].hypot(x[1]);
                let radial_displacement_m = if radius_m > 0.0 {
                    (x[0] * u[0] + x[1] * u[1]) / radius_m
                } else {
                    0.0
                };
                SurfacePoint {
                    radius_m,
                    depression_m: -u[2],
                    radial_displacement_m,
                }
            })
            .collect()
    }
}

/// One top-surface node of the profile line in its deformed state.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SurfacePoint {
    /// Distance from the contact axis in the undeformed body.
    pub radius_m: f64,
    /// How far the node sank (−u_z).
    pub depression_m: f64,
    /// Displacement away from the axis (negative: towards it).
    pub radial_displacement_m: f64,
}

fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// Outermost radius at which a profile's depression exceeds `threshold_m`, linearly
/// interpolated between the nodes around the crossing; 0 when it never does.
pub fn deformed_radius_m(profile: &[(f64, f64)], threshold_m: f64) -> f64 {
    let Some(last) = profile.iter().rposition(|&(_, d)| d > threshold_m) else {
        return 0.0;
    };
    match profile.get(last + 1) {
        None => profile[last].0,
        Some(&(r1, d1)) => {
            let (r0, d0) = profile[last];
            r0 + (r1 - r0) * (d0 - threshold_m) / (d0 - d1)
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use softhaptic_proto::Material;

    use super::*;
    use crate::mesh::{self, BlockSpec, Symmetry};

    /// The linear laws' increment through the constant stiffness and the contact's dense system
    /// is the one of the tangent factorised directly, with the same frames, contact constraints
    /// and curvature, on a displaced state; and stays so when the contact grows (new columns of
    /// K⁻¹ beside the kept ones) and shrinks.
    #[test]
    fn constant_stiffness_increment_is_the_direct_one() {
        let spec = BlockSpec::graded([0.03, 0.03, 0.02], 0.004, 0.003, 2, Symmetry::Quarter);
        let mesh = mesh::block(&spec).unwrap();
        let n = mesh.node_count();
        let mut near: Vec<usize> = mesh
            .contact_candidates
            .iter()
            .map(|&c| c as usize)
            .collect();
        near.sort_by(|&a, &b| {
            let r = |i: usize| mesh.nodes_m[i][0].hypot(mesh.nodes_m[i][1]);
            r(a).total_cmp(&r(b))
        });
        for kind in [
            LawKind::LinearDeformedContact,
            LawKind::LinearSmallDeformation,
        ] {
            let law = Constitutive::new(kind, &Material::PAPER_SOFT);
            let mut model = ContactModel::new(mesh.clone(), law, SolverOptions::default()).unwrap();
            for (i, u) in model.u.iter_mut().enumerate() {
                let wave = (i as f64 * 0.37).sin();
                for (k, v) in u.iter_mut().enumerate() {
                    if mesh.fixed[i] & (1 << k) == 0 {
                        *v = 1e-4 * wave * [0.3, -0.5, 1.0][k];
                    }
                }
            }
            let mut f_int = vec![[0.0; 3]; n];
            model.internal_forces(&model.u, &mut f_int).unwrap();
            for contact in [6, 20, 12] {
                let mut frames: Vec<NodeFrame> = (0..n).map(|i| model.frame(i, None)).collect();
                let mut curvature_terms = Vec::new();
                for (k, &i) in near.iter().take(contact).enumerate() {
                    let x = mesh.nodes_m[i];
                    let normal = normalise([0.4 * x[0] / 0.004, 0.4 * x[1] / 0.004, -1.0]);
                    frames[i] = model.frame(i, Some((-1e-4 * (1.0 + k as f64), normal)));
                    if k % 2 == 0 {
                        // −p dn/dx of a sphere of radius 4 mm under a reaction of 0.05 N.
                        let block: [[f64; 3]; 3] = std::array::from_fn(|r| {
                            std::array::from_fn(|c| {
                                let delta = if r == c { 1.0 } else { 0.0 };
                                -0.05 * (delta - normal[r] * normal[c]) / 0.004
                            })
                        });
                        curvature_terms.push((i, block));
                    }
                }
                let mut rhs = vec![0.0; 3 * n];
                let direct = model
                    .direct_increment(&frames, &curvature_terms, &mut rhs)
                    .unwrap();
                let constant = model
                    .constant_stiffness_increment(&frames, &curvature_terms, &f_int)
                    .unwrap();
                let scale = direct.iter().flatten().fold(0.0_f64, |m, v| m.max(v.abs()));
                let worst = direct
                    .iter()
                    .flatten()
                    .zip(constant.iter().flatten())
                    .fold(0.0_f64, |m, (a, b)| m.max((a - b).abs()));
                assert!(
                    scale > 1e-6,
                    "{kind:?}: no increment to compare ({scale:e} m)"
                );
                assert!(
                    worst <= 1e-9 * scale,
                    "{kind:?}, {contact} nodes in contact: increments differ by {worst:e} m (scale {scale:e} m)"
                );
            }
        }
    }

    fn normalise(v: [f64; 3]) -> [f64; 3] {
        let l = dot(v, v).sqrt();
        [v[0] / l, v[1] / l, v[2] / l]
    }
}
