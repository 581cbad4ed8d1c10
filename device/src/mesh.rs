//! The coarse haptic mesh: a triangle surface with per-vertex normals, and the test surfaces
//! built from code (the flat grids of the paper's timing study, spheres of the curvature study).

use std::collections::HashMap;

use glam::DVec3;

/// Why a mesh was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeshError {
    #[error("vertex {index} is not finite: {value:?}")]
    NonFiniteVertex { index: usize, value: [f64; 3] },
    #[error(
        "vertex {index} is {value:?}: a haptic mesh's coordinates must lie within ±{MAX_COORDINATE_M} m of its origin (is the file in millimetres?)"
    )]
    CoordinateOutOfRange { index: usize, value: [f64; 3] },
    #[error(
        "triangle {triangle} refers to vertex {vertex}, but the mesh has {vertex_count} vertices"
    )]
    IndexOutOfRange {
        triangle: usize,
        vertex: u32,
        vertex_count: usize,
    },
    #[error("the mesh has no triangles")]
    Empty,
}

/// Largest coordinate a haptic mesh may have, metres. The collision's bounding-volume tree stores
/// boxes in `f32` (7 significant digits): at 100 m a box edge is still placed within 8 µm, well
/// under any indentation felt, while a larger object (no haptic scene spans more than a room)
/// would blur the contact, and coordinates past `f32`'s range (3.4e38) would not fit at all.
pub const MAX_COORDINATE_M: f64 = 100.0;

/// A triangle surface in the object's frame, with area-weighted vertex normals pointing out of
/// the object.
#[derive(Debug, Clone)]
pub struct HapticMesh {
    positions_m: Vec<DVec3>,
    normals: Vec<DVec3>,
    triangles: Vec<[u32; 3]>,
}

impl HapticMesh {
    /// Validates the data and computes vertex normals from the triangles' winding
    /// (counter-clockwise seen from outside). A vertex whose faces cancel (or that no face
    /// uses) gets a zero normal.
    pub fn new(positions_m: Vec<DVec3>, triangles: Vec<[u32; 3]>) -> Result<Self, MeshError> {
        if triangles.is_empty() {
            return Err(MeshError::Empty);
        }
        if let Some((index, p)) = positions_m.iter().enumerate().find(|(_, p)| !p.is_finite()) {
            return Err(MeshError::NonFiniteVertex {
                index,
                value: p.to_array(),
            });
        }
        if let Some((index, p)) = positions_m
            .iter()
            .enumerate()
            .find(|(_, p)| p.abs().max_element() > MAX_COORDINATE_M)
        {
            return Err(MeshError::CoordinateOutOfRange {
                index,
                value: p.to_array(),
            });
        }
        for (t, tri) in triangles.iter().enumerate() {
            if let Some(&v) = tri.iter().find(|&&v| v as usize >= positions_m.len()) {
                return Err(MeshError::IndexOutOfRange {
                    triangle: t,
                    vertex: v,
                    vertex_count: positions_m.len(),
                });
            }
        }
        let mut normals = vec![DVec3::ZERO; positions_m.len()];
        // Sum of the face areas around each vertex, to tell a real normal from rounding noise.
        let mut area_sums = vec![0.0f64; positions_m.len()];
        for tri in &triangles {
            let [a, b, c] = tri.map(|i| positions_m[i as usize]);
            // Unnormalised cross product: weights each face by its area.
            let n = (b - a).cross(c - a);
            let area = n.length();
            for &i in tri {
                normals[i as usize] += n;
                area_sums[i as usize] += area;
            }
        }
        for (n, area_sum) in normals.iter_mut().zip(area_sums) {
            // Faces that cancel (a two-sided sheet) leave a sum made of rounding errors whose
            // direction means nothing: call such a normal zero, so the collision's documented
            // fallback takes over instead of a random direction.
            *n = if n.length() > 1e-9 * area_sum {
                n.normalize_or_zero()
            } else {
                DVec3::ZERO
            };
        }
        Ok(Self {
            positions_m,
            normals,
            triangles,
        })
    }

    pub fn positions_m(&self) -> &[DVec3] {
        &self.positions_m
    }

    pub fn normals(&self) -> &[DVec3] {
        &self.normals
    }

    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// A flat square grid of `n × n` vertices in the y = 0 plane, normals +y, spanning
    /// `size_m` on each side and centred on the origin: the surfaces of the paper's timing study
    /// (Table 1), with 2(n−1)² triangles.
    pub fn grid(n: usize, size_m: f64) -> Self {
        let n = n.max(2);
        let step = size_m / (n - 1) as f64;
        let half = size_m / 2.0;
        let mut positions = Vec::with_capacity(n * n);
        for k in 0..n {
            for i in 0..n {
                positions.push(DVec3::new(
                    i as f64 * step - half,
                    0.0,
                    k as f64 * step - half,
                ));
            }
        }
        let mut triangles = Vec::with_capacity(2 * (n - 1) * (n - 1));
        for k in 0..n - 1 {
            for i in 0..n - 1 {
                let v = |i: usize, k: usize| (k * n + i) as u32;
                // Counter-clockwise seen from +y.
                triangles.push([v(i, k), v(i, k + 1), v(i + 1, k)]);
                triangles.push([v(i + 1, k), v(i, k + 1), v(i + 1, k + 1)]);
            }
        }
        Self::new(positions, triangles).expect("a grid is a valid mesh")
    }

