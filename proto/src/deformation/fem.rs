//! `fem`: the FEM's own top surface tabulated by the calibration ([`SurfaceFamily`]), the
//! profile drawn from it at any depth ([`SurfaceProfile`]) and the table the viewer samples it
//! into ([`SurfaceTable`]), as proto/WIRE.md ("Deformation profile", `fem`) defines them.
//!
//! Long only because of its tests: the profile itself is about 400 lines.

use serde::{Deserialize, Serialize};

use crate::tool::ToolShape;

use super::{sanitise, tool_height_m};

/// Why a [`SurfaceFamily`] was refused: the field (with the row and sample index where there is
/// one) and the value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SurfaceFamilyError {
    #[error("radius_exponent must be finite and in (0, 2], got {0}")]
    RadiusExponent(f64),
    #[error("radius_step_m must be finite and > 0, got {0}")]
    RadiusStep(f64),
    #[error("rows must not be empty")]
    NoRows,
    #[error("rows[{index}].depth_m must be finite and > 0, got {value}")]
    RowDepth { index: usize, value: f64 },
    #[error(
        "rows[{index}].depth_m = {value} is not greater than the row before it ({previous_value}): rows must be in increasing depth"
    )]
    RowsNotIncreasing {
        index: usize,
        value: f64,
        previous_value: f64,
    },
    #[error("rows[{index}].depression_m must hold at least 2 samples, got {len}")]
    TooFewSamples { index: usize, len: usize },
    #[error("rows[{row}].depression_m[{index}] must be finite and >= 0, got {value}")]
    Sample {
        row: usize,
        index: usize,
        value: f64,
    },
    #[error(
        "rows[{row}].depression_m must end at 0 (the surface beyond the table is unmoved), its last sample is {value}"
    )]
    OpenEnd { row: usize, value: f64 },
    #[error(
        "rows[{row}].radial_displacement_m must hold as many samples as depression_m ({expected}), got {len}"
    )]
    RadialLength {
        row: usize,
        len: usize,
        expected: usize,
    },
    #[error("rows[{row}].radial_displacement_m[{index}] must be finite, got {value}")]
    RadialSample {
        row: usize,
        index: usize,
        value: f64,
    },
    #[error(
        "rows[{row}].radial_displacement_m[{index}] must be 0 (the axis and the unmoved surface beyond the table do not move sideways), got {value}"
    )]
    RadialEnd {
        row: usize,
        index: usize,
        value: f64,
    },
    #[error(
        "rows[{row}].radial_displacement_m[{index}] = {value} folds the surface over itself: the displaced radius j·Δ + u[j] must increase with j"
    )]
    RadialFold {
        row: usize,
        index: usize,
        value: f64,
    },
}

/// One depth of a [`SurfaceFamily`]: the surface's depression at the radii 0, Δ, 2Δ, … from the
/// contact axis (Δ the family's `radius_step_m`), the last sample 0, and how far each of those
/// surface points moved away from the axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SurfaceRow {
    pub depth_m: f64,
    pub depression_m: Vec<f64>,
    /// Outward radial displacement at the same radii (negative: towards the axis), the first
    /// and last 0; empty for a row without sideways motion (every table written before it).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub radial_displacement_m: Vec<f64>,
}

impl SurfaceRow {
    /// A row without sideways motion.
    pub fn new(depth_m: f64, depression_m: Vec<f64>) -> Self {
        SurfaceRow {
            depth_m,
            depression_m,
            radial_displacement_m: Vec::new(),
        }
    }
}

/// The `fem` render profile: the depression of an object's surface against the distance from
/// the contact axis, tabulated at a set of depths (the calibration's, from its FEM), and how to
/// draw any depth from them (proto/WIRE.md, "Deformation profile", `fem`).
///
/// Between two rows the drawn depression blends the two rows, each first scaled to the depth
/// drawn as an elastic contact scales: depression in proportion to δ, radius in proportion to
/// δ^p (p = `radius_exponent`: ½ for a sphere, whose contact radius is √(Rδ), 1 for a cone).
/// On a half-space that scaling is exact, so the blend only has to carry what the finite block
/// and the large strains change from one row to the next; below the first row and beyond the
/// last the nearest row is scaled alone.
///
/// Every `SurfaceFamily` in the program has been validated (deserialising runs the same checks
/// as [`SurfaceFamily::new`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "SurfaceFamilyFields", into = "SurfaceFamilyFields")]
pub struct SurfaceFamily {
    radius_exponent: f64,
    radius_step_m: f64,
    rows: Vec<SurfaceRow>,
}

