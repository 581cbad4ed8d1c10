//! Scenes: what the server simulates, described in a TOML file.
//!
//! A scene names one object (haptic and render meshes, pose, material), the tool, the device,
//! the calibration table that gives R_d, the collision mode and the damping. [`SceneFile`] is
//! the file as written; [`Scene`] is the same content validated and loaded (meshes read, the
//! calibration table read or built), ready to build the haptic world. An invalid file is
//! refused before anything starts, with the file, the field and the reason
//! ([`SceneError`]); syntax and type errors carry toml's line and column.
//!
//! ```toml
//! [object]
//! name = "liver"
//! builtin = "liver"                 # or: haptic_mesh = "x.obj", render_mesh = "x_fine.obj"
//! position_m = [0.0, 0.0, 0.0]
//! orientation = [0.0, 0.0, 0.0, 1.0] # quaternion [x, y, z, w]
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
//! kind = "simulated"
//! model = "phantom_desktop"        # phantom_desktop | touch | omni
//! press_depth_m = 0.008            # how deep the simulated hand aims
//!
//! [calibration]
//! table = "half_space"             # or a path to a calibration JSON, relative to this file
//!
//! [haptics]
//! collision = "continuous"         # or "paper_vertices"
//! damping_n_s_per_m = 1.0
//! ```

use std::path::{Path, PathBuf};

use glam::{DQuat, DVec3};
use serde::Deserialize;
use softhaptic_device::collision::CollisionMode;
use softhaptic_device::device::DeviceLimits;
use softhaptic_device::mesh::HapticMesh;
use softhaptic_device::render::RenderConfig;
use softhaptic_proto::calibration::PAPER_THRESHOLD_M;
use softhaptic_proto::{CalibrationTable, Material, Pose, ToolShape};

/// Why a scene could not be loaded. Every variant names the file; field-level errors name the
/// field and the value.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("{path}: {source}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
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
}

/// A tool checked on deserialisation, so a bad radius is reported with toml's span.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(try_from = "ToolShape")]
pub struct ValidTool(pub ToolShape);

impl TryFrom<ToolShape> for ValidTool {
    type Error = softhaptic_proto::ToolError;
    fn try_from(tool: ToolShape) -> Result<Self, Self::Error> {
        tool.validate().map(|()| ValidTool(tool))
    }
}

/// The scene file as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub object: ObjectSection,
    pub material: Material,
    pub tool: ValidTool,
    #[serde(default)]
    pub device: DeviceSection,
    pub calibration: CalibrationSection,
    #[serde(default)]
    pub haptics: HapticsSection,
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
        }
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationSection {
    /// `"half_space"` for the analytical table, or a calibration JSON file relative to the scene.
    pub table: String,
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
}

/// A render surface in the object's frame with unit vertex normals.
#[derive(Debug, Clone)]
pub struct RenderSurface {
    pub positions_m: Vec<DVec3>,
    pub normals: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
}

impl RenderSurface {
    /// The binary layout of `GET /meshes/<name>.bin` (wire.md): "SHM1", u32 vertex count,
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
    pub device_limits: DeviceLimits,
    pub press_depth_m: f64,
    /// Where the simulated hand presses, object frame: a surface point and its outward normal.
    pub press_site_in_object: (DVec3, DVec3),
    pub calibration: CalibrationTable,
    pub collision: CollisionMode,
    pub render: RenderConfig,
}

impl Scene {
    /// The scene used when no file is given: the procedural liver, a 10 mm sphere, E = 50 kPa,
    /// ν = 0.33, the half-space R_d table (labelled `half_space` in the scene message), a
    /// simulated PHANTOM Desktop.
    pub fn builtin_default() -> Result<Scene, SceneError> {
        let text = include_str!("../../scenes/default.toml");
        Self::from_toml(text, Path::new("<built-in scenes/default.toml>"), None)
    }

