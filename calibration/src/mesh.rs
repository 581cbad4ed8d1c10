//! Quadratic tetrahedral meshes (10-node tets) built from graded structured grids.
//!
//! # Why 10-node tetrahedra
//! Linear (4-node) tetrahedra have constant strain: they are too stiff in bending and near the
//! edge of the contact, where the strain changes fastest, and need very fine meshes before the
//! Hertz force converges. 10-node tetrahedra carry linear strain, integrate the contact pressure
//! and the surface profile far better at the same node count, and still mesh any box or mapped
//! ball with the same generator. Each hexahedral cell of a structured grid is split into six
//! tetrahedra around its main diagonal (Kuhn's split). Every cell uses the same diagonal, so the
//! split is conforming across cells, and every node of the quadratic mesh (corner, mid-edge,
//! face-diagonal midpoint, body-diagonal midpoint) is a node of the grid with doubled resolution.
//!
//! # Frame
//! The FEM frame has `+z` along the outward normal of the indented surface: the block occupies
//! `z ≤ 0` with its top face at `z = 0`. Symmetry planes are `x = 0` and `y = 0`.

use serde::Serialize;

/// Bit for a displacement component held at zero (x, y, z).
pub const FIX_X: u8 = 1;
/// See [`FIX_X`].
pub const FIX_Y: u8 = 2;
/// See [`FIX_X`].
pub const FIX_Z: u8 = 4;
/// All three components held: the clamped bottom face.
pub const FIX_ALL: u8 = FIX_X | FIX_Y | FIX_Z;

/// Which part of an axisymmetric or mirror-symmetric problem the mesh models.
///
/// The forces of the whole object are the modelled part's forces times [`Symmetry::factors`]
/// per axis: components normal to a symmetry plane cancel with the mirror image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Symmetry {
    /// `x ≥ 0, y ≥ 0`: valid when the load is symmetric about both planes, as for a sphere or
    /// cone pressed along the surface normal.
    Quarter,
    /// `y ≥ 0`: valid when the load is symmetric about `y = 0`, as for a tool tilted in the x–z
    /// plane.
    HalfY,
    /// The whole object.
    Full,
}

impl Symmetry {
    /// Factors that turn the modelled part's resultant into the whole object's resultant.
    pub fn factors(self) -> [f64; 3] {
        match self {
            Symmetry::Quarter => [0.0, 0.0, 4.0],
            Symmetry::HalfY => [2.0, 0.0, 2.0],
            Symmetry::Full => [1.0, 1.0, 1.0],
        }
    }

    /// Number of copies of the modelled part in the whole object.
    pub fn copies(self) -> f64 {
        match self {
            Symmetry::Quarter => 4.0,
            Symmetry::HalfY => 2.0,
            Symmetry::Full => 1.0,
        }
    }
}

/// A 10-node tetrahedral mesh with its boundary conditions.
///
/// Element node order: corners 0–3, then mid-edge nodes on edges 01, 12, 02, 03, 13, 23.
#[derive(Debug, Clone)]
pub struct TetMesh {
    /// Reference (undeformed) node positions in metres, FEM frame.
    pub nodes_m: Vec<[f64; 3]>,
    /// Elements, 10 node indices each, positively oriented.
    pub elements: Vec<[u32; 10]>,
    /// Per node: the displacement components held at zero ([`FIX_X`] | …).
    pub fixed: Vec<u8>,
    /// Nodes that may touch the indenter (the free outer surface, minus the clamped part).
    pub contact_candidates: Vec<u32>,
    /// Top-surface nodes on the `y = 0` line, ordered by increasing reference `x`: where the
    /// surface profile is read.
    pub profile_nodes: Vec<u32>,
    /// The modelled part of the object.
    pub symmetry: Symmetry,
    /// Node counts (nx, ny, nz) of the structured grid the mesh came from, node (i, j, k) being
    /// number i + nx (j + ny k): what the fill-reducing ordering of the factorisation dissects
    /// (`crate::sparse`). `None` for a mesh without that structure.
    pub grid_nodes: Option<[usize; 3]>,
}

/// Errors in mesh parameters.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeshError {
    #[error("mesh parameter {field} must be finite and > 0, got {value}")]
    NonPositive { field: &'static str, value: f64 },
    #[error("mesh parameter {field} must be at least {min}, got {value}")]
    TooFewCells {
        field: &'static str,
        value: usize,
        min: usize,
    },
}

