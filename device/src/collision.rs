//! Collision of the tool tip with the haptic mesh (paper §4.1).
//!
//! Long only because of its tests: the collider itself is under 600 lines.
//!
//! Build a [`Collider`] once from a [`HapticMesh`], then call [`Collider::query`] every tick.
//! After construction a query never allocates, locks, logs or does I/O: every buffer it needs
//! is sized in [`Collider::new`].
//!
//! # How a query runs
//! - **Broad phase**: a binary BVH over the triangles' boxes, built once by `obvhs` (PLOC, f32
//!   boxes padded so that f32 rounding can never drop a triangle). The two traversals, box
//!   overlap (paper mode) and nearest point ([`Collider::closest_surface_point`]), are written
//!   here: the nearest-point search prunes by the best distance found so far, which `obvhs`
//!   does not offer, and both keep their stack in a buffer of the [`Collider`], sized from the
//!   measured tree depth, so no tree shape can make a tick allocate.
//! - **Narrow phase, [`CollisionMode::PaperVertices`]**: the paper's method. The mesh vertices of
//!   the triangles whose boxes overlap the tip's box are tested against the tip's implicit shape
//!   ([`crate::shape::contains_local`]); the contact normal is the mean of the colliding
//!   vertices' normals and δ = (centre of the colliding vertices − tip) · normal. A vertex shared
//!   by several candidate triangles is tested once (a per-vertex stamp, no set is built).
//! - **Narrow phase, [`CollisionMode::Continuous`]** (default): the closest surface point p to
//!   the tip's reference point q (sphere centre, cone apex) and the Phong normal n at p (vertex
//!   normals blended by p's barycentric coordinates). Sphere: δ = R − s, with s = |q − p| signed
//!   by n (negative when q is inside the object). Cone: δ = depth of the cone's support point
//!   along −n below the tangent plane at p. Both are continuous in the tool pose: p and n move
//!   continuously on the surface, so a mesh coarser than the tip is not felt (no zero between
//!   vertices, no jump when a vertex enters the tip, no bump while sliding on a flat mesh).
//!
//! # Local curvature
//! When the scene's contact model uses the object's curvature, [`Collider::with_curvature`]
//! estimates it once per vertex ([`crate::curvature`]) and every contact then carries
//! [`ContactGeometry::curvature_1_per_m`]: in continuous mode the vertex values of the triangle
//! under the contact blended by the contact point's barycentric weights (the blend the normal
//! uses, so the curvature moves continuously as the tool slides), in paper mode the mean over
//! the colliding vertices. Without it the field is zero and nothing is computed.
//!
//! # Inside and outside
//! The side of the surface a point is on is the sign of (q − p) · n, n the Phong normal at the
//! closest point p. Inside a face this is the face's own side whenever the three vertex normals
//! lean less than 90° from the face, which area-weighted normals do on any mesh without folds.
//! On an edge or a vertex, the exact test uses the angle-weighted pseudo-normal (Bærentzen &
//! Aanæs 2005); the Phong normal there is a blend of the same faces' normals and points into the
//! same half-space unless the surface has a crease sharper than a right angle, where points very
//! close to the crease can be misjudged. With the sign right, the signed distance is continuous
//! and 1-Lipschitz in q, and so is the sphere's δ (tested on the liver by proptest). Where the
//! vertex normals cancel (a two-sided sheet) the shaft direction stands in, flagged
//! [`ContactGeometry::degenerate_normal`]. Past the border of an open mesh (the flat grids) the
//! side follows the nearest border normal; objects should be closed meshes.
//!
//! # Depth bound and reach
//! δ is clamped to the tip's height ([`crate::shape::max_depth_m`]: 2R for the sphere, h for the
//! cone) and the clamp is reported in [`ContactGeometry::depth_clamped`]. The continuous search
//! only looks for the surface within a reach of q (the tip's bounding radius plus that depth
//! bound), so a tool that appears deep inside a closed mesh, e.g. entering from below through the
//! far side, yields either a clamped contact against the nearest surface or no contact; never an
//! unbounded depth measured across the whole object. A query sees one tick only: a tool pushed
//! past the bound by a hand stronger than the device is followed across ticks and held on the
//! side it entered by [`crate::tracking::ContactTracker`], which the haptic world runs around
//! this query.