/// The JSON layout, checked on the way in.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SurfaceFamilyFields {
    radius_exponent: f64,
    radius_step_m: f64,
    rows: Vec<SurfaceRow>,
}

impl TryFrom<SurfaceFamilyFields> for SurfaceFamily {
    type Error = SurfaceFamilyError;
    fn try_from(f: SurfaceFamilyFields) -> Result<Self, Self::Error> {
        SurfaceFamily::new(f.radius_exponent, f.radius_step_m, f.rows)
    }
}

impl From<SurfaceFamily> for SurfaceFamilyFields {
    fn from(f: SurfaceFamily) -> Self {
        SurfaceFamilyFields {
            radius_exponent: f.radius_exponent,
            radius_step_m: f.radius_step_m,
            rows: f.rows,
        }
    }
}

impl SurfaceFamily {
    /// A family from its rows, checked: exponent in (0, 2], step finite > 0, rows non-empty in
    /// increasing depth, each with at least 2 finite non-negative samples ending at 0 (so the
    /// drawn surface meets the unmoved one without a step).
    pub fn new(
        radius_exponent: f64,
        radius_step_m: f64,
        rows: Vec<SurfaceRow>,
    ) -> Result<Self, SurfaceFamilyError> {
        if !(radius_exponent.is_finite() && radius_exponent > 0.0 && radius_exponent <= 2.0) {
            return Err(SurfaceFamilyError::RadiusExponent(radius_exponent));
        }
        if !(radius_step_m.is_finite() && radius_step_m > 0.0) {
            return Err(SurfaceFamilyError::RadiusStep(radius_step_m));
        }
        if rows.is_empty() {
            return Err(SurfaceFamilyError::NoRows);
        }
        for (index, row) in rows.iter().enumerate() {
            if !(row.depth_m.is_finite() && row.depth_m > 0.0) {
                return Err(SurfaceFamilyError::RowDepth {
                    index,
                    value: row.depth_m,
                });
            }
            if index > 0 && row.depth_m <= rows[index - 1].depth_m {
                return Err(SurfaceFamilyError::RowsNotIncreasing {
                    index,
                    value: row.depth_m,
                    previous_value: rows[index - 1].depth_m,
                });
            }
            if row.depression_m.len() < 2 {
                return Err(SurfaceFamilyError::TooFewSamples {
                    index,
                    len: row.depression_m.len(),
                });
            }
            if let Some((i, &value)) = row
                .depression_m
                .iter()
                .enumerate()
                .find(|(_, z)| !(z.is_finite() && **z >= 0.0))
            {
                return Err(SurfaceFamilyError::Sample {
                    row: index,
                    index: i,
                    value,
                });
            }
            if let Some(&last) = row.depression_m.last()
                && last != 0.0
            {
                return Err(SurfaceFamilyError::OpenEnd {
                    row: index,
                    value: last,
                });
            }
            check_radial(index, row, radius_step_m)?;
        }
        Ok(SurfaceFamily {
            radius_exponent,
            radius_step_m,
            rows,
        })
    }

    pub fn radius_exponent(&self) -> f64 {
        self.radius_exponent
    }

    /// True when some row moves the surface sideways.
    pub fn has_radial_displacement(&self) -> bool {
        self.rows
            .iter()
            .any(|row| row.radial_displacement_m.iter().any(|&u| u != 0.0))
    }

    pub fn radius_step_m(&self) -> f64 {
        self.radius_step_m
    }

    pub fn rows(&self) -> &[SurfaceRow] {
        &self.rows
    }