/// Cell coordinates along one axis, from `0` to `length_m`: uniform cells of `fine_cell_m` up to
/// `fine_length_m`, then `coarse_cells` cells growing geometrically to the end.
///
/// The growth ratio is found by bisection so that the first coarse cell is at least as large as
/// the fine ones and the last coordinate is exactly `length_m`.
pub fn graded_axis(
    length_m: f64,
    fine_length_m: f64,
    fine_cell_m: f64,
    coarse_cells: usize,
) -> Result<Vec<f64>, MeshError> {
    for (field, value) in [
        ("length_m", length_m),
        ("fine_cell_m", fine_cell_m),
        ("fine_length_m", fine_length_m),
    ] {
        if !(value.is_finite() && value > 0.0) {
            return Err(MeshError::NonPositive { field, value });
        }
    }
    let fine_length_m = fine_length_m.min(length_m);
    let n_fine = ((fine_length_m / fine_cell_m).round() as usize).max(1);
    let h = fine_length_m / n_fine as f64;
    let mut coords: Vec<f64> = (0..=n_fine).map(|i| i as f64 * h).collect();
    let rest = length_m - fine_length_m;
    if rest <= 1e-12 * length_m {
        if let Some(last) = coords.last_mut() {
            *last = length_m;
        }
        return Ok(coords);
    }
    let n = coarse_cells.max(1);
    // Sum of h r^k for k = 1..=n equals rest; uniform spacing if that needs r < 1.
    let sum = |r: f64| (1..=n).map(|k| h * r.powi(k as i32)).sum::<f64>();
    let ratio = if sum(1.0) >= rest {
        None
    } else {
        let (mut lo, mut hi) = (1.0_f64, 2.0_f64);
        while sum(hi) < rest {
            hi *= 2.0;
        }
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if sum(mid) < rest {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        Some(0.5 * (lo + hi))
    };
    let mut x = fine_length_m;
    for k in 1..=n {
        let dx = match ratio {
            Some(r) => h * r.powi(k as i32),
            None => rest / n as f64,
        };
        x += dx;
        coords.push(x);
    }
    if let Some(last) = coords.last_mut() {
        *last = length_m;
    }
    Ok(coords)
}

/// Inserts the midpoint between consecutive coordinates: the doubled grid of a quadratic mesh.
fn doubled(coords: &[f64]) -> Vec<f64> {
    let mut out = Vec::with_capacity(coords.len() * 2);
    for w in coords.windows(2) {
        out.push(w[0]);
        out.push(0.5 * (w[0] + w[1]));
    }
    if let Some(&last) = coords.last() {
        out.push(last);
    }
    out
}

/// Parameters of a graded block mesh.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BlockSpec {
    /// Whole block size along x, y (lateral) and z (depth), metres.
    pub size_m: [f64; 3],
    /// Edge of the uniform cells near the contact axis and the top face.
    pub fine_cell_m: f64,
    /// Lateral extent of the uniform zone from the axis.
    pub fine_radius_m: f64,
    /// Depth of the uniform zone below the top face.
    pub fine_depth_m: f64,
    /// Number of growing cells laterally beyond the fine zone (per half-width).
    pub coarse_cells_lateral: usize,
    /// Number of growing cells in depth below the fine zone.
    pub coarse_cells_depth: usize,
    /// The part of the block that is modelled.
    pub symmetry: Symmetry,
}

impl BlockSpec {
    /// A block graded toward the centre of its top face, sized for a tool whose contact radius
    /// reaches `contact_radius_m`, with `fine_cell_m` cells over 1.5 contact radii.
    pub fn graded(
        size_m: [f64; 3],
        contact_radius_m: f64,
        fine_cell_m: f64,
        coarse_cells: usize,
        symmetry: Symmetry,
    ) -> Self {
        BlockSpec {
            size_m,
            fine_cell_m,
            fine_radius_m: (1.5 * contact_radius_m).max(2.0 * fine_cell_m),
            fine_depth_m: (1.0 * contact_radius_m).max(2.0 * fine_cell_m),
            coarse_cells_lateral: coarse_cells,
            coarse_cells_depth: coarse_cells,
            symmetry,
        }
    }
}

