//! The local curvature of the haptic mesh, per vertex, for the curvature correction of the
//! contact model ([`crate::model`]; docs/physics.md, "Curvature of the object").
//!
//! Computed once, when a [`Collider`](crate::collision::Collider) is asked for it (only scenes
//! whose model uses curvature do), and read by every collision query afterwards: the query
//! blends the three values of the triangle under the contact by the contact point's barycentric
//! weights (continuous mode, so the curvature moves continuously as the tool slides) or
//! averages the colliding vertices (the paper's vertex mode).
//!
//! # The estimate
//! The mean curvature H = (κ₁ + κ₂)/2 at vertex i, signed positive where the surface is convex
//! seen from outside (a ball: +1/R), negative where it is concave, zero on a plane. Along each
//! edge e = p_j − p_i of the one-ring the normal curvature is read from the variation of the
//! vertex normals, κ(e) = (n_j − n_i)·e / |e|². The normals here are Max's (1999, J. Graphics
//! Tools 4:2): face normals weighted by 1/(|e₁|²|e₂|²) of the face's two edges at the vertex,
//! which are exact for vertices on a sphere, so κ(e) is exact there whatever the edge length
//! (n = p/R). The mesh's own area-weighted normals are first-order only: on an irregular
//! tessellation their error does not shrink as the mesh is refined, and neither would the
//! curvature's. The normal curvature in a tangent direction t is the second fundamental form,
//! κ(t) = a t₁² + 2b t₁t₂ + c t₂², so a least-squares fit of (a, b, c) to the one-ring's edges
//! (their directions projected on the tangent plane) gives H = (a + c)/2 without assuming the
//! edges are evenly spread around the vertex (they are not on a grid's diagonals or a mesh
//! border). Where the fit is singular (fewer than three independent directions) the plain mean
//! of the edges' κ stands in. A vertex without a normal (cancelled faces) gets zero.

use glam::{DMat3, DVec3};

use crate::mesh::HapticMesh;

/// Below this, relative to the square of the mean row norm, the fit's normal matrix is treated
/// as singular (the edge directions do not span three independent quadratic forms).
const SINGULAR_FIT: f64 = 1e-9;

/// Mean curvature at every vertex of `mesh`, 1/m, in vertex order (see the module docs).
///
/// Cost: O(E log E) for the edge list plus O(E) for the fits, E the edge count; allocates its
/// result and the edge list. Meant to run once per mesh, never on the haptic tick.
pub fn vertex_mean_curvatures_1_per_m(mesh: &HapticMesh) -> Vec<f64> {
    let positions = mesh.positions_m();
    let normals = max_vertex_normals(mesh);
    let normals = normals.as_slice();
    let mut edges: Vec<(u32, u32)> = mesh
        .triangles()
        .iter()
        .flat_map(|&[a, b, c]| [(a, b), (b, c), (c, a)])
        .map(|(i, j)| (i.min(j), i.max(j)))
        .filter(|(i, j)| i != j)
        .collect();
    edges.sort_unstable();
    edges.dedup();

    let mut fits = vec![Fit::default(); positions.len()];
    for &(i, j) in &edges {
        let (i, j) = (i as usize, j as usize);
        let (ni, nj) = (normals[i], normals[j]);
        if ni == DVec3::ZERO || nj == DVec3::ZERO {
            continue;
        }
        let e = positions[j] - positions[i];
        let length_sq = e.length_squared();
        // Zero-length edges (and NaN, which a validated mesh cannot hold) carry no direction.
        if length_sq.is_nan() || length_sq <= 0.0 {
            continue;
        }
        let kappa = (nj - ni).dot(e) / length_sq;
        fits[i].add(ni, e, kappa);
        fits[j].add(nj, -e, kappa);
    }
    fits.iter().zip(normals).map(|(f, n)| f.mean(*n)).collect()
}