    /// The profile of `tool` pressed `depth_m` deep, ready to evaluate at any radius
    /// (proto/WIRE.md, `fem`, steps 1–2). A non-finite or non-positive depth, or a tool that
    /// fails [`ToolShape::validate`], draws nothing.
    pub fn at_depth(&self, tool: &ToolShape, depth_m: f64) -> SurfaceProfile<'_> {
        let d = if tool.validate().is_ok() {
            sanitise(depth_m)
        } else {
            0.0
        };
        let mut p = SurfaceProfile {
            family: self,
            tool: *tool,
            depth_m: d,
            terms: [SurfaceTerm::NONE; 2],
            footprint_m: 0.0,
            reach_m: 0.0,
        };
        if d == 0.0 {
            return p;
        }
        // Where the tool reaches below the undeformed surface: r with δ − h_tool(r) > 0.
        p.footprint_m = match *tool {
            ToolShape::Sphere { radius_m } if d < radius_m => (d * (2.0 * radius_m - d)).sqrt(),
            ToolShape::Sphere { radius_m } => radius_m,
            ToolShape::Cone {
                half_angle_rad,
                radius_m,
            } => (d * half_angle_rad.tan()).min(radius_m),
        };
        let last = self.rows.len() - 1;
        // The rows to blend and their weights: the nearest alone outside the table's depths.
        let (k, w) = if d <= self.rows[0].depth_m {
            (0, 0.0)
        } else if d >= self.rows[last].depth_m {
            (last, 0.0)
        } else {
            let k = self.rows.partition_point(|row| row.depth_m <= d) - 1;
            let (d0, d1) = (self.rows[k].depth_m, self.rows[k + 1].depth_m);
            (k, (d - d0) / (d1 - d0))
        };
        p.terms[0] = self.term(k, 1.0 - w, d);
        if w > 0.0 {
            p.terms[1] = self.term(k + 1, w, d);
        }
        p.reach_m = p
            .terms
            .iter()
            .map(|t| t.reach_m)
            .fold(p.footprint_m, f64::max);
        p
    }

    /// Row `index` scaled to depth `d` with blend `weight`.
    fn term(&self, index: usize, weight: f64, d: f64) -> SurfaceTerm {
        let row = &self.rows[index];
        // r at depth d corresponds to r (δ_k / d)^p on row k; in units of the sample spacing.
        let index_per_m = (row.depth_m / d).powf(self.radius_exponent) / self.radius_step_m;
        let samples = row.depression_m.len();
        SurfaceTerm {
            row: index,
            amplitude: weight * d / row.depth_m,
            index_per_m,
            reach_m: (samples - 1) as f64 / index_per_m,
        }
    }
}

/// The checks of a row's `radial_displacement_m` (none when it is empty): one sample per
/// depression sample, finite, 0 at the axis and at the end, and no fold (j·Δ + u[j] increasing).
fn check_radial(
    index: usize,
    row: &SurfaceRow,
    radius_step_m: f64,
) -> Result<(), SurfaceFamilyError> {
    let u = &row.radial_displacement_m;
    if u.is_empty() {
        return Ok(());
    }
    if u.len() != row.depression_m.len() {
        return Err(SurfaceFamilyError::RadialLength {
            row: index,
            len: u.len(),
            expected: row.depression_m.len(),
        });
    }
    if let Some((i, &value)) = u.iter().enumerate().find(|(_, x)| !x.is_finite()) {
        return Err(SurfaceFamilyError::RadialSample {
            row: index,
            index: i,
            value,
        });
    }
    for i in [0, u.len() - 1] {
        if u[i] != 0.0 {
            return Err(SurfaceFamilyError::RadialEnd {
                row: index,
                index: i,
                value: u[i],
            });
        }
    }
    for j in 1..u.len() {
        let before = (j - 1) as f64 * radius_step_m + u[j - 1];
        if j as f64 * radius_step_m + u[j] <= before {
            return Err(SurfaceFamilyError::RadialFold {
                row: index,
                index: j,
                value: u[j],
            });
        }
    }
    Ok(())
}

/// One scaled row of a [`SurfaceProfile`].
#[derive(Debug, Clone, Copy, PartialEq)]
struct SurfaceTerm {
    row: usize,
    /// Blend weight × δ / δ_k: what the row's depression is multiplied by.
    amplitude: f64,
    /// Sample index per metre of radius at the drawn depth: (δ_k / δ)^p / Δ.
    index_per_m: f64,
    /// Beyond this radius the row is 0.
    reach_m: f64,
}

impl SurfaceTerm {
    const NONE: SurfaceTerm = SurfaceTerm {
        row: 0,
        amplitude: 0.0,
        index_per_m: 0.0,
        reach_m: 0.0,
    };
}

/// A [`SurfaceFamily`] at one depth, prepared once per frame and evaluated per vertex.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceProfile<'a> {
    family: &'a SurfaceFamily,
    tool: ToolShape,
    depth_m: f64,
    terms: [SurfaceTerm; 2],
    /// Inside this radius the tool lies below the undeformed surface, and the drawn surface
    /// never above the tool.
    footprint_m: f64,
    reach_m: f64,
}

