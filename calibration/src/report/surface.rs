//! The drawn surface against the FEM surface: each render profile's error per depth, which FEM
//! the `fem` profile's goal is measured against and its error against the others, and the
//! profiles plotted.

use super::*;
use crate::experiments::surface::{FEM_PROFILE_GOAL_M, surface_difference_m, worst_error};

/// Depths at which the surface plots are drawn, where the study has them (mm).
const SURFACE_PLOT_DEPTHS_MM: [f64; 4] = [2.0, 4.0, 8.0, 10.0];

pub(super) fn surface_section(
    dir: &Path,
    studies: &[RdStudy],
    md: &mut String,
) -> Result<(), ReportError> {
    let _ = writeln!(
        md,
        "## The drawn surface against the FEM surface
"
    );
    let _ = writeln!(
        md,
        "The `paper` render profile moves each vertex along −n by the paper's Bézier (proto's \
         `DeformationProfile`: the tool inside the contact radius a, a quadratic Bézier from a to \
         R_d, nothing beyond), with a as the contact streams it (the sphere's scenes use the exact \
         sphere, so for the sphere the root of δ = (a/2) ln((R+a)/(R−a)), 0.83 R at δ = R where \
         Hertz's √(Rδ) would reach R and leave no flank; 2δ tanα/π for the cone) and R_d from the \
         table above. Here it is held against each R_d run's own top \
         surface, at the same undeformed radius, at every depth up to δ = R, beside two \
         analytical alternatives: the elastic half-space's surface (Johnson's Hertz profile for \
         the sphere, Sneddon's for the cone; no base) and the same with its far field cut by the \
         rigid base 50 mm down (`half_space_on_base_depression_m`). Errors are drawn − FEM at \
         the FEM's profile nodes from the axis to the block's side (negative: drawn too \
         shallow); \"max\" is the one of largest magnitude, with its undeformed radius and \
         region (contact r < a, flank a ≤ r < R_d, tail r ≥ R_d), then the largest at r ≥ a: \
         inside the contact the profiles drawn along −n alone follow the tool, so an error there \
         is the FEM node's slide under the tool (compared at its undeformed radius) or the \
         mesh's, the same for each of them. The RMS is taken along the line. The depressions at \
         2a and ½R_d are FEM / paper / half-space. \"Inward\" is how far the FEM surface at \
         undeformed r = a moved towards the axis, then how far the `fem` profile moves it (no \
         profile drawn along −n alone does). The last two profiles are the viewer's `fem` \
         profile (proto's `SurfaceFamily`): the neo-Hookean run's surface, depression and \
         sideways motion, tabulated every 0.5 mm at each table depth, as the table carries it, \
         each point held below the tool where it is drawn (at a table depth it is the FEM row \
         itself, so against the neo-Hookean FEM only the resampling remains), and with the \
         scored depth's own row \
         left out, so that it is interpolated from the rows beside it (the error of a depth \
         between rows, over twice their spacing; the first and last depths are extrapolated).\n"
    );
    goal_paragraph(studies, md);
    for s in studies {
        if s.surface.is_empty() {
            continue;
        }
        let _ = writeln!(md, "### {}\n", s.tool_name);
        let mut laws: Vec<LawKind> = Vec::new();
        for c in &s.surface {
            if !laws.contains(&c.law) {
                laws.push(c.law);
            }
        }
        // The neo-Hookean runs wrote the table: their comparison comes first.
        laws.sort_by_key(|&l| l != LawKind::NeoHookean);
        for law in laws {
            let _ = writeln!(md, "FEM {}:\n", law.name());
            let _ = write!(md, "| δ (mm) | a (mm) | R_d (mm) |");
            for p in DrawnProfile::ALL {
                let _ = write!(
                    md,
                    " {} max (mm) at r (mm) | max r ≥ a (mm) | RMS (mm) |",
                    p.title(&s.tool)
                );
            }
            let _ = writeln!(
                md,
                " at 2a (mm) | at ½R_d (mm) | inward at a, FEM / fem (mm) |"
            );
            let _ = write!(md, "|---|---|---|");
            for _ in DrawnProfile::ALL {
                let _ = write!(md, "---|---|---|");
            }
            let _ = writeln!(md, "---|---|---|");
            for c in s.surface.iter().filter(|c| c.law == law) {
                let _ = write!(
                    md,
                    "| {:.1} | {:.2} | {:.2} |",
                    c.depth_m / MM,
                    c.contact_radius_m / MM,
                    c.deformed_radius_m / MM
                );
                for e in &c.profiles {
                    let _ = write!(
                        md,
                        " {:+.2} at {:.1} ({}) | {:+.2} | {:.3} |",
                        e.worst_error_m / MM,
                        e.worst_error_radius_m / MM,
                        e.worst_error_region.name(),
                        e.worst_error_outside_contact_m / MM,
                        e.rms_error_m / MM
                    );
                }
                let twice = |p: DrawnProfile| {
                    c.error(p)
                        .map(|e| e.depression_at_twice_contact_m)
                        .unwrap_or(f64::NAN)
                };
                let half = |p: DrawnProfile| {
                    c.error(p)
                        .map(|e| e.depression_at_half_deformed_m)
                        .unwrap_or(f64::NAN)
                };
                let inward = c
                    .error(DrawnProfile::Fem)
                    .map_or(f64::NAN, |e| e.inward_motion_at_contact_edge_m);
                let _ = writeln!(
                    md,
                    " {:.2} / {:.2} / {:.2} | {:.2} / {:.2} / {:.2} | {:.2} / {:.2} |",
                    c.fem_depression_at_twice_contact_m / MM,
                    twice(DrawnProfile::Paper) / MM,
                    twice(DrawnProfile::HalfSpace) / MM,
                    c.fem_depression_at_half_deformed_m / MM,
                    half(DrawnProfile::Paper) / MM,
                    half(DrawnProfile::HalfSpace) / MM,
                    c.fem_inward_motion_at_contact_edge_m / MM,
                    inward / MM,
                );
            }
            md.push('\n');
        }
        surface_csv(dir, s)?;
        let mut plots = Vec::new();
        for depth_mm in SURFACE_PLOT_DEPTHS_MM {
            if let Some(svg) = surface_plot(dir, s, depth_mm * MM)? {
                plots.push(format!("![]({svg})"));
            }
        }
        let _ = writeln!(
            md,
            "Every number above: `surface_{0}.csv`; the profiles themselves: \
             `surface_profiles_{0}.csv`.\n\n{1}\n",
            s.tool_name,
            plots.join(" ")
        );
    }
    Ok(())
}

