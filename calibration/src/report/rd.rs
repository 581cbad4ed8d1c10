//! The R_d calibration section (paper §3.3.2): R_d against depth per formulation, the fit written
//! to the scene tables.

use super::*;

pub(super) fn rd_section(
    dir: &Path,
    studies: &[RdStudy],
    md: &mut String,
) -> Result<(), ReportError> {
    let _ = writeln!(md, "## R_d calibration (paper §3.3.2)\n");
    let _ = writeln!(
        md,
        "Block 100 × 100 × 50 mm, sphere R = 10 mm and cone 45° (base radius 10 mm), R_d = \
         outermost radius where the surface sinks more than 0.5 mm. The paper reports a \
         near-linear R_d(δ) below ~7 mm and fits a quadratic beyond (its Fig. 8 gives curves, \
         no numbers). Static elasticity with imposed displacement gives the same displacement \
         field for any E at fixed ν, so the 50 kPa and 1.5 MPa tables are identical here. The \
         paper shows separate profiles for the two moduli (Fig. 7) without quantifying a \
         difference; any it found would come from dynamics or gravity (its ArtiSynth runs pushed \
         the tool at constant velocity with a time integrator), which a static model leaves out. \
         The half-space column shows how much the clamped 50 mm depth cuts R_d.\n"
    );
    for s in studies {
        let depths: Vec<f64> = s.runs[0].depths_m.clone();
        let mut columns = Columns::starting_with("depth_mm", depths.iter().map(|d| d / MM));
        for r in &s.runs {
            columns.push(
                format!("rd_{}_mm", r.law.name()),
                r.deformed_radius_m.iter().map(|v| v / MM),
            );
            columns.push(format!("force_{}_n", r.law.name()), r.normal_forces_n());
        }
        columns.push("rd_half_space_mm", s.half_space_m.iter().map(|v| v / MM));
        columns.write_csv(&dir.join(format!("rd_{}.csv", s.tool_name)))?;
        let mut series: Vec<Series> = s
            .runs
            .iter()
            .map(|r| Series {
                name: format!("FEM {}", r.law.name()),
                points: depths
                    .iter()
                    .zip(&r.deformed_radius_m)
                    .map(|(d, v)| (d / MM, v / MM))
                    .collect(),
                dashed: false,
            })
            .collect();
        series.push(Series {
            name: "half-space".to_owned(),
            points: depths
                .iter()
                .zip(&s.half_space_m)
                .map(|(d, v)| (d / MM, v / MM))
                .collect(),
            dashed: true,
        });
        if let Some((_, table)) = s.tables.first() {
            series.push(Series {
                name: "fit (linear < 7 mm, quadratic beyond)".to_owned(),
                points: (0..=100)
                    .map(|i| {
                        let d = depths.last().copied().unwrap_or(0.01) * i as f64 / 100.0;
                        (d / MM, table.deformed_radius_m(d) / MM)
                    })
                    .collect(),
                dashed: true,
            });
        }
        let svg = format!("rd_{}.svg", s.tool_name);
        line_plot(
            &dir.join(&svg),
            &format!("R_d against depth, {}", s.tool_name),
            "depth (mm)",
            "R_d (mm)",
            &series,
        )?;
        let _ = writeln!(md, "### {}\n\n![]({svg})\n", s.tool_name);
        let _ = write!(md, "| δ (mm) |");
        for r in &s.runs {
            let _ = write!(md, " R_d {} (mm) | F {} (N) |", r.law.name(), r.law.name());
        }
        let _ = writeln!(md, " R_d half-space (mm) |");
        let _ = write!(md, "|---|");
        for _ in &s.runs {
            let _ = write!(md, "---|---|");
        }
        let _ = writeln!(md, "---|");
        for (i, d) in depths.iter().enumerate() {
            let _ = write!(md, "| {:.1} |", d / MM);
            for r in &s.runs {
                let _ = write!(
                    md,
                    " {:.2} | {:.4} |",
                    r.deformed_radius_m[i] / MM,
                    r.forces_n[i][2]
                );
            }
            let _ = writeln!(md, " {:.2} |", s.half_space_m[i] / MM);
        }
        if let Some((name, table)) = s.tables.first() {
            let fit = table.fit_coefficients();
            let _ = writeln!(
                md,
                "\nFit written to `{name}.json` (and its 1.5 MPa twin): R_d = {:.3} mm + {:.3} δ \
                 below {:.0} mm; quadratic {:.3} mm + {:.3} δ + {:.3} δ²/m beyond.\n",
                fit.linear[0] / MM,
                fit.linear[1],
                fit.breakpoint_m / MM,
                fit.quadratic[0] / MM,
                fit.quadratic[1],
                fit.quadratic[2],
            );
        }
        for r in &s.runs {
            let locked: usize = r.locked_nodes.iter().sum();
            let _ = writeln!(
                md,
                "- {}: {} unknowns, {} elements, Newton iterations per step {:?}, nodes held in \
                 contact after alternating: {locked}.",
                r.label, r.dofs, r.elements, r.newton_iterations
            );
        }
        md.push('\n');
    }
    Ok(())
}