impl SurfaceProfile<'_> {
    /// The sanitised indentation δ.
    pub fn depth_m(&self) -> f64 {
        self.depth_m
    }

    /// No vertex at or beyond this radius moves.
    pub fn reach_m(&self) -> f64 {
        self.reach_m
    }

    /// Inside this radius the drawn surface is held at or below the tool's.
    pub fn footprint_m(&self) -> f64 {
        self.footprint_m
    }

    /// The depression z(r), 0 ≤ z ≤ δ, at undeformed radial distance `r_m` from the contact
    /// axis (proto/WIRE.md, `fem`, step 3): the rows' blend, never above the tool where the
    /// point is drawn (at r + u(r)).
    pub fn depression_m(&self, r_m: f64) -> f64 {
        self.displacement_m(r_m).0
    }

    /// The outward radial displacement u(r) of the surface point at undeformed radius `r_m`
    /// (negative: towards the axis; 0 for a family without sideways motion).
    pub fn radial_displacement_m(&self, r_m: f64) -> f64 {
        self.displacement_m(r_m).1
    }

    /// (z(r), u(r)) of step 3.
    pub fn displacement_m(&self, r_m: f64) -> (f64, f64) {
        if self.depth_m == 0.0 {
            return (0.0, 0.0);
        }
        let r = sanitise(r_m);
        let (mut z, mut u) = (0.0, 0.0);
        for term in &self.terms {
            if term.amplitude == 0.0 {
                continue;
            }
            let row = &self.family.rows[term.row];
            let samples = &row.depression_m;
            let x = r * term.index_per_m;
            // Past the last sample (which is 0) the row is 0. x is finite: r is sanitised and
            // the scale is finite for a depth > 0.
            if x >= (samples.len() - 1) as f64 {
                continue;
            }
            let j = x.floor();
            let f = x - j;
            let j = j as usize;
            z += term.amplitude * (samples[j] + f * (samples[j + 1] - samples[j]));
            let radial = &row.radial_displacement_m;
            if !radial.is_empty() {
                u += term.amplitude * (radial[j] + f * (radial[j + 1] - radial[j]));
            }
        }
        // Between the FEM's nodes the rows are straight chords, which under the curved tool
        // would let the tool poke through the drawn surface; the tool's own surface bounds it,
        // where the point is drawn.
        let drawn_r = (r + u).max(0.0);
        if drawn_r < self.footprint_m {
            z = z.max(self.depth_m - tool_height_m(&self.tool, drawn_r));
        }
        (z.clamp(0.0, self.depth_m), u)
    }
}

/// Intervals of a [`SurfaceTable`]: the `fem` profile is sampled at 4097 radii from the axis to
/// its reach. Linear interpolation between the samples misses only the rows' kinks between two
/// samples, by at most a quarter of the sample spacing times the slope's jump: within 2 µm of
/// the profile for the repository's tables (depression and sideways motion: 1.04 µm and
/// 0.90 µm for the sphere's, 1.61 µm for the cone's, whose sideways motion turns sharply next
/// to the apex; over δ = 0.1 … 10.5 mm), so the drawn surface's error against the FEM surface
/// changes by no more than that.
pub const SURFACE_TABLE_INTERVALS: usize = 4096;

/// The `fem` profile as the viewer draws it on a render mesh: sampled once per frame at
/// [`SURFACE_TABLE_INTERVALS`] + 1 evenly spaced radii from the axis to the reach, then read
/// by linear interpolation for every vertex (web/src/deformation.js, `surfaceTable`). The
/// exact profile blends two rows and bounds them by the tool at each radius; a vertex of a
/// 100 000-vertex mesh cannot afford that, a lookup it can.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceTable {
    reach_m: f64,
    /// Samples per metre of radius, N / reach (0 when nothing is drawn).
    samples_per_m: f64,
    /// z(k · reach / N) for k = 0 … N; the last is 0, the profile's value at its reach.
    depression_m: Vec<f64>,
    /// u(k · reach / N) for k = 0 … N, the same way.
    radial_displacement_m: Vec<f64>,
}

impl SurfaceProfile<'_> {
    /// This profile sampled for drawing ([`SurfaceTable`]).
    pub fn table(&self) -> SurfaceTable {
        let n = SURFACE_TABLE_INTERVALS;
        let reach_m = if self.depth_m == 0.0 {
            0.0
        } else {
            self.reach_m
        };
        if reach_m == 0.0 {
            return SurfaceTable {
                reach_m: 0.0,
                samples_per_m: 0.0,
                depression_m: vec![0.0; n + 1],
                radial_displacement_m: vec![0.0; n + 1],
            };
        }
        let step_m = reach_m / n as f64;
        let (mut depression_m, mut radial_displacement_m): (Vec<f64>, Vec<f64>) = (0..n)
            .map(|k| self.displacement_m(k as f64 * step_m))
            .unzip();
        depression_m.push(0.0);
        radial_displacement_m.push(0.0);
        SurfaceTable {
            reach_m,
            samples_per_m: n as f64 / reach_m,
            depression_m,
            radial_displacement_m,
        }
    }
}

