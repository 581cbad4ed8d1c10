//! The measured validity limits of the runtime models (`scenes/calibration/model_limits.json`):
//! for every (tool kind, model) the studies evaluated, the depth up to which its eq. 9 error
//! against the neo-Hookean FEM stays under 7%, and the tilt up to which the inclination study
//! measured it within 7%.

use softhaptic_device::model::LocalGeometry;
use softhaptic_proto::model::{MeasuredLimit, ToolKind};
use softhaptic_proto::{ModelLimitsFile, ModelSpec, ToolShape};

use super::curvature::CurvatureStudy;
use super::force::FORCE_LAYER_M;
use super::force::{RowKind, SpeedAccuracyStudy};
use super::inclination::InclinationStudy;
use super::poisson::PoissonStudy;
use super::{ExperimentError, JND_PERCENT, MATERIAL, MM, first_crossing};
use crate::element::LawKind;
use crate::models::{self, ErrorCurve, RuntimeModel};

/// The inclination limit of `spec` on `tool`, and how it was found, from the inclination study
/// of the same tool kind with the deformed-contact linear FEM (the formulation whose force turns
/// with the contact, so that the direction is measured too), by the paper's criterion: the angle where the error of the force
/// magnitude reaches 7% (against the corrected magnitude for a cone model with the inclination
/// correction) or its direction 32°, or the largest angle measured if neither does.
fn inclination_limit(
    studies: Option<&[InclinationStudy]>,
    tool: &ToolShape,
    spec: &ModelSpec,
) -> (Option<f64>, String) {
    let Some(s) = studies.into_iter().flatten().find(|s| {
        ToolKind::of(&s.tool) == ToolKind::of(tool) && s.law == LawKind::LinearDeformedContact
    }) else {
        return (None, String::new());
    };
    let corrected = spec.inclination && matches!(tool, ToolShape::Cone { .. });
    let what = match (tool, corrected) {
        (ToolShape::Sphere { .. }, _) => "δ along the contact normal",
        (ToolShape::Cone { .. }, true) => "with the inclination correction",
        (ToolShape::Cone { .. }, false) => "perpendicular law",
    };
    let (angle, how) = match s.valid_inclination_rad(corrected) {
        Some(a) => (a, format!("limit reached at {:.1}°", a.to_degrees())),
        None => (
            s.max_angle_rad(),
            format!(
                "no limit reached up to {:.0}°, the largest angle measured",
                s.max_angle_rad().to_degrees()
            ),
        ),
    };
    (
        Some(angle),
        format!(
            "; inclination ({what}): {} tilted on the 100 × 100 × 50 mm block, linear FEM, \
             depths ≥ {:.0} mm, force magnitude within 7% and direction within {:.0}°; {how}",
            super::tool_description(&s.tool),
            s.resolved_from_m / MM,
            super::inclination::DIRECTION_THRESHOLD_DEG,
        ),
    )
}

/// The cone model with the inclination correction switched on: identical to `spec` for a
/// perpendicular tool (checked at every depth), so it inherits the depth limit.
fn inclined_variant(
    tool: &ToolShape,
    spec: &ModelSpec,
    depths_m: &[f64],
) -> Result<Option<ModelSpec>, ExperimentError> {
    if !matches!(tool, ToolShape::Cone { .. }) || spec.inclination {
        return Ok(None);
    }
    let variant = ModelSpec {
        inclination: true,
        ..*spec
    };
    let model = |s: ModelSpec| {
        RuntimeModel::new(*tool, MATERIAL, s).map_err(|source| ExperimentError::Model {
            run: "model limits".to_owned(),
            source,
        })
    };
    let base = model(*spec)?.forces_n(depths_m, &LocalGeometry::FLAT);
    let inclined = model(variant)?.forces_n(depths_m, &LocalGeometry::FLAT);
    if base
        .iter()
        .zip(&inclined)
        .any(|(a, b)| a.to_bits() != b.to_bits())
    {
        return Err(ExperimentError::Data {
            study: "model limits".to_owned(),
            reason: format!(
                "{}: the inclination correction changes the perpendicular force",
                variant.label(tool)
            ),
        });
    }
    Ok(Some(variant))
}

