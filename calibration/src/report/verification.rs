//! The FEM's verification: patch tests, convergence and Sneddon on the deep block.

use super::*;

/// The small-deformation formulation against Sneddon on the deep block: one table per tool,
/// the force on each mesh and its error, so the convergence reads along a row.
fn sneddon_section(dir: &Path, v: &VerificationStudy, md: &mut String) -> Result<(), ReportError> {
    let _ = writeln!(
        md,
        "\n### Small-deformation linear FEM against Sneddon (deep block)\n\n\
         The textbook linear contact problem ({}): small strain, gap measured on the reference \
         configuration along the surface normal (the tool's axis), reaction along it. Each depth has its own \
         quarter-model cube {:.0} contact radii a wide and deep (bottom clamped, sides free), \
         meshed with cells of a/n over 1.5 a laterally and a in depth, then geometric growth; \
         a is Hertz's √(Rδ) (capped at R) or the cone's 2δ tan α / π. The tool is pressed to \
         δ in one step. Reference: Sneddon's exact sphere and Sneddon's cone (E = 50 kPa, \
         ν = 0.33, then ν = 0.49: at ν = 0.49 the bulk modulus is 25 times the shear \
         modulus, where displacement elements that lock would come out stiff, and more so on \
         coarser meshes). Errors are FEM / Sneddon − 1.\n",
        LawKind::LinearSmallDeformation.name(),
        crate::experiments::verification::SNEDDON_BLOCK_OVER_CONTACT_RADIUS
    );
    for check in &v.sneddon {
        let _ = writeln!(
            md,
            "{}, ν = {:.2} — largest |error| on the finest mesh: {:.2}%\n",
            crate::experiments::tool_description(&check.tool),
            check.material.poisson_ratio(),
            check.worst_finest_error_percent()
        );
        let mut header = "| δ (mm) | Sneddon (N) |".to_owned();
        let mut rule = "|---|---|".to_owned();
        let mut csv_header = vec!["depth_mm".to_owned(), "sneddon_n".to_owned()];
        for m in &check.meshes {
            let _ = write!(header, " FEM cells {} (N) | unknowns | error (%) |", m.name);
            rule.push_str("---|---|---|");
            let tag = format!("{:.1}", m.cells_per_contact_radius);
            csv_header.push(format!("fem_cells_a_over_{tag}_n"));
            csv_header.push(format!("dofs_cells_a_over_{tag}"));
            csv_header.push(format!("error_cells_a_over_{tag}_percent"));
        }
        let _ = writeln!(md, "{header}\n{rule}");
        let mut rows = Vec::new();
        for p in &check.points {
            let mut line = format!("| {:.1} | {:.4} |", p.depth_m / MM, p.sneddon_n);
            let mut row = vec![p.depth_m / MM, p.sneddon_n];
            for ((f, dofs), e) in p.fem_n.iter().zip(&p.dofs).zip(&p.error_percent) {
                let _ = write!(line, " {f:.4} | {dofs} | {e:+.2} |");
                row.extend([*f, *dofs as f64, *e]);
            }
            let _ = writeln!(md, "{line}");
            rows.push(row);
        }
        md.push('\n');
        csv(
            &dir.join(format!(
                "verification_sneddon_{}{}.csv",
                check.tool_name,
                if check.material == crate::experiments::MATERIAL {
                    String::new()
                } else {
                    format!("_nu{:.0}", 100.0 * check.material.poisson_ratio())
                }
            )),
            &csv_header,
            &rows,
        )?;
    }
    Ok(())
}

