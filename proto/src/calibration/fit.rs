//! The paper's fit of a calibration table's rows: a line below the breakpoint and a quadratic
//! beyond it, continuous where they meet (paper §3.3.2).

use serde::{Deserialize, Serialize};

use super::{CalibrationError, CalibrationRow};

/// The piecewise fit R_d(δ): `linear` (c0 + c1 δ) below `breakpoint_m`, `quadratic`
/// (c0 + c1 δ + c2 δ²) from it on, the quadratic constrained to meet the line at the breakpoint.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationFit {
    pub breakpoint_m: f64,
    pub linear: [f64; 2],
    pub quadratic: [f64; 3],
}

impl CalibrationFit {
    /// Least-squares fit of `rows` (assumed validated: finite, depth increasing).
    ///
    /// The line is fitted to the rows with `depth_m < breakpoint_m` (at least two are needed).
    /// The quadratic is written Q(δ) = L(b) + p (δ − b) + q (δ − b)², which meets the line L at
    /// the breakpoint b by construction, and p, q are fitted to the rows with `depth_m ≥ b`. With
    /// one such row the curvature q is taken as 0; with none the quadratic is the line itself.
    pub fn from_rows(rows: &[CalibrationRow], breakpoint_m: f64) -> Result<Self, CalibrationError> {
        if !(breakpoint_m.is_finite() && breakpoint_m > 0.0) {
            return Err(CalibrationError::Breakpoint(breakpoint_m));
        }
        let (below, beyond): (Vec<&CalibrationRow>, Vec<&CalibrationRow>) =
            rows.iter().partition(|r| r.depth_m < breakpoint_m);
        if below.len() < 2 {
            return Err(CalibrationError::TooFewLinearRows {
                breakpoint_m,
                found: below.len(),
            });
        }
        // Ordinary least squares for the line, centred on the mean depth for conditioning.
        let n = below.len() as f64;
        let mean_x = below.iter().map(|r| r.depth_m).sum::<f64>() / n;
        let mean_y = below.iter().map(|r| r.deformed_radius_m).sum::<f64>() / n;
        let sxx: f64 = below.iter().map(|r| (r.depth_m - mean_x).powi(2)).sum();
        let sxy: f64 = below
            .iter()
            .map(|r| (r.depth_m - mean_x) * (r.deformed_radius_m - mean_y))
            .sum();
        // Rows are strictly increasing in depth, so two of them give sxx > 0.
        let c1 = sxy / sxx;
        let c0 = mean_y - c1 * mean_x;
        let at_break = c0 + c1 * breakpoint_m;

        // Constrained quadratic in u = δ − b, target y − L(b).
        let (p, q) = match beyond.len() {
            0 => (c1, 0.0),
            1 => {
                let r = beyond[0];
                let u = r.depth_m - breakpoint_m;
                // A single row at the breakpoint itself says nothing about the slope.
                if u > 0.0 {
                    ((r.deformed_radius_m - at_break) / u, 0.0)
                } else {
                    (c1, 0.0)
                }
            }
            _ => {
                let (mut s_uu, mut s_uuu, mut s_uuuu, mut s_uy, mut s_uuy) =
                    (0.0, 0.0, 0.0, 0.0, 0.0);
                for r in &beyond {
                    let u = r.depth_m - breakpoint_m;
                    let y = r.deformed_radius_m - at_break;
                    s_uu += u * u;
                    s_uuu += u * u * u;
                    s_uuuu += u * u * u * u;
                    s_uy += u * y;
                    s_uuy += u * u * y;
                }
                let det = s_uu * s_uuuu - s_uuu * s_uuu;
                if det.abs() > f64::EPSILON * s_uu * s_uuuu && det != 0.0 {
                    (
                        (s_uy * s_uuuu - s_uuy * s_uuu) / det,
                        (s_uu * s_uuy - s_uuu * s_uy) / det,
                    )
                } else if s_uu > 0.0 {
                    (s_uy / s_uu, 0.0)
                } else {
                    (c1, 0.0)
                }
            }
        };
        // Expand Q(δ) = L(b) + p(δ − b) + q(δ − b)² into powers of δ.
        let b = breakpoint_m;
        let quadratic = [at_break - p * b + q * b * b, p - 2.0 * q * b, q];
        Ok(CalibrationFit {
            breakpoint_m,
            linear: [c0, c1],
            quadratic,
        })
    }