impl SurfaceTable {
    /// No vertex at or beyond this radius moves.
    pub fn reach_m(&self) -> f64 {
        self.reach_m
    }

    /// The drawn depression at radial distance `r_m` from the contact axis: linear between the
    /// samples, 0 at and beyond the reach; `r_m` sanitised as for the profile (NaN, negative
    /// and infinite radii are the axis).
    pub fn depression_m(&self, r_m: f64) -> f64 {
        Self::lookup(&self.depression_m, self.reach_m, self.samples_per_m, r_m)
    }

    /// The drawn outward radial displacement at radial distance `r_m`, read the same way.
    pub fn radial_displacement_m(&self, r_m: f64) -> f64 {
        Self::lookup(
            &self.radial_displacement_m,
            self.reach_m,
            self.samples_per_m,
            r_m,
        )
    }

    fn lookup(samples: &[f64], reach_m: f64, samples_per_m: f64, r_m: f64) -> f64 {
        let r = sanitise(r_m);
        if r >= reach_m {
            return 0.0;
        }
        let x = r * samples_per_m;
        // x < N in exact arithmetic; the last interval also takes a product that rounds up to N.
        let j = x.floor().min((SURFACE_TABLE_INTERVALS - 1) as f64);
        let f = x - j;
        let j = j as usize;
        samples[j] + f * (samples[j + 1] - samples[j])
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use crate::deformation::surface_profile_vectors;
    use crate::deformation::test_tools::*;
    use proptest::prelude::*;

    /// A slender cone whose flank (slope cot 0.1 ≈ 10) is steeper than any row of
    /// `similar_family`, so that it never bounds them.
    fn slender() -> ToolShape {
        ToolShape::cone(0.1, 10.0 * MM).unwrap()
    }

    /// A family whose rows are exactly self-similar: z/δ = g(r / √δ) with g a cone-like ramp.
    fn similar_family() -> SurfaceFamily {
        let step = 0.5 * MM;
        let rows = [1.0 * MM, 4.0 * MM]
            .iter()
            .map(|&d| {
                // g falls from 1 at the axis to 0 at r = 10 mm × √(δ / 1 mm).
                let r_end = 10.0 * MM * (d / MM).sqrt();
                let n = (r_end / step).round() as usize;
                SurfaceRow::new(
                    d,
                    (0..=n).map(|k| d * (1.0 - k as f64 / n as f64)).collect(),
                )
            })
            .collect();
        SurfaceFamily::new(0.5, step, rows).unwrap()
    }

    #[test]
    fn fem_profile_reproduces_its_rows_at_their_depths() {
        let f = similar_family();
        for row in f.rows() {
            let p = f.at_depth(&slender(), row.depth_m);
            for (k, &z) in row.depression_m.iter().enumerate() {
                let r = k as f64 * f.radius_step_m();
                assert!(
                    (p.depression_m(r) - z).abs() < 1e-15,
                    "row δ = {}, k = {k}",
                    row.depth_m
                );
            }
            // Halfway between samples: the linear interpolation.
            let r = 2.5 * f.radius_step_m();
            let expected = 0.5 * (row.depression_m[2] + row.depression_m[3]);
            assert!((p.depression_m(r) - expected).abs() < 1e-15);
            assert_eq!(
                p.reach_m(),
                (row.depression_m.len() - 1) as f64 * f.radius_step_m()
            );
        }
    }

    #[test]
    fn fem_profile_scales_like_the_elastic_contact_between_and_beyond_its_rows() {
        // Rows that are exactly self-similar are reproduced at every depth: the blend of two
        // rows each scaled to δ is the scaled shape itself.
        let f = similar_family();
        for d_mm in [0.25, 1.0, 2.0, 3.3, 4.0, 9.0] {
            let d = d_mm * MM;
            let p = f.at_depth(&slender(), d);
            let r_end = 10.0 * MM * d_mm.sqrt();
            assert!((p.reach_m() - r_end).abs() < 1e-12, "δ = {d_mm} mm");
            for k in 0..=40 {
                let r = r_end * k as f64 / 40.0;
                let expected = d * (1.0 - r / r_end);
                assert!(
                    (p.depression_m(r) - expected).abs() < 1e-12,
                    "δ = {d_mm} mm, r = {r}: {} vs {expected}",
                    p.depression_m(r)
                );
            }
            assert_eq!(p.depression_m(r_end * 1.01), 0.0);
        }
    }

    #[test]
    fn fem_profile_draws_nothing_for_no_depth_and_treats_bad_radii_as_the_axis() {
        let f = similar_family();
        for d in [0.0, -MM, f64::NAN, f64::INFINITY] {
            let p = f.at_depth(&slender(), d);
            assert_eq!(p.depression_m(0.0), 0.0);
            assert_eq!(p.reach_m(), 0.0);
        }
        let invalid = ToolShape::Sphere { radius_m: f64::NAN };
        assert_eq!(f.at_depth(&invalid, 2.0 * MM).depression_m(0.0), 0.0);
        let p = f.at_depth(&slender(), 2.0 * MM);
        assert_eq!(p.depression_m(f64::NAN), p.depression_m(0.0));
        assert_eq!(p.depression_m(-1.0), p.depression_m(0.0));
        assert_eq!(p.depression_m(f64::INFINITY), p.depression_m(0.0));
        assert_eq!(p.depression_m(p.reach_m()), 0.0);
    }

    #[test]
    fn the_fem_profile_never_lies_above_the_tool() {
        // One row that is a single chord from δ at the axis to 0 at 20 mm: under a 10 mm sphere
        // the chord lies above the ball near the axis, and the ball's surface is drawn there.
        let f = SurfaceFamily::new(
            0.5,
            20.0 * MM,
            vec![SurfaceRow::new(4.0 * MM, vec![4.0 * MM, 0.0])],
        )
        .unwrap();
        let ball = sphere();
        let p = f.at_depth(&ball, 4.0 * MM);
        assert!((p.footprint_m() - (4.0 * MM * 16.0 * MM).sqrt()).abs() < 1e-15);
        for k in 0..=100 {
            let r = 20.0 * MM * k as f64 / 100.0;
            let chord = 4.0 * MM * (1.0 - r / (20.0 * MM));
            let tool = 4.0 * MM - tool_height_m(&ball, r);
            let z = p.depression_m(r);
            let expected = chord.max(if r < p.footprint_m() { tool } else { 0.0 });
            assert!((z - expected).abs() < 1e-15, "r = {r}: {z} vs {expected}");
            assert!(z >= tool - 1e-18);
        }
        assert!(p.depression_m(2.0 * MM) > 4.0 * MM * 0.9);
    }

    #[test]
    fn a_surface_family_is_refused_with_the_field_and_value() {
        let row = |d: f64, z: Vec<f64>| SurfaceRow::new(d, z);
        let ok = || {
            vec![
                row(MM, vec![MM, 0.0]),
                row(2.0 * MM, vec![2.0 * MM, MM, 0.0]),
            ]
        };
        assert!(SurfaceFamily::new(0.5, MM, ok()).is_ok());
        let err = |e: f64, s: f64, rows| SurfaceFamily::new(e, s, rows).unwrap_err().to_string();
        assert!(err(0.0, MM, ok()).contains("radius_exponent"));
        assert!(err(0.5, f64::NAN, ok()).contains("radius_step_m"));
        assert!(err(0.5, MM, vec![]).contains("rows must not be empty"));
        let e = err(
            0.5,
            MM,
            vec![row(MM, vec![MM, 0.0]), row(MM, vec![MM, 0.0])],
        );
        assert!(e.contains("rows[1].depth_m"), "{e}");
        let e = err(0.5, MM, vec![row(MM, vec![MM])]);
        assert!(e.contains("at least 2"), "{e}");
        let e = err(0.5, MM, vec![row(MM, vec![MM, -1.0, 0.0])]);
        assert!(
            e.contains("rows[0].depression_m[1]") && e.contains("-1"),
            "{e}"
        );
        let e = err(0.5, MM, vec![row(MM, vec![MM, 0.5 * MM])]);
        assert!(e.contains("must end at 0"), "{e}");
        // The same checks on the way in from JSON.
        let text = r#"{"radius_exponent": 0.5, "radius_step_m": 0.001, "rows": [{"depth_m": 0.001, "depression_m": [0.001, 0.0005]}]}"#;
        let e = serde_json::from_str::<SurfaceFamily>(text)
            .unwrap_err()
            .to_string();
        assert!(e.contains("must end at 0"), "{e}");
    }

    /// One row 4 mm deep, 2 mm apart, moved sideways by `u`.
    fn sideways(u: Vec<f64>) -> Result<SurfaceFamily, SurfaceFamilyError> {
        let mut row = SurfaceRow::new(4.0 * MM, vec![4.0 * MM, 3.0 * MM, 1.0 * MM, 0.0]);
        row.radial_displacement_m = u;
        SurfaceFamily::new(0.5, 2.0 * MM, vec![row])
    }

    #[test]
    fn sideways_motion_is_refused_with_the_field_and_value() {
        assert!(sideways(vec![]).is_ok());
        assert!(sideways(vec![0.0, -0.5 * MM, 0.3 * MM, 0.0]).is_ok());
        let err = |u: Vec<f64>| sideways(u).unwrap_err().to_string();
        let e = err(vec![0.0, 0.0]);
        assert!(
            e.contains("rows[0].radial_displacement_m") && e.contains("(4), got 2"),
            "{e}"
        );
        let e = err(vec![0.0, f64::NAN, 0.0, 0.0]);
        assert!(
            e.contains("radial_displacement_m[1]") && e.contains("NaN"),
            "{e}"
        );
        let e = err(vec![0.1 * MM, 0.0, 0.0, 0.0]);
        assert!(e.contains("radial_displacement_m[0] must be 0"), "{e}");
        let e = err(vec![0.0, 0.0, 0.0, 1e-6]);
        assert!(e.contains("radial_displacement_m[3] must be 0"), "{e}");
        // Sample 2 drawn at 4 − 2.5 = 1.5 mm, inside sample 1 at 2 mm: folded.
        let e = err(vec![0.0, 0.0, -2.5 * MM, 0.0]);
        assert!(
            e.contains("radial_displacement_m[2]") && e.contains("folds"),
            "{e}"
        );
        // A table without the field reads as no sideways motion and is written back without it.
        let text = r#"{"radius_exponent": 0.5, "radius_step_m": 0.001, "rows": [{"depth_m": 0.001, "depression_m": [0.001, 0.0]}]}"#;
        let f: SurfaceFamily = serde_json::from_str(text).unwrap();
        assert!(!f.has_radial_displacement());
        assert!(!serde_json::to_string(&f).unwrap().contains("radial"));
        let e = serde_json::from_str::<SurfaceFamily>(
            &text.replace("0.0]}", r#"0.0], "radial_displacement_m": [0.0]}"#),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("radial_displacement_m"), "{e}");
    }

    #[test]
    fn sideways_motion_is_drawn_from_its_row_and_the_tool_bounds_the_point_where_it_is_drawn() {
        let f = sideways(vec![0.0, -0.5 * MM, 0.3 * MM, 0.0]).unwrap();
        // A slender cone never bounds the rows: the row itself, both ways.
        let p = f.at_depth(&slender(), 4.0 * MM);
        for (r_mm, z_mm, u_mm) in [(0.0, 4.0, 0.0), (1.0, 3.5, -0.25), (3.0, 2.0, -0.1)] {
            let (z, u) = p.displacement_m(r_mm * MM);
            assert!((z - z_mm * MM).abs() < 1e-15, "z({r_mm} mm) = {z}");
            assert!((u - u_mm * MM).abs() < 1e-15, "u({r_mm} mm) = {u}");
        }
        // Twice as deep, the row scales: depression ×2, radius ×√2, sideways motion ×2.
        let p2 = f.at_depth(&slender(), 8.0 * MM);
        let r = 2.0 * MM * 2f64.sqrt();
        assert!((p2.radial_displacement_m(r) + MM).abs() < 1e-15);
        // A ball: the point of undeformed radius r is drawn at r + u, and held at or below the
        // ball there; without the sideways motion it would be held below the ball at r.
        let ball = sphere();
        let p = f.at_depth(&ball, 4.0 * MM);
        let r = 2.0 * MM;
        let (z, u) = p.displacement_m(r);
        assert_eq!(u, -0.5 * MM);
        let at_drawn = 4.0 * MM - tool_height_m(&ball, r + u);
        assert!(
            (z - at_drawn.max(3.0 * MM)).abs() < 1e-15,
            "{z} vs {at_drawn}"
        );
        assert!(z > 4.0 * MM - tool_height_m(&ball, r) + 1e-5);
        // The drawn table follows both to within its sampling.
        let table = p.table();
        for k in 0..=60 {
            let r = 6.0 * MM * k as f64 / 60.0;
            let (z, u) = p.displacement_m(r);
            assert!((table.depression_m(r) - z).abs() < 2e-6, "z at {r}");
            assert!(
                (table.radial_displacement_m(r) - u).abs() < 1e-6,
                "u at {r}"
            );
        }
        // A family without sideways motion draws none.
        let plain = similar_family();
        let p = plain.at_depth(&ball, 3.0 * MM);
        assert_eq!(p.radial_displacement_m(MM), 0.0);
        assert_eq!(p.table().radial_displacement_m(MM), 0.0);
    }

    #[test]
    fn a_straight_profile_is_drawn_exactly_by_its_table() {
        // The rows of `similar_family` are straight ramps, which the table's chords reproduce.
        let f = similar_family();
        for d_mm in [0.5, 1.0, 2.5, 4.0, 6.0] {
            let p = f.at_depth(&slender(), d_mm * MM);
            let table = p.table();
            assert_eq!(table.reach_m(), p.reach_m());
            for k in 0..=997 {
                let r = p.reach_m() * k as f64 / 997.0;
                let (drawn, exact) = (table.depression_m(r), p.depression_m(r));
                assert!((drawn - exact).abs() < 1e-15, "δ = {d_mm} mm, r = {r}");
            }
            assert_eq!(table.depression_m(p.reach_m()), 0.0);
            assert_eq!(table.depression_m(f64::NAN), table.depression_m(0.0));
        }
        let none = f.at_depth(&slender(), 0.0).table();
        assert_eq!((none.reach_m(), none.depression_m(0.0)), (0.0, 0.0));
    }

    /// The tool and the `fem` family of a calibration table of the repository.
    fn repository_family(text: &str) -> (ToolShape, SurfaceFamily) {
        let v: serde_json::Value = serde_json::from_str(text).unwrap();
        (
            serde_json::from_value(v["tool"].clone()).unwrap(),
            serde_json::from_value(v["surface"].clone()).unwrap(),
        )
    }

    #[test]
    fn the_drawn_table_is_within_two_micrometres_of_the_fem_profile_of_the_repositorys_tables() {
        // Between its samples the table misses the rows' kinks, so its error is largest at a
        // kink: every row sample's radius at the drawn depth is checked, with a uniform sweep.
        // Measured: 1.04 µm (sphere), 1.61 µm (cone); the bound is what
        // SURFACE_TABLE_INTERVALS promises, and what the drawn surface's error against the FEM
        // may grow by.
        for (name, text, measured_um) in [
            (
                "sphere",
                include_str!("../../../scenes/calibration/sphere10_50kpa.json"),
                1.04,
            ),
            (
                "cone",
                include_str!("../../../scenes/calibration/cone10_45_50kpa.json"),
                1.61,
            ),
        ] {
            let (tool, family) = repository_family(text);
            let mut worst: f64 = 0.0;
            let mut worst_radial: f64 = 0.0;
            for step in 2..=210 {
                let d = step as f64 * 0.05 * MM;
                let p = family.at_depth(&tool, d);
                let table = p.table();
                let mut radii: Vec<f64> =
                    (0..2000).map(|k| p.reach_m() * k as f64 / 2000.0).collect();
                for t in p.terms.iter().filter(|t| t.amplitude > 0.0) {
                    let samples = family.rows()[t.row].depression_m.len();
                    radii.extend((0..samples).map(|j| j as f64 / t.index_per_m));
                }
                for r in radii {
                    worst = worst.max((table.depression_m(r) - p.depression_m(r)).abs());
                    worst_radial = worst_radial
                        .max((table.radial_displacement_m(r) - p.radial_displacement_m(r)).abs());
                }
            }
            println!(
                "{name}: the table within {:.3} µm of the profile's depression, {:.3} µm of its sideways motion",
                worst / 1e-6,
                worst_radial / 1e-6
            );
            assert!(worst <= 2e-6, "{name}: {worst} m");
            assert!(worst_radial <= 2e-6, "{name}: {worst_radial} m sideways");
            assert!(
                worst > 0.5 * measured_um * 1e-6,
                "{name}: the sweep meets the kinks"
            );
        }
    }

    proptest! {
        #[test]
        fn fem_profile_is_bounded_and_continuous(d_mm in 0.0f64..9.9, r_mm in 0.0f64..60.0) {
            // Up to the tools' radius and height (10 mm): deeper, a buried tool's rim is a wall.
            let v = surface_profile_vectors();
            for (f, tool) in v.families.iter().zip([sphere(), cone(), sphere()]) {
                let z = |d: f64, r: f64| f.at_depth(&tool, d).depression_m(r);
                let (d, r) = (d_mm * MM, r_mm * MM);
                let here = z(d, r);
                prop_assert!(here.is_finite() && here >= 0.0 && here <= d);
                // Continuous in depth (across rows) and in radius (across samples and the reach).
                let h = 1e-10;
                prop_assert!((z(d + h, r) - here).abs() < 1e-6);
                prop_assert!((z(d, r + h) - here).abs() < 1e-6);
            }
        }
    }
}
