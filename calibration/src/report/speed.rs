//! The speed-versus-accuracy trade: each runtime model's cost per step against its error.

use super::*;

pub(super) fn speed_section(
    dir: &Path,
    s: &SpeedAccuracyStudy,
    md: &mut String,
) -> Result<(), ReportError> {
    let _ = writeln!(md, "### Speed against accuracy\n");
    let _ = writeln!(
        md,
        "The §4.3 tools on the 100 × 100 × {:.0} mm block; reference: the finest neo-Hookean \
         FEM. Error columns: the paper's eq. 9, (f_a − f_f) / max f_f in percent, signed \
         (positive = the model is stiffer), at each depth; then the largest |eq. 9| and the \
         largest pointwise |f_a − f_f| / f_f. Time: median over {} batches of {} calls of one \
         `ForceModel::force_n` (closed forms), or median wall time of one load step, a whole \
         static solve (FEM; two runs shared the two cores). Layer models use h = {:.0} mm, the \
         block's depth. The paper's haptic step (collision + force + mesh update) took \
         0.15–0.86 ms on an i7-2600 (Table 1); SOFA's FEM on 1600 vertices ≈ 20 ms. The \
         criterion bench `cargo bench -p softhaptic-device --bench force_model` times the same \
         evaluations.\n",
        s.thickness_m / MM,
        crate::models::TIMING_BATCHES,
        crate::models::CALLS_PER_BATCH,
        s.thickness_m / MM,
    );
    let mut csv_rows = Vec::new();
    let mut header = vec![
        "tool".to_owned(),
        "model".to_owned(),
        "kind".to_owned(),
        "nanoseconds".to_owned(),
    ];
    for d in &s.depths_m {
        header.push(format!("eq9_{:.0}mm_percent", d / MM));
    }
    header.push("max_eq9_percent".to_owned());
    for d in &s.depths_m {
        header.push(format!("relative_{:.0}mm_percent", d / MM));
    }
    header.push("max_relative_percent".to_owned());
    header.push("dofs".to_owned());
    for t in &s.tools {
        let _ = writeln!(
            md,
            "#### {} (reference `{}`, {} unknowns)\n",
            t.tool_name, t.reference, t.reference_dofs
        );
        let _ = write!(md, "| model | time |");
        for d in &s.depths_m {
            let _ = write!(md, " {:.0} mm |", d / MM);
        }
        let _ = writeln!(md, " max eq. 9 | max pointwise | unknowns |");
        let _ = write!(md, "|---|---|");
        for _ in &s.depths_m {
            let _ = write!(md, "---|");
        }
        let _ = writeln!(md, "---|---|---|");
        let mut scatter = Vec::new();
        let mut series = Vec::new();
        for m in &t.models {
            let name = match (m.kind, m.best_combined) {
                (_, true) => format!("**{} (best combined)**", m.name),
                (RowKind::Runtime, false) => m.name.clone(),
                _ => format!("*{}*", m.name),
            };
            let _ = write!(md, "| {name} | {} |", fmt_ns(m.nanoseconds));
            for e in &m.errors.eq9_percent {
                let _ = write!(md, " {e:+.2} |");
            }
            let _ = writeln!(
                md,
                " {:.2} | {:.2} | {} |",
                m.errors.max_eq9_percent(),
                m.errors.max_relative_percent(),
                m.dofs
                    .map(|d| d.to_string())
                    .unwrap_or_else(|| "—".to_owned())
            );
            let mut row = vec![
                t.tool_name.clone(),
                m.name.replace(',', ";"),
                format!("{:?}", m.kind).to_lowercase(),
                format!("{:.6e}", m.nanoseconds),
            ];
            row.extend(m.errors.eq9_percent.iter().map(|v| format!("{v:.4}")));
            row.push(format!("{:.4}", m.errors.max_eq9_percent()));
            row.extend(m.errors.relative_percent.iter().map(|v| format!("{v:.4}")));
            row.push(format!("{:.4}", m.errors.max_relative_percent()));
            row.push(m.dofs.unwrap_or(0).to_string());
            csv_rows.push(row.join(","));
            scatter.push((m.name.clone(), m.nanoseconds, m.errors.max_eq9_percent()));
            if m.kind != RowKind::Fem || m.name.contains("fine") {
                series.push(Series {
                    name: m.name.clone(),
                    points: s
                        .depths_m
                        .iter()
                        .map(|d| d / MM)
                        .zip(m.errors.eq9_percent.iter().copied())
                        .collect(),
                    dashed: m.kind != RowKind::Runtime,
                });
            }
        }
        md.push('\n');
        let err_svg = format!("speed_accuracy_{}.svg", t.tool_name);
        line_plot(
            &dir.join(&err_svg),
            &format!("eq. 9 error against the neo-Hookean FEM, {}", t.tool_name),
            "depth (mm)",
            "error (%)",
            &series,
        )?;
        let cost_svg = format!("speed_accuracy_cost_{}.svg", t.tool_name);
        scatter_plot(
            &dir.join(&cost_svg),
            &format!("Cost against accuracy, {}", t.tool_name),
            "log10(time per evaluation / ns)",
            "largest eq. 9 error, δ = 1…6 mm (%)",
            &scatter,
        )?;
        let _ = writeln!(md, "![]({err_svg}) ![]({cost_svg})\n");
    }
    write(
        &dir.join("speed_accuracy.csv"),
        &format!("{}\n{}\n", header.join(","), csv_rows.join("\n")),
    )?;
    if let Some(best) = s
        .tools
        .iter()
        .flat_map(|t| &t.models)
        .find(|m| m.best_combined)
    {
        let within = best.errors.max_eq9_percent() < JND_PERCENT;
        let _ = writeln!(
            md,
            "Goal (issue 6): the best combined model within 7% of the neo-Hookean FEM up to δ = \
             6 mm with the 6 mm sphere (the paper's law: 3.3 mm), under 1 µs per evaluation. \
             Measured: {} — largest eq. 9 error {:.2}% (pointwise {:.2}%), {}; {}.\n",
            best.name,
            best.errors.max_eq9_percent(),
            best.errors.max_relative_percent(),
            fmt_ns(best.nanoseconds),
            if within && best.nanoseconds < 1000.0 {
                "met"
            } else {
                "missed"
            }
        );
    }
    Ok(())
}