use std::time::Duration;

use glam::{DQuat, DVec3, Vec3A};
use obvhs::{BvhBuildParams, aabb::Aabb, bvh2::Bvh2};
use softhaptic_proto::{Material, Pose, ToolShape};

use crate::mesh::HapticMesh;
use crate::shape;

pub use crate::shape::inside_tool;

/// How the narrow phase finds the contact.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CollisionMode {
    /// The paper's method: mesh vertices inside the tool's implicit shape.
    PaperVertices,
    /// Continuous in the tool pose: depth measured against the triangles near the tip, so a
    /// mesh coarser than the tip is not felt.
    #[default]
    Continuous,
}

/// The geometric contact found by one query.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactGeometry {
    /// Indentation δ ≥ 0 along `normal`, at most [`crate::shape::max_depth_m`].
    pub depth_m: f64,
    /// Unit contact normal, object frame, pointing out of the object.
    pub normal: DVec3,
    /// Contact centre on the undeformed surface, object frame.
    pub contact_point_m: DVec3,
    /// True when the surface normals cancelled and `normal` is the fallback: the tool's shaft
    /// direction (`+y` of the tool frame, opposite to the way the tool points), so the force
    /// pushes the tool back the way it came.
    pub degenerate_normal: bool,
    /// True when the measured depth exceeded the tip's height and was clamped to it.
    pub depth_clamped: bool,
    /// Mean curvature of the surface at the contact, 1/m, positive where convex; zero unless
    /// the collider was built [`Collider::with_curvature`].
    pub curvature_1_per_m: f64,
}

/// The point of the mesh surface closest to a query point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePoint {
    /// The closest point, object frame.
    pub point_m: DVec3,
    /// Phong normal at the point (unit), or zero when the vertex normals cancel there.
    pub normal: DVec3,
    /// Distance from the query point, negative when the query point lies on the side opposite
    /// to `normal` (inside a closed, outward-oriented mesh). Positive when `normal` is zero.
    pub signed_distance_m: f64,
    /// Index of the triangle that holds the point.
    pub triangle: u32,
    /// The point's barycentric weights on the triangle's vertices, in the triangle's order.
    pub barycentric: DVec3,
}

/// Collision queries against one haptic mesh. A clone is a second, independent collider over the
/// same triangles (the build is the expensive part; a clone copies the tree).
#[derive(Clone)]
pub struct Collider {
    mesh: HapticMesh,
    mode: CollisionMode,
    /// The tree over the triangles. Only `nodes` and `primitive_indices` are read.
    bvh: Bvh2,
    /// Traversal stack, capacity fixed in `new` to the tree depth + 2: a depth-first traversal
    /// that pushes both children of each popped node never holds more than depth + 1 entries.
    stack: Vec<u32>,
    /// Number of nodes on the tree's longest root-to-leaf path.
    depth: usize,
    /// Per-vertex stamp of the last paper-mode query that tested the vertex, so a vertex shared
    /// by six candidate triangles is tested once without building a set.
    vertex_stamps: Vec<u32>,
    /// The current paper-mode query's stamp; when it would wrap, the stamps are cleared in place.
    stamp: u32,
    /// Padding (m) added to every f32 box, triangle and query alike: covers f32 rounding of the
    /// coordinates (relative 6e-8) with a wide safety factor.
    pad_m: f64,
    /// Mean curvature per vertex (1/m), or empty when the scene's model does not use it: only
    /// [`Collider::with_curvature`] computes it.
    vertex_curvature_1_per_m: Vec<f64>,
}

impl Collider {
    /// Builds the BVH and the query buffers. Cost O(n log n) in the triangle count; this is the
    /// only place the collider allocates.
    pub fn new(mesh: HapticMesh, mode: CollisionMode) -> Self {
        let extent_m = mesh
            .positions_m()
            .iter()
            .fold(0.0f64, |m, p| m.max(p.abs().max_element()));
        let pad_m = 1e-9 + 1e-6 * extent_m;
        let boxes: Vec<Aabb> = mesh
            .triangles()
            .iter()
            .map(|tri| {
                let [a, b, c] = tri.map(|i| mesh.positions_m()[i as usize]);
                f32_box(a.min(b).min(c), a.max(b).max(c), pad_m)
            })
            .collect();
        let bvh = obvhs::bvh2::builder::build_bvh2(
            &boxes,
            BvhBuildParams::fast_build(),
            &mut Duration::default(),
        );
        let depth = tree_depth(&bvh);
        Self {
            vertex_stamps: vec![0; mesh.positions_m().len()],
            mesh,
            mode,
            bvh,
            stack: Vec::with_capacity(depth + 2),
            depth,
            stamp: 0,
            pad_m,
            vertex_curvature_1_per_m: Vec::new(),
        }
    }

