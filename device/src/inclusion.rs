//! Stiffer inclusions felt through the tissue (palpation): the FEM's force ratio, interpolated
//! at run time.
//!
//! The calibration's FEM tabulates, for a sphere of tissue `stiffness_ratio` times stiffer
//! buried in the block, the force on the tool over the homogeneous block's force at the same
//! indentation ([`softhaptic_proto::InclusionTable`]). Here that ratio is read back for the
//! tool's contact: the lateral offset of the contact point from each inclusion's centre (in
//! the plane of the contact's surface) and the centre's depth below that plane come from the
//! collision's contact point and normal, the inclusion's radius and ratio are fixed when the
//! field is built, and the indentation is the contact's depth. The renderer multiplies its
//! contact model by the ratio ([`crate::force::ForceRenderer::set_inclusion`]).
//!
//! # Interpolation
//! Linear in the radius; in the centre's depth d, linear in 1/d³, the decay of a small stiff
//! region's effect under a load on the surface (a straight line in d overestimates between the
//! rows by a quarter, measured on held-out FEM cases); linear in ln(stiffness ratio), because
//! the force ratio grows ever more slowly with the inclusion's stiffness (a rigid inclusion is
//! the limit) and a straight line in the logarithm follows that bend with fewer table entries.
//! In the lateral offset and the indentation it is a bicubic Hermite patch (Catmull–Rom slopes;
//! in the offset a zero slope on the axis, where the ratio is symmetric, and at the table's last
//! offset, and at the first and last indentation, so that the derivative is continuous where
//! the ratio is held beyond them): the renderer
//! applies the ratio's derivatives as force (the potential's gradient, [`crate::force`]), and
//! they must be continuous in position and depth, which piecewise-linear interpolation would
//! not give at the grid lines.
//!
//! # Several inclusions
//! Their excess ratios add: 1 + Σ (ratio_i − 1). Exact for one; for several it treats them as
//! independent, which the FEM supports when they are apart by more than the contact's width
//! (the table's far offsets are within a percent of 1).
//!
//! # Cost
//! A contact farther from an inclusion than the table's last offset skips it after a dot
//! product; a near one costs at most 64 table reads. No allocation: the field is built once.
//! A scene without inclusions builds no field, and the world calls nothing.

use glam::DVec3;
use softhaptic_proto::{Inclusion, InclusionTable};

/// One inclusion with its fixed table coordinates precomputed.
#[derive(Debug, Clone)]
struct Placed {
    centre_m: DVec3,
    /// Bracketing indices and upper weight on the radius and ratio axes.
    radius: (usize, usize, f64),
    ratio: (usize, usize, f64),
}

/// The inclusions of one object and their table.
#[derive(Debug, Clone)]
pub struct InclusionField {
    table: InclusionTable,
    inclusions: Vec<Placed>,
    /// Lateral offset beyond which an inclusion is held at the table's last offset.
    max_offset_m: f64,
    /// The table's centre depths d as −1/d³, m⁻³: the coordinate interpolated in (module
    /// docs), increasing with d.
    centre_axis: Vec<f64>,
}

/// The centre-depth coordinate the table is interpolated in.
fn centre_coordinate(depth_m: f64) -> f64 {
    -1.0 / (depth_m * depth_m * depth_m)
}

/// The field's value for one contact.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InclusionLoad {
    /// Force over the homogeneous model's force at this contact.
    pub ratio: f64,
    /// Gradient of `ratio` with respect to the contact point, object frame, 1/m (in the
    /// contact's tangent plane).
    pub gradient_1_per_m: DVec3,
    /// Derivative of `ratio` with respect to the indentation, 1/m.
    pub ratio_per_depth_1_per_m: f64,
}

impl InclusionLoad {
    /// No inclusion near: the homogeneous model.
    pub const NONE: InclusionLoad = InclusionLoad {
        ratio: 1.0,
        gradient_1_per_m: DVec3::ZERO,
        ratio_per_depth_1_per_m: 0.0,
    };
}

/// Lower index, upper index and the upper weight of `x` on `axis`, clamped to its ends.
fn bracket(axis: &[f64], x: f64) -> (usize, usize, f64) {
    let n = axis.len();
    if n < 2 || x <= axis[0] || x.is_nan() {
        return (0, 0, 0.0);
    }
    if x >= axis[n - 1] {
        return (n - 1, n - 1, 0.0);
    }
    let upper = axis.partition_point(|&a| a <= x).clamp(1, n - 1);
    let lower = upper - 1;
    (
        lower,
        upper,
        (x - axis[lower]) / (axis[upper] - axis[lower]),
    )
}