/// Builds a graded block: top face `z = 0`, bottom `z = −depth` clamped, side faces free,
/// symmetry planes on `x = 0` / `y = 0` as [`BlockSpec::symmetry`] asks.
pub fn block(spec: &BlockSpec) -> Result<TetMesh, MeshError> {
    let [sx, sy, sz] = spec.size_m;
    let half = |len: f64, field: &'static str| -> Result<Vec<f64>, MeshError> {
        if !(len.is_finite() && len > 0.0) {
            return Err(MeshError::NonPositive { field, value: len });
        }
        graded_axis(
            0.5 * len,
            spec.fine_radius_m,
            spec.fine_cell_m,
            spec.coarse_cells_lateral,
        )
    };
    let mirror = |pos: Vec<f64>| -> Vec<f64> {
        let mut all: Vec<f64> = pos.iter().rev().map(|v| -v).collect();
        all.pop();
        all.extend(pos);
        all
    };
    let xs_half = half(sx, "size_m[0]")?;
    let ys_half = half(sy, "size_m[1]")?;
    let (xs, ys) = match spec.symmetry {
        Symmetry::Quarter => (xs_half, ys_half),
        Symmetry::HalfY => (mirror(xs_half), ys_half),
        Symmetry::Full => (mirror(xs_half), mirror(ys_half)),
    };
    let zs_down = graded_axis(
        sz,
        spec.fine_depth_m,
        spec.fine_cell_m,
        spec.coarse_cells_depth,
    )?;
    let zs: Vec<f64> = zs_down.iter().rev().map(|z| -z).collect();
    let grid = Grid::new(&xs, &ys, &zs);
    let symmetry = spec.symmetry;
    Ok(grid.build(
        |p| p,
        |i, j, k, g| {
            let mut mask = 0;
            if k == 0 {
                mask |= FIX_ALL;
            }
            if i == 0 && symmetry == Symmetry::Quarter {
                mask |= FIX_X;
            }
            if j == 0 && symmetry != Symmetry::Full {
                mask |= FIX_Y;
            }
            let _ = g;
            mask
        },
        |_, _, k, g| k == g.nz - 1,
        symmetry,
    ))
}

/// Parameters of a ball mesh (for the curvature study).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BallSpec {
    /// Radius of the ball.
    pub radius_m: f64,
    /// Cell edge near the top pole, where the tool presses.
    pub fine_cell_m: f64,
    /// Extent of the fine zone from the pole (laterally and in depth).
    pub fine_radius_m: f64,
    /// Growing cells beyond the fine zone, per axis.
    pub coarse_cells: usize,
}

/// Builds a quarter ball (`x ≥ 0, y ≥ 0`) of radius R with its top pole at the origin
/// (centre at `(0, 0, −R)`), graded toward the pole.
///
/// A quarter box `[0, R] × [0, R] × [−2R, 0]` is meshed with the block generator and mapped
/// radially onto the ball: p ↦ c + (p − c)·|p − c|∞ / |p − c|₂ (c the centre). Near the pole the
/// map is smooth and the mesh keeps its grading; the box's faces map onto the sphere. The nodes
/// that came from the box's bottom face (the lower cap, polar angle > 125°) are clamped: the ball
/// rests in a rigid cup, as the block rests on a rigid floor.
pub fn quarter_ball(spec: &BallSpec) -> Result<TetMesh, MeshError> {
    let r = spec.radius_m;
    if !(r.is_finite() && r > 0.0) {
        return Err(MeshError::NonPositive {
            field: "radius_m",
            value: r,
        });
    }
    let xs = graded_axis(r, spec.fine_radius_m, spec.fine_cell_m, spec.coarse_cells)?;
    let zs_down = graded_axis(
        2.0 * r,
        spec.fine_radius_m,
        spec.fine_cell_m,
        spec.coarse_cells + 2,
    )?;
    let zs: Vec<f64> = zs_down.iter().rev().map(|z| -z).collect();
    let grid = Grid::new(&xs, &xs, &zs);
    let centre = [0.0, 0.0, -r];
    Ok(grid.build(
        |p| {
            let d = [p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]];
            let inf = d[0].abs().max(d[1].abs()).max(d[2].abs());
            let two = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if two <= 0.0 {
                return p;
            }
            let s = inf / two;
            [
                centre[0] + d[0] * s,
                centre[1] + d[1] * s,
                centre[2] + d[2] * s,
            ]
        },
        |i, j, k, _| {
            let mut mask = 0;
            if k == 0 {
                mask |= FIX_ALL;
            }
            if i == 0 {
                mask |= FIX_X;
            }
            if j == 0 {
                mask |= FIX_Y;
            }
            mask
        },
        |i, j, k, g| k == g.nz - 1 || i == g.nx - 1 || j == g.ny - 1,
        Symmetry::Quarter,
    ))
}