    /// Estimates the mesh's curvature at every vertex ([`crate::curvature`]) so that contacts
    /// report it. Costs O(E log E) once, E the edge count; a collider that already has it is
    /// returned as is.
    pub fn with_curvature(mut self) -> Self {
        if self.vertex_curvature_1_per_m.is_empty() {
            self.vertex_curvature_1_per_m =
                crate::curvature::vertex_mean_curvatures_1_per_m(&self.mesh);
        }
        self
    }

    /// True when contacts report the surface's curvature.
    pub fn has_curvature(&self) -> bool {
        !self.vertex_curvature_1_per_m.is_empty()
    }

    /// The per-vertex mean curvature (1/m), empty unless built [`Collider::with_curvature`].
    pub fn vertex_curvatures_1_per_m(&self) -> &[f64] {
        &self.vertex_curvature_1_per_m
    }

    pub fn mesh(&self) -> &HapticMesh {
        &self.mesh
    }

    pub fn mode(&self) -> CollisionMode {
        self.mode
    }

    /// Switches the narrow phase; the tree and buffers serve both modes, so this is free.
    pub fn set_mode(&mut self, mode: CollisionMode) {
        self.mode = mode;
    }

    /// Depth of the BVH (a single leaf has depth 1).
    pub fn tree_depth(&self) -> usize {
        self.depth
    }

    /// The contact of `tool` at `tip_in_object` (the tool frame in the mesh's frame), or `None`
    /// out of contact.
    ///
    /// Returns `None`, without panicking, for a non-finite pose, a zero orientation quaternion or
    /// an invalid tool. Paper mode reports a contact as soon as one vertex is inside the tip
    /// (δ may then be 0); continuous mode only when δ > 0.
    ///
    /// Cost: O(log n) for the continuous mode; the paper mode also tests every vertex under the
    /// tip's box, so it grows with the mesh density.
    pub fn query(&mut self, tool: &ToolShape, tip_in_object: &Pose) -> Option<ContactGeometry> {
        let pose = clean_pose(tip_in_object)?;
        tool.validate().ok()?;
        match self.mode {
            CollisionMode::PaperVertices => self.query_paper(tool, &pose),
            CollisionMode::Continuous => self.query_continuous(tool, &pose),
        }
    }

    /// The paper's narrow phase: vertices inside the implicit tip.
    fn query_paper(&mut self, tool: &ToolShape, pose: &Pose) -> Option<ContactGeometry> {
        let (lo, hi) = shape::aabb_m(tool, pose);
        let query_box = f32_box(lo, hi, self.pad_m);
        self.stamp = match self.stamp.checked_add(1) {
            Some(s) => s,
            None => {
                // Once every 2³² queries (50 days at 1 kHz): one O(n) pass, no allocation.
                self.vertex_stamps.fill(0);
                1
            }
        };
        let inverse: DQuat = pose.orientation.inverse();
        let mut sum_p = DVec3::ZERO;
        let mut sum_n = DVec3::ZERO;
        let mut sum_curvature = 0.0;
        let mut count = 0usize;
        // The closure borrows the mesh and the stamps, the traversal borrows the tree and the
        // stack: disjoint fields, so split them before traversing.
        let Self {
            mesh,
            bvh,
            stack,
            vertex_stamps,
            stamp,
            vertex_curvature_1_per_m,
            ..
        } = self;
        traverse_overlap(bvh, stack, &query_box, |triangle| {
            for v in mesh.triangles()[triangle as usize] {
                let v = v as usize;
                if vertex_stamps[v] == *stamp {
                    continue;
                }
                vertex_stamps[v] = *stamp;
                let p = mesh.positions_m()[v];
                if shape::contains_local(tool, inverse * (p - pose.position_m)) {
                    sum_p += p;
                    sum_n += mesh.normals()[v];
                    sum_curvature += vertex_curvature_1_per_m.get(v).copied().unwrap_or(0.0);
                    count += 1;
                }
            }
        });
        if count == 0 {
            return None;
        }
        let centre = sum_p / count as f64;
        // The vertex normals are unit (or zero): a mean shorter than 1e-6 is cancellation, whose
        // direction would be rounding noise.
        let (normal, degenerate_normal) = match sum_n.try_normalize() {
            Some(n) if sum_n.length() > 1e-6 * count as f64 => (n, false),
            _ => (pose.orientation * DVec3::Y, true),
        };
        let raw_depth_m = (centre - pose.position_m).dot(normal).max(0.0);
        let max_depth_m = shape::max_depth_m(tool);
        Some(ContactGeometry {
            depth_m: raw_depth_m.min(max_depth_m),
            normal,
            contact_point_m: centre,
            degenerate_normal,
            depth_clamped: raw_depth_m > max_depth_m,
            curvature_1_per_m: sum_curvature / count as f64,
        })
    }