/// Weights of the cubic Hermite spline through the values at `xs` (Catmull–Rom slopes inside,
/// zero slopes at the ends), evaluated at `x`:
/// four node indices, the weights giving the value and those giving its derivative in `x`.
/// Held (value of the end node, zero derivative) beyond the ends. The spline is linear in the
/// node values, which is what lets two of them nest into a bicubic patch.
fn hermite_weights(xs: &[f64], x: f64) -> ([usize; 4], [f64; 4], [f64; 4]) {
    let n = xs.len();
    if n == 1 || x.is_nan() || x <= xs[0] || x >= xs[n - 1] {
        let end = if n > 1 && x >= xs[n - 1] { n - 1 } else { 0 };
        return ([end; 4], [1.0, 0.0, 0.0, 0.0], [0.0; 4]);
    }
    let (i0, i1, t) = bracket(xs, x);
    let idx = [i0.saturating_sub(1), i0, i1, (i1 + 1).min(n - 1)];
    let h = xs[i1] - xs[i0];
    // Slope at i0 and at i1 as weights on the four nodes.
    let mut a0 = [0.0; 4];
    if i0 > 0 {
        let d = xs[i1] - xs[i0 - 1];
        a0[0] = -1.0 / d;
        a0[2] = 1.0 / d;
    }
    let mut a1 = [0.0; 4];
    if i1 < n - 1 {
        let d = xs[i1 + 1] - xs[i0];
        a1[1] = -1.0 / d;
        a1[3] = 1.0 / d;
    }
    let (t2, t3) = (t * t, t * t * t);
    let (h00, h10, h01, h11) = (
        2.0 * t3 - 3.0 * t2 + 1.0,
        t3 - 2.0 * t2 + t,
        -2.0 * t3 + 3.0 * t2,
        t3 - t2,
    );
    let (d00, d10, d01, d11) = (
        6.0 * t2 - 6.0 * t,
        3.0 * t2 - 4.0 * t + 1.0,
        -6.0 * t2 + 6.0 * t,
        3.0 * t2 - 2.0 * t,
    );
    let mut w = [0.0; 4];
    let mut dw = [0.0; 4];
    for k in 0..4 {
        w[k] = h * (h10 * a0[k] + h11 * a1[k]);
        dw[k] = d10 * a0[k] + d11 * a1[k];
    }
    w[1] += h00;
    w[2] += h01;
    dw[1] += d00 / h;
    dw[2] += d01 / h;
    (idx, w, dw)
}

impl InclusionField {
    /// The field of `inclusions` (object frame) read from `table`. Refuses an inclusion whose
    /// radius or ratio the table does not cover, naming it by its index.
    pub fn new(table: InclusionTable, inclusions: &[Inclusion]) -> Result<Self, String> {
        let mut placed = Vec::with_capacity(inclusions.len());
        for (i, inc) in inclusions.iter().enumerate() {
            if let Some(reason) = table.refuses(inc.radius_m, inc.stiffness_ratio) {
                return Err(format!("inclusion {i}: {reason}"));
            }
            let log_ratios: Vec<f64> = table.stiffness_ratios().iter().map(|r| r.ln()).collect();
            placed.push(Placed {
                centre_m: DVec3::from_array(inc.centre_in_object_m),
                radius: bracket(table.radii_m(), inc.radius_m),
                ratio: bracket(&log_ratios, inc.stiffness_ratio.ln()),
            });
        }
        let max_offset_m = table.offsets_m().last().copied().unwrap_or(0.0);
        let centre_axis = table
            .centre_depths_m()
            .iter()
            .map(|&d| centre_coordinate(d))
            .collect();
        Ok(InclusionField {
            table,
            inclusions: placed,
            max_offset_m,
            centre_axis,
        })
    }

    pub fn table(&self) -> &InclusionTable {
        &self.table
    }

    pub fn len(&self) -> usize {
        self.inclusions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.inclusions.is_empty()
    }

    /// The force ratio of inclusion `index` alone and its slope with respect to the lateral
    /// offset, 1/m, at indentation `depth_m`, lateral offset `offset_m` and centre depth
    /// `centre_depth_m` (what the validation holds against the FEM).
    pub fn single(
        &self,
        index: usize,
        depth_m: f64,
        offset_m: f64,
        centre_depth_m: f64,
    ) -> (f64, f64) {
        let (value, slope, _) =
            self.single_with_depth_slope(index, depth_m, offset_m, centre_depth_m);
        (value, slope)
    }