/// Unit vertex normals with Max's weights (module docs); zero where the faces cancel.
fn max_vertex_normals(mesh: &HapticMesh) -> Vec<DVec3> {
    let positions = mesh.positions_m();
    let mut sums = vec![DVec3::ZERO; positions.len()];
    let mut magnitudes = vec![0.0f64; positions.len()];
    for tri in mesh.triangles() {
        for k in 0..3 {
            let (i, j, l) = (tri[k], tri[(k + 1) % 3], tri[(k + 2) % 3]);
            let p = positions[i as usize];
            let (e1, e2) = (positions[j as usize] - p, positions[l as usize] - p);
            let weight = e1.length_squared() * e2.length_squared();
            if weight > 0.0 {
                let n = e1.cross(e2) / weight;
                sums[i as usize] += n;
                magnitudes[i as usize] += n.length();
            }
        }
    }
    sums.iter()
        .zip(magnitudes)
        // As in the mesh's own normals: a sum that is rounding noise against its terms has
        // cancelled, and its direction means nothing.
        .map(|(n, m)| {
            if n.length() > 1e-9 * m {
                n.normalize_or_zero()
            } else {
                DVec3::ZERO
            }
        })
        .collect()
}

/// The normal equations of one vertex's fit of κ(t) = a t₁² + 2b t₁t₂ + c t₂².
#[derive(Debug, Clone, Copy, Default)]
struct Fit {
    /// Σ r rᵀ, r = (t₁², 2 t₁t₂, t₂²), as the upper triangle: [00, 01, 02, 11, 12, 22].
    normal: [f64; 6],
    /// Σ r κ.
    rhs: [f64; 3],
    /// Σ κ and the number of edges, for the fallback mean.
    kappa_sum: f64,
    count: u32,
}

impl Fit {
    fn add(&mut self, normal: DVec3, edge: DVec3, kappa: f64) {
        if !kappa.is_finite() {
            return;
        }
        self.kappa_sum += kappa;
        self.count += 1;
        let tangent = edge - edge.dot(normal) * normal;
        let Some(t) = tangent.try_normalize() else {
            return;
        };
        let (b1, b2) = normal.any_orthonormal_pair();
        let (u, v) = (t.dot(b1), t.dot(b2));
        let r = [u * u, 2.0 * u * v, v * v];
        let m = &mut self.normal;
        m[0] += r[0] * r[0];
        m[1] += r[0] * r[1];
        m[2] += r[0] * r[2];
        m[3] += r[1] * r[1];
        m[4] += r[1] * r[2];
        m[5] += r[2] * r[2];
        for (acc, ri) in self.rhs.iter_mut().zip(r) {
            *acc += ri * kappa;
        }
    }

