//! Scenes: what the server simulates, described in a TOML file; and the device a scene names,
//! opened.
//!
//! The crate is below the sessions, the doctor and the live server, which all load scenes; the
//! files it reads go through `softhaptic_io::files`, imported here as `files`.
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
//!                                  # or "spacemouse": a 3Dconnexion puck (input only, no force),
//!                                  # or "forcedimension": an omega, delta, sigma or Falcon
//!                                  # through Force Dimension's SDK
//! model = "phantom_desktop"        # phantom_desktop | touch | omni | falcon | omega3 | delta3 |
//!                                  # sigma7: the preset of limits (a real device's own limits
//!                                  # apply where tighter)
//! press_depth_m = 0.008            # how deep the simulated hand aims
//! name = "Default Device"          # openhaptics: the device configuration's name
//! world_from_device = { position_m = [0.0, 0.0, 0.0], orientation = [0.0, 0.0, 0.0, 1.0], scale = 1.0 }
//!                                  # openhaptics, forcedimension: where the device's origin and
//!                                  # axes are in the world, and world metres per metre of motion
//! index = 0                        # forcedimension: which device, among those plugged in
//!                                  # (default: the SDK's default device)
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
//! inclusions = "calibration/inclusion_sphere10_50kpa.json" # the inclusions' FEM table
//!                                  # (needed with [[inclusion]]; `softhaptic-calibrate inclusion`)
//!
//! [haptics]
//! collision = "continuous"         # or "paper_vertices"
//! damping_n_s_per_m = 1.0
//! safe_force_n = 2.0               # the trainee's metrics count the time above this force
//!
//! [[inclusion]]                    # a stiffer sphere inside the object (palpation); repeat
//! shape = "sphere"                 # for several, omit for none (nothing computed per tick)
//! near_m = [0.0, 0.08, 0.0]        # object frame: it lies under the surface point closest to this
//! centre_depth_m = 0.010           # its centre below that point, along the surface normal
//! radius_m = 0.005                 # within the table's radii
//! stiffness_ratio = 4.0            # its modulus over the tissue's, 1.5 to 10, within the table's
//! # Any value may be a range drawn from a seed instead (the recording keeps what was drawn):
//! # near_m = { min = [-0.02, 0.08, -0.02], max = [0.02, 0.08, 0.02] }
//! # stiffness_ratio = { min = 2.0, max = 8.0 }
//! # seed = 7
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
//!
//! # Layout
//! - `file`: the TOML schema, section by section ([`SceneFile`]), and its parsing, which shows
//!   a refused value on its own line.
//! - `load`: from a parsed file, or a recording, to a [`Scene`]: the object's pose and meshes,
//!   the device, the haptics, the contact model and its limits.
//! - `calibration`: the R_d table (built into the binary, a file, the half-space, or the
//!   recording's) and the model-limits file.
//! - `obj`: the OBJ reader.
//! - `message`: the `scene` message the viewers are sent for a scene ([`Scene::message`]).
//! - [`devices`]: opening the scene's device (simulated, or OpenHaptics with the limits it
//!   reports) and the `softhaptic devices` listing.
//! - here: the [`Scene`] itself, its errors, and what `load` and `calibration` both ask: where a
//!   scene's files resolve (`FileBase`) and whether its model comes from the files or from a
//!   recording (`ModelSource`).
//!
//! The render mesh's wire encoding ("SHM1") belongs to the wire, beside its specification:
//! [`softhaptic_proto::wire::shm1`].

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::DVec3;
use softhaptic_device::collision::{Collider, CollisionMode};
use softhaptic_device::device::DeviceLimits;
use softhaptic_device::force::ForceConfig;
use softhaptic_device::guide::{Guide, GuidePath};
use softhaptic_device::inclusion::InclusionField;
use softhaptic_device::mesh::HapticMesh;
use softhaptic_device::model::ForceModel;
use softhaptic_device::sim::HandScript;
use softhaptic_device::spacemouse::rate::RateConfig;
use softhaptic_device::world::HapticWorld;
use softhaptic_proto::deformation::RenderProfile;
use softhaptic_proto::guide::RecordedGuide;
use softhaptic_proto::record::{RecordedInclusions, RecordedMeshes, SceneRecord};
use softhaptic_proto::wire::{ContactModelInfo, shm1};
use softhaptic_proto::{
    CalibrationTable, Inclusion, InclusionTable, Material, Pose, ToolShape, ValidityLimits,
};

use softhaptic_io::files;
use softhaptic_io::files::FileKind;
use softhaptic_io::toml_file::{self, TomlFileError};

mod calibration;
pub mod devices;
mod file;
mod load;
mod message;
mod obj;