/// The doubled (quadratic) grid of a tensor-product cell grid.
struct Grid {
    xs: Vec<f64>,
    ys: Vec<f64>,
    zs: Vec<f64>,
    /// Node counts of the doubled grid.
    nx: usize,
    ny: usize,
    nz: usize,
}

impl Grid {
    fn new(xs: &[f64], ys: &[f64], zs: &[f64]) -> Self {
        let (xs, ys, zs) = (doubled(xs), doubled(ys), doubled(zs));
        Grid {
            nx: xs.len(),
            ny: ys.len(),
            nz: zs.len(),
            xs,
            ys,
            zs,
        }
    }

    fn id(&self, i: usize, j: usize, k: usize) -> u32 {
        // Node counts stay far below u32::MAX for any mesh this crate builds (memory bounds it
        // first), so the narrowing is an invariant.
        (i + self.nx * (j + self.ny * k)) as u32
    }

    /// Generates nodes, elements, boundary masks and surface lists. `map` places a grid point,
    /// `fix` gives its mask, `surface` says whether a grid node lies on the contact surface.
    fn build(
        &self,
        map: impl Fn([f64; 3]) -> [f64; 3],
        fix: impl Fn(usize, usize, usize, &Grid) -> u8,
        surface: impl Fn(usize, usize, usize, &Grid) -> bool,
        symmetry: Symmetry,
    ) -> TetMesh {
        let n_nodes = self.nx * self.ny * self.nz;
        let mut nodes_m = Vec::with_capacity(n_nodes);
        let mut fixed = Vec::with_capacity(n_nodes);
        let mut contact_candidates = Vec::new();
        for k in 0..self.nz {
            for j in 0..self.ny {
                for i in 0..self.nx {
                    nodes_m.push(map([self.xs[i], self.ys[j], self.zs[k]]));
                    let mask = fix(i, j, k, self);
                    fixed.push(mask);
                    if surface(i, j, k, self) && mask != FIX_ALL {
                        contact_candidates.push(self.id(i, j, k));
                    }
                }
            }
        }
        // Profile line: top face, y = 0 grid line (the symmetry plane, or the middle row).
        let j0 = if symmetry == Symmetry::Full {
            self.ny / 2
        } else {
            0
        };
        let i0 = if symmetry == Symmetry::Quarter {
            0
        } else {
            self.nx / 2
        };
        let profile_nodes = (i0..self.nx).map(|i| self.id(i, j0, self.nz - 1)).collect();

        // Kuhn split: for each permutation of the axes, walk from corner 000 to 111.
        const PERMS: [[usize; 3]; 6] = [
            [0, 1, 2],
            [0, 2, 1],
            [1, 0, 2],
            [1, 2, 0],
            [2, 0, 1],
            [2, 1, 0],
        ];
        let (cx, cy, cz) = ((self.nx - 1) / 2, (self.ny - 1) / 2, (self.nz - 1) / 2);
        let mut elements = Vec::with_capacity(cx * cy * cz * 6);
        for ck in 0..cz {
            for cj in 0..cy {
                for ci in 0..cx {
                    let base = [2 * ci, 2 * cj, 2 * ck];
                    for perm in PERMS {
                        let mut corners = [[0usize; 3]; 4];
                        let mut cur = base;
                        corners[0] = cur;
                        for (step, &axis) in perm.iter().enumerate() {
                            cur[axis] += 2;
                            corners[step + 1] = cur;
                        }
                        let pos = |g: [usize; 3]| nodes_m[self.id(g[0], g[1], g[2]) as usize];
                        let (p0, p1, p2, p3) = (
                            pos(corners[0]),
                            pos(corners[1]),
                            pos(corners[2]),
                            pos(corners[3]),
                        );
                        let v = signed_volume(p0, p1, p2, p3);
                        if v < 0.0 {
                            corners.swap(1, 2);
                        }
                        let mid = |a: [usize; 3], b: [usize; 3]| {
                            self.id((a[0] + b[0]) / 2, (a[1] + b[1]) / 2, (a[2] + b[2]) / 2)
                        };
                        let c = corners;
                        elements.push([
                            self.id(c[0][0], c[0][1], c[0][2]),
                            self.id(c[1][0], c[1][1], c[1][2]),
                            self.id(c[2][0], c[2][1], c[2][2]),
                            self.id(c[3][0], c[3][1], c[3][2]),
                            mid(c[0], c[1]),
                            mid(c[1], c[2]),
                            mid(c[0], c[2]),
                            mid(c[0], c[3]),
                            mid(c[1], c[3]),
                            mid(c[2], c[3]),
                        ]);
                    }
                }
            }
        }
        TetMesh {
            nodes_m,
            elements,
            fixed,
            contact_candidates,
            profile_nodes,
            symmetry,
            grid_nodes: Some([self.nx, self.ny, self.nz]),
        }
    }
}

