//! The Poisson sweep: the fits and R_d tables over ν = 0.30 … 0.49.

use super::*;

pub(super) fn poisson_section(
    dir: &Path,
    study: &PoissonStudy,
    md: &mut String,
) -> Result<(), ReportError> {
    let _ = writeln!(md, "## Nearly incompressible tissue: ν from 0.30 to 0.49\n");
    let _ = writeln!(
        md,
        "Every fit above is made at the paper's ν = 0.33; soft tissue is nearly incompressible \
         (ν ≈ 0.45–0.49). At each ν the §4.3 runs (6 mm tools, 30 mm block, finest mesh, \
         neo-Hookean and small-deformation) and the R_d study's neo-Hookean runs (10 mm tools, \
         50 mm block, δ to 10 mm) are repeated. The hyperelastic factor is refitted against \
         the closed form of the same ν (exact sphere or cone on the bonded layer, whose factor \
         depends on ν, with the layer's FEM residual below) on the 30 mm block (in sample) and scored on the 50 mm block with the \
         10 mm tools (out of sample). Errors are the largest eq. 9 error of the closed form on \
         the layer times the factor against the neo-Hookean FEM, sphere / cone, percent: with \
         the refit, with the runtime's constants at that ν (its table of fits, interpolated \
         linearly in ν between them), with the ν = 0.33 constants at every ν, and with no factor. \
         Whether the elements lock at ν = 0.49 is answered in 'Verification' (patch test and \
         Sneddon on the deep block at ν = 0.49).\n"
    );
    let _ = writeln!(
        md,
        "| ν | refit SPHERE_C1 | SPHERE_C2 | CONE_RATIO | runtime's c1 / c2 / cone | sphere F_nH / closed form at δ = R | in sample: refit | runtime | ν = 0.33 constants | no factor | out of sample: refit | runtime | no factor |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    let pair = |v: [f64; 2]| format!("{:.2} / {:.2}", v[0], v[1]);
    let mut rows = Vec::new();
    for p in &study.points {
        let _ = writeln!(
            md,
            "| {:.2} | {:.4} | {:.4} | {:.4} | {:.4} / {:.4} / {:.4} | {:.3} | {} | {} | {} | {} | {} | {} | {} |",
            p.poisson_ratio,
            p.fit.sphere_c1,
            p.fit.sphere_c2,
            p.fit.cone_ratio,
            p.runtime.sphere_c1,
            p.runtime.sphere_c2,
            p.runtime.cone_ratio,
            p.sphere_ratio_at_radius,
            pair(p.in_sample_percent),
            pair(p.in_sample_runtime_percent),
            pair(p.in_sample_paper_constants_percent),
            pair(p.in_sample_unfitted_percent),
            pair(p.out_of_sample_percent),
            pair(p.out_of_sample_runtime_percent),
            pair(p.out_of_sample_unfitted_percent),
        );
        rows.push(vec![
            p.poisson_ratio,
            p.fit.sphere_c1,
            p.fit.sphere_c2,
            p.fit.cone_ratio,
            p.sphere_ratio_at_radius,
            p.in_sample_percent[0],
            p.in_sample_percent[1],
            p.out_of_sample_percent[0],
            p.out_of_sample_percent[1],
        ]);
    }
    csv(
        &dir.join("poisson_hyperelastic.csv"),
        &[
            "poisson_ratio",
            "sphere_c1",
            "sphere_c2",
            "cone_ratio",
            "sphere_ratio_at_radius",
            "in_sample_sphere_percent",
            "in_sample_cone_percent",
            "out_of_sample_sphere_percent",
            "out_of_sample_cone_percent",
        ]
        .map(String::from),
        &rows,
    )?;
    let _ = writeln!(
        md,
        "\nThe bonded-layer factor at each ν: the small-deformation FEM of the 6 mm tools on \
         100 × 100 mm blocks 12, 20 and 30 mm thick (bottom clamped, finest mesh), over Sneddon's \
         half-space of the same ν, from δ = 2 mm (at 1 mm the cone's contact spans less than a \
         cell) to 6 mm, where χ reaches 0.5 on the 12 mm layer. The published series \
         (Dimitriadis et al. for the sphere, a function of ν; Garcia & Garcia for the cone, \
         derived at ν = 0.5) is multiplied by a residual 1 + k1 χ + k2 χ s (s = δ/R for the \
         sphere, whose series takes Hertz's contact radius, too large as δ nears R; s = χ for the \
         cone) fitted to these three layers (least squares on the factor) and scored out of sample on a 15 mm layer. Each \
         cell: the largest |FEM / law − 1|, percent, of the published series / the refit / the \
         runtime (its table of residuals, `softhaptic_device::model::layer_fit`, interpolated in \
         ν). Every sample is in `poisson_layer.csv`.\n"
    );
    let _ = writeln!(
        md,
        "| ν | sphere k1 / k2 (refit) | runtime's | in sample | 15 mm layer (out of sample) | cone k1 / k2 (refit) | runtime's | in sample | 15 mm layer (out of sample) |\n|---|---|---|---|---|---|---|---|---|"
    );
    let triple = |v: [f64; 3]| format!("{:.1} / {:.1} / {:.1}", v[0], v[1], v[2]);
    let mut layer_rows = Vec::new();
    for p in &study.points {
        let _ = write!(md, "| {:.2} |", p.poisson_ratio);
        for (k, l) in p.layer.iter().enumerate() {
            let _ = write!(
                md,
                " {:.4} / {:.4} | {:.4} / {:.4} | {} | {} |",
                l.fit[0],
                l.fit[1],
                l.runtime[0],
                l.runtime[1],
                triple(l.worst_percent(false)),
                triple(l.worst_percent(true)),
            );
            for s in &l.samples {
                layer_rows.push(vec![
                    p.poisson_ratio,
                    k as f64,
                    s.thickness_m / MM,
                    s.depth_m / MM,
                    s.chi,
                    s.measured,
                    s.published,
                    s.refit,
                    s.runtime,
                ]);
            }
        }
        let _ = writeln!(md);
    }
    csv(
        &dir.join("poisson_layer.csv"),
        &[
            "poisson_ratio",
            "tool_0_sphere6_1_cone6_45",
            "thickness_mm",
            "depth_mm",
            "chi",
            "fem_over_sneddon",
            "published",
            "refit",
            "runtime",
        ]
        .map(String::from),
        &layer_rows,
    )?;
    let _ = writeln!(
        md,
        "\nR_d (mm) of the neo-Hookean FEM on the 100 × 100 × 50 mm block at each ν, 10 mm tools; \
         the tables of each ν but the paper's are written as `<tool>_50kpa_nu<100ν>.json` \
         beside the scenes' tables (the displacement field does not depend on E), each with the \
         run's own top surface tabulated for the viewer's `fem` profile.\n"
    );
    let _ = write!(md, "| δ (mm) |");
    for tool in ["sphere", "cone"] {
        for p in &study.points {
            let _ = write!(md, " {tool} ν={:.2} |", p.poisson_ratio);
        }
    }
    let _ = writeln!(md);
    let _ = write!(md, "|---|");
    for _ in 0..2 * study.points.len() {
        let _ = write!(md, "---|");
    }
    let _ = writeln!(md);
    let mut rd_rows = Vec::new();
    for (i, d) in study.rd_depths_m.iter().enumerate() {
        let _ = write!(md, "| {:.1} |", d / MM);
        let mut row = vec![d / MM];
        for k in 0..2 {
            for p in &study.points {
                let r = p
                    .rd_m
                    .get(k)
                    .and_then(|v| v.get(i))
                    .copied()
                    .unwrap_or(f64::NAN);
                let _ = write!(md, " {:.2} |", r / MM);
                row.push(r / MM);
            }
        }
        let _ = writeln!(md);
        rd_rows.push(row);
    }
    let mut header = vec!["depth_mm".to_owned()];
    for tool in ["sphere10", "cone10_45"] {
        for p in &study.points {
            header.push(format!("rd_{tool}_nu{:.0}_mm", 100.0 * p.poisson_ratio));
        }
    }
    csv(&dir.join("poisson_rd.csv"), &header, &rd_rows)?;
    md.push('\n');
    surface_table(dir, study, md)?;
    Ok(())
}

/// The drawn surface against the FEM surface for the table of each ν (the measure of 'The drawn
/// surface against the FEM surface', summed up per table).
fn surface_table(dir: &Path, study: &PoissonStudy, md: &mut String) -> Result<(), ReportError> {
    let _ = writeln!(
        md,
        "The drawn surface of each ν's table against the top surface of the neo-Hookean run it \
         is made from, at every depth of the run to δ = R, measured as in 'The drawn surface \
         against the FEM surface' (depression at the same undeformed radius along y = 0): the \
         `paper` profile (the paper's Bézier with the table's R_d and the streamed contact \
         radius), the `fem` profile with the scored depth's row held out (how a depth between \
         rows is drawn) and as tabulated; the largest |error| over the depths and the depth \
         where it sits. The ν = 0.33 tables are rd-table's.\n"
    );
    let _ = writeln!(
        md,
        "| ν | table | depths | paper: max error (mm) | at δ (mm) | fem, row held out: max error (mm) | at δ (mm) | fem as tabulated: max error (mm) | at δ (mm) |\n|---|---|---|---|---|---|---|---|---|"
    );
    let cell = |e: Option<(f64, f64)>| {
        e.map_or("— | —".to_owned(), |(d, err)| {
            format!("{:.3} | {:.1}", err / MM, d / MM)
        })
    };
    let mut rows = Vec::new();
    for p in &study.points {
        for (k, t) in p.surface.iter().enumerate() {
            let _ = writeln!(
                md,
                "| {:.2} | `{}.json` | {} | {} | {} | {} |",
                p.poisson_ratio,
                t.table,
                t.depths,
                cell(t.paper),
                cell(t.fem_held_out),
                cell(t.fem)
            );
            let pair =
                |e: Option<(f64, f64)>| e.map_or([f64::NAN; 2], |(d, err)| [d / MM, err / MM]);
            let mut row = vec![p.poisson_ratio, k as f64];
            for e in [t.paper, t.fem_held_out, t.fem] {
                row.extend(pair(e));
            }
            rows.push(row);
        }
    }
    md.push('\n');
    csv(
        &dir.join("poisson_surface.csv"),
        &[
            "poisson_ratio",
            "tool_0_sphere10_1_cone10_45",
            "paper_depth_mm",
            "paper_max_error_mm",
            "fem_held_out_depth_mm",
            "fem_held_out_max_error_mm",
            "fem_depth_mm",
            "fem_max_error_mm",
        ]
        .map(String::from),
        &rows,
    )
}
