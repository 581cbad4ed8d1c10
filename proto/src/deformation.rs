//! The deformation profiles the viewer draws, exactly as proto/WIRE.md ("Deformation profile")
//! defines them. A scene chooses one ([`RenderProfile`]).
//!
//! `paper`, the paper's profile (§3.3), [`DeformationProfile`]: around the contact axis (the line
//! through the contact point along the outward normal), a render vertex at radial distance r is
//! moved along −n by the depression z(r):
//! - r < a: on the tool surface (the paper's region Π);
//! - a ≤ r < R_d: on the quadratic Bézier cross-section P0 = (a, z0), P1 = (r1, 0), P2 = (R_d, 0),
//!   where P1 is where the tool's tangent at P0 meets the undeformed surface (region Ū);
//! - r ≥ R_d: unchanged.
//!
//! `fem`, the FEM's own top surface, [`SurfaceFamily`]: the calibration tabulates the depression
//! of its block's surface against the radius at each depth of the table, and the viewer
//! interpolates between the two nearest depths after scaling each row to the depth drawn the
//! way the elastic contact itself scales (depression ∝ δ, radius ∝ the contact radius). The
//! paper's Bézier is too shallow everywhere outside the contact and drops the tail beyond R_d
//! (calibration report, "The drawn surface against the FEM surface"); this profile follows the
//! FEM surface at every depth it was calibrated for.
//!
//! The viewer draws the `fem` profile on its render mesh from a [`SurfaceTable`], the profile
//! sampled once per frame, within 1.1 µm of it.
//!
//! The viewer (web/src) implements the same functions in JavaScript; the shared vectors in
//! `proto/vectors/deformation.json` and `proto/vectors/surface_profile.json`, written from this
//! code, keep the two identical. Every degenerate input (zero depth, R_d inside the contact, a
//! contact wider than the tool, a vertical or horizontal tool tangent, NaN) has a defined,
//! continuous answer.

use serde::{Deserialize, Serialize};

use crate::tool::ToolShape;

/// Non-finite or negative inputs count as zero (proto/WIRE.md, "Deformation profile", step 1).
#[inline]
fn sanitise(x: f64) -> f64 {
    if x.is_finite() && x > 0.0 { x } else { 0.0 }
}

/// The tool's profile height above its tip at radius r: the sphere's cap R − √(R² − r²) (r ≤ R),
/// the cone's flank r cot α.
#[inline]
fn tool_height_m(tool: &ToolShape, r_m: f64) -> f64 {
    match *tool {
        ToolShape::Sphere { radius_m } => {
            let r = r_m.min(radius_m);
            radius_m - (radius_m * radius_m - r * r).max(0.0).sqrt()
        }
        ToolShape::Cone { half_angle_rad, .. } => r_m / half_angle_rad.tan(),
    }
}

/// The cross-section of one contact, precomputed once per frame and then evaluated per vertex.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DeformationProfile {
    tool: ToolShape,
    /// Sanitised indentation δ.
    depth_m: f64,
    /// Effective contact radius: a clamped to the tool's lateral extent.
    contact_radius_eff_m: f64,
    /// Depression at the contact edge (P0's height).
    edge_depression_m: f64,
    /// P1's radius, in [a_eff, R_d_eff].
    control_radius_m: f64,
    /// Effective deformed radius: at least a_eff + z0, so the Bézier region is never inverted.
    deformed_radius_eff_m: f64,
}

impl DeformationProfile {
    /// Builds the profile from the tool, depth δ, contact radius a (from the contact law) and
    /// deformed radius R_d (from the calibration table), following proto/WIRE.md steps 1–4.
    ///
    /// A tool that fails [`ToolShape::validate`] deforms nothing (depth treated as 0), so no
    /// input can produce NaN.
    pub fn new(
        tool: &ToolShape,
        depth_m: f64,
        contact_radius_m: f64,
        deformed_radius_m: f64,
    ) -> Self {
        let valid_tool = tool.validate().is_ok();
        let depth_m = if valid_tool { sanitise(depth_m) } else { 0.0 };
        let a = sanitise(contact_radius_m);
        let rd = sanitise(deformed_radius_m);
        if depth_m == 0.0 {
            return Self {
                tool: *tool,
                depth_m: 0.0,
                contact_radius_eff_m: 0.0,
                edge_depression_m: 0.0,
                control_radius_m: 0.0,
                deformed_radius_eff_m: 0.0,
            };
        }
        let a_eff = a.min(tool.radius_m());
        let z0 = (depth_m - tool_height_m(tool, a_eff)).max(0.0);
        let rd_eff = rd.max(a_eff + z0);
        // Tool slope at the contact edge.
        let slope = match *tool {
            ToolShape::Sphere { radius_m } => {
                let under = radius_m * radius_m - a_eff * a_eff;
                if under > 0.0 {
                    a_eff / under.sqrt()
                } else {
                    f64::INFINITY
                }
            }
            ToolShape::Cone { half_angle_rad, .. } => 1.0 / half_angle_rad.tan(),
        };
        let r1 = if slope == f64::INFINITY || z0 == 0.0 {
            a_eff
        } else if slope == 0.0 {
            rd_eff
        } else {
            a_eff + z0 / slope
        };
        let r1 = r1.clamp(a_eff, rd_eff);
        Self {
            tool: *tool,
            depth_m,
            contact_radius_eff_m: a_eff,
            edge_depression_m: z0,
            control_radius_m: if r1.is_finite() { r1 } else { a_eff },
            deformed_radius_eff_m: rd_eff,
        }
    }