/// Six times the signed volume of the tetrahedron (p0, p1, p2, p3).
pub fn signed_volume(p0: [f64; 3], p1: [f64; 3], p2: [f64; 3], p3: [f64; 3]) -> f64 {
    let a = sub(p1, p0);
    let b = sub(p2, p0);
    let c = sub(p3, p0);
    a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
        + a[2] * (b[0] * c[1] - b[1] * c[0])
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

impl TetMesh {
    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.nodes_m.len()
    }

    /// Number of unknowns (three per node, fixed ones included).
    pub fn dof_count(&self) -> usize {
        3 * self.nodes_m.len()
    }

    /// Total reference volume of the modelled part, m³.
    pub fn volume_m3(&self) -> f64 {
        self.elements
            .iter()
            .map(|e| {
                let p = |i: usize| self.nodes_m[e[i] as usize];
                signed_volume(p(0), p(1), p(2), p(3)) / 6.0
            })
            .sum()
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn graded_axis_reaches_length_and_grows() {
        let xs = graded_axis(0.05, 0.01, 0.001, 8).unwrap();
        assert_eq!(xs[0], 0.0);
        assert!((xs.last().unwrap() - 0.05).abs() < 1e-15);
        let steps: Vec<f64> = xs.windows(2).map(|w| w[1] - w[0]).collect();
        assert!(steps.iter().all(|&s| s > 0.0));
        assert!((steps[0] - 0.001).abs() < 1e-12);
        assert!(steps.last().unwrap() > &0.003);
        assert!(graded_axis(-1.0, 0.01, 0.001, 3).is_err());
    }

    #[test]
    fn block_volume_and_orientation() {
        let spec = BlockSpec::graded([0.1, 0.1, 0.05], 0.005, 0.005, 3, Symmetry::Quarter);
        let mesh = block(&spec).unwrap();
        assert!((mesh.volume_m3() - 0.05 * 0.05 * 0.05).abs() < 1e-12);
        for e in &mesh.elements {
            let p = |i: usize| mesh.nodes_m[e[i] as usize];
            assert!(signed_volume(p(0), p(1), p(2), p(3)) > 0.0);
        }
        let full = block(&BlockSpec {
            symmetry: Symmetry::Full,
            ..spec
        })
        .unwrap();
        assert!((full.volume_m3() - 0.1 * 0.1 * 0.05).abs() < 1e-12);
    }

    #[test]
    fn ball_volume_approaches_quarter_sphere() {
        let r = 0.03;
        let mesh = quarter_ball(&BallSpec {
            radius_m: r,
            fine_cell_m: 0.003,
            fine_radius_m: 0.006,
            coarse_cells: 4,
        })
        .unwrap();
        let exact = std::f64::consts::PI * r * r * r / 3.0;
        // Curved (isoparametric) faces: the volume of straight-edged tets underestimates a
        // ball only by the chord error of the corner-node faces.
        assert!((mesh.volume_m3() / exact - 1.0).abs() < 0.05);
        for e in &mesh.elements {
            let p = |i: usize| mesh.nodes_m[e[i] as usize];
            assert!(signed_volume(p(0), p(1), p(2), p(3)) > 0.0);
        }
    }
}