/// The neo-Hookean law against Sneddon's exact sphere at small depths on the deep block.
fn neo_hookean_section(v: &VerificationStudy, md: &mut String) {
    let Some(first) = v.neo_hookean.first() else {
        return;
    };
    let _ = writeln!(
        md,
        "### Neo-Hookean FEM against Sneddon at small depths (deep block)\n\n\
         The sphere of radius 6 mm at δ/R ≤ 1/6, where the strain is small and the neo-Hookean \
         law must come down to linear elasticity, at ν = 0.33 and at ν = 0.49 (where a locking \
         element would come out stiff). Same deep block and load as above, cells {} (the \
         neo-Hookean tangent is refactorised every Newton iteration, so not the finest mesh), \
         two load steps; the small-deformation FEM of the same mesh beside it cancels the mesh's \
         own error, and Lin et al.'s incompressible neo-Hookean sphere over Hertz is the \
         stiffening the law itself should add at that depth (contact on the deformed surface \
         adds its own small softening).\n",
        first.mesh.name
    );
    let _ = writeln!(
        md,
        "| ν | δ (mm) | unknowns | Sneddon (N) | small deformation (N) | neo-Hookean (N) | neo-Hookean / Sneddon − 1 (%) | neo-Hookean / small deformation − 1 (%) | Lin et al. / Hertz − 1 (%) |\n|---|---|---|---|---|---|---|---|---|"
    );
    for p in &v.neo_hookean {
        let _ = writeln!(
            md,
            "| {:.2} | {:.1} | {} | {:.4} | {:.4} | {:.4} | {:+.2} | {:+.2} | {:+.2} |",
            p.poisson_ratio,
            p.depth_m / MM,
            p.dofs,
            p.sneddon_n,
            p.small_deformation_n,
            p.neo_hookean_n,
            p.error_percent(),
            p.over_linear_percent(),
            100.0 * (p.lin_et_al_over_hertz - 1.0)
        );
    }
    md.push('\n');
}

pub(super) fn verification_section(
    dir: &Path,
    v: &VerificationStudy,
    md: &mut String,
) -> Result<(), ReportError> {
    let _ = writeln!(md, "## Verification\n");
    let _ = writeln!(
        md,
        "Linear FEM, δ = {} R on a block {} R wide and deep (quarter model, bottom clamped), \
         R = 10 mm. 'Corrected' = the runtime's model with the bonded-layer correction \
         (Dimitriadis) for the block depth, and for the sphere also the exact-sphere correction \
         (Sneddon). Profile error = largest \
         |FEM − Johnson half-space| depression for a < r < 4a, relative to δ (the finite block \
         and the sphere-vs-paraboloid shape account for part of it).\n",
        v.depth_over_radius, v.block_over_radius
    );
    let _ = writeln!(
        md,
        "| indenter | fine cells (mm) | unknowns | FEM (N) | Hertz (N) | vs Hertz (%) | vs corrected (%) | profile error (% of δ) |\n|---|---|---|---|---|---|---|---|"
    );
    let mut rows = Vec::new();
    for c in &v.checks {
        let _ = writeln!(
            md,
            "| {} | {:.2} | {} | {:.4} | {:.4} | {:+.2} | {:+.2} | {:.2} |",
            c.indenter,
            c.fine_cell_m / MM,
            c.dofs,
            c.fem_n,
            c.hertz_n,
            c.error_vs_hertz_percent,
            c.error_vs_corrected_percent,
            c.profile_error_percent
        );
        rows.push(vec![
            c.fine_cell_m / MM,
            c.dofs as f64,
            c.fem_n,
            c.hertz_n,
            c.error_vs_hertz_percent,
            c.error_vs_corrected_percent,
            c.profile_error_percent,
        ]);
    }
    csv(
        &dir.join("verification.csv"),
        &[
            "fine_cell_mm",
            "dofs",
            "fem_n",
            "hertz_n",
            "error_vs_hertz_percent",
            "error_vs_corrected_percent",
            "profile_error_percent",
        ]
        .map(String::from),
        &rows,
    )?;
    sneddon_section(dir, v, md)?;
    neo_hookean_section(v, md);
    let _ = writeln!(
        md,
        "\nPatch test (linear displacement imposed on the boundary of a graded block, interior free):"
    );
    for p in &v.patch_test {
        let _ = writeln!(
            md,
            "- {}, ν = {:.2}: largest interior error {:.1e} of the largest displacement.",
            p.law.name(),
            p.poisson_ratio,
            p.error
        );
    }
    md.push('\n');
    Ok(())
}
