//! What one haptic tick computes, as a plain synchronous object.
//!
//! [`HapticWorld::step`] turns one device reading into one [`ContactState`]: fault guard,
//! collision in the object's frame (with the surface's local curvature when the scene's contact
//! model uses it), followed across ticks so that a tool pushed through the object is held on the
//! side it entered ([`crate::tracking`]), force rendering with every safety limit. The loop thread
//! calls it at 1 kHz; tests, replays and benches call it directly, with no thread and no clock,
//! which is what makes a replay bit-identical (docs/design.md, invariant 5).

use glam::DVec3;
use softhaptic_proto::{ContactFlags, ContactState, GuideState, Material, Pose, ToolShape};

use crate::collision::Collider;
use crate::device::{DeviceError, DeviceLimits, DeviceSample, HapticDevice};
use crate::metrics::{MetricsAccumulator, TickInput, TraineeMetrics};

/// The safe force of a world whose scene sets none, N.
pub const DEFAULT_SAFE_FORCE_N: f64 = 2.0;
use crate::force::{ForceConfig, ForceRenderer, RenderedForce, WorldContact};
use crate::guide::{Guide, GuideOutput};
use crate::inclusion::InclusionField;
use crate::model::{ForceModel, LocalGeometry};
use crate::tracking::ContactTracker;

/// What [`HapticWorld::tick`] read, computed and commanded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickOutcome {
    /// The contact state; its `force_n` is what the device was commanded (zero when refused).
    pub state: ContactState,
    /// The device's reading, or why it failed.
    pub read: Result<DeviceSample, DeviceError>,
    /// Whether the device took the command.
    pub command: Result<(), DeviceError>,
}

/// One object, one tool, one device: everything a tick needs. Owns its collider, so it never
/// shares memory with another thread.
pub struct HapticWorld {
    collider: Collider,
    /// Holds a tool pushed past what the collision measures on the side it entered. Kept through
    /// a fault: a gap in the readings is not a release.
    tracker: ContactTracker,
    object_in_world: Pose,
    renderer: ForceRenderer,
    /// Ticks stepped so far (the next state's `tick`).
    tick: u64,
    /// The last valid reading: a faulted tick reports it rather than a NaN pose.
    last_good: Option<DeviceSample>,
    /// The trainee's metrics, updated by every [`HapticWorld::tick`].
    metrics: MetricsAccumulator,
    /// The object's stiffer inclusions; `None` (nothing computed per tick) without any.
    inclusions: Option<InclusionField>,
    /// Guidance along an expert's path; `None` (nothing computed per tick) without it.
    guide: Option<Guide>,
    /// What the guide did on the last tick it ran.
    guide_output: Option<GuideOutput>,
}

impl HapticWorld {
    /// Builds the world with the paper's law for `tool` on `material`. `object_in_world` places
    /// the collider's mesh; the device's origin is the world origin (its workspace is checked
    /// around it).
    pub fn new(
        collider: Collider,
        object_in_world: Pose,
        tool: ToolShape,
        material: Material,
        force: ForceConfig,
        limits: DeviceLimits,
    ) -> Self {
        Self::with_model(
            collider,
            object_in_world,
            ForceModel::paper(tool, material),
            force,
            limits,
        )
    }

    /// Builds the world with the scene's contact model. When the model uses the object's
    /// curvature and the collider does not measure it yet, the curvature is estimated here, once
    /// (docs/design.md, invariant 7: only a model that asks for it pays for it).
    pub fn with_model(
        collider: Collider,
        object_in_world: Pose,
        model: ForceModel,
        force: ForceConfig,
        limits: DeviceLimits,
    ) -> Self {
        let collider = if model.spec().curvature {
            collider.with_curvature()
        } else {
            collider
        };
        Self {
            collider,
            tracker: ContactTracker::new(),
            object_in_world,
            renderer: ForceRenderer::with_model(model, force, limits),
            tick: 0,
            last_good: None,
            metrics: MetricsAccumulator::new(DEFAULT_SAFE_FORCE_N),
            inclusions: None,
            guide: None,
            guide_output: None,
        }
    }

