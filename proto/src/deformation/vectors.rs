//! The shared test vectors of both profiles (`proto/vectors/deformation.json`,
//! `proto/vectors/surface_profile.json`), built from this code and read by the viewer's tests.

use serde::{Deserialize, Serialize};

use crate::tool::ToolShape;

use super::{
    DeformationProfile, SURFACE_TABLE_INTERVALS, SurfaceFamily, SurfaceRow,
    exact_sphere_contact_radius_m,
};

/// One entry of `proto/vectors/deformation.json`: inputs and the expected depression, and for a
/// sphere the exact sphere's contact radius at the entry's depth.
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
    /// Sphere tools only: [`exact_sphere_contact_radius_m`] of the tool's radius at `depth_m`,
    /// the contact radius a model with the exact sphere streams (always finite).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exact_sphere_contact_radius_m: Option<f64>,
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
/// inside the contact, contact wider than the tool, zero contact radius, negative radius); the
/// sphere also drawn with the exact sphere's contact radius from a micrometre to far past δ = R,
/// each sphere entry carrying that radius at its depth.
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
    // The exact sphere's contact radius, as a model with the exact sphere streams it: a
    // micrometre deep (Hertz's to 7 digits), at depth, at δ = R (0.83 R, where Hertz's reaches R
    // and the flank would vanish), past it, and where it is R to the last bit.
    for (d_mm, rd_mm) in [
        (1e-3, 0.5),
        (4.0, 25.0),
        (10.0, 31.0),
        (15.0, 60.0),
        (250.0, 300.0),
    ] {
        let d = d_mm * MM;
        let a = exact_sphere_contact_radius_m(sphere.radius_m(), d);
        cases.push((sphere, d, a, rd_mm * MM));
    }

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
                exact_sphere_contact_radius_m: match tool {
                    ToolShape::Sphere { radius_m } => {
                        Some(exact_sphere_contact_radius_m(radius_m, depth_m))
                    }
                    ToolShape::Cone { .. } => None,
                },
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
    /// The profile's outward radial displacement there (0 for a family without it).
    pub radial_displacement_m: f64,
    pub reach_m: f64,
    /// What the viewer draws there: the profile's [`SurfaceTable`](super::SurfaceTable) at `r_m`.
    pub table_depression_m: f64,
    pub table_radial_displacement_m: f64,
}

/// The shared vectors of the `fem` profile: a sphere's family (radius ∝ √δ), a cone's
/// (radius ∝ δ) and the sphere's again with sideways motion, each drawn below its first row, on a row, between rows, beyond its last row,
/// and at no, negative and non-finite depths, at radii across the profile, between two samples
/// of its [`SurfaceTable`](super::SurfaceTable), at its reach, past it, and negative or non-finite; each case holds
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
                SurfaceRow::new(d, depression_m)
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
    // The sphere's rows moved towards the axis most midway along each row, by up to 30% of
    // the depression there: 0 at the axis and at the end, and never folding.
    let with_sideways = |f: SurfaceFamily| {
        let rows = f
            .rows()
            .iter()
            .map(|row| {
                let n = row.depression_m.len() - 1;
                let mut row = row.clone();
                row.radial_displacement_m = (row.depression_m.iter().enumerate())
                    .map(|(j, z)| -0.3 * z * (4 * j * (n - j)) as f64 / (n * n) as f64)
                    .collect();
                row
            })
            .collect();
        SurfaceFamily::new(f.radius_exponent(), f.radius_step_m(), rows)
    };
    let tools = [sphere, cone, sphere];
    let families: Vec<SurfaceFamily> = [
        family(sphere, 0.5, 0.5 * MM, &[1.0, 2.0, 4.0, 8.0]),
        family(cone, 1.0, 0.25 * MM, &[1.0, 3.0]),
        family(sphere, 0.5, 0.5 * MM, &[1.0, 2.0, 4.0, 8.0]).and_then(with_sideways),
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
                    radial_displacement_m: p.radial_displacement_m(r_m),
                    reach_m: reach,
                    table_depression_m: table.depression_m(r_m),
                    table_radial_displacement_m: table.radial_displacement_m(r_m),
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
    use crate::deformation::depression_m;

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
            let exact = match b.tool {
                ToolShape::Sphere { radius_m } => {
                    Some(exact_sphere_contact_radius_m(radius_m, b.depth_m))
                }
                ToolShape::Cone { .. } => None,
            };
            assert_eq!(exact, b.exact_sphere_contact_radius_m);
        }
        // The exact sphere's radius is drawn below δ = R, at it and past it, never as wide as the
        // tool before it saturates.
        let exact: Vec<(f64, f64)> = vectors
            .iter()
            .filter_map(|v| Some((v.depth_m, v.exact_sphere_contact_radius_m?)))
            .collect();
        assert!(
            exact
                .iter()
                .any(|&(d, a)| (d - 0.01).abs() < 1e-12 && a > 0.0083 && a < 0.0084)
        );
        assert!(
            exact
                .iter()
                .any(|&(d, a)| (d - 0.25).abs() < 1e-12 && a == 0.01)
        );
        assert!(exact.iter().any(|&(d, a)| d.is_nan() && a == 0.0));
    }

    #[test]
    fn surface_vectors_round_trip_and_match_the_code() {
        let v = surface_profile_vectors();
        assert_eq!(v.families.len(), 3);
        assert!(v.families[2].has_radial_displacement());
        assert!(
            v.cases
                .iter()
                .any(|c| c.family == 2 && c.radial_displacement_m < -0.1e-3)
        );
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
            assert_eq!(p.radial_displacement_m(c.r_m), c.radial_displacement_m);
            assert_eq!(
                p.table().radial_displacement_m(c.r_m),
                c.table_radial_displacement_m
            );
        }
    }
}
