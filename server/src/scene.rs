//! Scenes: what the server simulates, described in a TOML file.
//!
//! A scene names one object (haptic and render meshes, pose, material, contact model), the
//! tool, the device, the calibration table that gives R_d and the measured limits of the
//! contact models, the collision mode and the damping. [`SceneFile`] is the file as written;
//! [`Scene`] is the same content validated and loaded (meshes read, the calibration table read
//! or built, the object's [`ForceModel`] built for the scene's tool and its validity limits
//! looked up), ready to build the haptic world. An invalid file is refused before anything
//! starts, with the file, the field and the reason ([`SceneError`]); syntax and type errors
//! carry toml's line and column.
//!
//! ```toml
//! [object]
//! name = "liver"
//! builtin = "liver"                 # or: haptic_mesh = "x.obj", render_mesh = "x_fine.obj"
//! position_m = [0.0, 0.0, 0.0]
//! orientation = [0.0, 0.0, 0.0, 1.0] # quaternion [x, y, z, w]
//!
//! [object.model]                    # the object's contact model; absent: the paper's law
//! exact_sphere = true               # Sneddon's exact sphere (sphere tools only)
//! curvature = true                  # the object's local curvature, from the haptic mesh
//! hyperelastic = true               # neo-Hookean stiffening fitted to the project's FEM
//! inclination = false               # force along the normal of a tilted tool (cone)
//! thickness = { thickness_m = 0.03, bonded = true } # a layer on a rigid base; omit if none
//!
//! [material]
//! youngs_modulus_pa = 50000.0
//! poisson_ratio = 0.33
//!
//! [tool]
//! shape = "sphere"
//! radius_m = 0.01
//!
//! [device]
//! kind = "simulated"               # or "openhaptics": a PHANTOM / Touch through OpenHaptics,
//!                                  # or "spacemouse": a 3Dconnexion puck (input only, no force)
//! model = "phantom_desktop"        # phantom_desktop | touch | omni: the preset of limits (a real
//!                                  # device's own nominal limits apply where tighter)
//! press_depth_m = 0.008            # how deep the simulated hand aims
//! name = "Default Device"          # openhaptics: the device configuration's name
//! world_from_device = { position_m = [0.0, 0.0, 0.0], orientation = [0.0, 0.0, 0.0, 1.0], scale = 1.0 }
//!                                  # openhaptics: where the device's origin and axes are in the
//!                                  # world, and world metres per metre of stylus motion
//! serial = "..."                   # spacemouse: the one to open (default: the first found)
//! report_script = "puck.hid"       # spacemouse: play a recorded report stream instead of a
//!                                  # device (relative to this file)
//!
//! [device.rate]                    # spacemouse: the puck's deflection as the tool's velocity
//! dead_band = 0.1                  # fraction of full deflection that commands nothing
//! gain_m_s = 0.05                  # tool speed at full deflection of one axis
//! max_speed_m_s = 0.05             # speed limit
//! smoothing_s = 0.04               # time constant of the velocity's smoothing
//! workspace_half_extent_m = [0.06, 0.06, 0.06]  # the box the tip stays in, around the press site
//! home_height_m = 0.03             # the start (and reset) point above the press site
//! rotation = false                 # whether the puck's twist turns the tool (default: on for
//!                                  # a cone, off for a sphere, whose force it does not change)
//! angular_gain_rad_s = 1.0         # turn rate at full twist
//! reset_button = 0                 # the button that puts the tool back home
//!
//! [calibration]
//! table = "half_space"             # or a path to a calibration JSON, relative to this file;
//!                                  # with a model thickness, the half-space on that rigid base
//! limits = "my_limits.json"        # measured limits of the models; when absent, the default
//!                                  # calibration/model_limits.json, which may be missing
//!
//! [haptics]
//! collision = "continuous"         # or "paper_vertices"
//! damping_n_s_per_m = 1.0
//! safe_force_n = 2.0               # the trainee's metrics count the time above this force
//!
//! [render]                         # what the viewers draw; never changes the force
//! profile = "fem"                  # the calibration's FEM surface (needs a table that carries
//!                                  # it), or "paper": the paper's Bézier. Default: "fem" when
//!                                  # the table carries a surface, else "paper"
//! ```
//!
//! # Model only what the scene requires
//! The scene builds one [`ForceModel`], for its tool: a scene with a cone builds no sphere law,
//! and the mesh's curvature is estimated only when the model uses it (the haptic world asks the
//! collider for it, [`Scene::haptic_world`]).
//!
//! # Validity limits
//! The flags `beyond_valid_depth` and `beyond_valid_inclination` use the measured limits of the
//! object's model for the scene's tool kind, from the limits file (`calibration.limits`, written
//! by `softhaptic-calibrate`), or the paper's (4.3 mm; 22° sphere, 9° cone) when the file has no
//! entry for the model ([`ValidityLimits`]). A missing file at the default path falls back to
//! the paper's with a log line; a file named in the scene must exist and be well formed.
//!
//! # Files of the built-in scene
//! The built-in default scene has no directory of its own. The calibration tables it may name
//! (the ones under the repository's `scenes/calibration/`) are built into the binary, so it
//! runs from any directory; its limits file is looked up in the `scenes/` directory of the
//! source tree the binary was built from (the calibration command rewrites it, so it is read
//! when the scene loads rather than frozen into the binary).

use std::path::{Path, PathBuf};

use crate::files::{self, FileKind, ReadError};

use glam::{DQuat, DVec3};
use serde::Deserialize;
use softhaptic_device::collision::{Collider, CollisionMode};
use softhaptic_device::device::DeviceLimits;
use softhaptic_device::force::ForceConfig;
use softhaptic_device::mesh::HapticMesh;
use softhaptic_device::model::ForceModel;
use softhaptic_device::spacemouse::rate::RateConfig;
use softhaptic_device::world::HapticWorld;
use softhaptic_proto::calibration::PAPER_THRESHOLD_M;
use softhaptic_proto::deformation::RenderProfile;
use softhaptic_proto::record::{MeshRecord, RecordedMeshes, SceneRecord};
use softhaptic_proto::wire::ContactModelInfo;
use softhaptic_proto::{
    CalibrationError, CalibrationTable, Material, ModelError, ModelLimitsFile, ModelSpec, Pose,
    ToolShape, ValidityLimits,
};

/// The limits file a scene uses when it names none, relative to the scene file.
pub const DEFAULT_LIMITS_FILE: &str = "calibration/model_limits.json";