    /// A sphere of radius `radius_m` centred on the origin: an icosphere of `subdivisions`
    /// levels (clamped to 7, 163 842 vertices), outward normals. The objects of the paper's
    /// curvature study (§3.2) and the reference surface of the curvature estimate. A
    /// non-finite radius is refused like any non-finite vertex.
    pub fn sphere(radius_m: f64, subdivisions: u32) -> Result<Self, MeshError> {
        let (directions, triangles) = unit_icosphere(subdivisions.min(7));
        let positions = directions.into_iter().map(|u| u * radius_m).collect();
        Self::new(positions, triangles)
    }
}

/// Unit icosphere (directions and counter-clockwise-outward triangles, 10·4ᵏ + 2 vertices):
/// subdivision keeps the coarser level's vertices first and appends each edge's midpoint once
/// (pushed out to the sphere), so levels nest exactly. The caller bounds `subdivisions`: the
/// vertex count grows as 4ᵏ.
pub fn unit_icosphere(subdivisions: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut vertices: Vec<DVec3> = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| DVec3::new(x, y, z).normalize())
    .collect();
    let mut triangles: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    // Make every face counter-clockwise seen from outside, whatever the table's convention.
    for tri in &mut triangles {
        let [a, b, c] = tri.map(|i| vertices[i as usize]);
        if (b - a).cross(c - a).dot(a + b + c) < 0.0 {
            tri.swap(1, 2);
        }
    }
    for _ in 0..subdivisions {
        let mut midpoints: HashMap<(u32, u32), u32> = HashMap::with_capacity(triangles.len() * 3);
        let mut finer = Vec::with_capacity(triangles.len() * 4);
        for &[a, b, c] in &triangles {
            let mut midpoint = |i: u32, j: u32| -> u32 {
                let key = (i.min(j), i.max(j));
                *midpoints.entry(key).or_insert_with(|| {
                    let m = (vertices[i as usize] + vertices[j as usize]).normalize();
                    vertices.push(m);
                    (vertices.len() - 1) as u32
                })
            };
            let ab = midpoint(a, b);
            let bc = midpoint(b, c);
            let ca = midpoint(c, a);
            finer.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        triangles = finer;
    }
    (vertices, triangles)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // In tests a panic is the failure report.
mod tests {
    use super::*;

    #[test]
    fn grid_has_paper_counts_and_up_normals() {
        let g = HapticMesh::grid(40, 0.1);
        assert_eq!(g.positions_m().len(), 1600);
        assert_eq!(g.triangles().len(), 3042);
        assert!(g.normals().iter().all(|n| (*n - DVec3::Y).length() < 1e-12));
    }

    #[test]
    fn bad_meshes_are_refused() {
        let nan = HapticMesh::new(
            vec![DVec3::ZERO, DVec3::X, DVec3::new(f64::NAN, 0.0, 0.0)],
            vec![[0, 1, 2]],
        );
        assert!(matches!(
            nan,
            Err(MeshError::NonFiniteVertex { index: 2, .. })
        ));
        let oob = HapticMesh::new(vec![DVec3::ZERO, DVec3::X, DVec3::Z], vec![[0, 1, 7]]);
        assert!(oob.unwrap_err().to_string().contains("vertex 7"));
        // Finite, but beyond what the f32 bounding-volume tree can hold (a grid spaced 1e39 m
        // used to panic inside its builder) or place precisely.
        for far_m in [1e39, 1e6, MAX_COORDINATE_M * 1.01] {
            let far = HapticMesh::new(
                vec![DVec3::ZERO, DVec3::X, DVec3::new(0.0, 0.0, -far_m)],
                vec![[0, 1, 2]],
            );
            let e = far.unwrap_err();
            assert!(
                matches!(e, MeshError::CoordinateOutOfRange { index: 2, .. }),
                "{e}"
            );
            assert!(e.to_string().contains("±100 m"), "{e}");
        }
        let edge = HapticMesh::new(
            vec![DVec3::ZERO, DVec3::X, DVec3::splat(-MAX_COORDINATE_M)],
            vec![[0, 1, 2]],
        );
        assert!(edge.is_ok());
    }
}
