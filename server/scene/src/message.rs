//! The `scene` message the viewers are sent for a scene.
//!
//! Built here, beside the [`Scene`] it reads, rather than in the proto crate beside the
//! [`SceneMessage`] type: it needs the server's scene and the device crate's limits, and the
//! proto crate depends on neither.

use softhaptic_proto::wire::{
    DeviceInfo, ModelInfo, PROTOCOL_VERSION, RenderMeshInfo, SceneMessage,
};

use softhaptic_proto::guide::GuidePathInfo;

use super::Scene;

impl Scene {
    /// The `scene` message for this scene: what the viewers draw and how they label it.
    pub fn message(&self) -> SceneMessage {
        let limits = self.device_limits;
        let device_name = self
            .device_label
            .clone()
            .unwrap_or_else(|| format!("{} {}", self.device_kind.name(), limits.name));
        SceneMessage {
            protocol_version: PROTOCOL_VERSION,
            tool: self.tool,
            material: self.material,
            model: ModelInfo::new(
                &self.tool,
                self.force.valid_depth_m,
                self.force.valid_inclination_rad,
            ),
            contact_model: self.contact_model_info(),
            calibration: self.calibration.clone(),
            render_profile: self.render_profile,
            render_meshes: vec![RenderMeshInfo {
                name: self.object_name.clone(),
                url: format!("/meshes/{}.bin", self.object_name),
                vertex_count: self.render_surface.positions_m.len() as u32,
                object_in_world: self.object_in_world,
            }],
            device: DeviceInfo {
                name: device_name,
                force_feedback: self.device_renders_force,
                peak_force_n: limits.peak_force_n,
                continuous_force_n: limits.continuous_force_n,
                max_stiffness_n_per_m: limits.max_stiffness_n_per_m,
                damping_n_s_per_m: limits.damping_n_s_per_m,
                workspace_radius_m: limits.workspace_radius_m,
            },
            guide: self
                .guide
                .as_ref()
                .map(|g| GuidePathInfo::from_recorded(&g.recorded)),
        }
    }
}