/// The calibration tables built into the binary, by the name the built-in scene gives them
/// (relative to the repository's `scenes/`).
const EMBEDDED_TABLES: [(&str, &str); 4] = [
    (
        "calibration/sphere10_50kpa.json",
        include_str!("../../scenes/calibration/sphere10_50kpa.json"),
    ),
    (
        "calibration/sphere10_1500kpa.json",
        include_str!("../../scenes/calibration/sphere10_1500kpa.json"),
    ),
    (
        "calibration/cone10_45_50kpa.json",
        include_str!("../../scenes/calibration/cone10_45_50kpa.json"),
    ),
    (
        "calibration/cone10_45_1500kpa.json",
        include_str!("../../scenes/calibration/cone10_45_1500kpa.json"),
    ),
];

/// The `scenes/` directory of the source tree this binary was built from.
pub fn source_tree_scenes_dir() -> PathBuf {
    let server = Path::new(env!("CARGO_MANIFEST_DIR"));
    server
        .parent()
        .map_or_else(|| server.join(".."), Path::to_path_buf)
        .join("scenes")
}

/// Why a scene could not be loaded. Every variant names the file; field-level errors name the
/// field and the value.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read. The OS's text is part of this message, not a separate
    /// cause, so that an error chain prints it once.
    #[error("{path}: {reason}")]
    Read { path: PathBuf, reason: ReadError },
    /// Syntax, an unknown field, a wrong type, or a value refused by its type (material, tool):
    /// toml's message shows the line, the column and the offending text.
    #[error("{path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("{path}: {field}: {reason}")]
    Field {
        path: PathBuf,
        field: String,
        reason: String,
    },
    #[error("{path}: {field}: mesh {mesh}: {reason}")]
    Mesh {
        path: PathBuf,
        field: &'static str,
        mesh: PathBuf,
        reason: String,
    },
    #[error("{path}: calibration.table: {table}: {reason}")]
    Calibration {
        path: PathBuf,
        table: PathBuf,
        reason: String,
    },
    #[error("{path}: calibration.limits: {file}: {reason}")]
    Limits {
        path: PathBuf,
        file: PathBuf,
        reason: String,
    },
}

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

fn identity_quaternion() -> [f64; 4] {
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
}

impl DeviceKind {
    /// The name a scene file and `--device` use.
    pub fn name(self) -> &'static str {
        match self {
            DeviceKind::Simulated => "simulated",
            DeviceKind::Openhaptics => "openhaptics",
            DeviceKind::Spacemouse => "spacemouse",
        }
    }
}

/// The device a run uses, as `--device` names it: `simulated`, `openhaptics`,
/// `openhaptics:<configuration name>`, `spacemouse` or `spacemouse:<serial>`; it replaces the
/// scene's `[device] kind` (and `name` or `serial`).
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
            other => {
                return Err(format!(
                    "unknown device kind {other:?}: expected simulated, openhaptics, \"openhaptics:<configuration name>\", spacemouse or \"spacemouse:<serial>\""
                ));
            }
        };
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
}