    /// The depression z(r) ≥ 0 at radial distance `r_m` from the contact axis (proto/WIRE.md,
    /// "Deformation profile", step 5).
    pub fn depression_m(&self, r_m: f64) -> f64 {
        let r = sanitise(r_m);
        let a = self.contact_radius_eff_m;
        let rd = self.deformed_radius_eff_m;
        if self.depth_m == 0.0 || r >= rd {
            return 0.0;
        }
        if r < a {
            return (self.depth_m - tool_height_m(&self.tool, r)).max(0.0);
        }
        // Invert the Bézier's radial coordinate r(t) = (1−t)² a + 2t(1−t) r1 + t² R_d for t.
        let r1 = self.control_radius_m;
        let qa = a - 2.0 * r1 + rd;
        let qb = 2.0 * (r1 - a);
        let qc = a - r;
        let root = (qb * qb - 4.0 * qa * qc).max(0.0).sqrt();
        let t = if qb + root > 0.0 {
            -2.0 * qc / (qb + root)
        } else {
            (r - a) / (rd - a)
        };
        let t = t.clamp(0.0, 1.0);
        (1.0 - t) * (1.0 - t) * self.edge_depression_m
    }

    /// The sanitised indentation δ.
    pub fn depth_m(&self) -> f64 {
        self.depth_m
    }

    /// a_eff: the contact radius clamped to the tool's lateral extent.
    pub fn contact_radius_eff_m(&self) -> f64 {
        self.contact_radius_eff_m
    }

    /// z0: the depression at the contact edge.
    pub fn edge_depression_m(&self) -> f64 {
        self.edge_depression_m
    }

    /// r1: the radius of the middle control point P1.
    pub fn control_radius_m(&self) -> f64 {
        self.control_radius_m
    }

    /// R_d_eff: no vertex at or beyond this radius moves.
    pub fn deformed_radius_eff_m(&self) -> f64 {
        self.deformed_radius_eff_m
    }
}

/// One-shot form of [`DeformationProfile::depression_m`].
pub fn depression_m(
    tool: &ToolShape,
    depth_m: f64,
    contact_radius_m: f64,
    deformed_radius_m: f64,
    r_m: f64,
) -> f64 {
    DeformationProfile::new(tool, depth_m, contact_radius_m, deformed_radius_m).depression_m(r_m)
}

/// Which cross-section the viewer draws: a scene's `[render] profile`, carried to the viewer by
/// the `scene` message's `render_profile` (proto/WIRE.md). The profile changes only what is
/// drawn, never the force.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RenderProfile {
    /// The paper's Bézier (§3.3), [`DeformationProfile`]. The default for a message or a
    /// recording that does not name one: every viewer before the choice existed drew it.
    #[default]
    Paper,
    /// The FEM's top surface as the calibration tabulated it ([`SurfaceFamily`], carried in the
    /// scene's calibration table).
    Fem,
}

impl RenderProfile {
    /// The name a scene file and the wire use.
    pub fn as_str(self) -> &'static str {
        match self {
            RenderProfile::Paper => "paper",
            RenderProfile::Fem => "fem",
        }
    }
}

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
}

/// One depth of a [`SurfaceFamily`]: the surface's depression at the radii 0, Δ, 2Δ, … from the
/// contact axis (Δ the family's `radius_step_m`), the last sample 0.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SurfaceRow {
    pub depth_m: f64,
    pub depression_m: Vec<f64>,
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

    /// The depression z(r), 0 ≤ z ≤ δ, at radial distance `r_m` from the contact axis
    /// (proto/WIRE.md, `fem`, step 3): the rows' blend, never above the tool.
    pub fn depression_m(&self, r_m: f64) -> f64 {
        if self.depth_m == 0.0 {
            return 0.0;
        }
        let r = sanitise(r_m);
        let mut z = 0.0;
        for term in &self.terms {
            if term.amplitude == 0.0 {
                continue;
            }
            let samples = &self.family.rows[term.row].depression_m;
            let u = r * term.index_per_m;
            // Past the last sample (which is 0) the row is 0. u is finite: r is sanitised and
            // the scale is finite for a depth > 0.
            if u >= (samples.len() - 1) as f64 {
                continue;
            }
            let j = u.floor();
            let f = u - j;
            let j = j as usize;
            z += term.amplitude * (samples[j] + f * (samples[j + 1] - samples[j]));
        }
        // Between the FEM's nodes the rows are straight chords, which under the curved tool
        // would let the tool poke through the drawn surface; the tool's own surface bounds it.
        if r < self.footprint_m {
            z = z.max(self.depth_m - tool_height_m(&self.tool, r));
        }
        z.clamp(0.0, self.depth_m)
    }
}

