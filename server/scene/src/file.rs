//! The scene file as written: its TOML schema, section by section, and its parsing.
//!
//! Each section keeps what the file says; checks that need more than one section, or a file
//! the scene names, are the loader's (`load.rs`). A value its own type refuses (the material,
//! the tool) is refused here, where the text is, so that the error shows its line.

use std::path::{Path, PathBuf};

use serde::Deserialize;
use softhaptic_device::collision::CollisionMode;
use softhaptic_device::device::DeviceLimits;
use softhaptic_proto::deformation::RenderProfile;
use softhaptic_proto::{CalibrationTable, Material, ModelSpec, ToolShape};

use super::SceneError;
use crate::toml_file::{self, TomlFileError};

/// A value refused where it stands in the file: its byte range and why.
type Refusal = (std::ops::Range<usize>, String);

/// The `[material]` table as written, each value with its place in the file, so that a refused
/// value is shown on its own line (a check of the whole table would point at its header).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSection {
    pub youngs_modulus_pa: toml::Spanned<f64>,
    pub poisson_ratio: toml::Spanned<f64>,
}

impl MaterialSection {
    /// The material, or the value that breaks it.
    pub fn material(&self) -> Result<Material, Refusal> {
        let (e, nu) = (&self.youngs_modulus_pa, &self.poisson_ratio);
        Material::new(*e.get_ref(), *nu.get_ref()).map_err(|err| {
            let span = match err {
                softhaptic_proto::MaterialError::PoissonRatio(_) => nu.span(),
                _ => e.span(),
            };
            (span, err.to_string())
        })
    }
}

/// The tip's shape, as `[tool] shape` names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ToolKind {
    Sphere,
    Cone,
}

/// The `[tool]` table as written, each value with its place in the file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ToolSection {
    pub shape: toml::Spanned<ToolKind>,
    pub radius_m: toml::Spanned<f64>,
    /// The cone's half-angle (axis to flank); a cone only.
    #[serde(default)]
    pub half_angle_rad: Option<toml::Spanned<f64>>,
}

impl ToolSection {
    /// The tool, or the value that breaks it.
    pub fn tool(&self) -> Result<ToolShape, Refusal> {
        let radius_m = *self.radius_m.get_ref();
        let tool = match (self.shape.get_ref(), &self.half_angle_rad) {
            (ToolKind::Sphere, None) => ToolShape::Sphere { radius_m },
            (ToolKind::Sphere, Some(angle)) => {
                return Err((
                    angle.span(),
                    "half_angle_rad: only a cone has a half-angle".into(),
                ));
            }
            (ToolKind::Cone, Some(angle)) => ToolShape::Cone {
                half_angle_rad: *angle.get_ref(),
                radius_m,
            },
            (ToolKind::Cone, None) => {
                return Err((
                    self.shape.span(),
                    "a cone needs half_angle_rad (axis to flank, radians)".into(),
                ));
            }
        };
        tool.validate().map(|()| tool).map_err(|err| {
            let span = match err {
                softhaptic_proto::ToolError::HalfAngle(_) => self
                    .half_angle_rad
                    .as_ref()
                    .map_or(self.shape.span(), |a| a.span()),
                _ => self.radius_m.span(),
            };
            (span, err.to_string())
        })
    }
}

/// A refusal shown as toml shows its own errors: the line and column, the line, a caret under
/// the value, and why.
fn located(text: &str, (span, reason): Refusal) -> String {
    let start = span.start.min(text.len());
    let line_start = text[..start].rfind('\n').map_or(0, |i| i + 1);
    let line_end = text[start..].find('\n').map_or(text.len(), |i| start + i);
    let line_number = text[..start].matches('\n').count() + 1;
    let column = text[line_start..start].chars().count() + 1;
    let width = text[start..span.end.clamp(start, line_end)]
        .chars()
        .count()
        .max(1);
    let gutter = " ".repeat(line_number.to_string().len());
    format!(
        "TOML parse error at line {line_number}, column {column}\n{gutter} |\n{line_number} | {}\n{gutter} | {}{}\n{reason}",
        &text[line_start..line_end],
        " ".repeat(column - 1),
        "^".repeat(width)
    )
}