    /// Guides the trainee along an expert's path from the next tick (`None`: no guidance).
    pub fn set_guide(&mut self, mut guide: Option<Guide>) {
        if let Some(g) = guide.as_mut() {
            g.set_max_damping(self.renderer.limits().damping_n_s_per_m);
        }
        self.guide = guide;
        self.guide_output = None;
        self.renderer.set_guidance(DVec3::ZERO);
    }

    /// The guide, to set its gain or restart it between attempts.
    pub fn guide_mut(&mut self) -> Option<&mut Guide> {
        self.guide.as_mut()
    }

    /// What the guide did on the last tick it ran (`None` without guidance).
    pub fn guide_output(&self) -> Option<GuideOutput> {
        self.guide_output
    }

    /// Puts the object's stiffer inclusions into the world ([`crate::inclusion`]); an empty
    /// field is dropped, so a world without inclusions does no work for them.
    pub fn with_inclusions(mut self, field: InclusionField) -> Self {
        self.inclusions = (!field.is_empty()).then_some(field);
        self
    }

    /// The object's inclusions, if it has any.
    pub fn inclusions(&self) -> Option<&InclusionField> {
        self.inclusions.as_ref()
    }

    pub fn tool(&self) -> &ToolShape {
        self.renderer.tool()
    }

    pub fn material(&self) -> &Material {
        self.renderer.material()
    }

    /// The contact model the world renders.
    pub fn model(&self) -> &ForceModel {
        self.renderer.model()
    }

    /// The local geometry the model was last evaluated at.
    pub fn geometry(&self) -> &LocalGeometry {
        self.renderer.geometry()
    }

    pub fn limits(&self) -> &DeviceLimits {
        self.renderer.limits()
    }

    pub fn force_config(&self) -> &ForceConfig {
        self.renderer.config()
    }

    pub fn object_in_world(&self) -> &Pose {
        &self.object_in_world
    }

    pub fn collider(&self) -> &Collider {
        &self.collider
    }

    /// Depth δ* beyond which the stiffness cap (when on) linearises the law, at the current
    /// geometry.
    pub fn cap_depth_m(&self) -> f64 {
        self.renderer.cap_depth_m()
    }

    /// The elastic force magnitude the renderer uses at `depth_m` and the current geometry (the
    /// model, or its capped extension past δ*), before damping and the other limits.
    pub fn elastic_force_n(&self, depth_m: f64) -> f64 {
        self.renderer.elastic_force_n(depth_m).0
    }

    /// Energy the environment has absorbed in the current contact (passivity observer); negative
    /// means the loop has created energy that the controller has not yet removed.
    pub fn passivity_energy_j(&self) -> f64 {
        self.renderer.passivity_energy_j()
    }

    /// The trainee's metrics over the ticks run so far ([`HapticWorld::tick`]).
    pub fn metrics(&self) -> TraineeMetrics {
        self.metrics.metrics()
    }

    /// The force above which the metrics count time (the scene's safe force). Resets them.
    pub fn set_safe_force(&mut self, safe_force_n: f64) {
        self.metrics = MetricsAccumulator::new(safe_force_n);
    }

    /// Ticks stepped so far.
    pub fn ticks(&self) -> u64 {
        self.tick
    }