/// Intervals of a [`SurfaceTable`]: the `fem` profile is sampled at 4097 radii from the axis to
/// its reach. Linear interpolation between the samples misses only the rows' kinks between two
/// samples, by at most a quarter of the sample spacing times the slope's jump: within 1.1 µm of
/// the profile for the repository's tables (1.04 µm for the sphere's, 0.87 µm for the cone's,
/// over δ = 0.1 … 10.5 mm), so the drawn surface's error against the FEM surface changes by
/// no more than that.
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
            };
        }
        let step_m = reach_m / n as f64;
        let mut depression_m: Vec<f64> = (0..n)
            .map(|k| self.depression_m(k as f64 * step_m))
            .collect();
        depression_m.push(0.0);
        SurfaceTable {
            reach_m,
            samples_per_m: n as f64 / reach_m,
            depression_m,
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
        let r = sanitise(r_m);
        if r >= self.reach_m {
            return 0.0;
        }
        let u = r * self.samples_per_m;
        // u < N in exact arithmetic; the last interval also takes a product that rounds up to N.
        let j = u.floor().min((SURFACE_TABLE_INTERVALS - 1) as f64);
        let f = u - j;
        let j = j as usize;
        let z = &self.depression_m;
        z[j] + f * (z[j + 1] - z[j])
    }
}

/// One entry of `proto/vectors/deformation.json`: inputs and the expected depression.
///
/// JSON has no NaN or infinity, so non-finite inputs are written as the strings `"NaN"`,
/// `"Infinity"` and `"-Infinity"` (the spellings of JavaScript's `Number()`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DeformationVector {
    pub tool: ToolShape,
    #[serde(with = "number_or_name")]
    pub depth_m: f64,
    #[serde(with = "number_or_name")]
    pub contact_radius_m: f64,
    #[serde(with = "number_or_name")]
    pub deformed_radius_m: f64,
    #[serde(with = "number_or_name")]
    pub r_m: f64,
    pub depression_m: f64,
}

/// A finite `f64` as a JSON number, a non-finite one as its name.
mod number_or_name {
    use serde::de::Error;
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
        if x.is_finite() {
            s.serialize_f64(*x)
        } else if x.is_nan() {
            s.serialize_str("NaN")
        } else if *x > 0.0 {
            s.serialize_str("Infinity")
        } else {
            s.serialize_str("-Infinity")
        }
    }

    #[derive(Deserialize)]
    #[serde(untagged)]
    enum NumberOrName {
        Number(f64),
        Name(String),
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        match NumberOrName::deserialize(d)? {
            NumberOrName::Number(x) => Ok(x),
            NumberOrName::Name(name) => match name.as_str() {
                "NaN" => Ok(f64::NAN),
                "Infinity" => Ok(f64::INFINITY),
                "-Infinity" => Ok(f64::NEG_INFINITY),
                other => Err(D::Error::custom(format_args!(
                    "expected a number, \"NaN\", \"Infinity\" or \"-Infinity\", got {other:?}"
                ))),
            },
        }
    }
}