/// The scene file as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub object: ObjectSection,
    pub material: MaterialSection,
    pub tool: ToolSection,
    #[serde(default)]
    pub device: DeviceSection,
    pub calibration: CalibrationSection,
    #[serde(default)]
    pub haptics: HapticsSection,
    #[serde(default)]
    pub render: RenderSection,
    /// `[[inclusion]]`: stiffer spheres inside the object (palpation); none when absent.
    #[serde(default)]
    pub inclusion: Vec<InclusionSection>,
}

/// One `[[inclusion]]`: a sphere under the surface point closest to `near_m`. Each value is a
/// number, or a range `{ min = .., max = .. }` drawn from `seed` (so a class gets different
/// cases, and the recording keeps the values drawn).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InclusionSection {
    pub shape: InclusionShape,
    /// Object frame: the inclusion lies under the surface point closest to this point.
    pub near_m: Drawn<[f64; 3]>,
    /// Depth of the centre below that surface point, along its normal.
    pub centre_depth_m: Drawn<f64>,
    pub radius_m: Drawn<f64>,
    /// The inclusion's Young's modulus over the tissue's, 1.5 to 10.
    pub stiffness_ratio: Drawn<f64>,
    /// Seeds the draw of the values given as ranges; required when one is.
    pub seed: Option<u64>,
}

/// A value as written: fixed, or a range to draw it from.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(untagged)]
pub enum Drawn<T> {
    Fixed(T),
    Range { min: T, max: T },
}

impl<T> Drawn<T> {
    pub fn is_range(&self) -> bool {
        matches!(self, Drawn::Range { .. })
    }
}

/// The shape of an inclusion (a sphere; the FEM table is measured for spheres).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InclusionShape {
    Sphere,
}

/// `[render]`: what the viewers draw. Nothing here reaches the haptic loop, so a recording
/// replays to the same forces whichever profile it was drawn with.
#[derive(Debug, Clone, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct RenderSection {
    /// The deformation profile (proto/WIRE.md, "Deformation profile"); when absent, `fem` if the
    /// calibration table carries the FEM surface, else `paper`.
    pub profile: Option<RenderProfile>,
}