impl DeviceModel {
    pub fn limits(self) -> DeviceLimits {
        match self {
            DeviceModel::PhantomDesktop => DeviceLimits::PHANTOM_DESKTOP,
            DeviceModel::Touch => DeviceLimits::TOUCH,
            DeviceModel::Omni => DeviceLimits::OMNI,
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
    /// Where an OpenHaptics device sits in the world (identity, one to one, when absent).
    #[serde(default)]
    pub world_from_device: Option<WorldFromDeviceSection>,
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
    /// [`DEFAULT_LIMITS_FILE`] when absent.
    pub limits: Option<PathBuf>,
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

/// A render surface in the object's frame with unit vertex normals.
#[derive(Debug, Clone)]
pub struct RenderSurface {
    pub positions_m: Vec<DVec3>,
    pub normals: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
}

impl RenderSurface {
    /// The binary layout of `GET /meshes/<name>.bin` (proto/WIRE.md): "SHM1", u32 vertex count,
    /// u32 triangle count, f32 positions, f32 normals, u32 indices, all little-endian.
    pub fn to_shm1(&self) -> Vec<u8> {
        let n = self.positions_m.len();
        let t = self.triangles.len();
        let mut out = Vec::with_capacity(12 + n * 24 + t * 12);
        out.extend_from_slice(b"SHM1");
        out.extend_from_slice(&(n as u32).to_le_bytes());
        out.extend_from_slice(&(t as u32).to_le_bytes());
        for list in [&self.positions_m, &self.normals] {
            for v in list.iter() {
                for c in v.to_array() {
                    out.extend_from_slice(&(c as f32).to_le_bytes());
                }
            }
        }
        for tri in &self.triangles {
            for i in tri {
                out.extend_from_slice(&i.to_le_bytes());
            }
        }
        out
    }

    /// Builds the surface and its area-weighted normals (the haptic mesh's own computation).
    fn from_mesh(mesh: &HapticMesh) -> Self {
        RenderSurface {
            positions_m: mesh.positions_m().to_vec(),
            normals: mesh.normals().to_vec(),
            triangles: mesh.triangles().to_vec(),
        }
    }
}

/// A scene validated and loaded, ready to build the haptic world.
#[derive(Debug, Clone)]
pub struct Scene {
    /// The file it came from (`None` for the built-in default).
    pub source: Option<PathBuf>,
    pub object_name: String,
    pub object_in_world: Pose,
    pub haptic_mesh: HapticMesh,
    pub render_surface: RenderSurface,
    pub material: Material,
    pub tool: ToolShape,
    pub device_kind: DeviceKind,
    /// The preset's limits as loaded; once a real device is open, the tighter of them and the
    /// device's own (`crate::devices::open`), and in a replay check the limits the recording
    /// ran with.
    pub device_limits: DeviceLimits,
    /// The OpenHaptics device configuration name, or the SpaceMouse's serial (`None`: the
    /// default device, the first SpaceMouse found).
    pub device_name: Option<String>,
    /// Where a real device sits in the world.
    pub world_from_device: Pose,
    /// World metres per metre of stylus motion.
    pub device_scale: f64,
    /// The opened device as viewers are told it (model, serial); `None` before it is opened.
    pub device_label: Option<String>,
    /// Whether the opened device renders force (false for a SpaceMouse).
    pub device_renders_force: bool,
    /// A SpaceMouse's rate control, in the world: the box around the press site, the home
    /// above it.
    pub spacemouse_rate: RateConfig,
    /// The SpaceMouse report stream to play instead of a device, resolved against the scene's
    /// directory (never read for a recording's check or replay).
    pub spacemouse_script: Option<PathBuf>,
    /// The object's meshes came from files (and go into the recording, [`Scene::recorded_meshes`]).
    pub meshes_from_files: bool,
    pub press_depth_m: f64,
    /// The force above which the trainee's metrics count time, N.
    pub safe_force_n: f64,
    /// Where the simulated hand presses, object frame: a surface point and its outward normal.
    pub press_site_in_object: (DVec3, DVec3),
    pub calibration: CalibrationTable,
    /// The deformation profile the viewers draw (`[render] profile`).
    pub render_profile: RenderProfile,
    pub collision: CollisionMode,
    /// The safety layers, damping, and the validity limits of `validity`.
    pub force: ForceConfig,
    /// The object's contact model, built for the scene's tool (and only for it).
    pub contact_model: ForceModel,
    /// The limits the validity flags use, and where they come from.
    pub validity: ValidityLimits,
}

/// Where a scene's relative file names resolve: the scene file's directory, or, for a built-in
/// scene, the tables built into the binary and the source tree's `scenes/`.
#[derive(Debug, Clone, Copy)]
enum FileBase<'a> {
    Dir(&'a Path),
    BuiltIn,
}

impl FileBase<'_> {
    fn resolve(&self, p: &Path) -> PathBuf {
        match self {
            FileBase::Dir(base) => base.join(p),
            FileBase::BuiltIn => source_tree_scenes_dir().join(p),
        }
    }
}

/// Where the object's model and its limits come from.
#[derive(Debug, Clone, Copy)]
enum ModelSource<'a> {
    /// The scene file's `[object.model]` and limits file.
    File,
    /// A recording: the model and limits its `scene` message says the session ran with, its
    /// calibration table, and the meshes it holds (never the files its scene names).
    Recorded(&'a SceneRecord),
}

impl Scene {
    /// The scene used when no file is given: the procedural liver, a 10 mm sphere, E = 50 kPa,
    /// ν = 0.33, the best combined contact model for a sphere on a curved organ (exact sphere,
    /// hyperelastic fit, curvature), the neo-Hookean FEM R_d table of a 10 mm sphere at 50 kPa
    /// (built into the binary), a simulated PHANTOM Desktop.
    pub fn builtin_default() -> Result<Scene, SceneError> {
        let text = include_str!("../../scenes/default.toml");
        Self::from_toml(text, Path::new("<built-in scenes/default.toml>"), None)
    }

    /// Reads and loads a scene file. Relative mesh and table paths are relative to the file.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        let text = files::read_text(path, FileKind::Scene).map_err(|reason| SceneError::Read {
            path: path.to_owned(),
            reason,
        })?;
        let base = path.parent().unwrap_or(Path::new("."));
        Self::from_toml(&text, path, Some(base))
    }

    /// Parses, validates and loads scene text; `path` is used in errors, `base` resolves
    /// relative files (`None`: a built-in scene, whose files resolve as the module docs say).
    pub fn from_toml(text: &str, path: &Path, base: Option<&Path>) -> Result<Scene, SceneError> {
        let file = Self::parse(text, path)?;
        Self::from_file(file, path, base, ModelSource::File)
    }

    /// Loads the scene a recording ran with, from what the recording holds alone: its scene
    /// text, the contact model and limits and the calibration table of its `scene` message (so a
    /// replay rebuilds the same model even if the scene's defaults, the limits file or the table
    /// have changed since), and the meshes it kept. No file is read: a recording's scene cannot
    /// make a check read a local file, and an edited mesh on disk does not change a check.
    /// `path` names the recording's scene in errors.
    pub fn from_recording(record: &SceneRecord, path: &Path) -> Result<Scene, SceneError> {
        let file = Self::parse(&record.scene_toml, path)?;
        let mut scene = Self::from_file(file, path, None, ModelSource::Recorded(record))?;
        scene.meshes_from_files = record.meshes.is_some();
        Ok(scene)
    }

    /// The object's meshes for the recording, when they came from files (a built-in object's
    /// are the build's own).
    pub fn recorded_meshes(&self) -> Option<RecordedMeshes> {
        if !self.meshes_from_files {
            return None;
        }
        let haptic = mesh_record(self.haptic_mesh.positions_m(), self.haptic_mesh.triangles());
        let render = mesh_record(
            &self.render_surface.positions_m,
            &self.render_surface.triangles,
        );
        Some(RecordedMeshes {
            render: (render != haptic).then_some(render),
            haptic,
        })
    }

    fn parse(text: &str, path: &Path) -> Result<SceneFile, SceneError> {
        let refused = |message: String| SceneError::Parse {
            path: path.to_owned(),
            message,
        };
        let file: SceneFile =
            toml::from_str(text).map_err(|e| refused(e.to_string().trim_end().to_owned()))?;
        // Checked here, where the text is, so that a refused value is shown on its line.
        file.material
            .material()
            .map_err(|r| refused(located(text, r)))?;
        file.tool.tool().map_err(|r| refused(located(text, r)))?;
        Ok(file)
    }

    /// Replaces the scene's device with `--device`'s choice.
    pub fn choose_device(&mut self, choice: &DeviceChoice) {
        if choice.kind != self.device_kind || choice.name.is_some() {
            self.device_name = choice.name.clone();
        }
        self.device_kind = choice.kind;
    }

    /// The haptic world of this scene: its mesh, pose, contact model, force configuration and
    /// device limits. The world estimates the mesh's curvature only if the model uses it.
    pub fn haptic_world(&self) -> HapticWorld {
        let mut world = HapticWorld::with_model(
            Collider::new(self.haptic_mesh.clone(), self.collision),
            self.object_in_world,
            self.contact_model.clone(),
            self.force,
            self.device_limits,
        );
        world.set_safe_force(self.safe_force_n);
        world
    }

    /// The active contact model as the `scene` message describes it.
    pub fn contact_model_info(&self) -> ContactModelInfo {
        ContactModelInfo::new(&self.tool, self.contact_model.spec(), &self.validity)
    }

    fn from_file(
        file: SceneFile,
        path: &Path,
        base: Option<&Path>,
        model_source: ModelSource<'_>,
    ) -> Result<Scene, SceneError> {
        let field = |field: &str, reason: String| SceneError::Field {
            path: path.to_owned(),
            field: field.to_owned(),
            reason,
        };
        let files = match base {
            Some(b) => FileBase::Dir(b),
            None => FileBase::BuiltIn,
        };
        let resolve = |p: &Path| files.resolve(p);
        let object = &file.object;
        if object.name.is_empty()
            || !object
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
        {
            return Err(field(
                "object.name",
                format!(
                    "must be non-empty letters, digits, '_' or '-' (it names /meshes/<name>.bin), got {:?}",
                    object.name
                ),
            ));
        }
        let position_m = DVec3::from_array(object.position_m);
        if !position_m.is_finite() {
            return Err(field(
                "object.position_m",
                format!("must be finite, got {:?}", object.position_m),
            ));
        }
        let q = DQuat::from_array(object.orientation);
        let orientation = match q.is_finite().then(|| q.length()) {
            Some(len) if len > 1e-9 => q / len,
            _ => {
                return Err(field(
                    "object.orientation",
                    format!(
                        "must be a finite non-zero quaternion [x, y, z, w], got {:?}",
                        object.orientation
                    ),
                ));
            }
        };
        let object_in_world = Pose {
            position_m,
            orientation,
        };

        let (haptic_mesh, render_surface, press_site_in_object) = match (
            object.builtin,
            &object.haptic_mesh,
        ) {
            (Some(Builtin::Liver), None) => {
                if object.render_mesh.is_some() {
                    return Err(field(
                        "object.render_mesh",
                        "cannot be combined with builtin = \"liver\" (it brings its own)".into(),
                    ));
                }
                let render = softhaptic_device::liver::render_mesh();
                let top = softhaptic_device::liver::top_contact();
                (
                    softhaptic_device::liver::haptic_mesh(),
                    RenderSurface::from_mesh(&render),
                    (top.point_m, top.normal),
                )
            }
            (Some(_), Some(_)) => {
                return Err(field(
                    "object.haptic_mesh",
                    "give either builtin or haptic_mesh, not both".into(),
                ));
            }
            (None, None) => {
                return Err(field(
                    "object",
                    "needs builtin = \"liver\" or haptic_mesh = \"<file.obj>\"".into(),
                ));
            }
            (None, Some(haptic_path)) => {
                let (haptic, render) = match model_source {
                    ModelSource::Recorded(record) => {
                        let Some(meshes) = &record.meshes else {
                            return Err(field(
                                "object.haptic_mesh",
                                format!(
                                    "{} is not in the recording (it was made before recordings kept their meshes), and a check never reads a file a recording names",
                                    haptic_path.display()
                                ),
                            ));
                        };
                        let haptic = mesh_from_record(&meshes.haptic)
                            .map_err(|e| field("object.haptic_mesh", e))?;
                        let render = match &meshes.render {
                            Some(r) => {
                                mesh_from_record(r).map_err(|e| field("object.render_mesh", e))?
                            }
                            None => haptic.clone(),
                        };
                        (haptic, render)
                    }
                    ModelSource::File => {
                        if base.is_none() {
                            return Err(field(
                                "object.haptic_mesh",
                                "the built-in scene cannot name files".into(),
                            ));
                        }
                        let haptic = load_obj(&resolve(haptic_path), path, "object.haptic_mesh")?;
                        let render = match &object.render_mesh {
                            Some(p) => load_obj(&resolve(p), path, "object.render_mesh")?,
                            None => haptic.clone(),
                        };
                        (haptic, render)
                    }
                };
                let surface = RenderSurface::from_mesh(&render);
                let site = highest_vertex(&haptic, &object_in_world);
                (haptic, surface, site)
            }
        };

        // Both were checked when the text was parsed.
        let tool = file
            .tool
            .tool()
            .map_err(|(_, reason)| field("tool", reason))?;
        let material = file
            .material
            .material()
            .map_err(|(_, reason)| field("material", reason))?;
        let press_depth_m = file.device.press_depth_m;
        if !(press_depth_m.is_finite() && (0.0..=0.05).contains(&press_depth_m)) {
            return Err(field(
                "device.press_depth_m",
                format!("must be finite and in [0, 0.05] m, got {press_depth_m}"),
            ));
        }
        if file.device.kind != DeviceKind::Openhaptics {
            if file.device.name.is_some() {
                return Err(field(
                    "device.name",
                    "names an OpenHaptics device configuration: only for kind = \"openhaptics\""
                        .into(),
                ));
            }
            if file.device.world_from_device.is_some() {
                return Err(field(
                    "device.world_from_device",
                    "places a real device in the world: only for kind = \"openhaptics\"".into(),
                ));
            }
        }
        if file
            .device
            .name
            .as_deref()
            .is_some_and(|n| n.is_empty() || n.contains('\0'))
        {
            return Err(field(
                "device.name",
                format!(
                    "must be a non-empty configuration name, got {:?}; leave it out for the default device",
                    file.device.name.as_deref().unwrap_or_default()
                ),
            ));
        }
        let placement = file
            .device
            .world_from_device
            .unwrap_or(WorldFromDeviceSection {
                position_m: [0.0; 3],
                orientation: identity_quaternion(),
                scale: 1.0,
            });
        let device_position_m = DVec3::from_array(placement.position_m);
        if !device_position_m.is_finite() {
            return Err(field(
                "device.world_from_device.position_m",
                format!("must be finite, got {:?}", placement.position_m),
            ));
        }
        let dq = DQuat::from_array(placement.orientation);
        let device_orientation = match dq.is_finite().then(|| dq.length()) {
            Some(len) if len > 1e-9 => dq / len,
            _ => {
                return Err(field(
                    "device.world_from_device.orientation",
                    format!(
                        "must be a finite non-zero quaternion [x, y, z, w], got {:?}",
                        placement.orientation
                    ),
                ));
            }
        };
        if !(placement.scale.is_finite() && placement.scale > 0.0 && placement.scale <= 100.0) {
            return Err(field(
                "device.world_from_device.scale",
                format!(
                    "must be finite and in (0, 100] world metres per metre of stylus motion, got {}",
                    placement.scale
                ),
            ));
        }
        if file.device.kind != DeviceKind::Spacemouse {
            for (name, given) in [
                ("device.serial", file.device.serial.is_some()),
                ("device.report_script", file.device.report_script.is_some()),
            ] {
                if given {
                    return Err(field(
                        name,
                        "is a SpaceMouse setting: only for kind = \"spacemouse\"".into(),
                    ));
                }
            }
        }
        if file.device.serial.as_deref().is_some_and(str::is_empty) {
            return Err(field(
                "device.serial",
                "must be a non-empty serial number; leave it out for the first SpaceMouse found"
                    .into(),
            ));
        }
        let spacemouse_rate = {
            let r = file.device.rate;
            let (point, normal) = press_site_in_object;
            let normal_in_world = object_in_world.orientation * normal;
            let site_in_world = object_in_world.transform_point(point);
            let half = DVec3::from_array(r.workspace_half_extent_m);
            if !(half.is_finite() && half.cmpgt(DVec3::ZERO).all() && half.cmple(DVec3::ONE).all())
            {
                return Err(field(
                    "device.rate.workspace_half_extent_m",
                    format!(
                        "must be three finite values in (0, 1] m, got {:?}",
                        r.workspace_half_extent_m
                    ),
                ));
            }
            if !(r.home_height_m.is_finite() && r.home_height_m >= 0.0) {
                return Err(field(
                    "device.rate.home_height_m",
                    format!("must be finite and ≥ 0 m, got {}", r.home_height_m),
                ));
            }
            if r.reset_button >= 32 {
                return Err(field(
                    "device.rate.reset_button",
                    format!("must be a button index in 0..32, got {}", r.reset_button),
                ));
            }
            let home = Pose {
                position_m: site_in_world + normal_in_world * r.home_height_m,
                orientation: DQuat::from_rotation_arc(DVec3::Y, normal_in_world),
            };
            let config = RateConfig {
                dead_band: r.dead_band,
                gain_m_s: r.gain_m_s,
                max_speed_m_s: r.max_speed_m_s,
                smoothing_s: r.smoothing_s,
                rotation: r.rotation.unwrap_or(matches!(tool, ToolShape::Cone { .. })),
                angular_gain_rad_s: r.angular_gain_rad_s,
                reset_buttons: 1 << r.reset_button,
                ..RateConfig::new(home, site_in_world - half, site_in_world + half)
            };
            if let Some(problem) = config.problem() {
                return Err(field("device.rate", problem));
            }
            config
        };
        let spacemouse_script = file.device.report_script.as_deref().map(resolve);
        let mut force = ForceConfig::for_tool(&tool);
        if let Some(d) = file.haptics.damping_n_s_per_m {
            if !(d.is_finite() && d >= 0.0) {
                return Err(field(
                    "haptics.damping_n_s_per_m",
                    format!("must be finite and >= 0, got {d}"),
                ));
            }
            force.damping_n_s_per_m = d;
        }
        let safe_force_n = file
            .haptics
            .safe_force_n
            .unwrap_or(softhaptic_device::world::DEFAULT_SAFE_FORCE_N);
        if !(safe_force_n.is_finite() && safe_force_n > 0.0 && safe_force_n <= 100.0) {
            return Err(field(
                "haptics.safe_force_n",
                format!("must be finite and in (0, 100] N, got {safe_force_n}"),
            ));
        }

        let calibration = if let ModelSource::Recorded(record) = model_source {
            // The table the session ran with, as its viewers were sent it.
            record.message.calibration.clone()
        } else if file.calibration.table == "half_space" {
            // An object that is a layer on a rigid base gets the half-space profile with the far
            // field the base removes, which is much closer to an FEM table of that layer than the
            // plain half-space (CalibrationTable::half_space_on_base); the model is the one the
            // session runs with, from the file or the recording.
            let layer = match model_source {
                ModelSource::File => file.object.model.thickness,
                ModelSource::Recorded(record) => record.message.contact_model.spec.thickness,
            };
            match layer {
                Some(layer) => CalibrationTable::half_space_on_base(
                    tool,
                    material,
                    PAPER_THRESHOLD_M,
                    layer.thickness_m,
                )
                .map_err(|e| match e {
                    CalibrationError::Thickness(_) => {
                        field("object.model.thickness.thickness_m", e.to_string())
                    }
                    _ => field("calibration.table", e.to_string()),
                })?,
                None => CalibrationTable::half_space(tool, material, PAPER_THRESHOLD_M)
                    .map_err(|e| field("calibration.table", e.to_string()))?,
            }
        } else {
            let table_path = PathBuf::from(&file.calibration.table);
            let (full, text) = match files {
                FileBase::Dir(_) => {
                    let full = resolve(&table_path);
                    let text = files::read_text(&full, FileKind::Table).map_err(|e| {
                        SceneError::Calibration {
                            path: path.to_owned(),
                            table: full.clone(),
                            reason: e.to_string(),
                        }
                    })?;
                    (full, text)
                }
                FileBase::BuiltIn => {
                    let name = file.calibration.table.as_str();
                    let found = EMBEDDED_TABLES.iter().find(|(n, _)| *n == name);
                    let Some((_, text)) = found else {
                        let names: Vec<&str> = EMBEDDED_TABLES.iter().map(|(n, _)| *n).collect();
                        return Err(field(
                            "calibration.table",
                            format!(
                                "a built-in scene can name only the tables built into the binary ({}), got {name:?}",
                                names.join(", ")
                            ),
                        ));
                    };
                    (
                        PathBuf::from(format!("<built-in {name}>")),
                        (*text).to_owned(),
                    )
                }
            };
            let calibration_error = |reason: String| SceneError::Calibration {
                path: path.to_owned(),
                table: full.clone(),
                reason,
            };
            let table: CalibrationTable =
                serde_json::from_str(&text).map_err(|e| calibration_error(e.to_string()))?;
            if table.tool() != &tool {
                return Err(calibration_error(format!(
                    "was made for tool {:?}, the scene's tool is {:?}",
                    table.tool(),
                    tool
                )));
            }
            table
        };

        // The object's contact model, for the scene's tool only, and its validity limits.
        let (spec, validity) = match model_source {
            ModelSource::File => {
                let spec = file.object.model;
                let limits = load_limits(file.calibration.limits.as_deref(), files, path)?;
                let validity = ValidityLimits::at_poisson_ratio(
                    limits.as_ref(),
                    &tool,
                    &spec,
                    material.poisson_ratio(),
                );
                (spec, validity)
            }
            ModelSource::Recorded(record) => {
                let info = &record.message.contact_model;
                (info.spec, info.validity())
            }
        };
        let contact_model = ForceModel::new(tool, material, spec).map_err(|e| {
            let name = match e {
                ModelError::Thickness(_) => "object.model.thickness.thickness_m",
                ModelError::ExactSphereOnCone => "object.model.exact_sphere",
                ModelError::UnbondedCone => "object.model.thickness.bonded",
            };
            field(name, e.to_string())
        })?;
        force = force.with_limits(&validity);
        let render_profile = file
            .render
            .profile(&calibration)
            .map_err(|reason| field("render.profile", reason))?;

        Ok(Scene {
            source: base.map(|_| path.to_owned()),
            object_name: object.name.clone(),
            object_in_world,
            haptic_mesh,
            render_surface,
            material,
            tool,
            device_kind: file.device.kind,
            device_limits: file.device.model.limits(),
            device_name: file.device.name.clone().or(file.device.serial.clone()),
            world_from_device: Pose {
                position_m: device_position_m,
                orientation: device_orientation,
            },
            device_scale: placement.scale,
            device_label: None,
            device_renders_force: true,
            spacemouse_rate,
            spacemouse_script,
            meshes_from_files: object.haptic_mesh.is_some(),
            press_depth_m,
            safe_force_n,
            press_site_in_object,
            calibration,
            render_profile,
            collision: file.haptics.collision.into(),
            force,
            contact_model,
            validity,
        })
    }
}