pub use calibration::{DEFAULT_LIMITS_FILE, validate_limits};
pub use file::{
    Builtin, CalibrationSection, CollisionModeName, DeviceChoice, DeviceKind, DeviceModel,
    DeviceSection, Drawn, HapticsSection, InclusionSection, InclusionShape, MaterialSection,
    ObjectSection, RateSection, RenderSection, SceneFile, ToolKind, ToolSection,
    WorldFromDeviceSection,
};
pub use obj::parse_obj;

/// Why a scene could not be loaded. Every variant names the file; field-level errors name the
/// field and the value.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// Not read, not TOML of a scene file, or a value refused.
    #[error(transparent)]
    File(#[from] TomlFileError),
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
    #[error("{path}: guide: {reason}")]
    Guide { path: PathBuf, reason: String },
}

/// The `scenes/` directory of the source tree this binary was built from (this crate is
/// `server/scene/` in it).
pub fn source_tree_scenes_dir() -> PathBuf {
    let crate_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    crate_dir
        .ancestors()
        .nth(2)
        .map_or_else(|| crate_dir.join("../.."), Path::to_path_buf)
        .join("scenes")
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

/// A render surface in the object's frame with unit vertex normals.
#[derive(Debug, Clone)]
pub struct RenderSurface {
    pub positions_m: Vec<DVec3>,
    pub normals: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
}

impl RenderSurface {
    /// The surface as `GET /meshes/<name>.bin` serves it ([`shm1::encode`]).
    pub fn to_shm1(&self) -> Vec<u8> {
        shm1::encode(&self.positions_m, &self.normals, &self.triangles)
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
    /// The fine mesh the viewers draw, shared: a clone of the scene (a replay check's, a
    /// recording's) shares it rather than copying its vertices (163 842 for the liver).
    pub render_surface: Arc<RenderSurface>,
    pub material: Material,
    pub tool: ToolShape,
    pub device_kind: DeviceKind,
    /// The preset's limits as loaded; once a real device is open, the tighter of them and the
    /// device's own (`crate::devices::open`), and in a replay check the limits the recording
    /// ran with.
    pub device_limits: DeviceLimits,
    /// The OpenHaptics device configuration name, the SpaceMouse's serial, or the Force
    /// Dimension device's index (`None`: the default device, the first SpaceMouse found).
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
    /// The scene text this scene was built from, as read: what a recording keeps, so that a
    /// check rebuilds the scene that ran, not the file as it is later.
    pub source_toml: String,
    /// The object's inclusions as placed, object frame (empty: none, and the world computes
    /// nothing for them).
    pub inclusions: Vec<Inclusion>,
    /// Their FEM force-ratio table; `Some` exactly when there are inclusions.
    pub inclusion_table: Option<InclusionTable>,
    /// The expert's path the trainee is pulled along (`--guide`), or `None`: set by
    /// [`Scene::set_guide`], restored from a recording by [`Scene::from_recording`].
    pub guide: Option<SceneGuide>,
}

/// A scene's guide: the path and settings as a recording keeps them, and the guide built from
/// them (checked once, cloned into each world).
#[derive(Debug, Clone)]
pub struct SceneGuide {
    pub recorded: RecordedGuide,
    pub guide: Guide,
}

impl Scene {
    /// The scene used when no file is given: the procedural liver, a 10 mm sphere, E = 50 kPa,
    /// ν = 0.33, the best combined contact model for a sphere on a curved organ (exact sphere,
    /// hyperelastic fit, curvature), the neo-Hookean FEM R_d table of a 10 mm sphere at 50 kPa
    /// (built into the binary), a simulated PHANTOM Desktop.
    pub fn builtin_default() -> Result<Scene, SceneError> {
        let text = include_str!("../../../scenes/default.toml");
        Self::from_toml(text, Path::new("<built-in scenes/default.toml>"), None)
    }

    /// Reads and loads a scene file. Relative mesh and table paths are relative to the file.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        let text = toml_file::read(path, FileKind::Scene)?;
        let base = path.parent().unwrap_or(Path::new("."));
        Self::from_toml(&text, path, Some(base))
    }

    /// Parses, validates and loads scene text; `path` is used in errors, `base` resolves
    /// relative files (`None`: a built-in scene, whose files resolve as the module docs say).
    pub fn from_toml(text: &str, path: &Path, base: Option<&Path>) -> Result<Scene, SceneError> {
        let file = SceneFile::parse(text, path)?;
        let mut scene = Self::from_file(file, path, base, ModelSource::File)?;
        scene.source_toml = text.to_owned();
        Ok(scene)
    }

    /// Loads the scene a recording ran with, from what the recording holds alone: its scene
    /// text, the contact model and limits and the calibration table of its `scene` message (so a
    /// replay rebuilds the same model even if the scene's defaults, the limits file or the table
    /// have changed since), and the meshes it kept. No file is read: a recording's scene cannot
    /// make a check read a local file, and an edited mesh on disk does not change a check.
    /// `path` names the recording's scene in errors.
    pub fn from_recording(record: &SceneRecord, path: &Path) -> Result<Scene, SceneError> {
        let file = SceneFile::parse(&record.scene_toml, path)?;
        let mut scene = Self::from_file(file, path, None, ModelSource::Recorded(record))?;
        scene.meshes_from_files = record.meshes.is_some();
        scene.source_toml = record.scene_toml.clone();
        if let Some(guide) = &record.guide {
            scene
                .set_guide(guide.clone())
                .map_err(|reason| SceneError::Guide {
                    path: path.to_owned(),
                    reason,
                })?;
        }
        Ok(scene)
    }

    /// Guides the trainee along `recorded`'s path with its settings, checked first (the reason
    /// names the field when one is out of range).
    pub fn set_guide(&mut self, recorded: RecordedGuide) -> Result<(), String> {
        recorded
            .params
            .validate()
            .map_err(|(name, value)| format!("params.{name} = {value} is out of range"))?;
        recorded
            .gain
            .validate()
            .map_err(|(name, value)| format!("gain.{name} = {value} is out of range"))?;
        let path = GuidePath::from_recorded(&recorded).map_err(|e| e.to_string())?;
        let mut guide = Guide::new(path, recorded.params);
        guide.set_gain_mode(recorded.gain.clone());
        self.guide = Some(SceneGuide { recorded, guide });
        Ok(())
    }

    /// The guide for the recording (`None` without one).
    pub fn recorded_guide(&self) -> Option<RecordedGuide> {
        self.guide.as_ref().map(|g| g.recorded.clone())
    }

    /// The object's meshes for the recording, when they came from files (a built-in object's
    /// are the build's own).
    pub fn recorded_meshes(&self) -> Option<RecordedMeshes> {
        if !self.meshes_from_files {
            return None;
        }
        let haptic =
            load::mesh_record(self.haptic_mesh.positions_m(), self.haptic_mesh.triangles());
        let render = load::mesh_record(
            &self.render_surface.positions_m,
            &self.render_surface.triangles,
        );
        Some(RecordedMeshes {
            render: (render != haptic).then_some(render),
            haptic,
        })
    }

    /// The inclusions and their table for the recording (`None` without inclusions).
    pub fn recorded_inclusions(&self) -> Option<RecordedInclusions> {
        let table = self.inclusion_table.clone()?;
        Some(RecordedInclusions {
            placed: self.inclusions.clone(),
            table,
        })
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
        self.haptic_world_with(Collider::new(self.haptic_mesh.clone(), self.collision))
    }

    /// [`Scene::haptic_world`] around a collider already built over this scene's haptic mesh
    /// with its collision mode (a clone of one built earlier for the same mesh).
    pub fn haptic_world_with(&self, collider: Collider) -> HapticWorld {
        let mut world = HapticWorld::with_model(
            collider,
            self.object_in_world,
            self.contact_model.clone(),
            self.force,
            self.device_limits,
        );
        if let Some(table) = &self.inclusion_table {
            // The loader checked that the table covers every inclusion.
            if let Ok(field) = InclusionField::new(table.clone(), &self.inclusions) {
                world = world.with_inclusions(field);
            }
        }
        world.set_safe_force(self.safe_force_n);
        world.set_guide(self.guide.as_ref().map(|g| g.guide.clone()));
        world
    }

    /// The simulated hand's demonstration at the scene's press site: approach, press, hold,
    /// slide, release, repeated forever (a recording of one press sets `repeat` to false).
    pub fn hand_script(&self) -> HandScript {
        let pose = self.object_in_world;
        let (point, normal) = self.press_site_in_object;
        let mut script = HandScript::press(
            pose.transform_point(point),
            pose.orientation * normal,
            self.press_depth_m,
        );
        script.repeat = true;
        script
    }

    /// The active contact model as the `scene` message describes it.
    pub fn contact_model_info(&self) -> ContactModelInfo {
        ContactModelInfo::new(&self.tool, self.contact_model.spec(), &self.validity)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use softhaptic_proto::{ModelLimitsFile, ModelSpec};

    use super::*;
    use crate::files;

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
            &files::read_text(
                &source_tree_scenes_dir().join("calibration/sphere10_50kpa.json"),
                FileKind::Table,
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
        let file = files::read_text(
            &source_tree_scenes_dir().join(DEFAULT_LIMITS_FILE),
            FileKind::Table,
        )
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
    fn a_scene_without_a_model_table_runs_the_papers_law() {
        let text = include_str!("../../../scenes/default.toml");
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
    fn the_cone_scene_builds_a_cone_model_only() {
        let s = Scene::from_toml(
            include_str!("../../../scenes/cone.toml"),
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

    /// The palpation scene's text and the directory its files resolve in.
    fn palpation() -> (String, PathBuf) {
        let dir = source_tree_scenes_dir();
        let text = files::read_text(&dir.join("palpation.toml"), FileKind::Scene).unwrap();
        (text, dir)
    }

    #[test]
    fn the_palpation_scene_places_its_inclusions_and_keeps_them_from_the_viewers() {
        let (text, dir) = palpation();
        let load = |t: &str| Scene::from_toml(t, Path::new("palpation.toml"), Some(&dir));
        let s = load(&text).unwrap();
        assert_eq!(s.inclusions.len(), 2);
        let fixed = s.inclusions[0];
        assert_eq!((fixed.radius_m, fixed.stiffness_ratio), (0.005, 4.0));
        // 10 mm under the liver's top: below the point asked for.
        assert!(fixed.centre_in_object_m[1] < 0.09 - 0.01);
        let drawn = s.inclusions[1];
        assert!((2.0..=6.0).contains(&drawn.stiffness_ratio));
        assert!((0.008..=0.014).contains(&drawn.centre_depth_m));
        assert_eq!(s.haptic_world().inclusions().map(|f| f.len()), Some(2));
        // The same seed draws the same lump; another seed another one.
        assert_eq!(load(&text).unwrap().inclusions[1], drawn);
        let other = load(&text.replace("seed = 7", "seed = 8")).unwrap();
        assert_ne!(other.inclusions[1], drawn);
        // Nothing the viewers get names them.
        let message = serde_json::to_string(&s.message()).unwrap();
        assert!(!message.contains("inclusion"), "{message}");
        let x = format!("{}", fixed.centre_in_object_m[0]);
        assert!(!message.contains(&x));
        // The recording keeps them, and a check rebuilds them from it without the files.
        let record = SceneRecord {
            message: s.message(),
            scene_toml: text.replace("seed = 7", "seed = 9"),
            scene_file: None,
            period_ns: 1_000_000,
            meshes: s.recorded_meshes(),
            inclusions: s.recorded_inclusions(),
            guide: None,
        };
        let again = Scene::from_recording(&record, Path::new("<recording>")).unwrap();
        assert_eq!(again.inclusions, s.inclusions);
        assert_eq!(again.inclusion_table, s.inclusion_table);
        // A scene without inclusions has no field.
        let plain = Scene::builtin_default().unwrap();
        assert!(plain.inclusions.is_empty() && plain.haptic_world().inclusions().is_none());
        assert!(plain.recorded_inclusions().is_none());
    }

    #[test]
    fn a_bad_inclusion_is_refused_naming_the_file_the_field_and_the_value() {
        let (text, dir) = palpation();
        let err = |t: String| {
            Scene::from_toml(&t, Path::new("palpation.toml"), Some(&dir))
                .unwrap_err()
                .to_string()
        };
        let e = err(text.replacen("stiffness_ratio = 4.0", "stiffness_ratio = 12.0", 1));
        assert!(
            e.starts_with("palpation.toml: inclusion[0].stiffness_ratio:") && e.contains("12"),
            "{e}"
        );
        let e = err(text.replacen("radius_m = 0.005", "radius_m = 0.009", 1));
        assert!(
            e.contains("inclusion[0].radius_m") && e.contains("0.009"),
            "{e}"
        );
        let e = err(text.replacen("centre_depth_m = 0.010", "centre_depth_m = -0.01", 1));
        assert!(
            e.contains("inclusion[0].centre_depth_m") && e.contains("-0.01"),
            "{e}"
        );
        let e = err(text.replace("seed = 7", ""));
        assert!(e.contains("inclusion[1].seed"), "{e}");
        let e = err(text.replace("max = 0.014", "max = 0.004"));
        assert!(
            e.contains("inclusion[1].centre_depth_m") && e.contains("0.004"),
            "{e}"
        );
        let e = err(text.replace(
            "inclusions = \"calibration/inclusion_sphere10_50kpa.json\"",
            "",
        ));
        assert!(e.contains("calibration.inclusions"), "{e}");
        let e = err(text.replace("youngs_modulus_pa = 50000.0", "youngs_modulus_pa = 60000.0"));
        assert!(
            e.contains("calibration.inclusions") && e.contains("60000"),
            "{e}"
        );
    }

    /// The scene record a session of `text` (a built-in-object scene) writes, with the recorded
    /// model `model`.
    pub(super) fn recording_of(text: &str, model: ContactModelInfo) -> SceneRecord {
        let scene = Scene::from_toml(text, Path::new("<test>"), None).unwrap();
        let mut message = scene.message();
        message.contact_model = model;
        SceneRecord {
            message,
            scene_toml: text.to_owned(),
            scene_file: None,
            period_ns: 1_000_000,
            meshes: scene.recorded_meshes(),
            inclusions: scene.recorded_inclusions(),
            guide: scene.recorded_guide(),
        }
    }
}
