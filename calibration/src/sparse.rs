//! The global stiffness matrix: a fixed sparsity pattern built once per mesh, element
//! assembly into its lower triangle, and a sparse Cholesky factorisation (faer) whose symbolic
//! analysis (fill-reducing ordering, elimination tree) is also done once per mesh.
//!
//! Constraints never change the pattern: a constrained unknown keeps its row and column, which
//! are zeroed with a unit-scaled diagonal. That is what lets the contact active set change every
//! Newton iteration at the cost of a numeric factorisation only.
//!
//! That numeric factorisation is most of a neo-Hookean run's time (dense supernodal kernels; the
//! linear laws factorise once per run, see `solver::ContactModel::constant_stiffness_increment`),
//! and its cost is set by the fill-reducing ordering: on the structured meshes of the experiments
//! a geometric nested dissection ([`nested_dissection_order`]) leaves about 30% less fill than
//! minimum degree and halves the factorisation time (22 491 unknowns: 0.42 s against 0.90 s on
//! the 2-core calibration machine). A refactorisation reuses the buffers of the previous factor
//! ([`StiffnessPattern::refactorise`]). Reusing the last factor as a conjugate-gradient
//! preconditioner was measured too and lost: a new contact ring changes tens of rows at once, so
//! a factor one Newton iteration old needed 17 conjugate-gradient iterations to a relative
//! residual of 1e-10 and older ones 30 to 110, at 30 ms each against 0.27 s for the
//! factorisation (22 491 unknowns).

use std::cell::RefCell;
use std::sync::Arc;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::perm::PermRef;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use serde::Serialize;

use crate::mesh::TetMesh;

/// Errors of the linear-algebra layer.
#[derive(Debug, thiserror::Error)]
pub enum LinearError {
    #[error("symbolic factorisation failed: {0}")]
    Symbolic(String),
    #[error(
        "stiffness matrix is not positive definite ({0}); the mesh may be unconstrained or an element has collapsed"
    )]
    NotPositiveDefinite(String),
}

/// Lower-triangular CSC pattern of a 3-dof-per-node stiffness matrix.
pub struct StiffnessPattern {
    n: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    /// For node b: the sorted nodes a ≥ b coupled to it.
    lower_neighbours: Vec<Vec<u32>>,
    symbolic: Arc<SymbolicCholesky<usize>>,
}

/// The fill-reducing ordering of the Cholesky factorisation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FillOrdering {
    /// faer's approximate minimum degree.
    MinimumDegree,
    /// Geometric nested dissection of the mesh's structured grid (George 1973): the grid is cut
    /// in halves by planes of nodes, recursively, each plane numbered after both halves.
    NestedDissection,
}

/// Node order of a geometric nested dissection of a doubled (quadratic) grid of `dims` nodes.
///
/// A quadratic cell spans three node planes (2c, 2c + 1, 2c + 2) along each axis, so a plane at
/// an even index separates the nodes on its two sides: no element holds nodes of both.
pub fn nested_dissection_order(dims: [usize; 3]) -> Vec<usize> {
    /// Boxes of at most this many nodes are numbered in grid order.
    const LEAF_NODES: usize = 8;
    fn dissect(lo: [usize; 3], hi: [usize; 3], dims: [usize; 3], out: &mut Vec<usize>) {
        let ext = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
        let count = ext[0] * ext[1] * ext[2];
        if count == 0 {
            return;
        }
        let id = |i: usize, j: usize, k: usize| i + dims[0] * (j + dims[1] * k);
        let mut axes = [0usize, 1, 2];
        axes.sort_by_key(|&a| std::cmp::Reverse(ext[a]));
        // The even plane nearest the middle of the longest axis that leaves nodes on both sides.
        let split = if count <= LEAF_NODES {
            None
        } else {
            axes.iter().find_map(|&axis| {
                let mid = (lo[axis] + hi[axis] - 1) / 2;
                [mid, mid + 1, mid.saturating_sub(1), mid + 2]
                    .into_iter()
                    .find(|&s| s.is_multiple_of(2) && s > lo[axis] && s + 1 < hi[axis])
                    .map(|s| (axis, s))
            })
        };
        let Some((axis, s)) = split else {
            for k in lo[2]..hi[2] {
                for j in lo[1]..hi[1] {
                    for i in lo[0]..hi[0] {
                        out.push(id(i, j, k));
                    }
                }
            }
            return;
        };
        let mut left_hi = hi;
        left_hi[axis] = s;
        let mut right_lo = lo;
        right_lo[axis] = s + 1;
        dissect(lo, left_hi, dims, out);
        dissect(right_lo, hi, dims, out);
        let mut plane_lo = lo;
        plane_lo[axis] = s;
        let mut plane_hi = hi;
        plane_hi[axis] = s + 1;
        dissect(plane_lo, plane_hi, dims, out);
    }
    let mut out = Vec::with_capacity(dims[0] * dims[1] * dims[2]);
    dissect([0, 0, 0], dims, dims, &mut out);
    out
}