impl RenderSection {
    /// The profile to draw with `table`: `fem` needs the table's tabulated surface.
    pub fn profile(&self, table: &CalibrationTable) -> Result<RenderProfile, String> {
        match self.profile {
            Some(RenderProfile::Fem) if table.surface().is_none() => Err(format!(
                "\"fem\" draws the FEM surface the calibration table carries, and this table ({}) has none: name an FEM table written by `softhaptic-calibrate rd-table`, or draw \"paper\"",
                table.source().as_str()
            )),
            Some(profile) => Ok(profile),
            None if table.surface().is_some() => Ok(RenderProfile::Fem),
            None => Ok(RenderProfile::Paper),
        }
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectSection {
    /// Name of the object; also the render mesh's URL name (`/meshes/<name>.bin`).
    pub name: String,
    /// A procedural object of the device crate (only `"liver"` today).
    pub builtin: Option<Builtin>,
    /// OBJ file of the coarse haptic mesh, relative to the scene file.
    pub haptic_mesh: Option<PathBuf>,
    /// OBJ file of the fine render mesh; the haptic mesh is drawn when absent.
    pub render_mesh: Option<PathBuf>,
    #[serde(default)]
    pub position_m: [f64; 3],
    /// Quaternion [x, y, z, w]; normalised on load.
    #[serde(default = "identity_quaternion")]
    pub orientation: [f64; 4],
    /// The object's contact model (`[object.model]`): the paper's law when absent.
    #[serde(default)]
    pub model: ModelSpec,
}

pub(super) fn identity_quaternion() -> [f64; 4] {
    [0.0, 0.0, 0.0, 1.0]
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Builtin {
    Liver,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum DeviceKind {
    /// The simulated device of the device crate, moved by a scripted hand.
    #[default]
    Simulated,
    /// A PHANTOM / Touch through OpenHaptics' HD library, loaded at run time.
    Openhaptics,
    /// A 3Dconnexion SpaceMouse through hidapi: rate control, no force rendered.
    Spacemouse,
    /// A Force Dimension device (omega, delta, sigma, Novint Falcon) through the SDK's libdhd,
    /// loaded at run time.
    Forcedimension,
}

impl DeviceKind {
    /// The name a scene file and `--device` use.
    pub fn name(self) -> &'static str {
        match self {
            DeviceKind::Simulated => "simulated",
            DeviceKind::Openhaptics => "openhaptics",
            DeviceKind::Spacemouse => "spacemouse",
            DeviceKind::Forcedimension => "forcedimension",
        }
    }
}

/// The device a run uses, as `--device` names it: `simulated`, `openhaptics`,
/// `openhaptics:<configuration name>`, `spacemouse`, `spacemouse:<serial>`, `forcedimension` or
/// `forcedimension:<index>`; it replaces the scene's `[device] kind` (and `name`, `serial` or
/// `index`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceChoice {
    pub kind: DeviceKind,
    pub name: Option<String>,
}

impl std::str::FromStr for DeviceChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let (kind, name) = match s.split_once(':') {
            Some((kind, name)) => (kind, Some(name.trim().to_owned())),
            None => (s, None),
        };
        let kind = match kind.trim() {
            "simulated" => DeviceKind::Simulated,
            "openhaptics" => DeviceKind::Openhaptics,
            "spacemouse" => DeviceKind::Spacemouse,
            "forcedimension" => DeviceKind::Forcedimension,
            other => {
                return Err(format!(
                    "unknown device kind {other:?}: expected simulated, openhaptics, \"openhaptics:<configuration name>\", spacemouse, \"spacemouse:<serial>\", forcedimension or \"forcedimension:<index>\""
                ));
            }
        };
        if kind == DeviceKind::Forcedimension
            && let Some(index) = name.as_deref()
            && parse_device_index(index).is_err()
        {
            return Err(format!(
                "\"forcedimension:{index}\": the device index must be a whole number from 0 to {MAX_DEVICE_INDEX} (0 is the first device plugged in)"
            ));
        }
        if kind == DeviceKind::Simulated && name.is_some() {
            return Err("the simulated device has no configuration name".into());
        }
        if name.as_deref() == Some("") {
            return Err(format!(
                "an empty {}: write {} alone for the default device",
                if kind == DeviceKind::Spacemouse {
                    "serial"
                } else {
                    "configuration name"
                },
                kind.name()
            ));
        }
        Ok(DeviceChoice { kind, name })
    }
}

/// Where a device's origin and axes are in the world, and its motion scale.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldFromDeviceSection {
    #[serde(default)]
    pub position_m: [f64; 3],
    /// Quaternion [x, y, z, w]; normalised on load.
    #[serde(default = "identity_quaternion")]
    pub orientation: [f64; 4],
    /// World metres per metre of stylus motion.
    #[serde(default = "unit_scale")]
    pub scale: f64,
}