    /// The continuous narrow phase: closest surface point and its Phong normal.
    fn query_continuous(&mut self, tool: &ToolShape, pose: &Pose) -> Option<ContactGeometry> {
        let q = pose.transform_point(shape::reference_point_local(tool));
        let max_depth_m = shape::max_depth_m(tool);
        let reach_m = shape::bounding_radius_m(tool) + max_depth_m;
        let surface = self.closest_surface_point(q, reach_m)?;
        let (normal, degenerate_normal) = match surface.normal.try_normalize() {
            Some(n) => (n, false),
            None => (pose.orientation * DVec3::Y, true),
        };
        let (raw_depth_m, contact_point_m) = match *tool {
            ToolShape::Sphere { radius_m } => {
                let distance_m = (q - surface.point_m).length();
                let signed_m = if (q - surface.point_m).dot(normal) >= 0.0 {
                    distance_m
                } else {
                    -distance_m
                };
                (radius_m - signed_m, surface.point_m)
            }
            ToolShape::Cone { .. } => {
                let deepest = shape::support_point(tool, pose, -normal);
                let depth_m = (surface.point_m - deepest).dot(normal);
                (depth_m, deepest + normal * depth_m)
            }
        };
        if raw_depth_m.is_nan() || raw_depth_m <= 0.0 {
            return None;
        }
        Some(ContactGeometry {
            depth_m: raw_depth_m.min(max_depth_m),
            normal,
            contact_point_m,
            degenerate_normal,
            depth_clamped: raw_depth_m > max_depth_m,
            curvature_1_per_m: self.curvature_at(&surface),
        })
    }

    /// The mesh's curvature at a surface point: its triangle's vertex values blended by its
    /// barycentric weights; zero without [`Collider::with_curvature`].
    #[inline]
    fn curvature_at(&self, surface: &SurfacePoint) -> f64 {
        let k = &self.vertex_curvature_1_per_m;
        if k.is_empty() {
            return 0.0;
        }
        let [a, b, c] = self.mesh.triangles()[surface.triangle as usize];
        let w = surface.barycentric;
        w.x * k[a as usize] + w.y * k[b as usize] + w.z * k[c as usize]
    }