/// The shared deformation vectors: normal contacts of a sphere and of cones (45° and 30°) swept
/// across every region, and each degenerate case of proto/WIRE.md (zero and negative depth, R_d
/// inside the contact, contact wider than the tool, zero contact radius, negative radius).
pub fn deformation_vectors() -> Vec<DeformationVector> {
    const MM: f64 = 1e-3;
    let sphere = ToolShape::Sphere {
        radius_m: 10.0 * MM,
    };
    let cone45 = ToolShape::Cone {
        half_angle_rad: std::f64::consts::FRAC_PI_4,
        radius_m: 10.0 * MM,
    };
    let cone30 = ToolShape::Cone {
        half_angle_rad: std::f64::consts::FRAC_PI_6,
        radius_m: 5.0 * MM,
    };
    let law_a = |tool: &ToolShape, d: f64| match *tool {
        ToolShape::Sphere { radius_m } => (radius_m * d).sqrt(),
        ToolShape::Cone { half_angle_rad, .. } => {
            2.0 * d * half_angle_rad.tan() / std::f64::consts::PI
        }
    };
    // (tool, δ, a, R_d): a from the contact law unless the case is about a degenerate a.
    let mut cases: Vec<(ToolShape, f64, f64, f64)> = Vec::new();
    for tool in [sphere, cone45, cone30] {
        for (d_mm, rd_mm) in [(0.5, 3.0), (2.0, 12.0), (4.0, 25.0), (8.0, 45.0)] {
            let d = d_mm * MM;
            cases.push((tool, d, law_a(&tool, d), rd_mm * MM));
        }
    }
    let d = 4.0 * MM;
    // R_d inside the contact: lifted to a_eff + z0.
    cases.push((sphere, d, law_a(&sphere, d), 1.0 * MM));
    cases.push((cone45, d, law_a(&cone45, d), 0.0));
    // Contact wider than the tool (sphere δ > R, cone a > base radius).
    cases.push((sphere, 15.0 * MM, law_a(&sphere, 15.0 * MM), 60.0 * MM));
    cases.push((cone30, 20.0 * MM, law_a(&cone30, 20.0 * MM), 40.0 * MM));
    // Zero contact radius: horizontal tangent, P1 at R_d.
    cases.push((sphere, 1.0 * MM, 0.0, 10.0 * MM));
    // No contact, negative inputs (treated as 0).
    cases.push((sphere, 0.0, 0.0, 20.0 * MM));
    cases.push((sphere, -MM, 0.002, 20.0 * MM));
    cases.push((cone45, 3.0 * MM, -0.001, -0.01));
    // Non-finite inputs: each treated as 0 (a NaN or infinite depth deforms nothing).
    cases.push((sphere, f64::NAN, 0.002, 20.0 * MM));
    cases.push((sphere, f64::INFINITY, 0.002, 20.0 * MM));
    cases.push((sphere, 2.0 * MM, f64::NAN, 20.0 * MM));
    cases.push((cone45, 2.0 * MM, law_a(&cone45, 2.0 * MM), f64::INFINITY));

    let mut out = Vec::new();
    for (tool, depth_m, contact_radius_m, deformed_radius_m) in cases {
        let p = DeformationProfile::new(&tool, depth_m, contact_radius_m, deformed_radius_m);
        let a = p.contact_radius_eff_m();
        let rd = p.deformed_radius_eff_m();
        let mut radii = vec![0.0, 0.5 * a, a, a + 0.25 * (rd - a), 0.5 * (a + rd)];
        radii.extend([
            a + 0.9 * (rd - a),
            rd,
            1.5 * rd + MM,
            -MM,
            f64::NAN,
            f64::INFINITY,
        ]);
        for r_m in radii {
            out.push(DeformationVector {
                tool,
                depth_m,
                contact_radius_m,
                deformed_radius_m,
                r_m,
                depression_m: p.depression_m(r_m),
            });
        }
    }
    out
}

/// `proto/vectors/surface_profile.json`: families of the `fem` profile and what they draw.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SurfaceProfileVectors {
    pub families: Vec<SurfaceFamily>,
    pub cases: Vec<SurfaceProfileVector>,
}

/// One case of [`SurfaceProfileVectors`]: family `family` drawn at `depth_m`, evaluated at
/// `r_m`. Non-finite inputs are written as in [`DeformationVector`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SurfaceProfileVector {
    pub family: usize,
    pub tool: ToolShape,
    #[serde(with = "number_or_name")]
    pub depth_m: f64,
    #[serde(with = "number_or_name")]
    pub r_m: f64,
    pub depression_m: f64,
    pub reach_m: f64,
    /// What the viewer draws there: the profile's [`SurfaceTable`] at `r_m`.
    pub table_depression_m: f64,
}