    /// [`InclusionField::single`] and the ratio's derivative with respect to the indentation,
    /// 1/m.
    pub fn single_with_depth_slope(
        &self,
        index: usize,
        depth_m: f64,
        offset_m: f64,
        centre_depth_m: f64,
    ) -> (f64, f64, f64) {
        let Some(p) = self.inclusions.get(index) else {
            return (1.0, 0.0, 0.0);
        };
        let t = &self.table;
        let (depth_index, depth_w, depth_dw) = hermite_weights(t.depths_m(), depth_m);
        let (offset_index, offset_w, offset_dw) = hermite_weights(t.offsets_m(), offset_m);
        // Clamped before the change of coordinate, which is monotonic only for d > 0.
        let axis = t.centre_depths_m();
        let c = bracket(
            &self.centre_axis,
            centre_coordinate(centre_depth_m.clamp(axis[0], axis[axis.len() - 1])),
        );
        let (mut value, mut slope, mut per_depth) = (0.0, 0.0, 0.0);
        for (ratio, w_ratio) in [(p.ratio.0, 1.0 - p.ratio.2), (p.ratio.1, p.ratio.2)] {
            for (radius, w_radius) in [(p.radius.0, 1.0 - p.radius.2), (p.radius.1, p.radius.2)] {
                for (centre, w_centre) in [(c.0, 1.0 - c.2), (c.1, c.2)] {
                    let w_corner = w_ratio * w_radius * w_centre;
                    if w_corner == 0.0 {
                        continue;
                    }
                    for a in 0..4 {
                        if depth_w[a] == 0.0 && depth_dw[a] == 0.0 {
                            continue;
                        }
                        for b in 0..4 {
                            if offset_w[b] == 0.0 && offset_dw[b] == 0.0 {
                                continue;
                            }
                            let y = w_corner
                                * t.at(ratio, radius, centre, offset_index[b], depth_index[a]);
                            value += depth_w[a] * offset_w[b] * y;
                            slope += depth_w[a] * offset_dw[b] * y;
                            per_depth += depth_dw[a] * offset_w[b] * y;
                        }
                    }
                }
            }
        }
        (value, slope, per_depth)
    }