    /// The surface point closest to `point_m` (object frame) within `max_distance_m`, or `None`
    /// when no triangle is that close or the input is not finite. Ties go to the triangle met
    /// first in the (fixed) traversal order, so the answer is deterministic.
    ///
    /// Cost: O(log n) node visits for a query point near the surface; no allocation.
    pub fn closest_surface_point(
        &mut self,
        point_m: DVec3,
        max_distance_m: f64,
    ) -> Option<SurfacePoint> {
        if !point_m.is_finite() || max_distance_m.is_nan() || max_distance_m < 0.0 {
            return None;
        }
        let positions = self.mesh.positions_m();
        let triangles = self.mesh.triangles();
        let nodes = &self.bvh.nodes;
        let stack = &mut self.stack;
        let pad_sq = self.pad_m * self.pad_m;
        let mut best_sq = max_distance_m * max_distance_m;
        let mut best: Option<(u32, DVec3, DVec3)> = None;
        stack.clear();
        if nodes.is_empty() {
            return None;
        }
        stack.push(0);
        while let Some(index) = stack.pop() {
            let node = &nodes[index as usize];
            // Boxes are padded by pad_m, so the box distance underestimates the true distance
            // by at most that much; the allowance keeps the pruning conservative.
            if box_distance_sq(node.aabb(), point_m) > best_sq + pad_sq {
                continue;
            }
            if node.is_leaf() {
                let first = node.first_index as usize;
                for &triangle in
                    &self.bvh.primitive_indices[first..first + node.prim_count as usize]
                {
                    let [a, b, c] = triangles[triangle as usize].map(|i| positions[i as usize]);
                    let (p, bary) = closest_on_triangle(point_m, a, b, c);
                    let d_sq = (point_m - p).length_squared();
                    if d_sq < best_sq || (best.is_none() && d_sq <= best_sq) {
                        best_sq = d_sq;
                        best = Some((triangle, p, bary));
                    }
                }
            } else {
                let left = node.first_index;
                let right = left + 1;
                let d_left = box_distance_sq(nodes[left as usize].aabb(), point_m);
                let d_right = box_distance_sq(nodes[right as usize].aabb(), point_m);
                // Nearer child last, so it is popped first and tightens the bound sooner.
                let (near, far) = if d_left <= d_right {
                    (left, right)
                } else {
                    (right, left)
                };
                push_bounded(stack, far);
                push_bounded(stack, near);
            }
        }
        let (triangle, p, bary) = best?;
        let [na, nb, nc] = triangles[triangle as usize].map(|i| self.mesh.normals()[i as usize]);
        // A blend of unit normals shorter than 1e-6 has cancelled: its direction is noise.
        let blend = na * bary.x + nb * bary.y + nc * bary.z;
        let normal = if blend.length() > 1e-6 {
            blend.normalize_or_zero()
        } else {
            DVec3::ZERO
        };
        let distance_m = (point_m - p).length();
        let signed_distance_m = if (point_m - p).dot(normal) >= 0.0 {
            distance_m
        } else {
            -distance_m
        };
        Some(SurfacePoint {
            point_m: p,
            normal,
            signed_distance_m,
            triangle,
            barycentric: bary,
        })
    }
}

/// One haptic step of the paper's timing study (§4.2, Table 1): collision query, contact law
/// and damping along the normal, F = max(0, Φ(δ) − b·(v·n))·n in the object frame (zero out of
/// contact). The benchmark and the step report time exactly this; the real tick adds the
/// safety layer on top.
pub fn timing_step_force_n(
    collider: &mut Collider,
    tool: &ToolShape,
    material: &Material,
    tip_in_object: &Pose,
    tip_velocity_m_s: DVec3,
    damping_n_s_per_m: f64,
) -> DVec3 {
    match collider.query(tool, tip_in_object) {
        Some(contact) => {
            let law_n = crate::law::contact_force_n(tool, material, contact.depth_m);
            let damping_n = damping_n_s_per_m * tip_velocity_m_s.dot(contact.normal);
            contact.normal * (law_n - damping_n).max(0.0)
        }
        None => DVec3::ZERO,
    }
}

/// Calls `visit` with every triangle whose (padded) box overlaps `query`, in a fixed order.
fn traverse_overlap(bvh: &Bvh2, stack: &mut Vec<u32>, query: &Aabb, mut visit: impl FnMut(u32)) {
    stack.clear();
    if bvh.nodes.is_empty() {
        return;
    }
    stack.push(0);
    while let Some(index) = stack.pop() {
        let node = &bvh.nodes[index as usize];
        if !node.aabb().intersect_aabb(query) {
            continue;
        }
        if node.is_leaf() {
            let first = node.first_index as usize;
            for &triangle in &bvh.primitive_indices[first..first + node.prim_count as usize] {
                visit(triangle);
            }
        } else {
            push_bounded(stack, node.first_index + 1);
            push_bounded(stack, node.first_index);
        }
    }
}

/// Pushes without ever growing the buffer. The capacity is the tree depth + 2, which a
/// depth-first traversal cannot exceed (an invariant of `Collider::new`); were it ever exceeded,
/// the node would be skipped, deterministically, rather than allocate on the tick.
#[inline]
fn push_bounded(stack: &mut Vec<u32>, index: u32) {
    if stack.len() < stack.capacity() {
        stack.push(index);
    }
}