/// The shared vectors of the `fem` profile: a sphere's family (radius ∝ √δ) and a cone's
/// (radius ∝ δ), each drawn below its first row, on a row, between rows, beyond its last row,
/// and at no, negative and non-finite depths, at radii across the profile, between two samples
/// of its [`SurfaceTable`], at its reach, past it, and negative or non-finite; each case holds
/// the profile's depression and its table's.
pub fn surface_profile_vectors() -> SurfaceProfileVectors {
    const MM: f64 = 1e-3;
    // Rows sampled from the half-space surface on a 50 mm base, cut where it falls below 10 µm.
    let family = |tool: ToolShape, exponent: f64, step_m: f64, depths_mm: &[f64]| {
        let rows = depths_mm
            .iter()
            .map(|&d_mm| {
                let d = d_mm * MM;
                let mut depression_m: Vec<f64> = (0..)
                    .map(|k| {
                        crate::calibration::half_space_on_base_depression_m(
                            &tool,
                            d,
                            k as f64 * step_m,
                            0.05,
                        )
                    })
                    .take_while(|&z| z >= 0.01 * MM)
                    .collect();
                depression_m.push(0.0);
                SurfaceRow {
                    depth_m: d,
                    depression_m,
                }
            })
            .collect();
        SurfaceFamily::new(exponent, step_m, rows)
    };
    let sphere = ToolShape::Sphere {
        radius_m: 10.0 * MM,
    };
    let cone = ToolShape::Cone {
        half_angle_rad: std::f64::consts::FRAC_PI_4,
        radius_m: 10.0 * MM,
    };
    let tools = [sphere, cone];
    let families: Vec<SurfaceFamily> = [
        family(sphere, 0.5, 0.5 * MM, &[1.0, 2.0, 4.0, 8.0]),
        family(cone, 1.0, 0.25 * MM, &[1.0, 3.0]),
    ]
    .into_iter()
    .filter_map(Result::ok)
    .collect();
    let mut cases = Vec::new();
    for (index, f) in families.iter().enumerate() {
        let tool = tools[index];
        let first = f.rows()[0].depth_m;
        let last = f.rows()[f.rows().len() - 1].depth_m;
        let depths = [
            0.3 * first,
            first,
            0.5 * (first + f.rows()[1].depth_m),
            f.rows()[1].depth_m,
            0.8 * last + 0.2 * f.rows()[f.rows().len() - 2].depth_m,
            last,
            1.5 * last,
            0.0,
            -MM,
            f64::NAN,
            f64::INFINITY,
        ];
        for depth_m in depths {
            let p = f.at_depth(&tool, depth_m);
            let table = p.table();
            let reach = p.reach_m();
            let mut radii: Vec<f64> = [0.0, 0.01, 0.05, 0.1, 0.2, 0.35, 0.5, 0.75, 0.99]
                .iter()
                .map(|x| x * reach)
                .collect();
            // Under the tool, where the chords between samples meet the tool's surface.
            radii.extend([0.3, 0.6, 0.95].map(|x| x * p.footprint_m()));
            // Between two samples of the table, where it interpolates.
            radii.extend([0.4, 0.7].map(|x| (x + 1000.0) * reach / SURFACE_TABLE_INTERVALS as f64));
            radii.extend([reach, 1.2 * reach + MM, -MM, f64::NAN, f64::INFINITY]);
            for r_m in radii {
                cases.push(SurfaceProfileVector {
                    family: index,
                    tool,
                    depth_m,
                    r_m,
                    depression_m: p.depression_m(r_m),
                    reach_m: reach,
                    table_depression_m: table.depression_m(r_m),
                });
            }
        }
    }
    SurfaceProfileVectors { families, cases }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use proptest::prelude::*;

    const MM: f64 = 1e-3;

    fn sphere() -> ToolShape {
        ToolShape::sphere(10.0 * MM).unwrap()
    }

    fn cone() -> ToolShape {
        ToolShape::cone(std::f64::consts::FRAC_PI_4, 10.0 * MM).unwrap()
    }

    fn sphere_a(d: f64) -> f64 {
        (10.0 * MM * d).sqrt()
    }

    fn cone_a(d: f64) -> f64 {
        2.0 * d / std::f64::consts::PI
    }

    #[test]
    fn centre_is_pressed_by_the_full_depth() {
        for d in [1e-9, 0.5 * MM, 3.0 * MM, 9.0 * MM] {
            let z = depression_m(&sphere(), d, sphere_a(d), 30.0 * MM, 0.0);
            assert!((z - d).abs() < 1e-15, "sphere δ = {d}");
            let z = depression_m(&cone(), d, cone_a(d), 30.0 * MM, 0.0);
            assert!((z - d).abs() < 1e-15, "cone δ = {d}");
        }
    }

    #[test]
    fn inside_the_contact_follows_the_tool_surface() {
        let d = 4.0 * MM;
        let a = sphere_a(d);
        for k in 0..20 {
            let r = a * k as f64 / 20.0;
            let expected = d - (10.0 * MM - ((10.0 * MM).powi(2) - r * r).sqrt());
            let z = depression_m(&sphere(), d, a, 30.0 * MM, r);
            assert!((z - expected).abs() < 1e-15);
        }
        let a = cone_a(d);
        for k in 0..20 {
            let r = a * k as f64 / 20.0;
            let z = depression_m(&cone(), d, a, 30.0 * MM, r);
            assert!((z - (d - r)).abs() < 1e-15);
        }
    }

    #[test]
    fn zero_at_and_beyond_the_deformed_radius() {
        let d = 4.0 * MM;
        let p = DeformationProfile::new(&sphere(), d, sphere_a(d), 30.0 * MM);
        assert_eq!(p.deformed_radius_eff_m(), 30.0 * MM);
        for r in [30.0 * MM, 30.0001 * MM, 1.0] {
            assert_eq!(p.depression_m(r), 0.0);
        }
        assert!(p.depression_m(29.9 * MM) > 0.0);
    }

    #[test]
    fn bezier_region_matches_the_control_points() {
        // Sphere δ = 4 mm, R = 10 mm: a = √40 mm, z0 = δ − (R − √(R² − a²)).
        let d = 4.0 * MM;
        let a = sphere_a(d);
        let p = DeformationProfile::new(&sphere(), d, a, 30.0 * MM);
        let r_tool = 10.0 * MM;
        let z0 = d - (r_tool - (r_tool * r_tool - a * a).sqrt());
        assert!((p.edge_depression_m() - z0).abs() < 1e-15);
        let slope = a / (r_tool * r_tool - a * a).sqrt();
        assert!((p.control_radius_m() - (a + z0 / slope)).abs() < 1e-15);
        // Points on the curve: r(t), z(t) for sample t.
        let (r1, rd) = (p.control_radius_m(), 30.0 * MM);
        for k in 0..=10 {
            let t = k as f64 / 10.0;
            let r = (1.0 - t).powi(2) * a + 2.0 * t * (1.0 - t) * r1 + t * t * rd;
            let z = (1.0 - t).powi(2) * z0;
            assert!((p.depression_m(r) - z).abs() < 1e-12, "t = {t}");
        }
        // The curve leaves P0 along the tool's tangent: the one-sided slope at a matches.
        let h = 1e-9;
        let slope_out = (p.depression_m(a) - p.depression_m(a + h)) / h;
        assert!((slope_out / slope - 1.0).abs() < 1e-3);
    }

    #[test]
    fn deformed_radius_inside_the_contact_is_lifted() {
        // R_d ≤ a: R_d_eff = a_eff + z0, still continuous and zero beyond.
        let d = 4.0 * MM;
        let a = sphere_a(d);
        let p = DeformationProfile::new(&sphere(), d, a, 0.1 * a);
        assert!((p.deformed_radius_eff_m() - (a + p.edge_depression_m())).abs() < 1e-15);
        // The steepest slope here is 1 (z0 over r1 − a_eff, P1 clamped to R_d_eff).
        let step = p.deformed_radius_eff_m() * 1.1 / 1000.0;
        let mut prev = p.depression_m(0.0);
        for k in 1..=1000 {
            let r = step * k as f64;
            let z = p.depression_m(r);
            assert!(z <= prev + 1e-15, "monotone at r = {r}");
            assert!(prev - z <= 1.01 * step, "jump at r = {r}");
            prev = z;
        }
        assert_eq!(p.depression_m(p.deformed_radius_eff_m()), 0.0);
    }

    #[test]
    fn contact_wider_than_the_tool_is_clamped() {
        // Sphere: a ≥ R → a_eff = R, vertical tangent, r1 = a_eff.
        let d = 15.0 * MM;
        let p = DeformationProfile::new(&sphere(), d, sphere_a(d), 60.0 * MM);
        assert_eq!(p.contact_radius_eff_m(), 10.0 * MM);
        assert!((p.edge_depression_m() - 5.0 * MM).abs() < 1e-15);
        assert_eq!(p.control_radius_m(), 10.0 * MM);
        // Cone: a beyond the base radius is clamped to it.
        let d = 30.0 * MM;
        let p = DeformationProfile::new(&cone(), d, cone_a(d), 60.0 * MM);
        assert_eq!(p.contact_radius_eff_m(), 10.0 * MM);
        assert!((p.edge_depression_m() - 20.0 * MM).abs() < 1e-15);
    }

    #[test]
    fn degenerate_inputs_give_no_deformation() {
        for (d, a, rd, r) in [
            (0.0, 0.001, 0.02, 0.0),
            (-1.0, 0.001, 0.02, 0.0),
            (f64::NAN, 0.001, 0.02, 0.0),
            (f64::INFINITY, 0.001, 0.02, 0.0),
        ] {
            assert_eq!(depression_m(&sphere(), d, a, rd, r), 0.0);
        }
        // NaN radius behaves as r = 0.
        let d = 2.0 * MM;
        assert_eq!(
            depression_m(&sphere(), d, sphere_a(d), 0.02, f64::NAN),
            depression_m(&sphere(), d, sphere_a(d), 0.02, 0.0)
        );
        // Zero contact radius: tiny contact, horizontal slope, r1 = R_d.
        let p = DeformationProfile::new(&sphere(), d, 0.0, 0.02);
        assert_eq!(p.control_radius_m(), 0.02);
        assert_eq!(p.depression_m(0.0), d);
        // An invalid tool deforms nothing.
        let bad = ToolShape::Sphere { radius_m: -1.0 };
        assert_eq!(depression_m(&bad, d, 0.001, 0.02, 0.0), 0.0);
    }

    #[test]
    fn vectors_round_trip_with_non_finite_inputs_named() {
        let vectors = deformation_vectors();
        assert!(vectors.iter().any(|v| v.depth_m.is_nan()));
        assert!(vectors.iter().any(|v| v.r_m == f64::INFINITY));
        let text = serde_json::to_string(&vectors).unwrap();
        assert!(text.contains("\"NaN\"") && text.contains("\"Infinity\""));
        assert!(!text.contains("null"));
        let back: Vec<DeformationVector> = serde_json::from_str(&text).unwrap();
        for (a, b) in vectors.iter().zip(&back) {
            assert_eq!(a.depth_m.to_bits(), b.depth_m.to_bits());
            assert_eq!(a.r_m.to_bits(), b.r_m.to_bits());
            assert_eq!(a.depression_m, b.depression_m);
            assert!(a.depression_m.is_finite());
            // The expected value is what the profile computes from the decoded inputs.
            let z = depression_m(
                &b.tool,
                b.depth_m,
                b.contact_radius_m,
                b.deformed_radius_m,
                b.r_m,
            );
            assert_eq!(z, b.depression_m);
        }
    }

    /// Largest jump of z over a fine sweep of r, to check continuity in r.
    fn max_jump(p: &DeformationProfile, r_max: f64, n: usize) -> f64 {
        let mut prev = p.depression_m(0.0);
        let mut worst: f64 = 0.0;
        for k in 1..=n {
            let z = p.depression_m(r_max * k as f64 / n as f64);
            worst = worst.max((z - prev).abs());
            prev = z;
        }
        worst
    }

    proptest! {
        #[test]
        fn never_nan_and_bounded_for_any_input(
            d in prop_oneof![Just(f64::NAN), Just(f64::INFINITY), Just(-1.0), Just(0.0), -0.1f64..0.1],
            a in prop_oneof![Just(f64::NAN), Just(f64::INFINITY), Just(0.0), -0.1f64..0.1],
            rd in prop_oneof![Just(f64::NAN), Just(f64::INFINITY), Just(0.0), -0.1f64..0.5],
            r in prop_oneof![Just(f64::NAN), Just(f64::INFINITY), Just(0.0), -0.1f64..0.5],
            radius in prop_oneof![Just(f64::NAN), Just(0.0), 1e-4f64..0.05],
            alpha in prop_oneof![Just(f64::NAN), Just(0.0), Just(std::f64::consts::FRAC_PI_2), 0.01f64..1.56],
        ) {
            for tool in [ToolShape::Sphere { radius_m: radius }, ToolShape::Cone { half_angle_rad: alpha, radius_m: radius }] {
                let z = depression_m(&tool, d, a, rd, r);
                prop_assert!(z.is_finite());
                prop_assert!(z >= 0.0);
                let bound = if d.is_finite() && d > 0.0 { d } else { 0.0 };
                prop_assert!(z <= bound);
            }
        }

        #[test]
        fn continuous_in_r(
            d_mm in 0.01f64..15.0, rd_mm in 0.0f64..100.0, r_tool_mm in 1.0f64..20.0,
            alpha in 0.1f64..1.4, cone in any::<bool>(),
        ) {
            let d = d_mm * MM;
            let tool = if cone {
                ToolShape::cone(alpha, r_tool_mm * MM).unwrap()
            } else {
                ToolShape::sphere(r_tool_mm * MM).unwrap()
            };
            let a = crate_contact_radius(&tool, d);
            let p = DeformationProfile::new(&tool, d, a, rd_mm * MM);
            // With 20 000 samples, no step exceeds what the steepest slope allows: the slope is
            // bounded by the tool's slope at the contact edge and by the Bézier's end tangents.
            let r_max = p.deformed_radius_eff_m() * 1.2;
            let n = 20_000;
            let dr = r_max / n as f64;
            let slope_bound = p.edge_depression_m() / (p.control_radius_m() - p.contact_radius_eff_m()).max(1e-300);
            let tool_slope = match tool {
                ToolShape::Sphere { radius_m } => {
                    let a = p.contact_radius_eff_m();
                    let u = radius_m * radius_m - a * a;
                    if u > 0.0 { a / u.sqrt() } else { f64::INFINITY }
                }
                ToolShape::Cone { half_angle_rad, .. } => 1.0 / half_angle_rad.tan(),
            };
            let jump = max_jump(&p, r_max, n);
            // A vertical wall (infinite slope) is allowed only where the contact saturates the
            // tool; there z0 drops to 0 over the tool's own rim, still continuous in the limit.
            if tool_slope.is_finite() && slope_bound.is_finite() {
                let allowed = (2.0 * slope_bound.max(tool_slope)) * dr * 1.01 + 1e-12;
                prop_assert!(jump <= allowed, "jump {} > {}", jump, allowed);
            }
        }

        #[test]
        fn continuous_in_depth(
            d_mm in 0.0f64..15.0, r_mm in 0.0f64..60.0, cone in any::<bool>(),
        ) {
            let tool = if cone { self::cone() } else { sphere() };
            // R_d continuous in δ, as a calibration table's fit is.
            let rd = |d: f64| 0.003 + 5.0 * d;
            let z = |d: f64| depression_m(&tool, d, crate_contact_radius(&tool, d), rd(d), r_mm * MM);
            let d = d_mm * MM;
            let h = 1e-10;
            prop_assert!((z(d + h) - z(d)).abs() < 1e-5, "{} vs {}", z(d), z(d + h));
        }

        #[test]
        fn monotone_in_r(d_mm in 0.01f64..12.0, rd_mm in 0.0f64..90.0, cone in any::<bool>()) {
            let tool = if cone { self::cone() } else { sphere() };
            let d = d_mm * MM;
            let p = DeformationProfile::new(&tool, d, crate_contact_radius(&tool, d), rd_mm * MM);
            let mut prev = p.depression_m(0.0);
            for k in 1..=500 {
                let z = p.depression_m(p.deformed_radius_eff_m() * k as f64 / 450.0);
                prop_assert!(z <= prev + 1e-15);
                prev = z;
            }
        }
    }

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
                SurfaceRow {
                    depth_m: d,
                    depression_m: (0..=n).map(|k| d * (1.0 - k as f64 / n as f64)).collect(),
                }
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
            vec![SurfaceRow {
                depth_m: 4.0 * MM,
                depression_m: vec![4.0 * MM, 0.0],
            }],
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
        let row = |d: f64, z: Vec<f64>| SurfaceRow {
            depth_m: d,
            depression_m: z,
        };
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
    fn the_drawn_table_is_within_a_micrometre_of_the_fem_profile_of_the_repositorys_tables() {
        // Between its samples the table misses the rows' kinks, so its error is largest at a
        // kink: every row sample's radius at the drawn depth is checked, with a uniform sweep.
        // Measured: 1.04 µm (sphere), 0.87 µm (cone); the bound is what
        // SURFACE_TABLE_INTERVALS promises, and what the drawn surface's error against the FEM
        // may grow by.
        for (name, text, measured_um) in [
            (
                "sphere",
                include_str!("../../scenes/calibration/sphere10_50kpa.json"),
                1.04,
            ),
            (
                "cone",
                include_str!("../../scenes/calibration/cone10_45_50kpa.json"),
                0.87,
            ),
        ] {
            let (tool, family) = repository_family(text);
            let mut worst: f64 = 0.0;
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
                }
            }
            println!(
                "{name}: the table within {:.3} µm of the profile",
                worst / 1e-6
            );
            assert!(worst <= 1.1e-6, "{name}: {worst} m");
            assert!(
                worst > 0.5 * measured_um * 1e-6,
                "{name}: the sweep meets the kinks"
            );
        }
    }

    #[test]
    fn surface_vectors_round_trip_and_match_the_code() {
        let v = surface_profile_vectors();
        assert_eq!(v.families.len(), 2);
        assert!(v.cases.len() > 100);
        assert!(v.cases.iter().any(|c| c.depth_m.is_nan()));
        assert!(
            v.cases
                .iter()
                .any(|c| c.depression_m > 0.0 && c.family == 1)
        );
        let text = serde_json::to_string(&v).unwrap();
        let back: SurfaceProfileVectors = serde_json::from_str(&text).unwrap();
        assert_eq!(back.families, v.families);
        for c in &back.cases {
            let p = back.families[c.family].at_depth(&c.tool, c.depth_m);
            assert_eq!(p.depression_m(c.r_m), c.depression_m);
            assert_eq!(p.reach_m(), c.reach_m);
            assert_eq!(p.table().depression_m(c.r_m), c.table_depression_m);
        }
    }

    proptest! {
        #[test]
        fn fem_profile_is_bounded_and_continuous(d_mm in 0.0f64..9.9, r_mm in 0.0f64..60.0) {
            // Up to the tools' radius and height (10 mm): deeper, a buried tool's rim is a wall.
            let v = surface_profile_vectors();
            for (f, tool) in v.families.iter().zip([sphere(), cone()]) {
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

    /// The contact law's radius (duplicated from `softhaptic-device::law` only for these tests,
    /// since proto cannot depend on the device crate): √(Rδ) sphere, 2δ tanα/π cone.
    fn crate_contact_radius(tool: &ToolShape, d: f64) -> f64 {
        match *tool {
            ToolShape::Sphere { radius_m } => (radius_m * d).sqrt(),
            ToolShape::Cone { half_angle_rad, .. } => {
                2.0 * d * half_angle_rad.tan() / std::f64::consts::PI
            }
        }
    }
}