impl StiffnessPattern {
    /// The pattern of `mesh`, ordered by nested dissection when the mesh comes from a structured
    /// grid (several times less fill and work than minimum degree on these 3D meshes).
    pub fn new(mesh: &TetMesh) -> Result<Self, LinearError> {
        let ordering = if mesh.grid_nodes.is_some() {
            FillOrdering::NestedDissection
        } else {
            FillOrdering::MinimumDegree
        };
        Self::with_ordering(mesh, ordering)
    }

    /// The pattern of `mesh` with the given fill-reducing ordering (nested dissection falls back
    /// to minimum degree on a mesh without grid structure).
    pub fn with_ordering(mesh: &TetMesh, ordering: FillOrdering) -> Result<Self, LinearError> {
        let nn = mesh.node_count();
        let mut lower_neighbours: Vec<Vec<u32>> = vec![Vec::new(); nn];
        for e in &mesh.elements {
            for &a in e {
                for &b in e {
                    if a >= b {
                        lower_neighbours[b as usize].push(a);
                    }
                }
            }
        }
        for l in &mut lower_neighbours {
            l.sort_unstable();
            l.dedup();
        }
        let n = 3 * nn;
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        col_ptr.push(0);
        for (b, neighbours) in lower_neighbours.iter().enumerate() {
            for c in 0..3 {
                for &a in neighbours {
                    let first = if a as usize == b { c } else { 0 };
                    for r in first..3 {
                        row_idx.push(3 * a as usize + r);
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        let sym = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
        let node_order = match (ordering, mesh.grid_nodes) {
            (FillOrdering::NestedDissection, Some(dims))
                if dims.iter().product::<usize>() == nn =>
            {
                Some(nested_dissection_order(dims))
            }
            _ => None,
        };
        let symbolic = match node_order {
            Some(order) => {
                // Unknowns 3i, 3i + 1, 3i + 2 of node i stay together.
                let forward: Vec<usize> = order
                    .iter()
                    .flat_map(|&node| [3 * node, 3 * node + 1, 3 * node + 2])
                    .collect();
                let mut inverse = vec![0usize; n];
                for (new, &old) in forward.iter().enumerate() {
                    inverse[old] = new;
                }
                let perm = PermRef::new_checked(&forward, &inverse, n);
                factorize_symbolic_cholesky(
                    sym,
                    Side::Lower,
                    SymmetricOrdering::Custom(perm),
                    CholeskySymbolicParams::default(),
                )
            }
            None => factorize_symbolic_cholesky(
                sym,
                Side::Lower,
                SymmetricOrdering::Amd,
                CholeskySymbolicParams::default(),
            ),
        }
        .map_err(|e| LinearError::Symbolic(format!("{e:?}")))?;
        Ok(StiffnessPattern {
            n,
            col_ptr,
            row_idx,
            lower_neighbours,
            symbolic: Arc::new(symbolic),
        })
    }

    /// Stored entries of the Cholesky factor (its fill).
    pub fn factor_entries(&self) -> usize {
        self.symbolic.len_val()
    }

    /// Number of unknowns.
    pub fn size(&self) -> usize {
        self.n
    }

    /// Number of stored (lower-triangle) entries.
    pub fn stored_entries(&self) -> usize {
        self.row_idx.len()
    }

    /// A zeroed value array for this pattern.
    pub fn zero_values(&self) -> Vec<f64> {
        vec![0.0; self.row_idx.len()]
    }

    /// Adds a 30×30 element matrix (already in the frames used for assembly) into `values`.
    pub fn add_element(&self, values: &mut [f64], nodes: &[u32; 10], k: &[[f64; 30]; 30]) {
        for q in 0..10 {
            let b = nodes[q];
            let neighbours = &self.lower_neighbours[b as usize];
            for p in 0..10 {
                let a = nodes[p];
                if a < b {
                    continue;
                }
                // The pattern was built from these very elements, so the neighbour is present.
                let Ok(slot) = neighbours.binary_search(&a) else {
                    continue;
                };
                for c in 0..3 {
                    let col = 3 * b as usize + c;
                    for r in 0..3 {
                        if a == b && r < c {
                            continue;
                        }
                        values[self.entry(col, slot, c, r)] += k[3 * p + r][3 * q + c];
                    }
                }
            }
        }
    }

    /// Index in the value array of row `3a + r` of column `col = 3b + c`, where `a` is the
    /// `slot`-th lower neighbour of `b` (slot 0 is `b` itself). Within a column the diagonal
    /// block holds rows c..3 only, so the later blocks start `3 − c` entries after it.
    #[inline]
    fn entry(&self, col: usize, slot: usize, c: usize, r: usize) -> usize {
        if slot == 0 {
            self.col_ptr[col] + (r - c)
        } else {
            self.col_ptr[col] + (3 - c) + 3 * (slot - 1) + r
        }
    }

    /// Sets the diagonal entry of unknown `dof` (used for constrained unknowns, whose rows and
    /// columns the caller left out of the element matrices).
    pub fn set_diagonal(&self, values: &mut [f64], dof: usize, diag: f64) {
        values[self.col_ptr[dof]] = diag;
    }

    /// Adds `v` to entry (3·node + r, 3·node + c) of the node's diagonal block, r ≥ c.
    pub fn add_diagonal_block(&self, values: &mut [f64], node: usize, r: usize, c: usize, v: f64) {
        values[self.entry(3 * node + c, 0, c, r)] += v;
    }

    /// The diagonal entry of unknown `dof`.
    pub fn diagonal(&self, values: &[f64], dof: usize) -> f64 {
        values[self.col_ptr[dof]]
    }

    /// Factorises the matrix with these values.
    pub fn factorise(&self, values: &[f64]) -> Result<Factor, LinearError> {
        let mut factor = Factor {
            symbolic: Arc::clone(&self.symbolic),
            l_values: vec![0.0; self.symbolic.len_val()],
            factor_scratch: MemBuffer::new(
                self.symbolic
                    .factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
            ),
            solve_scratch: RefCell::new(MemBuffer::new(
                self.symbolic.solve_in_place_scratch::<f64>(1, Par::Seq),
            )),
        };
        self.refactorise(&mut factor, values)?;
        Ok(factor)
    }

    /// Factorises the matrix with these values into the buffers of an earlier factor of this
    /// pattern. A factor of the larger meshes is hundreds of megabytes: allocated afresh, every
    /// page of it is faulted in and zeroed again (the §4.3 neo-Hookean sphere run, 22 491
    /// unknowns: 19.1 s with a fresh factor per Newton iteration, 14.9 s reusing one).
    pub fn refactorise(&self, factor: &mut Factor, values: &[f64]) -> Result<(), LinearError> {
        debug_assert!(Arc::ptr_eq(&factor.symbolic, &self.symbolic));
        let sym = SymbolicSparseColMatRef::new_checked(
            self.n,
            self.n,
            &self.col_ptr,
            None,
            &self.row_idx,
        );
        let mat = SparseColMatRef::new(sym, values);
        self.symbolic
            .factorize_numeric_llt(
                &mut factor.l_values,
                mat,
                Side::Lower,
                LltRegularization::default(),
                Par::Seq,
                MemStack::new(&mut factor.factor_scratch),
                Default::default(),
            )
            .map_err(|e| LinearError::NotPositiveDefinite(format!("{e:?}")))?;
        Ok(())
    }

    /// y = K x using the stored lower triangle (symmetric product).
    pub fn multiply(&self, values: &[f64], x: &[f64], y: &mut [f64]) {
        y.iter_mut().for_each(|v| *v = 0.0);
        for col in 0..self.n {
            for idx in self.col_ptr[col]..self.col_ptr[col + 1] {
                let row = self.row_idx[idx];
                let v = values[idx];
                y[row] += v * x[col];
                if row != col {
                    y[col] += v * x[row];
                }
            }
        }
    }
}

/// A numeric Cholesky factor.
pub struct Factor {
    symbolic: Arc<SymbolicCholesky<usize>>,
    l_values: Vec<f64>,
    /// Work space of the numeric factorisation, allocated once per factor.
    factor_scratch: MemBuffer,
    /// Work space of the triangular solves, allocated once per factor.
    solve_scratch: RefCell<MemBuffer>,
}

impl Factor {
    /// Solves K x = b in place.
    pub fn solve_in_place(&self, rhs: &mut [f64]) {
        let n = rhs.len();
        let m = MatMut::from_column_major_slice_mut(rhs, n, 1);
        let mut scratch = self.solve_scratch.borrow_mut();
        LltRef::new(&self.symbolic, &self.l_values).solve_in_place_with_conj(
            Conj::No,
            m,
            Par::Seq,
            MemStack::new(&mut scratch),
        );
    }

    /// Solves K X = B in place for several right-hand sides at once (one pass over the factor
    /// for all of them, where column by column would read it once per column).
    pub fn solve_columns_in_place(&self, rhs: MatMut<'_, f64>) {
        let mut scratch = MemBuffer::new(
            self.symbolic
                .solve_in_place_scratch::<f64>(rhs.ncols(), Par::Seq),
        );
        LltRef::new(&self.symbolic, &self.l_values).solve_in_place_with_conj(
            Conj::No,
            rhs,
            Par::Seq,
            MemStack::new(&mut scratch),
        );
    }
}