/// Builds the limits file from the studies that ran: the speed-accuracy study gives the depth
/// limits of the flat-object models (§4.3 tools), the curvature study those of the
/// curvature-corrected models (tools of radius 10 mm on balls), the inclination study the
/// angles. Each (tool kind, model) appears once.
pub fn model_limits(
    speed: Option<&SpeedAccuracyStudy>,
    curvature: Option<&[CurvatureStudy]>,
    inclination: Option<&[InclinationStudy]>,
    poisson: Option<&PoissonStudy>,
) -> Result<ModelLimitsFile, ExperimentError> {
    let mut limits: Vec<MeasuredLimit> = Vec::new();
    let push_at = |tool: &ToolShape,
                   spec: ModelSpec,
                   crossing: Option<f64>,
                   deepest_m: f64,
                   reference: &str,
                   poisson_ratio: Option<f64>,
                   limits: &mut Vec<MeasuredLimit>| {
        let kind = ToolKind::of(tool);
        if limits
            .iter()
            .any(|l| l.tool == kind && l.model == spec && l.poisson_ratio == poisson_ratio)
        {
            return;
        }
        let (valid_inclination_rad, inclination_note) = inclination_limit(inclination, tool, &spec);
        limits.push(MeasuredLimit {
            tool: kind,
            model: spec,
            valid_depth_m: crossing.unwrap_or(deepest_m),
            crossed: crossing.is_some(),
            valid_inclination_rad,
            reference: format!("{reference}{inclination_note}"),
            poisson_ratio,
        });
    };
    let push = |tool: &ToolShape,
                spec: ModelSpec,
                crossing: Option<f64>,
                deepest_m: f64,
                reference: &str,
                limits: &mut Vec<MeasuredLimit>| {
        push_at(tool, spec, crossing, deepest_m, reference, None, limits)
    };
    if let Some(speed) = speed {
        for t in &speed.tools {
            let reference = format!(
                "{} on the §4.3 block 100 × 100 × 30 mm (bottom clamped), δ ≤ {:.1} mm: eq. 9 \
                 against the neo-Hookean FEM, 10-node tets, {:.1} mm cells, {} unknowns",
                super::tool_description(&t.tool),
                t.models.first().map_or(0.0, |m| m.deepest_m) / MM,
                t.reference_cell_m / MM,
                t.reference_dofs,
            );
            let grid: Vec<f64> = (1..=60).map(|i| i as f64 * 0.1 * MM).collect();
            for m in t.models.iter().filter(|m| m.kind == RowKind::Runtime) {
                let Some(spec) = m.spec else { continue };
                push(
                    &t.tool,
                    spec,
                    m.crossing_m,
                    m.deepest_m,
                    &reference,
                    &mut limits,
                );
                if let Some(variant) = inclined_variant(&t.tool, &spec, &grid)? {
                    push(
                        &t.tool,
                        variant,
                        m.crossing_m,
                        m.deepest_m,
                        &reference,
                        &mut limits,
                    );
                }
            }
        }
    }
    for s in curvature.into_iter().flatten() {
        let Some(nh) = s.laws.iter().find(|l| l.law == LawKind::NeoHookean) else {
            continue;
        };
        let deepest_m = s.depths_m.last().copied().unwrap_or(0.0);
        let reference = format!(
            "{} on balls R0 = {} mm (lower cap clamped), δ ≤ {:.0} mm: eq. 9 against the \
             neo-Hookean FEM of each ball, 10-node tets, {:.1} mm cells; the shallowest crossing \
             of the three",
            super::tool_description(&s.tool),
            s.object_radii_m
                .iter()
                .map(|r| format!("{:.0}", r / MM))
                .collect::<Vec<_>>()
                .join(", "),
            deepest_m / MM,
            nh.balls.first().map_or(0.0, |b| b.resolution.fine_cell_m) / MM,
        );
        for m in nh.models.iter().filter(|m| m.spec.curvature) {
            push(
                &s.tool,
                m.spec,
                m.first_crossing_m(),
                deepest_m,
                &reference,
                &mut limits,
            );
            if let Some(variant) = inclined_variant(&s.tool, &m.spec, &s.depths_m)? {
                push(
                    &s.tool,
                    variant,
                    m.first_crossing_m(),
                    deepest_m,
                    &reference,
                    &mut limits,
                );
            }
        }
    }
    for l in poisson_limits(poisson, inclination)? {
        if !limits
            .iter()
            .any(|o| o.tool == l.tool && o.model == l.model && o.poisson_ratio == l.poisson_ratio)
        {
            limits.push(l);
        }
    }
    Ok(ModelLimitsFile {
        version: ModelLimitsFile::VERSION,
        threshold_percent: JND_PERCENT,
        limits,
    })
}