/// Depth of the tree (number of nodes on the longest root-to-leaf path).
fn tree_depth(bvh: &Bvh2) -> usize {
    let mut deepest = 0;
    if bvh.nodes.is_empty() {
        return 0;
    }
    let mut pending = vec![(0u32, 1usize)];
    while let Some((index, depth)) = pending.pop() {
        deepest = deepest.max(depth);
        let node = &bvh.nodes[index as usize];
        if !node.is_leaf() {
            pending.push((node.first_index, depth + 1));
            pending.push((node.first_index + 1, depth + 1));
        }
    }
    deepest
}

/// A rigid pose with a unit quaternion, or `None` when it is not usable.
fn clean_pose(pose: &Pose) -> Option<Pose> {
    if !pose.is_finite() {
        return None;
    }
    let length = pose.orientation.length();
    if length.is_nan() || length <= 1e-9 {
        return None;
    }
    Some(Pose {
        position_m: pose.position_m,
        orientation: pose.orientation / length,
    })
}

/// An f32 box holding the f64 box `[lo, hi]` padded by `pad_m` on every side.
fn f32_box(lo: DVec3, hi: DVec3, pad_m: f64) -> Aabb {
    Aabb::new(
        Vec3A::from((lo - pad_m).as_vec3()),
        Vec3A::from((hi + pad_m).as_vec3()),
    )
}

/// Squared distance from `p` to an f32 box (0 inside).
#[inline]
fn box_distance_sq(aabb: &Aabb, p: DVec3) -> f64 {
    let lo = aabb.min.as_dvec3();
    let hi = aabb.max.as_dvec3();
    let d = (lo - p).max(p - hi).max(DVec3::ZERO);
    d.length_squared()
}

/// Closest point of triangle `abc` to `p`, with its barycentric weights (wa, wb, wc).
///
/// Ericson, *Real-Time Collision Detection* §5.1.5: classify `p` against the Voronoi regions of
/// the vertices, edges and face. Degenerate (zero-length) edges take the first vertex instead of
/// dividing by zero, so a zero-area triangle gives a finite answer.
fn closest_on_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> (DVec3, DVec3) {
    let ratio = |num: f64, den: f64| if den != 0.0 { num / den } else { 0.0 };
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, DVec3::X);
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return (b, DVec3::Y);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = ratio(d1, d1 - d3);
        return (a + ab * v, DVec3::new(1.0 - v, v, 0.0));
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return (c, DVec3::Z);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = ratio(d2, d2 - d6);
        return (a + ac * w, DVec3::new(1.0 - w, 0.0, w));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = ratio(d4 - d3, (d4 - d3) + (d5 - d6));
        return (b + (c - b) * w, DVec3::new(0.0, 1.0 - w, w));
    }
    let sum = va + vb + vc;
    let v = ratio(vb, sum);
    let w = ratio(vc, sum);
    (a + ab * v + ac * w, DVec3::new(1.0 - v - w, v, w))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // In tests a panic is the failure report.
mod tests {
    use super::*;

    #[test]
    fn closest_point_regions_of_a_triangle() {
        let (a, b, c) = (DVec3::ZERO, DVec3::X, DVec3::Z);
        let (p, w) = closest_on_triangle(DVec3::new(0.25, 1.0, 0.25), a, b, c);
        assert!((p - DVec3::new(0.25, 0.0, 0.25)).length() < 1e-15);
        assert!((w - DVec3::new(0.5, 0.25, 0.25)).length() < 1e-15);
        let (p, _) = closest_on_triangle(DVec3::new(-1.0, 0.0, -1.0), a, b, c);
        assert_eq!(p, a);
        let (p, w) = closest_on_triangle(DVec3::new(0.5, 0.0, -1.0), a, b, c);
        assert!((p - DVec3::new(0.5, 0.0, 0.0)).length() < 1e-15 && w.z == 0.0);
        let (p, _) = closest_on_triangle(DVec3::new(1.0, 0.0, 1.0), a, b, c);
        assert!((p - DVec3::new(0.5, 0.0, 0.5)).length() < 1e-15);
        // Zero-area triangles give finite answers.
        let (p, w) = closest_on_triangle(DVec3::ONE, a, a, a);
        assert!(p.is_finite() && w.is_finite());
        let (p, w) = closest_on_triangle(DVec3::new(0.5, 1.0, 0.0), a, b, b * 2.0);
        assert!(p.is_finite() && w.is_finite());
    }