/// Reads the limits file: the one `named` in the scene (which must exist), or the default one
/// (whose absence means the paper's limits, logged). `None` when there is no file.
fn load_limits(
    named: Option<&Path>,
    files: FileBase<'_>,
    scene: &Path,
) -> Result<Option<ModelLimitsFile>, SceneError> {
    let full = files.resolve(named.unwrap_or(Path::new(DEFAULT_LIMITS_FILE)));
    let error = |reason: String| SceneError::Limits {
        path: scene.to_owned(),
        file: full.clone(),
        reason,
    };
    let text = match files::read_text(&full, FileKind::Table) {
        Ok(text) => text,
        Err(ReadError::Io(e)) if named.is_none() && e.kind() == std::io::ErrorKind::NotFound => {
            tracing::info!(
                scene = %scene.display(),
                file = %full.display(),
                "no model limits file: the validity flags use the paper's limits (4.3 mm; 22° sphere, 9° cone)"
            );
            return Ok(None);
        }
        Err(e) => return Err(error(e.to_string())),
    };
    let limits: ModelLimitsFile = serde_json::from_str(&text).map_err(|e| error(e.to_string()))?;
    validate_limits(&limits).map_err(error)?;
    Ok(Some(limits))
}

/// Checks what serde cannot: the version, and that every limit is a usable positive number.
/// Public so the fuzz targets (`tests/src/fuzz.rs`) run the same check the loader does.
pub fn validate_limits(file: &ModelLimitsFile) -> Result<(), String> {
    if file.version != ModelLimitsFile::VERSION {
        return Err(format!(
            "version: this build reads version {}, got {}",
            ModelLimitsFile::VERSION,
            file.version
        ));
    }
    if !(file.threshold_percent.is_finite() && file.threshold_percent > 0.0) {
        return Err(format!(
            "threshold_percent: must be finite and > 0, got {}",
            file.threshold_percent
        ));
    }
    for (i, limit) in file.limits.iter().enumerate() {
        if !(limit.valid_depth_m.is_finite() && limit.valid_depth_m > 0.0) {
            return Err(format!(
                "limits[{i}].valid_depth_m: must be finite and > 0, got {}",
                limit.valid_depth_m
            ));
        }
        if let Some(angle) = limit.valid_inclination_rad
            && !(angle.is_finite() && angle > 0.0 && angle <= std::f64::consts::FRAC_PI_2)
        {
            return Err(format!(
                "limits[{i}].valid_inclination_rad: must be in (0, π/2], got {angle}"
            ));
        }
    }
    Ok(())
}

