//! From a parsed scene file, or a recording, to a [`Scene`]: the object's pose and meshes, the
//! device and its placement, the haptics, the calibration table (`calibration.rs`) and the
//! contact model with its validity limits. Every value is checked here, and a refused one names
//! its field.

use std::path::Path;
use std::sync::{Arc, OnceLock};

use glam::{DQuat, DVec3};
use softhaptic_device::collision::{Collider, CollisionMode};
use softhaptic_device::force::ForceConfig;
use softhaptic_device::mesh::HapticMesh;
use softhaptic_device::model::ForceModel;
use softhaptic_device::spacemouse::rate::RateConfig;
use softhaptic_proto::record::MeshRecord;
use softhaptic_proto::{
    Inclusion, InclusionTable, Material, ModelError, Pose, ToolShape, ValidityLimits,
};

use super::calibration;
use super::file::{
    Builtin, DeviceKind, Drawn, InclusionSection, SceneFile, WorldFromDeviceSection,
    identity_quaternion,
};
use super::{FileBase, ModelSource, RenderSurface, Scene, SceneError, obj};
use crate::toml_file::TomlFileError;

impl Scene {
    /// Validates a parsed scene file and loads what it names; `path` names the scene in errors,
    /// `base` resolves its relative files (`None`: a built-in scene), `model_source` says
    /// whether the model, limits, table and meshes come from the files or from a recording.
    pub(super) fn from_file(
        file: SceneFile,
        path: &Path,
        base: Option<&Path>,
        model_source: ModelSource<'_>,
    ) -> Result<Scene, SceneError> {
        let field = |field: &str, reason: String| {
            SceneError::from(TomlFileError::field(path, field, reason))
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
                let top = softhaptic_device::liver::top_contact();
                (
                    softhaptic_device::liver::haptic_mesh(),
                    liver_render_surface(),
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
                        let haptic =
                            obj::load_obj(&resolve(haptic_path), path, "object.haptic_mesh")?;
                        let render = match &object.render_mesh {
                            Some(p) => obj::load_obj(&resolve(p), path, "object.render_mesh")?,
                            None => haptic.clone(),
                        };
                        (haptic, render)
                    }
                };
                let surface = Arc::new(RenderSurface::from_mesh(&render));
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
        if file.device.kind != DeviceKind::Openhaptics && file.device.name.is_some() {
            return Err(field(
                "device.name",
                "names an OpenHaptics device configuration: only for kind = \"openhaptics\"".into(),
            ));
        }
        if !matches!(
            file.device.kind,
            DeviceKind::Openhaptics | DeviceKind::Forcedimension
        ) && file.device.world_from_device.is_some()
        {
            return Err(field(
                "device.world_from_device",
                "places a real device in the world: only for kind = \"openhaptics\" or \"forcedimension\"".into(),
            ));
        }
        if let Some(index) = file.device.index {
            if file.device.kind != DeviceKind::Forcedimension {
                return Err(field(
                    "device.index",
                    "picks a Force Dimension device: only for kind = \"forcedimension\"".into(),
                ));
            }
            if index > crate::file::MAX_DEVICE_INDEX {
                return Err(field(
                    "device.index",
                    format!(
                        "must be from 0 to {} (0 is the first device plugged in), got {index}",
                        crate::file::MAX_DEVICE_INDEX
                    ),
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

        let calibration =
            calibration::calibration_table(&file, tool, material, files, model_source, path)?;

        // The object's contact model, for the scene's tool only, and its validity limits.
        let (spec, validity) = match model_source {
            ModelSource::File => {
                let spec = file.object.model;
                let limits =
                    calibration::load_limits(file.calibration.limits.as_deref(), files, path)?;
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

        let (inclusions, inclusion_table) = place_inclusions(
            &file,
            &haptic_mesh,
            &tool,
            &material,
            model_source,
            &resolve,
            base.is_some(),
        )
        .map_err(|(name, reason)| field(&name, reason))?;

        Ok(Scene {
            inclusions,
            inclusion_table,
            guide: None,
            source: base.map(|_| path.to_owned()),
            object_name: object.name.clone(),
            object_in_world,
            haptic_mesh,
            render_surface,
            material,
            tool,
            device_kind: file.device.kind,
            device_limits: file.device.model.limits(),
            device_name: file
                .device
                .name
                .clone()
                .or(file.device.serial.clone())
                .or(file.device.index.map(|i| i.to_string())),
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
            source_toml: String::new(),
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

/// A mesh as a recording keeps it, with the hash of its content.
pub(super) fn mesh_record(positions_m: &[DVec3], triangles: &[[u32; 3]]) -> MeshRecord {
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

/// The built-in liver's render surface, built once per process and shared by every scene that
/// draws it: each load (a fuzz input, a replay check, a test) would otherwise copy its
/// 163 842 vertices and 327 680 triangles twice.
fn liver_render_surface() -> Arc<RenderSurface> {
    static SURFACE: OnceLock<Arc<RenderSurface>> = OnceLock::new();
    SURFACE
        .get_or_init(|| {
            Arc::new(RenderSurface::from_mesh(
                &softhaptic_device::liver::render_mesh(),
            ))
        })
        .clone()
}

/// The scene's inclusions placed in the object and their table, or the field and the reason a
/// value is refused. From a recording, the placed inclusions and the table it kept (no file is
/// read); from files, each under the surface point closest to its `near_m`.
fn place_inclusions(
    file: &SceneFile,
    haptic_mesh: &HapticMesh,
    tool: &ToolShape,
    material: &Material,
    model_source: ModelSource<'_>,
    resolve: &dyn Fn(&Path) -> std::path::PathBuf,
    has_files: bool,
) -> Result<(Vec<Inclusion>, Option<InclusionTable>), (String, String)> {
    if file.inclusion.is_empty() {
        return Ok((Vec::new(), None));
    }
    if let ModelSource::Recorded(record) = model_source {
        let Some(kept) = &record.inclusions else {
            return Err((
                "inclusion".into(),
                "the recording keeps no inclusions, and a check never reads a file a recording names".into(),
            ));
        };
        return Ok((kept.placed.clone(), Some(kept.table.clone())));
    }
    let Some(table_path) = &file.calibration.inclusions else {
        return Err((
            "calibration.inclusions".into(),
            "a scene with [[inclusion]] names the inclusions' FEM table (`softhaptic-calibrate inclusion` writes it)".into(),
        ));
    };
    if !has_files {
        return Err((
            "calibration.inclusions".into(),
            "the built-in scene cannot name files".into(),
        ));
    }
    let full = resolve(table_path);
    let table: InclusionTable = crate::files::read_text(&full, crate::files::FileKind::Table)
        .map_err(|e| e.to_string())
        .and_then(|text| serde_json::from_str(&text).map_err(|e| e.to_string()))
        .map_err(|e| {
            (
                "calibration.inclusions".to_owned(),
                format!("{}: {e}", table_path.display()),
            )
        })?;
    if table.tool() != tool || table.material() != material {
        return Err((
            "calibration.inclusions".into(),
            format!(
                "{} was measured for {:?} on {:?}, not the scene's {:?} on {:?}",
                table_path.display(),
                table.tool(),
                table.material(),
                tool,
                material
            ),
        ));
    }
    let mut collider = Collider::new(haptic_mesh.clone(), CollisionMode::Continuous);
    let mut placed = Vec::with_capacity(file.inclusion.len());
    for (i, section) in file.inclusion.iter().enumerate() {
        let name = |f: &str| format!("inclusion[{i}].{f}");
        let inc = draw(section).map_err(|(f, reason)| (name(f), reason))?;
        let positive = |f: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err((name(f), format!("must be finite and > 0, got {v}")))
            }
        };
        positive("radius_m", inc.radius_m)?;
        positive("centre_depth_m", inc.centre_depth_m)?;
        if !softhaptic_proto::inclusion::STIFFNESS_RATIO_RANGE.contains(&inc.stiffness_ratio) {
            return Err((
                name("stiffness_ratio"),
                format!("must be 1.5 to 10, got {}", inc.stiffness_ratio),
            ));
        }
        if let Some(reason) = table.refuses(inc.radius_m, inc.stiffness_ratio) {
            let f = if reason.starts_with("radius") {
                "radius_m"
            } else {
                "stiffness_ratio"
            };
            return Err((
                name(f),
                format!("{reason}: run `softhaptic-calibrate inclusion` for it"),
            ));
        }
        let near = DVec3::from_array(inc.near_m);
        let Some(surface) = collider
            .closest_surface_point(near, 1.0)
            .filter(|s| s.normal != DVec3::ZERO)
        else {
            return Err((
                name("near_m"),
                format!("{:?}: no surface point near it", inc.near_m),
            ));
        };
        let centre = surface.point_m - inc.centre_depth_m * surface.normal;
        placed.push(Inclusion {
            centre_in_object_m: centre.to_array(),
            radius_m: inc.radius_m,
            stiffness_ratio: inc.stiffness_ratio,
            centre_depth_m: inc.centre_depth_m,
        });
    }
    Ok((placed, Some(table)))
}

/// An inclusion's values as drawn.
struct DrawnInclusion {
    near_m: [f64; 3],
    centre_depth_m: f64,
    radius_m: f64,
    stiffness_ratio: f64,
}

/// Draws an inclusion's ranges from its seed (in the order of the fields, so a seed always
/// draws the same values), or the field and why it cannot.
fn draw(section: &InclusionSection) -> Result<DrawnInclusion, (&'static str, String)> {
    use rand::{Rng, SeedableRng};
    let any_range = section.near_m.is_range()
        || section.centre_depth_m.is_range()
        || section.radius_m.is_range()
        || section.stiffness_ratio.is_range();
    let mut rng = match (section.seed, any_range) {
        (Some(seed), _) => rand_chacha::ChaCha8Rng::seed_from_u64(seed),
        (None, false) => rand_chacha::ChaCha8Rng::seed_from_u64(0),
        (None, true) => {
            return Err((
                "seed",
                "a value given as a range is drawn from a seed: add seed = <integer>".into(),
            ));
        }
    };
    let mut one = |field: &'static str, v: Drawn<f64>| match v {
        Drawn::Fixed(x) => Ok(x),
        // A finite width too: the sampler refuses (panics on) a range wider than f64 holds.
        Drawn::Range { min, max } if (max - min).is_finite() && min <= max => Ok(if min == max {
            min
        } else {
            rng.random_range(min..=max)
        }),
        Drawn::Range { min, max } => Err((
            field,
            format!("range {{ min = {min}, max = {max} }} needs finite min <= max"),
        )),
    };
    let near_m = match section.near_m {
        Drawn::Fixed(p) => p,
        Drawn::Range { min, max } => {
            let mut p = [0.0; 3];
            for a in 0..3 {
                p[a] = one(
                    "near_m",
                    Drawn::Range {
                        min: min[a],
                        max: max[a],
                    },
                )?;
            }
            p
        }
    };
    Ok(DrawnInclusion {
        near_m,
        centre_depth_m: one("centre_depth_m", section.centre_depth_m)?,
        radius_m: one("radius_m", section.radius_m)?,
        stiffness_ratio: one("stiffness_ratio", section.stiffness_ratio)?,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use softhaptic_proto::ModelSpec;
    use softhaptic_proto::wire::ContactModelInfo;

    use super::super::tests::recording_of;
    use super::*;

    #[test]
    fn a_recorded_model_overrides_the_scene_file() {
        // A replay runs the model the session ran, whatever the scene text's defaults say now.
        let text = include_str!("../../../scenes/default.toml");
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
            include_str!("../../../scenes/cone.toml"),
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
            &recording_of(include_str!("../../../scenes/cone.toml"), exact),
            Path::new("<test>"),
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("object.model.exact_sphere"), "{err}");
    }
}