    #[test]
    fn closest_surface_point_matches_brute_force() {
        let mesh = crate::liver::mesh(3);
        let mut collider = Collider::new(mesh.clone(), CollisionMode::Continuous);
        for k in 0..200 {
            let t = k as f64 * 0.37;
            let q = DVec3::new(
                0.12 * t.sin(),
                0.08 * (1.3 * t).cos(),
                0.09 * (0.7 * t).sin(),
            );
            let found = collider.closest_surface_point(q, 1.0).unwrap();
            let brute = mesh
                .triangles()
                .iter()
                .map(|tri| {
                    let [a, b, c] = tri.map(|i| mesh.positions_m()[i as usize]);
                    (q - closest_on_triangle(q, a, b, c).0).length()
                })
                .fold(f64::INFINITY, f64::min);
            assert!((found.signed_distance_m.abs() - brute).abs() < 1e-12, "{k}");
        }
    }

    #[test]
    fn stack_capacity_is_never_exceeded_and_stays_fixed() {
        let mut collider = Collider::new(HapticMesh::grid(60, 0.1), CollisionMode::PaperVertices);
        let capacity = collider.stack.capacity();
        let tool = ToolShape::sphere(0.02).unwrap();
        for k in 0..50 {
            let pose = Pose::from_position(DVec3::new(k as f64 * 0.002 - 0.05, -0.01, 0.0));
            collider.query(&tool, &pose);
            collider.closest_surface_point(pose.position_m, 1.0);
        }
        assert_eq!(collider.stack.capacity(), capacity);
        assert!(collider.tree_depth() >= 2);
    }

    #[test]
    fn contacts_report_the_curvature_only_when_asked() {
        // A 10 mm sphere pressed 2 mm into a ball of R0 = 50 mm from several directions: in
        // both modes the contact's curvature is 1/R0 (the estimate is exact on a sphere; the
        // blend and the mean of equal values stay within rounding).
        let r0 = 0.05;
        let tool = ToolShape::sphere(0.01).unwrap();
        for mode in [CollisionMode::Continuous, CollisionMode::PaperVertices] {
            let mut plain = Collider::new(HapticMesh::sphere(r0, 4).unwrap(), mode);
            let mut curved =
                Collider::new(HapticMesh::sphere(r0, 4).unwrap(), mode).with_curvature();
            assert!(!plain.has_curvature() && curved.has_curvature());
            for k in 0..20 {
                let a = k as f64 * 0.7;
                let direction = DVec3::new(a.cos(), 0.3 * a.sin(), a.sin()).normalize();
                // The tool frame's origin is the tip, its +y axis the shaft: press along −direction.
                let pose = Pose {
                    position_m: direction * (r0 - 0.002),
                    orientation: DQuat::from_rotation_arc(DVec3::Y, direction),
                };
                let g = curved.query(&tool, &pose).unwrap();
                assert!(
                    (g.curvature_1_per_m * r0 - 1.0).abs() < 1e-9,
                    "{mode:?}: {g:?}"
                );
                assert_eq!(plain.query(&tool, &pose).unwrap().curvature_1_per_m, 0.0);
            }
        }
        // A flat grid: zero either way.
        let mut grid =
            Collider::new(HapticMesh::grid(21, 0.1), CollisionMode::Continuous).with_curvature();
        let g = grid
            .query(
                &tool,
                &Pose::from_position(DVec3::new(0.003, -0.002, 0.001)),
            )
            .unwrap();
        assert!(g.curvature_1_per_m.abs() < 1e-9);
    }

    #[test]
    fn stamps_wrap_without_losing_vertices() {
        let mut collider = Collider::new(HapticMesh::grid(5, 0.1), CollisionMode::PaperVertices);
        let tool = ToolShape::sphere(0.005).unwrap();
        let pose = Pose::from_position(DVec3::new(0.0, -0.001, 0.0));
        let before = collider.query(&tool, &pose).unwrap();
        collider.stamp = u32::MAX;
        collider.vertex_stamps.fill(u32::MAX);
        let after = collider.query(&tool, &pose).unwrap();
        assert_eq!(before, after);
        assert_eq!(collider.stamp, 1);
    }
}