/// The vertex highest in the world (largest y) and its normal: where a hand coming from above
/// presses an arbitrary mesh.
fn highest_vertex(mesh: &HapticMesh, object_in_world: &Pose) -> (DVec3, DVec3) {
    mesh.positions_m()
        .iter()
        .zip(mesh.normals())
        .max_by(|(a, _), (b, _)| {
            let ya = object_in_world.transform_point(**a).y;
            let yb = object_in_world.transform_point(**b).y;
            ya.total_cmp(&yb)
        })
        .map(|(p, n)| (*p, *n))
        // A validated mesh has triangles, hence vertices; the fallback is never used.
        .unwrap_or((DVec3::ZERO, DVec3::Y))
}

/// A mesh as a recording keeps it, with the hash of its content.
fn mesh_record(positions_m: &[DVec3], triangles: &[[u32; 3]]) -> MeshRecord {
    let positions_m: Vec<[f64; 3]> = positions_m.iter().map(|p| p.to_array()).collect();
    let sha256 = mesh_hash(&positions_m, triangles);
    MeshRecord {
        positions_m,
        triangles: triangles.to_vec(),
        sha256,
    }
}

/// SHA-256 (hex) of the positions' little-endian f64 bytes, then the indices' u32 bytes.
fn mesh_hash(positions_m: &[[f64; 3]], triangles: &[[u32; 3]]) -> String {
    use sha2::Digest as _;
    let mut hash = sha2::Sha256::new();
    for c in positions_m.iter().flatten() {
        hash.update(c.to_le_bytes());
    }
    for i in triangles.iter().flatten() {
        hash.update(i.to_le_bytes());
    }
    hash.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// The mesh a recording kept, once its hash and its geometry check out.
fn mesh_from_record(r: &MeshRecord) -> Result<HapticMesh, String> {
    if mesh_hash(&r.positions_m, &r.triangles) != r.sha256 {
        return Err("the recording's copy of the mesh does not match its hash (damaged)".into());
    }
    let positions = r
        .positions_m
        .iter()
        .map(|p| DVec3::from_array(*p))
        .collect();
    HapticMesh::new(positions, r.triangles.clone()).map_err(|e| e.to_string())
}

/// Refuses a face, line or point whose texture-coordinate or normal index falls outside the
/// file's `vt` or `vn` lines. The OBJ reader refuses these too, but only after multiplying the
/// index (`vt * 2`, `vn * 3`): a relative index reaching before the first `vt` (`f 1/-9 ...`)
/// or a huge one overflows there, which panics in a build with overflow checks and in release
/// silently wraps. Indices are resolved as the reader resolves them (1-based; negative counts
/// back from the lines read so far; 0 and empty mean none) and checked, as it checks them,
/// against the whole file's count when the file has any.
fn check_attribute_indices(text: &str) -> Result<(), String> {
    let count = |kind: &str| {
        text.lines()
            .filter(|l| l.split_whitespace().next() == Some(kind))
            .count()
    };
    let totals = [count("vt"), count("vn")];
    let names = ["texture coordinate", "normal"];
    let mut so_far = [0usize; 2];
    for (line_index, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("vt") => so_far[0] += 1,
            Some("vn") => so_far[1] += 1,
            Some("f" | "l" | "p") => {
                for word in words {
                    // Part 0 is the position (the reader checks it without overflow).
                    for (slot, part) in word.split('/').skip(1).take(2).enumerate() {
                        // Not a number: the reader refuses the face itself.
                        let Ok(x) = part.parse::<i128>() else {
                            continue;
                        };
                        let index = if x < 0 {
                            so_far[slot] as i128 + x
                        } else {
                            x - 1
                        };
                        // -1 from a 0 is the reader's "missing"; with no such lines at all the
                        // reader ignores the index.
                        if x == 0 || totals[slot] == 0 {
                            continue;
                        }
                        if !(0..totals[slot] as i128).contains(&index) {
                            return Err(format!(
                                "line {}: {word:?} names {} {x}, but the file has {} of them",
                                line_index + 1,
                                names[slot],
                                totals[slot]
                            ));
                        }
                    }
                }
            }
            _ => {}
        }
    }
    Ok(())
}