/// The columns of `surface_<tool>.csv`: the FEM run's own values (`fem_run_…`: its R_d, its
/// depression at 2a and ½R_d, its inward motion at a), then each drawn profile's (`<profile>_…`,
/// the `fem` profile's among them), so that no two columns share a name.
fn surface_csv_header() -> Vec<String> {
    let mut header: Vec<String> = [
        "law",
        "depth_mm",
        "contact_radius_mm",
        "deformed_radius_mm",
        "fem_run_deformed_radius_mm",
        "fem_run_depression_at_2a_mm",
        "fem_run_depression_at_half_rd_mm",
        "fem_run_inward_motion_at_a_mm",
    ]
    .iter()
    .map(|h| (*h).to_owned())
    .collect();
    for p in DrawnProfile::ALL {
        for field in [
            "worst_error_mm",
            "worst_error_radius_mm",
            "worst_error_region",
            "worst_error_outside_contact_mm",
            "rms_error_mm",
            "depression_at_2a_mm",
            "depression_at_half_rd_mm",
            "drawn_inward_motion_at_a_mm",
        ] {
            header.push(format!("{}_{field}", p.name()));
        }
    }
    header
}

/// The comparison table and the sampled profiles of one tool, as CSV.
fn surface_csv(dir: &Path, s: &RdStudy) -> Result<(), ReportError> {
    let mut text = surface_csv_header().join(",") + "\n";
    for c in &s.surface {
        let mut cells = vec![c.law.name().to_owned()];
        cells.extend(
            [
                c.depth_m,
                c.contact_radius_m,
                c.deformed_radius_m,
                c.fem_deformed_radius_m,
                c.fem_depression_at_twice_contact_m,
                c.fem_depression_at_half_deformed_m,
                c.fem_inward_motion_at_contact_edge_m,
            ]
            .iter()
            .map(|v| format!("{:.6e}", v / MM)),
        );
        for e in &c.profiles {
            cells.push(format!("{:.6e}", e.worst_error_m / MM));
            cells.push(format!("{:.6e}", e.worst_error_radius_m / MM));
            cells.push(e.worst_error_region.name().to_owned());
            cells.push(format!("{:.6e}", e.worst_error_outside_contact_m / MM));
            cells.push(format!("{:.6e}", e.rms_error_m / MM));
            cells.push(format!("{:.6e}", e.depression_at_twice_contact_m / MM));
            cells.push(format!("{:.6e}", e.depression_at_half_deformed_m / MM));
            cells.push(format!("{:.6e}", e.inward_motion_at_contact_edge_m / MM));
        }
        text.push_str(&cells.join(","));
        text.push('\n');
    }
    write(&dir.join(format!("surface_{}.csv", s.tool_name)), &text)?;

    let mut text =
        String::from("law,depth_mm,radius_mm,fem_depression_mm,fem_radial_displacement_mm");
    for p in DrawnProfile::ALL {
        let _ = write!(text, ",{}_drawn_depression_mm", p.name());
    }
    text.push_str(",fem_drawn_radial_displacement_mm\n");
    for c in &s.surface {
        let Some((run, surface)) = run_surface(s, c.law, c.depth_m) else {
            continue;
        };
        let drawn = DrawnSurface::of_study(s, c.depth_m, c.deformed_radius_m);
        for p in surface {
            let _ = write!(
                text,
                "{},{:.6e},{:.6e},{:.6e},{:.6e}",
                run.law.name(),
                c.depth_m / MM,
                p.radius_m / MM,
                p.depression_m / MM,
                p.radial_displacement_m / MM
            );
            for kind in DrawnProfile::ALL {
                let _ = write!(text, ",{:.6e}", drawn.depression_m(kind, p.radius_m) / MM);
            }
            let _ = writeln!(
                text,
                ",{:.6e}",
                drawn.radial_displacement_m(DrawnProfile::Fem, p.radius_m) / MM
            );
        }
    }
    write(
        &dir.join(format!("surface_profiles_{}.csv", s.tool_name)),
        &text,
    )
}

