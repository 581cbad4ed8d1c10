//! The 10-node tetrahedron and the two constitutive laws (linear elastic, compressible
//! neo-Hookean): internal forces and consistent tangents.
//!
//! Both laws are written in the total-Lagrangian form f_a = ∫ P · ∇₀N_a dV with P the first
//! Piola–Kirchhoff stress. For the linear law P is the small-strain stress σ(ε(u)), so the same
//! loop serves both.

use serde::Serialize;
use softhaptic_proto::Material;

/// Which formulation the FEM solves: the stress–strain law and where contact is imposed.
///
/// The two linear formulations share the small-strain law; they differ in the contact
/// kinematics, and that difference grows with depth (it is what separates them from the
/// closed forms of Hertz and Sneddon at δ ~ R).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LawKind {
    /// Small-strain linear elasticity with contact imposed on the deformed surface: a node's gap
    /// is its current distance from the indenter, the reaction acts along the indenter's normal
    /// at the node's current position, and the indenter's curvature enters the tangent. A
    /// hybrid, neither the textbook linear contact problem nor a large-deformation one: the
    /// surface rotates under the tool but the strain measure does not follow. Kept under the
    /// short name "linear" (and serialised so) because the committed report, its run keys and
    /// the scene tables use it.
    #[serde(rename = "linear")]
    LinearDeformedContact,
    /// The textbook small-deformation (geometrically linear) contact problem that Hertz and
    /// Sneddon solve: small strain, and the gap measured on the reference configuration along
    /// the body's surface normal (+z; the tool's axis when it presses straight down),
    /// g = f(X) − Z + u·(−z) with f the height of the tool's lower surface above the point, so
    /// only the normal displacement closes it and the contact reaction is normal to the
    /// undeformed surface. The contact problem is then linear apart from the active set.
    LinearSmallDeformation,
    /// Compressible neo-Hookean, W = μ/2 (I₁ − 3 − 2 ln J) + λ/2 (ln J)², large strain, contact
    /// on the deformed surface.
    NeoHookean,
}

impl LawKind {
    /// Short name for files and tables.
    pub fn name(self) -> &'static str {
        match self {
            LawKind::LinearDeformedContact => "linear",
            LawKind::LinearSmallDeformation => "linear_small_deformation",
            LawKind::NeoHookean => "neo_hookean",
        }
    }

    /// Whether the stress is the small-strain linear-elastic one (both linear formulations).
    pub fn small_strain(self) -> bool {
        matches!(
            self,
            LawKind::LinearDeformedContact | LawKind::LinearSmallDeformation
        )
    }

    /// Whether contact is imposed on the reference configuration (linearised gap along the
    /// tool's axis) rather than on the deformed surface.
    pub fn contact_on_reference(self) -> bool {
        self == LawKind::LinearSmallDeformation
    }
}

/// A law with its Lamé constants; the neo-Hookean law has the same small-strain limit as the
/// linear one (μ = G, λ = Eν/((1+ν)(1−2ν))).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Constitutive {
    pub kind: LawKind,
    pub mu_pa: f64,
    pub lambda_pa: f64,
}

impl Constitutive {
    pub fn new(kind: LawKind, material: &Material) -> Self {
        let e = material.youngs_modulus_pa();
        let nu = material.poisson_ratio();
        Constitutive {
            kind,
            mu_pa: material.shear_modulus_pa(),
            lambda_pa: e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
        }
    }
}

/// Gauss points of the degree-2 rule on the reference tetrahedron (exact for the linear-elastic
/// stiffness of straight-sided 10-node tets), with weights summing to the volume 1/6.
const QP_A: f64 = 0.585_410_196_624_968_5;
const QP_B: f64 = 0.138_196_601_125_010_5;
pub const QUADRATURE: [([f64; 3], f64); 4] = [
    ([QP_B, QP_B, QP_B], 1.0 / 24.0),
    ([QP_A, QP_B, QP_B], 1.0 / 24.0),
    ([QP_B, QP_A, QP_B], 1.0 / 24.0),
    ([QP_B, QP_B, QP_A], 1.0 / 24.0),
];