/// The limits of the flat-object models at every ν of the sweep but the paper's, against the
/// neo-Hookean FEM of that ν on the §4.3 block; the inclination limit is the paper's-ν one of
/// the inclination study when it ran (copied, since the tilted runs are made at the paper's ν
/// only, and the reference says so), none otherwise.
pub fn poisson_limits(
    poisson: Option<&PoissonStudy>,
    inclination: Option<&[InclinationStudy]>,
) -> Result<Vec<MeasuredLimit>, ExperimentError> {
    let mut limits = Vec::new();
    for p in poisson.into_iter().flat_map(|s| &s.points) {
        if p.poisson_ratio == MATERIAL.poisson_ratio() {
            continue;
        }
        let material = super::verification::material_with_poisson(p.poisson_ratio)?;
        let deepest_m = p.layer_depths_m.last().copied().unwrap_or(0.0);
        let grid: Vec<f64> = (1..=60).map(|i| i as f64 * 0.1 * MM).collect();
        for (tool, reference_n, specs) in [
            (
                p.tools[0],
                &p.sphere_nh_n,
                models::sphere_specs(FORCE_LAYER_M),
            ),
            (p.tools[1], &p.cone_nh_n, models::cone_specs(FORCE_LAYER_M)),
        ] {
            let reference = format!(
                "{} on the §4.3 block 100 × 100 × 30 mm (bottom clamped), ν = {:.2}, δ ≤ {:.1} \
                 mm: eq. 9 against the neo-Hookean FEM of that ν, 10-node tets, {:.1} mm cells",
                super::tool_description(&tool),
                p.poisson_ratio,
                deepest_m / MM,
                p.layer_cell_m / MM,
            );
            for spec in specs {
                let model = RuntimeModel::new(tool, material, spec).map_err(|source| {
                    ExperimentError::Model {
                        run: format!("model limits ν = {:.2}", p.poisson_ratio),
                        source,
                    }
                })?;
                let errors = ErrorCurve::new(
                    &model.forces_n(&p.layer_depths_m, &LocalGeometry::FLAT),
                    reference_n,
                );
                let crossing = first_crossing(&p.layer_depths_m, &errors.eq9_percent, JND_PERCENT);
                let mut variants = vec![spec];
                variants.extend(inclined_variant(&tool, &spec, &grid)?);
                for model in variants {
                    let (valid_inclination_rad, note) =
                        inclination_limit(inclination, &tool, &model);
                    let note = copied_inclination_note(&note);
                    limits.push(MeasuredLimit {
                        tool: ToolKind::of(&tool),
                        model,
                        valid_depth_m: crossing.unwrap_or(deepest_m),
                        crossed: crossing.is_some(),
                        valid_inclination_rad,
                        reference: format!("{reference}{note}"),
                        poisson_ratio: Some(p.poisson_ratio),
                    });
                }
            }
        }
    }
    Ok(limits)
}

/// The limits file with every entry's inclination limit derived again from `studies`: what the
/// `inclination` command alone refreshes (the depth limits need `all`). Entries of the paper's
/// ν take the studies' angle for their tool kind and model; entries measured at another ν keep
/// taking the paper's-ν angle of the same model, as [`merge_poisson_limits`] gives them. Entries
/// of a tool kind the studies did not tilt are left as they are.
pub fn refresh_inclination_limits(
    mut file: ModelLimitsFile,
    studies: &[InclinationStudy],
) -> ModelLimitsFile {
    for l in file.limits.iter_mut().filter(|l| l.poisson_ratio.is_none()) {
        let Some(tool) = studies
            .iter()
            .map(|s| s.tool)
            .find(|t| ToolKind::of(t) == l.tool)
        else {
            continue;
        };
        let (angle, note) = inclination_limit(Some(studies), &tool, &l.model);
        if angle.is_none() {
            continue;
        }
        l.valid_inclination_rad = angle;
        cut_from(&mut l.reference, "; inclination (");
        l.reference.push_str(&note);
    }
    let at_other_poisson: Vec<MeasuredLimit> = file
        .limits
        .iter()
        .filter(|l| l.poisson_ratio.is_some())
        .cloned()
        .map(|mut l| {
            l.valid_inclination_rad = None;
            cut_from(&mut l.reference, "; inclination as measured at ν");
            l
        })
        .collect();
    merge_poisson_limits(file, at_other_poisson)
}

/// The inclination part of an entry measured at another ν than the paper's: the tilted runs are
/// made at the paper's ν only, so its angle is copied from there, and the reference says so
/// (`"; inclination (…): …"` becomes `"; inclination as measured at ν = 0.33, copied: not
/// measured at this ν (…): …"`). Empty when `note` is.
fn copied_inclination_note(note: &str) -> String {
    match note.strip_prefix("; inclination") {
        Some(rest) => format!(
            "; inclination as measured at ν = {:.2}, copied: not measured at this ν{rest}",
            MATERIAL.poisson_ratio()
        ),
        None => note.to_owned(),
    }
}

/// `reference` without its part from `marker` on (unchanged when it has none).
fn cut_from(reference: &mut String, marker: &str) {
    if let Some(at) = reference.find(marker) {
        reference.truncate(at);
    }
}

/// `file` with its entries measured over ν replaced by `at_other_poisson` (what `poisson` alone
/// refreshes). A new entry without an inclination takes the one measured at the paper's ν for
/// the same model, and says so.
pub fn merge_poisson_limits(
    mut file: ModelLimitsFile,
    at_other_poisson: Vec<MeasuredLimit>,
) -> ModelLimitsFile {
    file.limits.retain(|l| l.poisson_ratio.is_none());
    for mut l in at_other_poisson {
        let paper = file
            .limits
            .iter()
            .find(|o| o.tool == l.tool && o.model == l.model && o.poisson_ratio.is_none())
            .and_then(|o| o.valid_inclination_rad);
        if let (None, Some(a)) = (l.valid_inclination_rad, paper) {
            l.valid_inclination_rad = Some(a);
            l.reference.push_str(&copied_inclination_note(&format!(
                "; inclination: {:.1}°",
                a.to_degrees()
            )));
        }
        file.limits.push(l);
    }
    file
}