/// Which FEM the `fem` profile's goal is measured against, and what its error is against the
/// other two: one paragraph, then a line per tool, from the comparisons themselves.
fn goal_paragraph(studies: &[RdStudy], md: &mut String) {
    let goal_mm = FEM_PROFILE_GOAL_M / MM;
    let linear = [
        LawKind::LinearDeformedContact,
        LawKind::LinearSmallDeformation,
    ];
    // Every linear FEM's surface further than the goal from the neo-Hookean one somewhere?
    let mut linear_beyond_goal = true;
    let mut lines = Vec::new();
    for s in studies.iter().filter(|s| !s.surface.is_empty()) {
        let held_out = |law| worst_error(&s.surface, law, DrawnProfile::FemHeldOut);
        let Some((nh_depth_m, nh_error_m)) = held_out(LawKind::NeoHookean) else {
            continue;
        };
        let mut line = format!(
            "- {}: against the neo-Hookean FEM {:.2} mm (worst at δ = {:.1} mm, {} the goal)",
            s.tool_name,
            nh_error_m / MM,
            nh_depth_m / MM,
            if nh_error_m <= FEM_PROFILE_GOAL_M {
                "within"
            } else {
                "beyond"
            }
        );
        for law in linear {
            let (Some((depth_m, error_m)), Some(diff)) =
                (held_out(law), difference_from_neo_hookean(s, law))
            else {
                continue;
            };
            linear_beyond_goal &= diff.max_m > FEM_PROFILE_GOAL_M;
            let beyond = diff.first_beyond_goal_depth_m.map_or_else(
                || format!("never more than {goal_mm:.2} mm"),
                |d| format!("first more than {goal_mm:.2} mm at δ = {:.1} mm", d / MM),
            );
            let name = match law {
                LawKind::LinearDeformedContact => "linear FEM (contact on the deformed surface)",
                _ => "linear FEM (small deformation)",
            };
            let _ = write!(
                line,
                "; against the {name} {:.2} mm (at δ = {:.1} mm), whose surface is up to {:.2} mm \
                 from the neo-Hookean one (at δ = {:.1} mm; {beyond})",
                error_m / MM,
                depth_m / MM,
                diff.max_m / MM,
                diff.depth_of_max_m / MM,
            );
        }
        line.push('.');
        lines.push(line);
    }
    if lines.is_empty() {
        return;
    }
    let consequence = if linear_beyond_goal {
        format!(
            "The two linear formulations' surfaces differ from the neo-Hookean one at depth by \
             more than {goal_mm:.2} mm, so no one profile can be within {goal_mm:.2} mm of all \
             three: against them the `fem` profile's error is mostly the difference between the \
             formulations, not the profile's."
        )
    } else {
        format!(
            "Where a linear formulation's surface stays within {goal_mm:.2} mm of the \
             neo-Hookean one, the `fem` profile's error against it stays near that difference."
        )
    };
    let _ = writeln!(
        md,
        "**Which FEM the goal is measured against.** The `fem` profile is tabulated from the \
         neo-Hookean FEM, the formulation the scenes' tables are written from (the depths reach \
         the tool's radius, far past small strain), and its goal, within {goal_mm:.2} mm (max) \
         of the FEM surface at every depth to δ = R, is measured against that FEM. \
         {consequence} The `fem` profile's worst error with the scored depth's row held out, \
         against each FEM, and how far each linear FEM's surface is from the neo-Hookean one \
         (largest |difference| of depression at the same undeformed radius, depths to δ = R):\n"
    );
    for line in lines {
        let _ = writeln!(md, "{line}");
    }
    md.push('\n');
}