/// Reads an OBJ file and parses it as a mesh ([`parse_obj`]).
fn load_obj(mesh: &Path, scene: &Path, field: &'static str) -> Result<HapticMesh, SceneError> {
    let error = |reason: String| SceneError::Mesh {
        path: scene.to_owned(),
        field,
        mesh: mesh.to_owned(),
        reason,
    };
    let text = files::read_text(mesh, FileKind::Mesh).map_err(|e| error(e.to_string()))?;
    parse_obj(&text, mesh, scene, field)
}

/// Parses OBJ text (polygons triangulated) into a mesh; `mesh`, `scene` and `field` only name
/// the file in errors. Non-finite vertices are refused with their line and their index in the
/// file (0-based), found before the OBJ reader reorders anything. Public so the fuzz targets
/// (`tests/src/fuzz.rs`) reach the parser without a file.
pub fn parse_obj(
    text: &str,
    mesh: &Path,
    scene: &Path,
    field: &'static str,
) -> Result<HapticMesh, SceneError> {
    let error = |reason: String| SceneError::Mesh {
        path: scene.to_owned(),
        field,
        mesh: mesh.to_owned(),
        reason,
    };
    let mut vertex = 0usize;
    for (line_index, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        if words.next() != Some("v") {
            continue;
        }
        let coordinates: Vec<&str> = words.take(3).collect();
        let finite = coordinates.len() == 3
            && coordinates
                .iter()
                .all(|w| w.parse::<f64>().is_ok_and(f64::is_finite));
        if !finite {
            return Err(error(format!(
                "line {}: vertex {vertex} is not finite: {:?}",
                line_index + 1,
                coordinates.join(" ")
            )));
        }
        vertex += 1;
    }
    check_attribute_indices(text).map_err(error)?;
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ..Default::default()
    };
    // Materials do not matter to the simulation: any `mtllib` is ignored.
    let (models, _materials) = tobj::load_obj_buf(&mut text.as_bytes(), &options, |_| {
        Err(tobj::LoadError::OpenFileFailed)
    })
    .map_err(|e| error(e.to_string()))?;
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    for model in &models {
        let m = &model.mesh;
        let offset = positions.len() as u32;
        positions.extend(
            m.positions
                .chunks_exact(3)
                .map(|p| DVec3::new(p[0], p[1], p[2])),
        );
        for tri in m.indices.chunks_exact(3) {
            triangles.push([tri[0] + offset, tri[1] + offset, tri[2] + offset]);
        }
    }
    HapticMesh::new(positions, triangles).map_err(|e| error(e.to_string()))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn builtin_default_scene_is_the_liver_with_the_combined_model_and_the_fem_table() {
        let s = Scene::builtin_default().unwrap();
        assert_eq!(s.object_name, "liver");
        assert!(s.render_surface.positions_m.len() >= 100_000);
        assert_eq!(s.tool, ToolShape::sphere(0.01).unwrap());
        assert_eq!(s.material, Material::PAPER_SOFT);
        assert_eq!(s.device_limits, DeviceLimits::PHANTOM_DESKTOP);
        // The FEM table of the 10 mm sphere at 50 kPa, from inside the binary: the same table
        // as the file of the source tree.
        assert_eq!(
            s.calibration.source(),
            softhaptic_proto::CalibrationSource::FemNeoHookean
        );
        let on_disk: CalibrationTable = serde_json::from_str(
            &std::fs::read_to_string(
                source_tree_scenes_dir().join("calibration/sphere10_50kpa.json"),
            )
            .unwrap(),
        )
        .unwrap();
        assert_eq!(s.calibration, on_disk);
        // The best combined model for a sphere on a curved organ, no layer.
        let spec = *s.contact_model.spec();
        assert_eq!(
            spec,
            ModelSpec {
                exact_sphere: true,
                curvature: true,
                hyperelastic: true,
                ..ModelSpec::PAPER
            }
        );
        assert_eq!(s.contact_model.tool(), &s.tool);
        // The limits: measured when the source tree's limits file has them, the paper's
        // otherwise; the renderer uses the same.
        let file = std::fs::read_to_string(source_tree_scenes_dir().join(DEFAULT_LIMITS_FILE))
            .ok()
            .map(|t| serde_json::from_str::<ModelLimitsFile>(&t).unwrap());
        assert_eq!(
            s.validity,
            ValidityLimits::of(file.as_ref(), &s.tool, &spec)
        );
        assert_eq!(s.force.valid_depth_m, s.validity.valid_depth_m);
        assert_eq!(
            s.force.valid_inclination_rad,
            s.validity.valid_inclination_rad
        );
        // The world measures the curvature, because the model uses it.
        assert!(s.haptic_world().collider().has_curvature());
    }

    #[test]
    fn the_scene_chooses_the_drawn_profile_and_fem_needs_the_tables_surface() {
        // The default scene names no profile: its FEM table carries the surface, so fem.
        let text = include_str!("../../scenes/default.toml");
        assert!(
            text.trim_end()
                .ends_with("instead, and \"fem\" with a table that carries no surface is refused.")
        );
        let load = |text: &str| Scene::from_toml(text, Path::new("<test>"), None);
        let s = load(text).unwrap();
        assert_eq!(s.render_profile, RenderProfile::Fem);
        assert!(s.calibration.surface().is_some());
        assert_eq!(
            crate::app::scene_message(&s).render_profile,
            RenderProfile::Fem
        );
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

    #[test]
    fn a_scene_without_a_model_table_runs_the_papers_law() {
        let text = include_str!("../../scenes/default.toml");
        let start = text.find("[object.model]").unwrap();
        let end = start + text[start..].find("\n[material]").unwrap();
        let plain = format!("{}{}", &text[..start], &text[end..]);
        let s = Scene::from_toml(&plain, Path::new("<test>"), None).unwrap();
        assert!(s.contact_model.spec().is_paper());
        assert!(!s.haptic_world().collider().has_curvature());
        let info = s.contact_model_info();
        assert_eq!(info.label, "Hertz");
        assert!(info.corrections.is_empty());
    }

    #[test]
    fn a_half_space_table_on_a_layer_is_cut_by_its_base() {
        let text = include_str!("../../scenes/default.toml").replace(
            "table = \"calibration/sphere10_50kpa.json\"",
            "table = \"half_space\"",
        );
        let with_layer = |thickness: &str| {
            text.replace(
                "hyperelastic = true\n",
                &format!("hyperelastic = true\nthickness = {{ thickness_m = {thickness}, bonded = true }}\n"),
            )
        };
        let tool = ToolShape::sphere(0.01).unwrap();
        // No thickness: the plain half-space.
        let plain = Scene::from_toml(&text, Path::new("<test>"), None).unwrap();
        assert_eq!(
            plain.calibration,
            CalibrationTable::half_space(tool, Material::PAPER_SOFT, PAPER_THRESHOLD_M).unwrap()
        );
        // A 50 mm layer: the base-corrected table of that thickness, which says so.
        let layer = Scene::from_toml(&with_layer("0.05"), Path::new("<test>"), None).unwrap();
        assert_eq!(
            layer.calibration.source(),
            softhaptic_proto::CalibrationSource::HalfSpaceOnBase
        );
        assert!(
            layer
                .calibration
                .description()
                .contains("rigid base 50.0 mm")
        );
        assert_eq!(
            layer.calibration,
            CalibrationTable::half_space_on_base(
                tool,
                Material::PAPER_SOFT,
                PAPER_THRESHOLD_M,
                0.05
            )
            .unwrap()
        );
        assert!(
            layer.calibration.deformed_radius_m(0.006)
                < 0.6 * plain.calibration.deformed_radius_m(0.006)
        );
        // A bad thickness is refused with its field and value.
        let err = Scene::from_toml(&with_layer("-0.02"), Path::new("<test>"), None)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("object.model.thickness.thickness_m") && err.contains("-0.02"),
            "{err}"
        );
        // A replay takes the layer from the recorded model, not from the scene text.
        let recorded = ContactModelInfo::new(
            &tool,
            &ModelSpec {
                thickness: Some(softhaptic_proto::LayerSpec {
                    thickness_m: 0.03,
                    bonded: true,
                }),
                ..ModelSpec::PAPER
            },
            &ValidityLimits::paper(&tool),
        );
        // The table the session ran with is the recording's: a replay never recomputes or
        // reads it.
        let table = CalibrationTable::half_space_on_base(
            tool,
            Material::PAPER_SOFT,
            PAPER_THRESHOLD_M,
            0.03,
        )
        .unwrap();
        let mut record = recording_of(&text, recorded);
        record.message.calibration = table.clone();
        let replay = Scene::from_recording(&record, Path::new("<test>")).unwrap();
        assert_eq!(replay.calibration, table);
    }

    #[test]
    fn the_built_in_scene_names_only_embedded_tables() {
        let text = include_str!("../../scenes/default.toml").replace(
            "calibration/sphere10_50kpa.json",
            "calibration/elsewhere.json",
        );
        let err = Scene::from_toml(&text, Path::new("<test>"), None)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("calibration.table")
                && err.contains("elsewhere.json")
                && err.contains("sphere10_50kpa.json"),
            "{err}"
        );
        // Every embedded table parses.
        for (name, text) in EMBEDDED_TABLES {
            serde_json::from_str::<CalibrationTable>(text)
                .unwrap_or_else(|e| panic!("{name}: {e}"));
        }
    }

    #[test]
    fn the_cone_scene_builds_a_cone_model_only() {
        let s = Scene::from_toml(
            include_str!("../../scenes/cone.toml"),
            Path::new("<test>"),
            None,
        )
        .unwrap();
        assert!(matches!(s.contact_model.tool(), ToolShape::Cone { .. }));
        assert_eq!(
            *s.contact_model.spec(),
            ModelSpec {
                curvature: true,
                inclination: true,
                ..ModelSpec::PAPER
            }
        );
        assert_eq!(
            s.contact_model_info().label,
            "Sneddon cone + curvature + inclination"
        );
    }

    /// The scene record a session of `text` (a built-in-object scene) writes, with the recorded
    /// model `model`.
    fn recording_of(text: &str, model: ContactModelInfo) -> SceneRecord {
        let scene = Scene::from_toml(text, Path::new("<test>"), None).unwrap();
        let mut message = crate::app::scene_message(&scene);
        message.contact_model = model;
        SceneRecord {
            message,
            scene_toml: text.to_owned(),
            scene_file: None,
            period_ns: 1_000_000,
            meshes: scene.recorded_meshes(),
        }
    }

    #[test]
    fn a_recorded_model_overrides_the_scene_file() {
        // A replay runs the model the session ran, whatever the scene text's defaults say now.
        let text = include_str!("../../scenes/default.toml");
        let tool = ToolShape::sphere(0.01).unwrap();
        let recorded = ContactModelInfo::new(
            &tool,
            &ModelSpec::PAPER,
            &ValidityLimits {
                valid_depth_m: 0.002,
                valid_inclination_rad: 0.1,
                source: "recorded".into(),
            },
        );
        let s = Scene::from_recording(&recording_of(text, recorded.clone()), Path::new("<test>"))
            .unwrap();
        assert!(s.contact_model.spec().is_paper());
        assert_eq!(s.force.valid_depth_m, 0.002);
        assert_eq!(s.force.valid_inclination_rad, 0.1);
        assert_eq!(s.contact_model_info(), recorded);
        // A recorded model the tool cannot take is refused, naming the field.
        let cone = Scene::from_toml(
            include_str!("../../scenes/cone.toml"),
            Path::new("<test>"),
            None,
        )
        .unwrap();
        let exact = ContactModelInfo::new(
            &cone.tool,
            &ModelSpec {
                exact_sphere: true,
                ..ModelSpec::PAPER
            },
            &ValidityLimits::paper(&cone.tool),
        );
        let err = Scene::from_recording(
            &recording_of(include_str!("../../scenes/cone.toml"), exact),
            Path::new("<test>"),
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("object.model.exact_sphere"), "{err}");
    }

    #[test]
    fn shm1_layout_matches_the_wire() {
        let surface = RenderSurface::from_mesh(&HapticMesh::grid(3, 0.02));
        let bytes = surface.to_shm1();
        assert_eq!(&bytes[0..4], b"SHM1");
        let n = u32::from_le_bytes(bytes[4..8].try_into().unwrap()) as usize;
        let t = u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize;
        assert_eq!((n, t), (9, 8));
        assert_eq!(bytes.len(), 12 + n * 24 + t * 12);
        // First normal is +y.
        let off = 12 + n * 12;
        let ny = f32::from_le_bytes(bytes[off + 4..off + 8].try_into().unwrap());
        assert_eq!(ny, 1.0);
    }
}