    /// One tick: from the device's reading (or its error) to the contact state whose `force_n`
    /// must be commanded. Never panics, never allocates.
    pub fn step(&mut self, sample: Result<DeviceSample, DeviceError>) -> ContactState {
        let tick = self.tick;
        self.tick += 1;
        let sample = match sample {
            Ok(s) if self.sample_is_plausible(&s) => s,
            Ok(s) => {
                // The time may still be meaningful when only the pose is broken.
                let time_ns = s.time_ns;
                return self.fault_state(tick, Some(time_ns));
            }
            Err(_) => return self.fault_state(tick, None),
        };
        self.last_good = Some(sample);

        let o = &self.object_in_world;
        let to_object = o.orientation.inverse();
        let tip_in_object = Pose {
            position_m: to_object * (sample.tip_in_world.position_m - o.position_m),
            orientation: to_object * sample.tip_in_world.orientation,
        };
        let tool = *self.renderer.tool();
        let tracked = self
            .tracker
            .query(&mut self.collider, &tool, &tip_in_object);
        let geometry = tracked.map(|t| t.geometry);
        let contact = geometry.map(|g| WorldContact {
            depth_m: g.depth_m,
            normal: o.orientation * g.normal,
            degenerate_normal: g.degenerate_normal,
            curvature_1_per_m: g.curvature_1_per_m,
        });
        if let (Some(field), Some(g)) = (&self.inclusions, geometry) {
            let load = field.load(g.contact_point_m, g.normal, g.depth_m);
            self.renderer.set_inclusion(
                load.ratio,
                o.orientation * load.gradient_1_per_m,
                load.ratio_per_depth_1_per_m,
            );
        }
        let tool_axis = sample.tip_in_world.orientation * DVec3::Y;
        if let Some(guide) = self.guide.as_mut() {
            let out = guide.step(
                sample.tip_in_world.position_m,
                sample.tip_velocity_m_s,
                contact.map(|c| (c.normal, c.depth_m)),
                sample.time_ns,
            );
            self.guide_output = Some(out);
            self.renderer.set_guidance(out.force_n);
        }
        self.renderer.set_motors_warm(
            sample.flags.contains(ContactFlags::MOTORS_WARM),
            sample.time_ns,
        );
        let rendered = self.renderer.render(
            contact.as_ref(),
            sample.tip_in_world.position_m,
            sample.tip_velocity_m_s,
            tool_axis,
            sample.time_ns,
        );

        let mut state = ContactState {
            tick,
            time_ns: sample.time_ns,
            tip_in_world: sample.tip_in_world,
            tip_velocity_m_s: sample.tip_velocity_m_s,
            buttons: sample.buttons,
            force_n: rendered.force_n,
            // The device's own words about the reading travel with the tick.
            flags: rendered.flags
                | (sample.flags & (ContactFlags::MOTORS_WARM | ContactFlags::OUTSIDE_WORKSPACE)),
            guide: self.guide_output.map(|o| o.state()),
            ..ContactState::IDLE
        };
        if tracked.is_some_and(|t| t.pushed_through) {
            state.flags |= ContactFlags::PUSHED_THROUGH;
        }
        if self.guide_output.is_some_and(|o| o.passivity_damping) {
            state.flags |= ContactFlags::PASSIVITY_DAMPING;
        }
        if let (Some(g), Some(c)) = (geometry, contact)
            && c.depth_m.is_finite()
        {
            state.in_contact = true;
            state.depth_m = g.depth_m.max(0.0);
            state.normal = c.normal;
            state.contact_point_m = o.transform_point(g.contact_point_m);
            // The paper's a = √(Rδ) (sphere) or 2δ tan α/π (cone) unless the model bends it
            // with the curvature or the exact sphere; the renderer holds this tick's geometry.
            // Computed after the force and never read by it: it is drawn, never felt.
            state.contact_radius_m = self
                .renderer
                .model()
                .contact_radius_m(state.depth_m, self.renderer.geometry());
        }
        state
    }