/// How far the surface of the run of `law` is from the neo-Hookean run's, over the depths both
/// have up to δ = R.
struct SurfaceDifference {
    max_m: f64,
    depth_of_max_m: f64,
    /// The first depth at which they are further apart than [`FEM_PROFILE_GOAL_M`].
    first_beyond_goal_depth_m: Option<f64>,
}

fn difference_from_neo_hookean(s: &RdStudy, law: LawKind) -> Option<SurfaceDifference> {
    let run = s.runs.iter().find(|r| r.law == law)?;
    let mut out: Option<SurfaceDifference> = None;
    for (&depth_m, surface) in run.depths_m.iter().zip(&run.surfaces) {
        if depth_m > s.tool.radius_m() * (1.0 + 1e-9) {
            continue;
        }
        let Some((_, reference)) = run_surface(s, LawKind::NeoHookean, depth_m) else {
            continue;
        };
        let diff_m = surface_difference_m(surface, reference);
        let d = out.get_or_insert(SurfaceDifference {
            max_m: 0.0,
            depth_of_max_m: depth_m,
            first_beyond_goal_depth_m: None,
        });
        if diff_m > d.max_m {
            d.max_m = diff_m;
            d.depth_of_max_m = depth_m;
        }
        if diff_m > FEM_PROFILE_GOAL_M && d.first_beyond_goal_depth_m.is_none() {
            d.first_beyond_goal_depth_m = Some(depth_m);
        }
    }
    out
}

/// The run of `law` in the study and its surface at `depth_m`.
fn run_surface(
    s: &RdStudy,
    law: LawKind,
    depth_m: f64,
) -> Option<(&crate::experiments::IndentationRun, &[SurfacePoint])> {
    let run = s.runs.iter().find(|r| r.law == law)?;
    let step = run
        .depths_m
        .iter()
        .position(|&d| (d - depth_m).abs() < 1e-9)?;
    Some((run, run.surfaces.get(step)?.as_slice()))
}

/// The FEM surfaces of every run and the drawn profiles at `depth_m`, as surface height
/// (−depression) against undeformed radius; `None` when the study has no such depth.
fn surface_plot(dir: &Path, s: &RdStudy, depth_m: f64) -> Result<Option<String>, ReportError> {
    let Some(c) = s
        .surface
        .iter()
        .find(|c| (c.depth_m - depth_m).abs() < 1e-9)
    else {
        return Ok(None);
    };
    // Out to twice the farther of the two R_d: the rest of the line is flat in every profile.
    let r_max = 2.0
        * c.deformed_radius_m
            .max(c.fem_deformed_radius_m)
            .max(c.contact_radius_m);
    let mut series = Vec::new();
    for run in &s.runs {
        if let Some((_, surface)) = run_surface(s, run.law, depth_m) {
            series.push(Series {
                name: format!("FEM {}", run.law.name()),
                points: surface
                    .iter()
                    .filter(|p| p.radius_m <= r_max)
                    .map(|p| (p.radius_m / MM, -p.depression_m / MM))
                    .collect(),
                dashed: false,
            });
        }
    }
    let drawn = DrawnSurface::of_study(s, depth_m, c.deformed_radius_m);
    for kind in DrawnProfile::ALL {
        series.push(Series {
            name: kind.title(&s.tool).to_owned(),
            points: (0..=200)
                .map(|k| {
                    let r = r_max * k as f64 / 200.0;
                    (r / MM, -drawn.depression_m(kind, r) / MM)
                })
                .collect(),
            dashed: true,
        });
    }
    let svg = format!("surface_{}_{:.0}mm.svg", s.tool_name, depth_m / MM);
    line_plot(
        &dir.join(&svg),
        &format!(
            "Surface at δ = {:.0} mm, {} (a = {:.1} mm, R_d = {:.1} mm)",
            depth_m / MM,
            s.tool_name,
            c.contact_radius_m / MM,
            c.deformed_radius_m / MM
        ),
        "undeformed radius (mm)",
        "surface height (mm)",
        &series,
    )?;
    Ok(Some(svg))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_surface_table_names_every_column_once() {
        let header = surface_csv_header();
        let mut seen = std::collections::HashSet::new();
        for h in &header {
            assert!(seen.insert(h.as_str()), "{h} appears twice");
        }
        assert!(header.iter().any(|h| h == "fem_run_depression_at_2a_mm"));
        assert!(header.iter().any(|h| h == "fem_depression_at_2a_mm"));
        assert!(header.iter().any(|h| h == "fem_held_out_worst_error_mm"));
    }
}
