//! The global stiffness matrix: a fixed sparsity pattern built once per mesh, element
//! assembly into its lower triangle, and a sparse Cholesky factorisation (faer) whose symbolic
//! analysis (fill-reducing ordering, elimination tree) is also done once per mesh.
//!
//! Constraints never change the pattern: a constrained unknown keeps its row and column, which
//! are zeroed with a unit-scaled diagonal. That is what lets the contact active set change every
//! Newton iteration at the cost of a numeric factorisation only.

use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{MatMut, Side};

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
    symbolic: SymbolicLlt<usize>,
}

impl StiffnessPattern {
    pub fn new(mesh: &TetMesh) -> Result<Self, LinearError> {
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
        let symbolic = SymbolicLlt::try_new(sym, Side::Lower)
            .map_err(|e| LinearError::Symbolic(format!("{e:?}")))?;
        Ok(StiffnessPattern {
            n,
            col_ptr,
            row_idx,
            lower_neighbours,
            symbolic,
        })
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
        let sym = SymbolicSparseColMatRef::new_checked(
            self.n,
            self.n,
            &self.col_ptr,
            None,
            &self.row_idx,
        );
        let mat = SparseColMatRef::new(sym, values);
        let llt = Llt::try_new_with_symbolic(self.symbolic.clone(), mat, Side::Lower)
            .map_err(|e| LinearError::NotPositiveDefinite(format!("{e:?}")))?;
        Ok(Factor { llt })
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
    llt: Llt<usize, f64>,
}

impl Factor {
    /// Solves K x = b in place.
    pub fn solve_in_place(&self, rhs: &mut [f64]) {
        use faer::linalg::solvers::Solve;
        let n = rhs.len();
        let m = MatMut::from_column_major_slice_mut(rhs, n, 1);
        self.llt.solve_in_place(m);
    }
}