    /// One whole tick against `device`: read it, step, command the force. A command the device
    /// refused (it output zero instead, [`HapticDevice::command_force`]) makes this tick a device
    /// fault with zero force, and the force ramps in again afterwards as after any fault. The
    /// loop thread runs its ticks through here, and so does the replay check, whose replay device
    /// refuses the commands the recorded device refused: one code path, so a replay is
    /// bit-identical (docs/design.md, invariant 5).
    pub fn tick<D: HapticDevice + ?Sized>(&mut self, device: &mut D) -> TickOutcome {
        let read = device.read();
        let mut state = self.step(read);
        let command = device.command_force(state.force_n);
        if command.is_err() {
            self.renderer.fault();
            state.force_n = DVec3::ZERO;
            state.flags |= ContactFlags::DEVICE_FAULT;
        }
        // The tick as it is recorded: the same input a recording's metrics are computed from.
        let fault = state.flags.contains(ContactFlags::DEVICE_FAULT);
        self.metrics.update(&TickInput {
            time_ns: state.time_ns,
            tip_position_m: (!fault && read.is_ok()).then_some(state.tip_in_world.position_m),
            in_contact: state.in_contact,
            depth_m: state.depth_m,
            force_n: state.force_n,
            flags: state.flags,
            buttons: if fault { 0 } else { state.buttons },
            guide: state.guide,
        });
        TickOutcome {
            state,
            read,
            command,
        }
    }

    /// A reading is plausible when every number is finite and the tip is where a device of this
    /// size can physically be.
    fn sample_is_plausible(&self, s: &DeviceSample) -> bool {
        let limits = self.renderer.limits();
        let reach_m = limits.workspace_radius_m * self.renderer.config().workspace_tolerance;
        s.is_finite() && s.tip_in_world.position_m.length() <= reach_m
    }