/// Edges of the mid-edge nodes 4..9, as pairs of corner indices.
pub const EDGES: [(usize, usize); 6] = [(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)];

/// Shape functions at reference point (ξ, η, ζ).
pub fn shape(xi: [f64; 3]) -> [f64; 10] {
    let l = [1.0 - xi[0] - xi[1] - xi[2], xi[0], xi[1], xi[2]];
    let mut n = [0.0; 10];
    for c in 0..4 {
        n[c] = l[c] * (2.0 * l[c] - 1.0);
    }
    for (e, &(a, b)) in EDGES.iter().enumerate() {
        n[4 + e] = 4.0 * l[a] * l[b];
    }
    n
}

/// Derivatives of the shape functions with respect to (ξ, η, ζ).
pub fn shape_gradients(xi: [f64; 3]) -> [[f64; 3]; 10] {
    let l = [1.0 - xi[0] - xi[1] - xi[2], xi[0], xi[1], xi[2]];
    // dL_c/dξ_k
    const DL: [[f64; 3]; 4] = [
        [-1.0, -1.0, -1.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
    ];
    let mut g = [[0.0; 3]; 10];
    for c in 0..4 {
        for k in 0..3 {
            g[c][k] = (4.0 * l[c] - 1.0) * DL[c][k];
        }
    }
    for (e, &(a, b)) in EDGES.iter().enumerate() {
        for k in 0..3 {
            g[4 + e][k] = 4.0 * (DL[a][k] * l[b] + l[a] * DL[b][k]);
        }
    }
    g
}

/// Precomputed reference-configuration data of one element: ∇₀N at each Gauss point and the
/// integration weight w·det J.
#[derive(Debug, Clone)]
pub struct ElementGeometry {
    pub grad: [[[f64; 3]; 10]; 4],
    pub weight_m3: [f64; 4],
}

/// Why an element's geometry was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("element {element} has a non-positive Jacobian {det_j:e} at Gauss point {point}")]
pub struct BadElement {
    pub element: usize,
    pub point: usize,
    pub det_j: f64,
}

pub fn invert3(m: &[[f64; 3]; 3]) -> Option<([[f64; 3]; 3], f64)> {
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    if !(det.is_finite()) || det == 0.0 {
        return None;
    }
    let inv_det = 1.0 / det;
    let mut inv = [[0.0; 3]; 3];
    inv[0][0] = (m[1][1] * m[2][2] - m[1][2] * m[2][1]) * inv_det;
    inv[0][1] = (m[0][2] * m[2][1] - m[0][1] * m[2][2]) * inv_det;
    inv[0][2] = (m[0][1] * m[1][2] - m[0][2] * m[1][1]) * inv_det;
    inv[1][0] = (m[1][2] * m[2][0] - m[1][0] * m[2][2]) * inv_det;
    inv[1][1] = (m[0][0] * m[2][2] - m[0][2] * m[2][0]) * inv_det;
    inv[1][2] = (m[0][2] * m[1][0] - m[0][0] * m[1][2]) * inv_det;
    inv[2][0] = (m[1][0] * m[2][1] - m[1][1] * m[2][0]) * inv_det;
    inv[2][1] = (m[0][1] * m[2][0] - m[0][0] * m[2][1]) * inv_det;
    inv[2][2] = (m[0][0] * m[1][1] - m[0][1] * m[1][0]) * inv_det;
    Some((inv, det))
}

impl ElementGeometry {
    /// Computes ∇₀N and weights from the element's reference node positions.
    pub fn new(index: usize, x: &[[f64; 3]; 10]) -> Result<Self, BadElement> {
        let mut grad = [[[0.0; 3]; 10]; 4];
        let mut weight_m3 = [0.0; 4];
        for (q, &(xi, w)) in QUADRATURE.iter().enumerate() {
            let dn = shape_gradients(xi);
            // J[i][k] = dX_i/dξ_k
            let mut j = [[0.0; 3]; 3];
            for a in 0..10 {
                for i in 0..3 {
                    for k in 0..3 {
                        j[i][k] += x[a][i] * dn[a][k];
                    }
                }
            }
            let (jinv, det) = invert3(&j).ok_or(BadElement {
                element: index,
                point: q,
                det_j: 0.0,
            })?;
            if det <= 0.0 {
                return Err(BadElement {
                    element: index,
                    point: q,
                    det_j: det,
                });
            }
            for a in 0..10 {
                // dN/dX_i = Σ_k dN/dξ_k dξ_k/dX_i
                for i in 0..3 {
                    grad[q][a][i] = (0..3).map(|k| dn[a][k] * jinv[k][i]).sum();
                }
            }
            weight_m3[q] = w * det;
        }
        Ok(ElementGeometry { grad, weight_m3 })
    }
}

/// An element whose deformation gradient left the admissible set (J ≤ 0 for neo-Hookean).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Inverted;

/// Internal force (30) and, when `tangent` is given, the 30×30 tangent of one element at nodal
/// displacements `u`. Returns the element's strain energy.
pub fn element_response(
    law: &Constitutive,
    geom: &ElementGeometry,
    u: &[[f64; 3]; 10],
    force: &mut [f64; 30],
    mut tangent: Option<&mut [[f64; 30]; 30]>,
) -> Result<f64, Inverted> {
    let (mu, lambda) = (law.mu_pa, law.lambda_pa);
    *force = [0.0; 30];
    if let Some(k) = tangent.as_deref_mut() {
        for row in k.iter_mut() {
            *row = [0.0; 30];
        }
    }
    let mut energy = 0.0;
    for q in 0..4 {
        let g = &geom.grad[q];
        let w = geom.weight_m3[q];
        // Displacement gradient H[i][j] = du_i/dX_j.
        let mut h = [[0.0; 3]; 3];
        for a in 0..10 {
            for i in 0..3 {
                for j in 0..3 {
                    h[i][j] += u[a][i] * g[a][j];
                }
            }
        }
        match law.kind {
            LawKind::LinearDeformedContact | LawKind::LinearSmallDeformation => {
                let tr = h[0][0] + h[1][1] + h[2][2];
                let mut s = [[0.0; 3]; 3];
                for i in 0..3 {
                    for j in 0..3 {
                        s[i][j] = mu * (h[i][j] + h[j][i]);
                    }
                    s[i][i] += lambda * tr;
                }
                let mut e_dot_s = 0.0;
                for i in 0..3 {
                    for j in 0..3 {
                        e_dot_s += 0.5 * (h[i][j] + h[j][i]) * s[i][j];
                    }
                }
                energy += 0.5 * w * e_dot_s;
                for a in 0..10 {
                    for i in 0..3 {
                        force[3 * a + i] += w * (0..3).map(|j| s[i][j] * g[a][j]).sum::<f64>();
                    }
                }
                if let Some(k) = tangent.as_deref_mut() {
                    for a in 0..10 {
                        for b in 0..10 {
                            let dot = g[a][0] * g[b][0] + g[a][1] * g[b][1] + g[a][2] * g[b][2];
                            for i in 0..3 {
                                for kk in 0..3 {
                                    let mut v =
                                        lambda * g[a][i] * g[b][kk] + mu * g[a][kk] * g[b][i];
                                    if i == kk {
                                        v += mu * dot;
                                    }
                                    k[3 * a + i][3 * b + kk] += w * v;
                                }
                            }
                        }
                    }
                }
            }
            LawKind::NeoHookean => {
                let mut f = h;
                for (i, row) in f.iter_mut().enumerate() {
                    row[i] += 1.0;
                }
                let (finv, det) = invert3(&f).ok_or(Inverted)?;
                if det <= 0.0 {
                    return Err(Inverted);
                }
                let ln_j = det.ln();
                let i1: f64 = f.iter().flatten().map(|v| v * v).sum();
                energy += w * (0.5 * mu * (i1 - 3.0 - 2.0 * ln_j) + 0.5 * lambda * ln_j * ln_j);
                // P = μ(F − F⁻ᵀ) + λ ln J F⁻ᵀ
                let mut p = [[0.0; 3]; 3];
                for i in 0..3 {
                    for j in 0..3 {
                        let finv_t = finv[j][i];
                        p[i][j] = mu * (f[i][j] - finv_t) + lambda * ln_j * finv_t;
                    }
                }
                // c_a = F⁻ᵀ ∇₀N_a
                let mut c = [[0.0; 3]; 10];
                for a in 0..10 {
                    for i in 0..3 {
                        c[a][i] = (0..3).map(|j| finv[j][i] * g[a][j]).sum();
                    }
                    for i in 0..3 {
                        force[3 * a + i] += w * (0..3).map(|j| p[i][j] * g[a][j]).sum::<f64>();
                    }
                }
                if let Some(k) = tangent.as_deref_mut() {
                    // μ − λ ln J turns negative where the element dilates by more than e^{μ/λ}:
                    // never at ν = 0.33 (J > 1.67), but at ν = 0.49 (λ = 49 μ) from J > 1.02,
                    // which a coarse mesh reaches at a Gauss point or two near the contact edge.
                    // The tangent is then indefinite and the Cholesky factorisation fails. Its
                    // negative part is dropped: the residual stays exact, so Newton converges to
                    // the same solution, only more slowly in those elements.
                    let geo = (mu - lambda * ln_j).max(0.0);
                    for a in 0..10 {
                        for b in 0..10 {
                            let dot = g[a][0] * g[b][0] + g[a][1] * g[b][1] + g[a][2] * g[b][2];
                            for i in 0..3 {
                                for kk in 0..3 {
                                    let mut v =
                                        geo * c[b][i] * c[a][kk] + lambda * c[a][i] * c[b][kk];
                                    if i == kk {
                                        v += mu * dot;
                                    }
                                    k[3 * a + i][3 * b + kk] += w * v;
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    Ok(energy)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    fn reference_tet() -> [[f64; 3]; 10] {
        let c = [
            [0.0, 0.0, 0.0],
            [1.0, 0.1, 0.0],
            [0.2, 1.0, 0.1],
            [0.1, 0.3, 1.2],
        ];
        let mut x = [[0.0; 3]; 10];
        x[..4].copy_from_slice(&c);
        for (e, &(a, b)) in EDGES.iter().enumerate() {
            for i in 0..3 {
                x[4 + e][i] = 0.5 * (c[a][i] + c[b][i]);
            }
        }
        x
    }

    #[test]
    fn shape_functions_partition_unity_and_interpolate() {
        for xi in [[0.1, 0.2, 0.3], [0.25, 0.25, 0.25], [0.0, 0.5, 0.5]] {
            let n = shape(xi);
            assert!((n.iter().sum::<f64>() - 1.0).abs() < 1e-14);
            let g = shape_gradients(xi);
            for k in 0..3 {
                assert!(g.iter().map(|r| r[k]).sum::<f64>().abs() < 1e-13);
            }
        }
        // Node 4 (edge 01 midpoint) sits at ξ = (0.5, 0, 0).
        let n = shape([0.5, 0.0, 0.0]);
        assert!((n[4] - 1.0).abs() < 1e-14);
        assert!(n.iter().enumerate().all(|(i, v)| i == 4 || v.abs() < 1e-14));
    }

    #[test]
    fn quadrature_integrates_volume() {
        let x = reference_tet();
        let g = ElementGeometry::new(0, &x).unwrap();
        let vol: f64 = g.weight_m3.iter().sum();
        let c = |i: usize| x[i];
        let exact = crate::mesh::signed_volume(c(0), c(1), c(2), c(3)) / 6.0;
        assert!((vol - exact).abs() < 1e-14);
    }

    /// The tangent must be the derivative of the force: a central finite difference checks it
    /// for both laws at a finite deformation.
    #[test]
    fn tangent_matches_finite_difference_of_force() {
        let x = reference_tet();
        let geom = ElementGeometry::new(0, &x).unwrap();
        let material = Material::new(50e3, 0.33).unwrap();
        for kind in [LawKind::LinearDeformedContact, LawKind::NeoHookean] {
            let law = Constitutive::new(kind, &material);
            let mut u = [[0.0; 3]; 10];
            for (a, ua) in u.iter_mut().enumerate() {
                for (i, v) in ua.iter_mut().enumerate() {
                    *v = 0.05 * ((a * 3 + i) as f64 * 0.7).sin();
                }
            }
            let mut f0 = [0.0; 30];
            let mut k = [[0.0; 30]; 30];
            element_response(&law, &geom, &u, &mut f0, Some(&mut k)).unwrap();
            let eps = 1e-7;
            let mut worst = 0.0_f64;
            let scale = k.iter().flatten().fold(0.0_f64, |m, v| m.max(v.abs()));
            for col in 0..30 {
                let mut up = u;
                let mut um = u;
                up[col / 3][col % 3] += eps;
                um[col / 3][col % 3] -= eps;
                let (mut fp, mut fm) = ([0.0; 30], [0.0; 30]);
                element_response(&law, &geom, &up, &mut fp, None).unwrap();
                element_response(&law, &geom, &um, &mut fm, None).unwrap();
                for row in 0..30 {
                    let fd = (fp[row] - fm[row]) / (2.0 * eps);
                    worst = worst.max((fd - k[row][col]).abs() / scale);
                }
            }
            assert!(worst < 1e-6, "{kind:?}: tangent error {worst:e}");
        }
    }

    /// The force must be the derivative of the energy.
    #[test]
    fn force_matches_finite_difference_of_energy() {
        let x = reference_tet();
        let geom = ElementGeometry::new(0, &x).unwrap();
        let material = Material::new(1e3, 0.45).unwrap();
        for kind in [LawKind::LinearDeformedContact, LawKind::NeoHookean] {
            let law = Constitutive::new(kind, &material);
            let mut u = [[0.0; 3]; 10];
            for (a, ua) in u.iter_mut().enumerate() {
                for (i, v) in ua.iter_mut().enumerate() {
                    *v = 0.03 * ((a * 3 + i) as f64 * 1.3).cos();
                }
            }
            let mut f = [0.0; 30];
            element_response(&law, &geom, &u, &mut f, None).unwrap();
            let eps = 1e-7;
            let fmax = f.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
            for dof in 0..30 {
                let mut up = u;
                let mut um = u;
                up[dof / 3][dof % 3] += eps;
                um[dof / 3][dof % 3] -= eps;
                let mut scratch = [0.0; 30];
                let ep = element_response(&law, &geom, &up, &mut scratch, None).unwrap();
                let em = element_response(&law, &geom, &um, &mut scratch, None).unwrap();
                let fd = (ep - em) / (2.0 * eps);
                assert!((fd - f[dof]).abs() < 1e-6 * fmax, "{kind:?} dof {dof}");
            }
        }
    }

    #[test]
    fn neo_hookean_refuses_inverted_elements() {
        let x = reference_tet();
        let geom = ElementGeometry::new(0, &x).unwrap();
        let law = Constitutive::new(LawKind::NeoHookean, &Material::PAPER_SOFT);
        // Mirror the element through x = 0: F = diag(−1, 1, 1), J = −1.
        let mut u = [[0.0; 3]; 10];
        for a in 0..10 {
            u[a][0] = -2.0 * x[a][0];
        }
        let mut f = [0.0; 30];
        assert_eq!(
            element_response(&law, &geom, &u, &mut f, None),
            Err(Inverted)
        );
    }
}