    /// H = (a + c)/2 from the fit, or the mean κ when the fit is singular.
    fn mean(&self, normal: DVec3) -> f64 {
        if normal == DVec3::ZERO || self.count == 0 {
            return 0.0;
        }
        let fallback = self.kappa_sum / self.count as f64;
        let m = &self.normal;
        let matrix =
            DMat3::from_cols_array(&[m[0], m[1], m[2], m[1], m[3], m[4], m[2], m[4], m[5]]);
        let scale = (m[0] + m[3] + m[5]) / 3.0;
        let det = matrix.determinant();
        // NaN counts as singular too.
        let threshold = SINGULAR_FIT * scale * scale * scale;
        if det.is_nan() || det <= threshold {
            return fallback;
        }
        let [a, _, c] = (matrix.inverse() * DVec3::from_array(self.rhs)).to_array();
        let h = 0.5 * (a + c);
        if h.is_finite() { h } else { fallback }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    fn range(values: &[f64]) -> (f64, f64) {
        values
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            })
    }

    #[test]
    fn a_sphere_has_curvature_one_over_its_radius() {
        // Max's normals are exact on a sphere, and so is κ(e): every vertex within 1e-9 of 1/R0
        // (rounding only; measured 1e-13), at the curvature study's radii, from a coarse to a
        // fine tessellation (edges of about 0.3 R0 down to 0.04 R0).
        for r0 in [0.03, 0.05, 0.1] {
            for level in [2, 5] {
                let mesh = HapticMesh::sphere(r0, level).unwrap();
                let (lo, hi) = range(&vertex_mean_curvatures_1_per_m(&mesh));
                let exact = 1.0 / r0;
                assert!(
                    (lo / exact - 1.0).abs() < 1e-9 && (hi / exact - 1.0).abs() < 1e-9,
                    "R0 = {r0}, level {level}: {lo} … {hi} vs {exact}"
                );
            }
        }
    }

    #[test]
    fn a_flat_grid_has_zero_curvature() {
        let mesh = HapticMesh::grid(21, 0.1);
        let (lo, hi) = range(&vertex_mean_curvatures_1_per_m(&mesh));
        assert!(lo.abs() < 1e-9 && hi.abs() < 1e-9, "{lo} … {hi}");
    }

    /// A grid bent into the paraboloid y = s (x² + z²)/(2 R0), normals up: a bowl (s = +1,
    /// concave seen from above) or a dome (s = −1).
    fn bent_grid(r0: f64, sign: f64) -> HapticMesh {
        let flat = HapticMesh::grid(41, 0.04);
        let positions = flat
            .positions_m()
            .iter()
            .map(|p| DVec3::new(p.x, sign * (p.x * p.x + p.z * p.z) / (2.0 * r0), p.z))
            .collect();
        HapticMesh::new(positions, flat.triangles().to_vec()).unwrap()
    }

    #[test]
    fn a_bowl_is_negative_and_a_dome_positive() {
        // At the apex of y = ±r²/(2 R0) both principal curvatures are 1/R0. Interior vertices
        // near the apex (within 5 mm, where the paraboloid's curvature differs from its apex
        // value by < 3 %) are compared within 5 %.
        let r0 = 0.05;
        for (sign, expected) in [(1.0, -1.0 / r0), (-1.0, 1.0 / r0)] {
            let mesh = bent_grid(r0, sign);
            let h = vertex_mean_curvatures_1_per_m(&mesh);
            let near: Vec<f64> = mesh
                .positions_m()
                .iter()
                .zip(&h)
                .filter(|(p, _)| p.x.hypot(p.z) < 0.005)
                .map(|(_, h)| *h)
                .collect();
            assert!(near.len() > 10);
            let (lo, hi) = range(&near);
            assert!(
                (lo / expected - 1.0).abs() < 0.05 && (hi / expected - 1.0).abs() < 0.05,
                "sign {sign}: {lo} … {hi} vs {expected}"
            );
            // Every vertex, border included, has the sign of the surface.
            assert!(h.iter().all(|k| k * expected > 0.0), "sign {sign}");
        }
    }

    #[test]
    fn the_liver_is_mostly_convex_with_finite_values() {
        let mesh = crate::liver::haptic_mesh();
        let h = vertex_mean_curvatures_1_per_m(&mesh);
        assert_eq!(h.len(), mesh.positions_m().len());
        assert!(h.iter().all(|k| k.is_finite()));
        let convex = h.iter().filter(|k| **k > 0.0).count();
        assert!(convex * 10 > h.len() * 8, "{convex} of {}", h.len());
        // The top of the right lobe: gently domed, radius between 2 and 50 cm.
        let top = crate::liver::top_contact();
        let (nearest, _) = mesh
            .positions_m()
            .iter()
            .enumerate()
            .min_by(|a, b| {
                (*a.1 - top.point_m)
                    .length()
                    .total_cmp(&(*b.1 - top.point_m).length())
            })
            .unwrap();
        assert!((2.0..50.0).contains(&h[nearest]), "{}", h[nearest]);
    }

    #[test]
    fn degenerate_input_gives_zero_not_nan() {
        // A two-sided sheet (normals cancel) and a single triangle.
        let sheet = HapticMesh::new(
            vec![DVec3::ZERO, DVec3::X, DVec3::Z],
            vec![[0, 1, 2], [0, 2, 1]],
        )
        .unwrap();
        assert_eq!(vertex_mean_curvatures_1_per_m(&sheet), vec![0.0; 3]);
        let single =
            HapticMesh::new(vec![DVec3::ZERO, DVec3::X, DVec3::Z], vec![[0, 2, 1]]).unwrap();
        assert!(
            vertex_mean_curvatures_1_per_m(&single)
                .iter()
                .all(|k| *k == 0.0)
        );
    }
}