    fn fault_state(&mut self, tick: u64, time_ns: Option<u64>) -> ContactState {
        let RenderedForce { force_n, flags } = self.renderer.fault();
        if let Some(guide) = self.guide.as_mut() {
            guide.release();
        }
        // The guide lets go: its target stays where it was, its pull is nothing.
        let guide = self.guide_output.map(|o| GuideState {
            force_n: DVec3::ZERO,
            effective_gain: 0.0,
            engaged: false,
            ..o.state()
        });
        let (tip_in_world, last_time_ns) = match self.last_good {
            Some(s) => (s.tip_in_world, s.time_ns),
            None => (Pose::IDENTITY, 0),
        };
        ContactState {
            tick,
            time_ns: time_ns.unwrap_or(last_time_ns),
            tip_in_world,
            force_n,
            flags: flags | ContactFlags::DEVICE_FAULT,
            guide,
            ..ContactState::IDLE
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use crate::collision::CollisionMode;
    use crate::law;
    use crate::mesh::HapticMesh;
    use glam::DQuat;

    const MS: u64 = 1_000_000;

    fn world(object_in_world: Pose) -> HapticWorld {
        let tool = ToolShape::sphere(0.01).unwrap();
        HapticWorld::new(
            Collider::new(HapticMesh::grid(41, 0.04), CollisionMode::default()),
            object_in_world,
            tool,
            Material::PAPER_SOFT,
            ForceConfig::for_tool(&tool),
            DeviceLimits::PHANTOM_DESKTOP,
        )
    }

    fn sample_at(time_ns: u64, position_m: DVec3) -> DeviceSample {
        DeviceSample {
            time_ns,
            tip_in_world: Pose::from_position(position_m),
            tip_velocity_m_s: DVec3::ZERO,
            buttons: 1,
            flags: ContactFlags::empty(),
        }
    }

    #[test]
    fn pressing_the_grid_gives_the_hertz_force_along_the_normal() {
        let mut w = world(Pose::IDENTITY);
        let mut s = ContactState::IDLE;
        // 0.67 N at once is a jump: the onset is ramped over 80 ms first.
        for k in 0..100 {
            s = w.step(Ok(sample_at(k * MS, DVec3::new(0.0, -0.002, 0.0))));
        }
        assert!(s.in_contact);
        assert!((s.depth_m - 0.002).abs() < 1e-12);
        let expected = law::contact_force_n(w.tool(), w.material(), 0.002);
        assert!((s.force_n.y - expected).abs() < 1e-9, "{:?}", s.force_n);
        assert!((s.contact_radius_m - (0.01f64 * 0.002).sqrt()).abs() < 1e-12);
        assert_eq!(s.tick, 99);
        assert_eq!(s.buttons, 1);
    }

    #[test]
    fn object_pose_maps_the_contact_into_the_world() {
        // The grid stood up: its +y normal now points along world +x, at x = 0.05.
        let placed = Pose {
            position_m: DVec3::new(0.05, 0.0, 0.0),
            orientation: DQuat::from_rotation_z(-std::f64::consts::FRAC_PI_2),
        };
        let mut w = world(placed);
        let tip = Pose {
            position_m: DVec3::new(0.05 - 0.001, 0.0, 0.0),
            orientation: DQuat::from_rotation_z(-std::f64::consts::FRAC_PI_2),
        };
        let s = w.step(Ok(DeviceSample {
            tip_in_world: tip,
            ..sample_at(0, DVec3::ZERO)
        }));
        assert!(s.in_contact);
        assert!((s.normal - DVec3::X).length() < 1e-9, "{:?}", s.normal);
        assert!(s.force_n.x > 0.0 && s.force_n.y.abs() < 1e-9);
        assert!((s.contact_point_m.x - 0.05).abs() < 1e-9);
        assert!(!s.flags.contains(ContactFlags::BEYOND_VALID_INCLINATION));
    }

    #[test]
    fn non_finite_and_out_of_workspace_samples_are_faults_with_zero_force() {
        let mut w = world(Pose::IDENTITY);
        w.step(Ok(sample_at(0, DVec3::new(0.0, -0.002, 0.0))));
        let mut nan = sample_at(MS, DVec3::new(f64::NAN, -0.002, 0.0));
        let s = w.step(Ok(nan));
        assert_eq!(s.force_n, DVec3::ZERO);
        assert!(s.flags.contains(ContactFlags::DEVICE_FAULT));
        assert!(s.tip_in_world.is_finite(), "the last good pose is reported");
        assert_eq!(s.time_ns, MS);
        nan.tip_in_world.position_m = DVec3::new(0.0, -0.002, 0.0);
        nan.tip_velocity_m_s = DVec3::new(0.0, f64::INFINITY, 0.0);
        assert!(w.step(Ok(nan)).flags.contains(ContactFlags::DEVICE_FAULT));
        let far = w.step(Ok(sample_at(2 * MS, DVec3::new(0.0, -0.002, 5.0))));
        assert!(far.flags.contains(ContactFlags::DEVICE_FAULT));
        assert_eq!(far.force_n, DVec3::ZERO);
        let gone = w.step(Err(DeviceError::Disconnected));
        assert!(gone.flags.contains(ContactFlags::DEVICE_FAULT) && !gone.in_contact);
        assert_eq!(gone.force_n, DVec3::ZERO);
    }

    #[test]
    fn recovery_after_a_fault_ramps_without_a_spike() {
        let mut w = world(Pose::IDENTITY);
        let p = DVec3::new(0.0, -0.003, 0.0);
        let mut steady = 0.0;
        for k in 0..100 {
            steady = w.step(Ok(sample_at(k * MS, p))).force_n.y;
        }
        w.step(Err(DeviceError::Timeout));
        let first = w.step(Ok(sample_at(101 * MS, p)));
        assert!(first.flags.contains(ContactFlags::RAMPING));
        assert!(
            first.force_n.y < 0.05 * steady,
            "{} vs {}",
            first.force_n.y,
            steady
        );
        let mut last = first.force_n.y;
        for k in 102..300 {
            let f = w.step(Ok(sample_at(k * MS, p))).force_n.y;
            assert!(f + 1e-12 >= last && f - last < 0.02 * steady + 1e-12);
            last = f;
        }
        assert!((last - steady).abs() < 1e-9);
    }

    #[test]
    fn replay_is_bit_identical() {
        let run = || {
            let mut w = world(Pose::IDENTITY);
            (0..300u64)
                .map(|k| {
                    let y = 0.004 * ((k as f64) * 0.03).sin() - 0.001;
                    let mut s = sample_at(k * MS, DVec3::new(0.0, y, 0.0));
                    s.tip_velocity_m_s.y = 0.12 * ((k as f64) * 0.03).cos();
                    w.step(Ok(s)).force_n
                })
                .collect::<Vec<_>>()
        };
        let (a, b) = (run(), run());
        assert!(
            a.iter()
                .zip(&b)
                .all(|(x, y)| x.to_array().map(f64::to_bits) == y.to_array().map(f64::to_bits))
        );
        assert!(a.iter().any(|f| f.y > 0.1));
    }

    /// A guide along x at height `y_m` and `z_m`, 2 mm deep at the expert's ticks.
    fn guide_along_x(y_m: f64, z_m: f64) -> Guide {
        use crate::guide::{GuideParams, GuidePath};
        let path = GuidePath::resample(
            (0..=10).map(|i| (DVec3::new(-0.01 + 0.002 * i as f64, y_m, z_m), 0.002)),
            0.001,
        )
        .unwrap();
        Guide::new(path, GuideParams::default())
    }

    #[test]
    fn the_guiding_force_is_added_in_free_space_and_ramps_in_again_after_a_fault() {
        let mut w = world(Pose::IDENTITY);
        // 10 mm above the grid, in free space.
        w.set_guide(Some(guide_along_x(0.01, 0.0)));
        // 5 mm above the path, free of the grid: pulled down, ramped in over 0.2 s.
        let tip = DVec3::new(0.0, 0.015, 0.0);
        let mut s = ContactState::IDLE;
        for k in 0..300 {
            s = w.step(Ok(sample_at(k * MS, tip)));
        }
        assert!(!s.in_contact);
        // k × 5 mm = 0.75 N, straight toward the path.
        assert!(
            (s.force_n - DVec3::new(0.0, -0.75, 0.0)).length() < 1e-9,
            "{:?}",
            s.force_n
        );
        assert!(w.guide_output().unwrap().engaged);
        // A fault: zero, and the pull starts again from zero afterwards.
        let s = w.step(Err(DeviceError::Disconnected));
        assert_eq!(s.force_n, DVec3::ZERO);
        let s = w.step(Ok(sample_at(301 * MS, tip)));
        assert!(s.force_n.length() < 0.01, "{:?}", s.force_n);
        // Without the guide, nothing in free space.
        w.set_guide(None);
        let s = w.step(Ok(sample_at(302 * MS, tip)));
        assert_eq!(s.force_n, DVec3::ZERO);
    }

    #[test]
    fn guidance_and_contact_together_stay_within_the_devices_peak() {
        let mut w = world(Pose::IDENTITY);
        // A path 5 mm down in the object and 8 mm to the side: the guide pulls sideways at its
        // cap (inward only until the tool is as deep as the expert's 2 mm), while the press
        // goes on to where the contact's force alone is at the peak.
        w.set_guide(Some(guide_along_x(-0.005, 0.008)));
        let peak = w.limits().peak_force_n;
        let mut both_at_peak = 0;
        for k in 0..3000u64 {
            // Pressing ever deeper, 10 µm per tick, to 30 mm.
            let y = -1e-5 * k as f64;
            let s = w.step(Ok(sample_at(k * MS, DVec3::new(0.0, y, 0.0))));
            assert!(
                s.force_n.length() <= peak + 1e-9,
                "tick {k}: {:?}",
                s.force_n
            );
            let guided = w.guide_output().unwrap();
            if guided.engaged
                && guided.force_n.length() > 1.0
                && s.flags.contains(ContactFlags::SATURATED)
            {
                both_at_peak += 1;
            }
        }
        assert!(both_at_peak > 100, "{both_at_peak} ticks with both");
    }
}