fn unit_scale() -> f64 {
    1.0
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum DeviceModel {
    #[default]
    PhantomDesktop,
    Touch,
    Omni,
    Falcon,
    Omega3,
    Delta3,
    Sigma7,
}

impl DeviceModel {
    pub fn limits(self) -> DeviceLimits {
        match self {
            DeviceModel::PhantomDesktop => DeviceLimits::PHANTOM_DESKTOP,
            DeviceModel::Touch => DeviceLimits::TOUCH,
            DeviceModel::Omni => DeviceLimits::OMNI,
            DeviceModel::Falcon => DeviceLimits::FALCON,
            DeviceModel::Omega3 => DeviceLimits::OMEGA3,
            DeviceModel::Delta3 => DeviceLimits::DELTA3,
            DeviceModel::Sigma7 => DeviceLimits::SIGMA7,
        }
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeviceSection {
    #[serde(default)]
    pub kind: DeviceKind,
    #[serde(default)]
    pub model: DeviceModel,
    /// How far below the undeformed surface the simulated hand aims (the tip stops shallower,
    /// where the hand's grip balances the contact force).
    #[serde(default = "default_press_depth_m")]
    pub press_depth_m: f64,
    /// The OpenHaptics device configuration to open (`None`: the default device).
    #[serde(default)]
    pub name: Option<String>,
    /// Where a real device (OpenHaptics, Force Dimension) sits in the world (identity, one to
    /// one, when absent).
    #[serde(default)]
    pub world_from_device: Option<WorldFromDeviceSection>,
    /// The Force Dimension device to open, by its index among those plugged in (`None`: the
    /// SDK's default device).
    #[serde(default)]
    pub index: Option<u8>,
    /// The SpaceMouse to open, by serial number (`None`: the first found).
    #[serde(default)]
    pub serial: Option<String>,
    /// A recorded SpaceMouse report stream to play instead of a device.
    #[serde(default)]
    pub report_script: Option<PathBuf>,
    /// How a SpaceMouse's puck drives the tool.
    #[serde(default)]
    pub rate: RateSection,
}

/// The largest Force Dimension device index taken (the SDK counts devices from 0).
pub const MAX_DEVICE_INDEX: u8 = 15;

/// A Force Dimension device index as `--device forcedimension:<index>` gives it.
pub fn parse_device_index(text: &str) -> Result<u8, ()> {
    match text.trim().parse::<u8>() {
        Ok(i) if i <= MAX_DEVICE_INDEX => Ok(i),
        _ => Err(()),
    }
}

/// `[device.rate]`: the SpaceMouse's rate control (`softhaptic_device::spacemouse::rate`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RateSection {
    pub dead_band: f64,
    pub gain_m_s: f64,
    pub max_speed_m_s: f64,
    pub smoothing_s: f64,
    /// Half the size of the box the tip stays in, centred on the press site, world axes.
    pub workspace_half_extent_m: [f64; 3],
    /// Height of the start (and reset) point above the press site, along its normal.
    pub home_height_m: f64,
    /// Whether the puck's twist turns the tool; by default on for a cone (its force depends on
    /// its inclination) and off for a sphere (it does not).
    pub rotation: Option<bool>,
    pub angular_gain_rad_s: f64,
    /// Index of the button that resets the tool (0 the first).
    pub reset_button: u32,
}

impl Default for RateSection {
    fn default() -> Self {
        Self {
            dead_band: 0.1,
            gain_m_s: 0.05,
            max_speed_m_s: 0.05,
            smoothing_s: 0.04,
            workspace_half_extent_m: [0.06; 3],
            home_height_m: 0.03,
            rotation: None,
            angular_gain_rad_s: 1.0,
            reset_button: 0,
        }
    }
}

fn default_press_depth_m() -> f64 {
    0.008
}

impl Default for DeviceSection {
    fn default() -> Self {
        Self {
            kind: DeviceKind::Simulated,
            model: DeviceModel::PhantomDesktop,
            press_depth_m: default_press_depth_m(),
            name: None,
            world_from_device: None,
            index: None,
            serial: None,
            report_script: None,
            rate: RateSection::default(),
        }
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationSection {
    /// `"half_space"` for the analytical table (cut by the rigid base when the object's model
    /// declares a thickness), or a calibration JSON file relative to the scene.
    pub table: String,
    /// The measured limits of the contact models (a `ModelLimitsFile`), relative to the scene;
    /// [`DEFAULT_LIMITS_FILE`](super::DEFAULT_LIMITS_FILE) when absent.
    pub limits: Option<PathBuf>,
    /// The inclusions' FEM force-ratio table (written by `softhaptic-calibrate inclusion`),
    /// relative to the scene; required when the scene has an `[[inclusion]]`.
    pub inclusions: Option<PathBuf>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum CollisionModeName {
    PaperVertices,
    #[default]
    Continuous,
}

impl From<CollisionModeName> for CollisionMode {
    fn from(m: CollisionModeName) -> Self {
        match m {
            CollisionModeName::PaperVertices => CollisionMode::PaperVertices,
            CollisionModeName::Continuous => CollisionMode::Continuous,
        }
    }
}

#[derive(Debug, Clone, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct HapticsSection {
    #[serde(default)]
    pub collision: CollisionModeName,
    /// Virtual damping along the normal; the tool's default when absent.
    pub damping_n_s_per_m: Option<f64>,
    /// The force above which the trainee's metrics count time (`time_above_safe_s`), N.
    pub safe_force_n: Option<f64>,
}

impl SceneFile {
    /// Parses scene text; `path` names it in errors. Syntax, an unknown field, a wrong type and
    /// a material or tool its type refuses are errors here, each shown on its line.
    pub(super) fn parse(text: &str, path: &Path) -> Result<SceneFile, SceneError> {
        let refused = |message: String| SceneError::from(TomlFileError::parse(path, message));
        let file: SceneFile = toml_file::parse(text, path)?;
        // Checked here, where the text is, so that a refused value is shown on its line.
        file.material
            .material()
            .map_err(|r| refused(located(text, r)))?;
        file.tool.tool().map_err(|r| refused(located(text, r)))?;
        Ok(file)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::super::Scene;
    use super::*;

    #[test]
    fn a_force_dimension_device_is_chosen_by_kind_index_and_preset() {
        let c: DeviceChoice = "forcedimension".parse().unwrap();
        assert_eq!((c.kind, c.name), (DeviceKind::Forcedimension, None));
        let c: DeviceChoice = "forcedimension:1".parse().unwrap();
        assert_eq!(c.name.as_deref(), Some("1"));
        for bad in ["forcedimension:x", "forcedimension:16", "forcedimension:-1"] {
            let e = bad.parse::<DeviceChoice>().unwrap_err();
            assert!(e.contains("whole number from 0 to 15"), "{bad}: {e}");
        }
        let e = "joystick".parse::<DeviceChoice>().unwrap_err();
        assert!(e.contains("forcedimension"), "{e}");

        let base = include_str!("../../../scenes/forcedimension.toml");
        let load = |text: &str| Scene::from_toml(text, Path::new("<test>"), None);
        let s = load(base).unwrap();
        assert_eq!(s.device_kind, DeviceKind::Forcedimension);
        assert_eq!(s.device_limits, DeviceLimits::OMEGA3);
        assert_eq!(s.device_name, None);
        let with = |from: &str, to: &str| base.replacen(from, to, 1);
        let s = load(&with("# index = 0", "index = 2")).unwrap();
        assert_eq!(s.device_name.as_deref(), Some("2"));
        let s = load(&with("model = \"omega3\"", "model = \"falcon\"")).unwrap();
        assert_eq!(s.device_limits, DeviceLimits::FALCON);
        let e = load(&with("# index = 0", "index = 16"))
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("device.index") && e.contains("16"), "{e}");
        let placed = base
            .lines()
            .find(|l| l.starts_with("world_from_device"))
            .unwrap();
        let simulated = base.replacen(placed, "", 1).replacen(
            "kind = \"forcedimension\"",
            "kind = \"simulated\"\nindex = 0",
            1,
        );
        let e = load(&simulated).err().unwrap().to_string();
        assert!(
            e.contains("device.index") && e.contains("forcedimension"),
            "{e}"
        );
    }

    #[test]
    fn the_scene_chooses_the_drawn_profile_and_fem_needs_the_tables_surface() {
        // The default scene names no profile: its FEM table carries the surface, so fem.
        let text = include_str!("../../../scenes/default.toml");
        assert!(
            text.trim_end()
                .ends_with("instead, and \"fem\" with a table that carries no surface is refused.")
        );
        let load = |text: &str| Scene::from_toml(text, Path::new("<test>"), None);
        let s = load(text).unwrap();
        assert_eq!(s.render_profile, RenderProfile::Fem);
        assert!(s.calibration.surface().is_some());
        assert_eq!(s.message().render_profile, RenderProfile::Fem);
        // The file ends in [render], so a line appended is that section's.
        let with = |text: &str, line: &str| format!("{text}{line}\n");
        let s = load(&with(text, "profile = \"paper\"")).unwrap();
        assert_eq!(s.render_profile, RenderProfile::Paper);
        let s = load(&with(text, "profile = \"fem\"")).unwrap();
        assert_eq!(s.render_profile, RenderProfile::Fem);
        // An analytical table carries no surface: paper by default, fem refused naming the field.
        let analytical = text.replace(
            "table = \"calibration/sphere10_50kpa.json\"",
            "table = \"half_space\"",
        );
        assert_eq!(
            load(&analytical).unwrap().render_profile,
            RenderProfile::Paper
        );
        let err = load(&with(&analytical, "profile = \"fem\""))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("render.profile") && err.contains("half_space"),
            "{err}"
        );
        // An unknown profile is refused with its line.
        let err = load(&with(text, "profile = \"smooth\""))
            .unwrap_err()
            .to_string();
        assert!(err.contains("smooth"), "{err}");
    }
}
