//! The validity limits of each runtime model, as written to `model_limits.json`.

use super::*;

pub(super) fn limits_section(limits: &ModelLimitsFile, md: &mut String) {
    let _ = writeln!(md, "### Measured validity limits\n");
    let _ = writeln!(
        md,
        "Written to `model_limits.json` (format `softhaptic_proto::ModelLimitsFile`, version {}, \
         threshold {:.0}%): the scenes' validity flags use the limit of their object's exact \
         model, the paper's (4.3 mm; 22° sphere, 9° cone) when the file has none. Depth: first \
         crossing of the eq. 9 error, or the deepest depth measured when it never crosses.\n",
        limits.version, limits.threshold_percent
    );
    let _ = writeln!(
        md,
        "| tool | model | valid depth | crossed | valid inclination |\n|---|---|---|---|---|"
    );
    for l in &limits.limits {
        let tool = match l.tool {
            ToolKind::Sphere => softhaptic_proto::ToolShape::Sphere { radius_m: 0.006 },
            ToolKind::Cone => softhaptic_proto::ToolShape::Cone {
                half_angle_rad: std::f64::consts::FRAC_PI_4,
                radius_m: 0.006,
            },
        };
        let _ = writeln!(
            md,
            "| {:?} | {} | {:.2} mm | {} | {} |",
            l.tool,
            l.model.label(&tool),
            l.valid_depth_m / MM,
            if l.crossed {
                "yes"
            } else {
                "no (deepest measured)"
            },
            l.valid_inclination_rad
                .map(|a| format!("{:.1}°", a.to_degrees()))
                .unwrap_or_else(|| "— (paper's)".to_owned())
        );
    }
    md.push('\n');
}