    /// R_d at depth `depth_m`, clamped ≥ 0. Non-finite or negative depths give 0.
    pub fn evaluate_m(&self, depth_m: f64) -> f64 {
        if !(depth_m.is_finite() && depth_m > 0.0) {
            return 0.0;
        }
        let d = depth_m;
        let r = if d < self.breakpoint_m {
            self.linear[0] + self.linear[1] * d
        } else {
            self.quadratic[0] + self.quadratic[1] * d + self.quadratic[2] * d * d
        };
        if r.is_finite() { r.max(0.0) } else { 0.0 }
    }

    pub(super) fn validate(&self) -> Result<(), CalibrationError> {
        if !(self.breakpoint_m.is_finite() && self.breakpoint_m > 0.0) {
            return Err(CalibrationError::Breakpoint(self.breakpoint_m));
        }
        for (field, values) in [
            ("linear", &self.linear[..]),
            ("quadratic", &self.quadratic[..]),
        ] {
            if let Some((index, &value)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
                return Err(CalibrationError::Coefficient {
                    field,
                    index,
                    value,
                });
            }
        }
        let b = self.breakpoint_m;
        let linear_m = self.linear[0] + self.linear[1] * b;
        let quadratic_m = self.quadratic[0] + self.quadratic[1] * b + self.quadratic[2] * b * b;
        // Relative to the size of the terms, so that tables written with short decimals pass.
        let scale = linear_m.abs().max(quadratic_m.abs()).max(1e-6);
        if (linear_m - quadratic_m).abs() > 1e-6 * scale + 1e-9 {
            return Err(CalibrationError::Discontinuous {
                breakpoint_m: b,
                linear_m,
                quadratic_m,
            });
        }
        Ok(())
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use crate::calibration::CalibrationTable;
    use proptest::prelude::*;

    const MM: f64 = 1e-3;

    #[test]
    fn fit_reproduces_exact_piecewise_data_and_is_continuous() {
        // Rows sampled from a known continuous piecewise law must be recovered exactly.
        let b = 7.0 * MM;
        let law = |d: f64| {
            if d < b {
                0.002 + 3.0 * d
            } else {
                0.002 + 3.0 * b + 5.0 * (d - b) + 400.0 * (d - b) * (d - b)
            }
        };
        let rows: Vec<_> = (1..=20)
            .map(|k| {
                let d = k as f64 * 0.5 * MM;
                CalibrationRow {
                    depth_m: d,
                    deformed_radius_m: law(d),
                }
            })
            .collect();
        let fit = CalibrationTable::fit(&rows, b).unwrap();
        assert!((fit.linear[0] - 0.002).abs() < 1e-12 && (fit.linear[1] - 3.0).abs() < 1e-9);
        assert!((fit.quadratic[2] - 400.0).abs() < 1e-6);
        for k in 0..200 {
            let d = k as f64 * 0.06 * MM;
            assert!((fit.evaluate_m(d.max(1e-9)) - law(d.max(1e-9))).abs() < 1e-9);
        }
        let left = fit.evaluate_m(b - 1e-12);
        let right = fit.evaluate_m(b);
        assert!((left - right).abs() < 1e-10);
    }

    #[test]
    fn fitting_needs_two_linear_rows() {
        let rows = [
            CalibrationRow {
                depth_m: 0.008,
                deformed_radius_m: 0.05,
            },
            CalibrationRow {
                depth_m: 0.009,
                deformed_radius_m: 0.06,
            },
        ];
        let err = CalibrationTable::fit(&rows, 0.007).unwrap_err();
        assert_eq!(
            err,
            CalibrationError::TooFewLinearRows {
                breakpoint_m: 0.007,
                found: 0
            }
        );
        assert!(matches!(
            CalibrationTable::fit(&rows, f64::NAN),
            Err(CalibrationError::Breakpoint(_))
        ));
    }

    proptest! {
        #[test]
        fn fit_is_continuous_and_finite_for_any_valid_rows(
            radii in proptest::collection::vec(0.0f64..0.2, 3..25),
            breakpoint_mm in 1.0f64..12.0,
        ) {
            let rows: Vec<_> = radii
                .iter()
                .enumerate()
                .map(|(k, &r)| CalibrationRow { depth_m: (k + 1) as f64 * 0.5 * MM, deformed_radius_m: r })
                .collect();
            let b = breakpoint_mm * MM;
            if let Ok(fit) = CalibrationTable::fit(&rows, b) {
                prop_assert!(fit.validate().is_ok());
                let l = fit.evaluate_m(b * (1.0 - 1e-12));
                let r = fit.evaluate_m(b);
                prop_assert!((l - r).abs() < 1e-8);
                for k in 0..50 {
                    let v = fit.evaluate_m(k as f64 * 0.3 * MM);
                    prop_assert!(v.is_finite() && v >= 0.0);
                }
            }
        }
    }
}