    /// Reads and loads a scene file. Relative mesh and table paths are relative to the file.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        let text = std::fs::read_to_string(path).map_err(|source| SceneError::Read {
            path: path.to_owned(),
            source,
        })?;
        let base = path.parent().unwrap_or(Path::new("."));
        Self::from_toml(&text, path, Some(base))
    }

    /// Parses, validates and loads scene text; `path` is used in errors, `base` resolves
    /// relative files (`None`: the built-in scene, which may not name files).
    pub fn from_toml(text: &str, path: &Path, base: Option<&Path>) -> Result<Scene, SceneError> {
        let file: SceneFile = toml::from_str(text).map_err(|e| SceneError::Parse {
            path: path.to_owned(),
            message: e.to_string().trim_end().to_owned(),
        })?;
        Self::from_file(file, path, base)
    }

    fn from_file(file: SceneFile, path: &Path, base: Option<&Path>) -> Result<Scene, SceneError> {
        let field = |field: &str, reason: String| SceneError::Field {
            path: path.to_owned(),
            field: field.to_owned(),
            reason,
        };
        let resolve = |p: &Path| match base {
            Some(b) => b.join(p),
            None => p.to_owned(),
        };
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

        let (haptic_mesh, render_surface, press_site_in_object) =
            match (object.builtin, &object.haptic_mesh) {
                (Some(Builtin::Liver), None) => {
                    if object.render_mesh.is_some() {
                        return Err(field(
                            "object.render_mesh",
                            "cannot be combined with builtin = \"liver\" (it brings its own)"
                                .into(),
                        ));
                    }
                    let (positions, triangles) = softhaptic_device::liver::render_surface();
                    let render = HapticMesh::new(positions, triangles)
                        .map_err(|e| field("object.builtin", e.to_string()))?;
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
                    let surface = RenderSurface::from_mesh(&render);
                    let site = highest_vertex(&haptic, &object_in_world);
                    (haptic, surface, site)
                }
            };

        let tool = file.tool.0;
        let material = file.material;
        let press_depth_m = file.device.press_depth_m;
        if !(press_depth_m.is_finite() && (0.0..=0.05).contains(&press_depth_m)) {
            return Err(field(
                "device.press_depth_m",
                format!("must be finite and in [0, 0.05] m, got {press_depth_m}"),
            ));
        }
        let mut render = RenderConfig::for_tool(&tool);
        if let Some(d) = file.haptics.damping_n_s_per_m {
            if !(d.is_finite() && d >= 0.0) {
                return Err(field(
                    "haptics.damping_n_s_per_m",
                    format!("must be finite and >= 0, got {d}"),
                ));
            }
            render.damping_n_s_per_m = d;
        }

        let calibration = if file.calibration.table == "half_space" {
            CalibrationTable::half_space(tool, material, PAPER_THRESHOLD_M)
                .map_err(|e| field("calibration.table", e.to_string()))?
        } else {
            let table_path = PathBuf::from(&file.calibration.table);
            if base.is_none() {
                return Err(field(
                    "calibration.table",
                    "the built-in scene cannot name files".into(),
                ));
            }
            let full = resolve(&table_path);
            let calibration_error = |reason: String| SceneError::Calibration {
                path: path.to_owned(),
                table: full.clone(),
                reason,
            };
            let text =
                std::fs::read_to_string(&full).map_err(|e| calibration_error(e.to_string()))?;
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
            press_depth_m,
            press_site_in_object,
            calibration,
            collision: file.haptics.collision.into(),
            render,
        })
    }
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

/// Loads an OBJ (polygons triangulated) as a mesh. Non-finite vertices are refused with their
/// line and their index in the file (0-based), found before the OBJ reader reorders anything.
fn load_obj(mesh: &Path, scene: &Path, field: &'static str) -> Result<HapticMesh, SceneError> {
    let error = |reason: String| SceneError::Mesh {
        path: scene.to_owned(),
        field,
        mesh: mesh.to_owned(),
        reason,
    };
    let text = std::fs::read_to_string(mesh).map_err(|e| error(e.to_string()))?;
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
    fn builtin_default_scene_is_the_liver_with_a_labelled_half_space_table() {
        let s = Scene::builtin_default().unwrap();
        assert_eq!(s.object_name, "liver");
        assert!(s.render_surface.positions_m.len() >= 100_000);
        assert_eq!(s.tool, ToolShape::sphere(0.01).unwrap());
        assert_eq!(s.material, Material::PAPER_SOFT);
        assert_eq!(
            s.calibration.source(),
            softhaptic_proto::CalibrationSource::HalfSpace
        );
        assert_eq!(s.device_limits, DeviceLimits::PHANTOM_DESKTOP);
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
