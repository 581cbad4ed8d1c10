//! The validity limits of each runtime model, as written to `model_limits.json`.

use super::*;
use crate::experiments::MATERIAL;

pub(super) fn limits_section(limits: &ModelLimitsFile, md: &mut String) {
    let _ = writeln!(md, "### Measured validity limits\n");
    let _ = writeln!(
        md,
        "Written to `model_limits.json` (format `softhaptic_proto::ModelLimitsFile`, version {}, \
         threshold {:.0}%): the scenes' validity flags use the limit of their object's exact \
         model, the paper's (4.3 mm; 22° sphere, 9° cone) when the file has none. Depth: first \
         crossing of the eq. 9 error, or the deepest depth measured when it never crosses. ν: \
         the Poisson ratio the depth was measured at (a scene takes the entries of its own ν). \
         The tilted runs are made at ν = {:.2} only, so the inclination of every other ν is the \
         one measured at ν = {:.2}, copied (marked *, and said so in the entry's reference).\n",
        limits.version,
        limits.threshold_percent,
        MATERIAL.poisson_ratio(),
        MATERIAL.poisson_ratio()
    );
    let _ = writeln!(
        md,
        "| tool | model | ν | valid depth | crossed | valid inclination |\n|---|---|---|---|---|---|"
    );
    for l in &limits.limits {
        let tool = match l.tool {
            ToolKind::Sphere => softhaptic_proto::ToolShape::Sphere { radius_m: 0.006 },
            ToolKind::Cone => softhaptic_proto::ToolShape::Cone {
                half_angle_rad: std::f64::consts::FRAC_PI_4,
                radius_m: 0.006,
            },
        };
        let copied = if l.poisson_ratio.is_some() { "*" } else { "" };
        let _ = writeln!(
            md,
            "| {:?} | {} | {:.2} | {:.2} mm | {} | {} |",
            l.tool,
            l.model.label(&tool),
            l.poisson_ratio.unwrap_or(MATERIAL.poisson_ratio()),
            l.valid_depth_m / MM,
            if l.crossed {
                "yes"
            } else {
                "no (deepest measured)"
            },
            l.valid_inclination_rad
                .map(|a| format!("{:.1}°{copied}", a.to_degrees()))
                .unwrap_or_else(|| "— (paper's)".to_owned())
        );
    }
    md.push('\n');
}