    /// The field at a contact: `contact_point_m` on the undeformed surface and its outward unit
    /// `normal`, object frame, at indentation `depth_m`.
    pub fn load(&self, contact_point_m: DVec3, normal: DVec3, depth_m: f64) -> InclusionLoad {
        let mut load = InclusionLoad::NONE;
        for (index, p) in self.inclusions.iter().enumerate() {
            let to_centre = p.centre_m - contact_point_m;
            let centre_depth_m = -to_centre.dot(normal);
            let lateral = to_centre + centre_depth_m * normal;
            let offset_m = lateral.length();
            // Held beyond the table's last offset, where its slope is zero.
            let (v, slope, per_depth) = self.single_with_depth_slope(
                index,
                depth_m,
                offset_m.min(self.max_offset_m),
                centre_depth_m,
            );
            load.ratio += v - 1.0;
            load.ratio_per_depth_1_per_m += per_depth;
            if offset_m >= self.max_offset_m {
                continue;
            }
            // Moving the contact point toward the centre shrinks the offset.
            if offset_m > 0.0 {
                load.gradient_1_per_m -= slope * lateral / offset_m;
            }
        }
        load
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use softhaptic_proto::{Material, ToolShape};

    /// A table whose excess ratio falls off with the offset as exp(−(s/5 mm)²), grows with the
    /// indentation, falls as 1/d³ with the centre's depth and grows as ln(ratio).
    fn table() -> InclusionTable {
        let depths = vec![0.001, 0.003, 0.006];
        let offsets: Vec<f64> = (0..9).map(|i| i as f64 * 0.0025).collect();
        let centres = vec![0.008, 0.012];
        let radii = vec![0.005];
        let ratios = vec![2.0, 4.0, 8.0];
        let mut values = Vec::new();
        for &k in &ratios {
            for _ in &radii {
                for &c in &centres {
                    for &s in &offsets {
                        for &d in &depths {
                            values.push(excess(k, c, s, d) + 1.0);
                        }
                    }
                }
            }
        }
        InclusionTable::new(
            "test".into(),
            ToolShape::sphere(0.01).unwrap(),
            Material::PAPER_SOFT,
            [0.08, 0.08, 0.04],
            depths,
            offsets,
            centres,
            radii,
            ratios,
            values,
        )
        .unwrap()
    }

    fn excess(k: f64, c: f64, s: f64, d: f64) -> f64 {
        0.2 * k.ln() * (d / 0.006) * (0.008 / c).powi(3) * (-(s / 0.005).powi(2)).exp()
    }

    fn inclusion(centre: [f64; 3], ratio: f64) -> Inclusion {
        Inclusion {
            centre_in_object_m: centre,
            radius_m: 0.005,
            stiffness_ratio: ratio,
            centre_depth_m: -centre[1],
        }
    }

    #[test]
    fn the_table_is_read_back_at_its_nodes_and_between_them() {
        let field = InclusionField::new(table(), &[inclusion([0.0, -0.008, 0.0], 4.0)]).unwrap();
        let up = DVec3::Y;
        // On a node: exact.
        let l = field.load(DVec3::new(0.005, 0.0, 0.0), up, 0.003);
        assert!((l.ratio - 1.0 - excess(4.0, 0.008, 0.005, 0.003)).abs() < 1e-12);
        // The gradient points toward the centre (the ratio grows that way).
        assert!(l.gradient_1_per_m.x < 0.0 && l.gradient_1_per_m.y.abs() < 1e-12);
        // Between ratios, in ln: ratio 2√2 is halfway between 2 and 4.
        let f =
            InclusionField::new(table(), &[inclusion([0.0, -0.008, 0.0], 8f64.sqrt())]).unwrap();
        let at = |f: &InclusionField| f.load(DVec3::ZERO, up, 0.003).ratio - 1.0;
        let want = 0.5 * (excess(2.0, 0.008, 0.0, 0.003) + excess(4.0, 0.008, 0.0, 0.003));
        assert!((at(&f) - want).abs() < 1e-12);
        // Between centre depths, a 1/d³ decay is followed exactly (at a node of the offset).
        let deep = InclusionField::new(table(), &[inclusion([0.0, -0.010, 0.0], 4.0)]).unwrap();
        let want = excess(4.0, 0.010, 0.0, 0.003);
        assert!((at(&deep) - want).abs() < 1e-12 * want.max(1.0));
        // Off the table's radius: refused, naming the inclusion.
        let mut bad = inclusion([0.0, -0.008, 0.0], 4.0);
        bad.radius_m = 0.007;
        let err = InclusionField::new(table(), &[bad]).unwrap_err();
        assert!(err.starts_with("inclusion 0: radius 0.007"), "{err}");
    }

    #[test]
    fn the_ratio_and_its_slope_are_continuous_across_the_grid_lines() {
        let field = InclusionField::new(table(), &[inclusion([0.0, -0.01, 0.0], 4.0)]).unwrap();
        let step = 1e-6;
        let (mut last, mut last_slope) = field.single(0, 0.004, 0.0, 0.01);
        let mut s = step;
        while s < 0.025 {
            let (v, slope) = field.single(0, 0.004, s, 0.01);
            // A step of 1 µm changes the value by at most slope × step, and the slope by a
            // bounded curvature × step: no jump anywhere, grid lines included.
            assert!((v - last).abs() <= 1.5 * last_slope.abs().max(slope.abs()) * step + 1e-12);
            assert!((slope - last_slope).abs() < 1.0, "slope jumps at {s}");
            (last, last_slope) = (v, slope);
            s += step;
        }
        // Beyond the last offset: held, no slope.
        assert_eq!(field.single(0, 0.004, 0.05, 0.01).1, 0.0);
        // Along the indentation too, between the table's first and last depths.
        let at = |d: f64| field.single_with_depth_slope(0, d, 0.003, 0.01);
        let (mut last, mut last_slope) = (at(0.001).0, at(0.001).2);
        let mut d = 0.001 + step;
        while d < 0.006 {
            let (v, _, per_depth) = at(d);
            assert!((v - last).abs() <= 1.5 * last_slope.abs().max(per_depth.abs()) * step + 1e-12);
            assert!((per_depth - last_slope).abs() < 1.0, "slope jumps at {d}");
            (last, last_slope) = (v, per_depth);
            d += step;
        }
    }

    #[test]
    fn excesses_of_several_inclusions_add() {
        let a = inclusion([0.0, -0.008, 0.0], 4.0);
        let b = inclusion([0.006, -0.008, 0.0], 2.0);
        let both = InclusionField::new(table(), &[a, b]).unwrap();
        let one = InclusionField::new(table(), &[a]).unwrap();
        let two = InclusionField::new(table(), &[b]).unwrap();
        let p = DVec3::new(0.002, 0.0, 0.001);
        let r = |f: &InclusionField| f.load(p, DVec3::Y, 0.003).ratio;
        assert!((r(&both) - (r(&one) + r(&two) - 1.0)).abs() < 1e-12);
    }
}
