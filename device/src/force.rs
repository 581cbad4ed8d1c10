//! From a contact to the force sent to the device: contact law, damping, then every safety limit.
//!
//! Long only because of its tests: the pipeline itself is under 600 lines.
//!
//! The pipeline of one tick, in order (each limit that acts sets its [`ContactFlags`] bit):
//! 1. the scene's contact model F(δ; geometry) ([`ForceModel`]: the paper's law, or the law with
//!    the corrections the scene turns on, fed the local curvature from the collision and the
//!    tool's inclination); past δ*, where its stiffness reaches the device's stable stiffness
//!    K_max, render F(δ*) + K_max(δ − δ*) instead (`STIFFNESS_CAPPED`); past the tip's height,
//!    which only a contact held after a push-through reaches ([`crate::tracking`],
//!    `PUSHED_THROUGH`), continue with slope K_max from the force there, so the force keeps
//!    rising to the device's peak instead of vanishing;
//! 2. damping along the normal, F − b(v·n) (paper Fig. 9b), clamped so it never pulls the tool
//!    into the object;
//! 3. a linear ramp from zero when contact begins with a force that would jump, or when the
//!    device comes back after a fault (`RAMPING`);
//! 4. the passivity controller (`PASSIVITY_DAMPING`, see [`crate::passivity`]);
//! 5. saturation at the device's peak force (`SATURATED`); then a guiding force, when an
//!    expert's path guides the trainee ([`crate::guide`], [`ForceRenderer::set_guidance`]), is
//!    added and the sum saturated at the peak again;
//! 6. the late-tick bound: a tick whose interval spans more than 1.5 nominal periods changes the
//!    force of the stages above by at most (K_max / r)|Δx| + 0.25 N from the last tick's force at
//!    this stage, and the lag it leaves settles on the next ticks (`LATE_TICK_LIMITED`);
//! 7. the continuous-force limit: a model of the motors' heating scales the force down, smoothly,
//!    when a long hard press would hold more than the device's continuous rating
//!    (`CONTINUOUS_FORCE_LIMITED`, see [`crate::thermal`]), and the warm-motors limit after it.
//!
//! An object with stiffer inclusions scales step 1 by the FEM's force ratio at the contact
//! ([`crate::inclusion`], [`ForceRenderer::set_inclusion`]) and adds the potential's sideways
//! part (below); an object without them never calls it, and the ratio stays exactly 1.
//!
//! Validity bounds of the model (`BEYOND_VALID_DEPTH`, `BEYOND_VALID_INCLINATION`) are reported,
//! not enforced: the force stays continuous, and the viewer shows that it is extrapolated. The
//! scene sets them to the measured limits of its model ([`softhaptic_proto::ValidityLimits`]).
//!
//! # The stiffness cap of a model that depends on the geometry
//! For the paper's law δ* is closed form and computed once. A corrected model finds it by
//! bisection (about a microsecond), once at construction when the force does not depend on the
//! geometry; when it does (curvature, a tilted cone), δ* is cached with the geometry it was
//! found for and found again only when the geometry has moved by more than
//! [`CAP_CURVATURE_TOLERANCE`] or [`CAP_INCLINATION_TOLERANCE_RAD`]. The rendered force stays
//! continuous in depth whatever δ* is (F(δ*) is evaluated with the current geometry), and a
//! slightly stale δ* only moves the point where the tangent takes over a little: the model's
//! slope there differs from K_max by about half the curvature tolerance (0.05 %), and when δ*
//! is found again the force changes to second order in its shift. Deterministic: the cache
//! evolves with the samples alone, so a replay finds δ* again at the same ticks.

use glam::DVec3;
use softhaptic_proto::{ContactFlags, Material, ToolShape};

use crate::device::DeviceLimits;
use crate::model::{ForceModel, LocalGeometry};
use crate::passivity::PassivityObserver;
use crate::shape;
use crate::thermal::ContinuousForceLimiter;

/// δ* is found again when the curvature has changed by more than this fraction of the tool's
/// curvature 1/R (the effective radius then moves by about as much, and δ* with it).
pub const CAP_CURVATURE_TOLERANCE: f64 = 1e-3;

/// δ* is found again when the cone's inclination has changed by more than this, radians.
pub const CAP_INCLINATION_TOLERANCE_RAD: f64 = 1e-3;

/// δ* is found again when an inclusion's force ratio has changed by more than this fraction:
/// the slope at δ* then differs from K_max by at most about as much, far inside the margin of
/// the passivity bound, and a tool sliding over an inclusion does not search δ* every tick.
pub const CAP_INCLUSION_TOLERANCE: f64 = 1e-2;

/// How the force is rendered and which safety layers are on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceConfig {
    /// Virtual damping b along the contact normal, N·s/m. Bounded by the device's
    /// `damping_n_s_per_m` at render time.
    pub damping_n_s_per_m: f64,
    /// Replace the law beyond δ* by its tangent of slope K_max (docs/physics.md, "Haptic
    /// stability"). Off only to study what happens without it.
    pub stiffness_cap: bool,
    /// Length of the force ramp after a fault or a jumping contact onset, nanoseconds.
    pub ramp_ns: u64,
    /// A contact that begins with a force above this is ramped in instead of stepped.
    pub ramp_threshold_n: f64,
    /// Run the passivity controller.
    pub passivity: bool,
    /// Depth beyond which the law is outside its validated range (flag only).
    pub valid_depth_m: f64,
    /// Angle between the tool axis and the contact normal beyond which the law is outside its
    /// validated range (flag only).
    pub valid_inclination_rad: f64,
    /// A tip farther than this many workspace radii from the device origin (the world origin)
    /// cannot be a real reading: it is treated as a device fault.
    pub workspace_tolerance: f64,
    /// Hold the motors' RMS force at the device's continuous rating ([`crate::thermal`]).
    pub continuous_force_limit: bool,
}

impl ForceConfig {
    /// The paper's validity limits for `tool`: within 7 % of the linear FEM up to 4.3 mm for
    /// both tips (§4.3), inclination up to 22° for the sphere (eq. 7) and 9° for the cone (§3.2);
    /// 1 N·s/m damping, 80 ms ramps, every safety layer on.
    pub fn for_tool(tool: &ToolShape) -> Self {
        Self {
            damping_n_s_per_m: 1.0,
            stiffness_cap: true,
            ramp_ns: 80_000_000,
            ramp_threshold_n: 0.5,
            passivity: true,
            valid_depth_m: softhaptic_proto::model::PAPER_VALID_DEPTH_M,
            valid_inclination_rad: softhaptic_proto::model::paper_valid_inclination_rad(tool),
            workspace_tolerance: 2.0,
            continuous_force_limit: true,
        }
    }

    /// [`ForceConfig::for_tool`] with the validity limits of the active model.
    pub fn with_limits(mut self, limits: &softhaptic_proto::ValidityLimits) -> Self {
        self.valid_depth_m = limits.valid_depth_m;
        self.valid_inclination_rad = limits.valid_inclination_rad;
        self
    }
}

/// The contact, in the world frame, as the renderer needs it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldContact {
    /// Indentation δ ≥ 0.
    pub depth_m: f64,
    /// Unit normal out of the object.
    pub normal: DVec3,
    /// True when the normal is a fallback (colliding normals cancelled).
    pub degenerate_normal: bool,
    /// Mean curvature of the object's surface at the contact, 1/m, positive where convex (zero
    /// when the collision does not measure it).
    pub curvature_1_per_m: f64,
}

/// The force of one tick and the flags of every limit that shaped it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderedForce {
    pub force_n: DVec3,
    pub flags: ContactFlags,
}

impl RenderedForce {
    const ZERO: RenderedForce = RenderedForce {
        force_n: DVec3::ZERO,
        flags: ContactFlags::empty(),
    };
}

/// The per-contact state of the force pipeline: contact model, stiffness cap, ramp, passivity
/// observer, previous tick.
#[derive(Debug, Clone)]
pub struct ForceRenderer {
    model: ForceModel,
    config: ForceConfig,
    limits: DeviceLimits,
    /// The geometry the model is evaluated at: the last contact's, with the parts the model
    /// does not use set to zero (so they can never move δ*). Flat before the first contact.
    geometry: LocalGeometry,
    /// δ* where the model's stiffness reaches K_max, for `cap_geometry`.
    cap_depth_m: f64,
    /// The geometry δ* was found for.
    cap_geometry: LocalGeometry,
    /// F(δ*) at `geometry`, the start of the linear extension.
    cap_force_n: f64,
    /// The tip's height ([`shape::max_depth_m`]): the collision clamps the depth to it, so only
    /// a contact the tracker holds after a push-through is rendered deeper.
    tip_height_m: f64,
    /// Slope of the force past the tip's height: the device's stable stiffness K_max (zero when
    /// the device does not give a usable one, which still holds the force there).
    beyond_tip_stiffness_n_per_m: f64,
    /// Effective damping: the configured one bounded by the device's.
    damping_n_s_per_m: f64,
    observer: PassivityObserver,
    /// The force commanded last tick (held by the device since) and where the tip was then: the
    /// observer books their exact work when the next sample arrives.
    previous_force_n: DVec3,
    previous_position_m: Option<DVec3>,
    ramp_start_ns: Option<u64>,
    /// Ramp factor applied last tick, to credit the elastic energy the ramp restores.
    previous_ramp_scale: f64,
    resume_pending: bool,
    was_in_contact: bool,
    previous_time_ns: Option<u64>,
    /// The motors' heating model; lives as long as the renderer (faults included) because the
    /// motors keep their heat through a fault. `None` when the configuration switches it off or
    /// the device's limits do not define a continuous rating below the peak.
    thermal: Option<ContinuousForceLimiter>,
    /// This tick's guiding force ([`ForceRenderer::set_guidance`]), zero without guidance.
    guidance_n: DVec3,
    /// The guiding force last tick's command included (zero after a fault).
    previous_guidance_n: DVec3,
    /// Device time of the last tick the heating model booked.
    thermal_time_ns: Option<u64>,
    /// Device time of the last tick whose device reported its motors warm, while the limit they
    /// set is in force or releasing ([`ForceRenderer::set_motors_warm`]).
    warm_last_ns: Option<u64>,
    /// A late tick limited the force, which may still lag the law's: the next ticks settle it
    /// under the same limit at the nominal stiffness.
    late_lag: bool,
    /// Last tick's force as the late-tick bound left it, before the heating and warm-motors
    /// limits scaled it: the bound compares this tick's force with it, like with like. Compared
    /// with the force those limits left, a press they hold down would read as a lag that never
    /// settles, and the bound would hold the force lower still for as long as they act.
    previous_bounded_n: DVec3,
    /// The inclusions' force ratio at the contact (1 without inclusions) and its gradient with
    /// respect to the contact point, world frame, 1/m ([`ForceRenderer::set_inclusion`]).
    inclusion_ratio: f64,
    inclusion_gradient_1_per_m: DVec3,
    /// The ratio's derivative with respect to the indentation, 1/m.
    inclusion_ratio_per_depth_1_per_m: f64,
    /// The ratio δ* was found for.
    cap_inclusion_ratio: f64,
}

/// The servo period the devices' stable stiffness K_max is rated at (1 kHz). A tick whose
/// interval spans more of these holds its force longer, and a sampled spring is stable only while
/// stiffness × interval stays below what the rating allows (Colgate & Schenkel 1997).
pub const NOMINAL_PERIOD_NS: u64 = 1_000_000;

/// A tick is late when its interval exceeds this many nominal periods: ordinary jitter is not.
const LATE_TICK_PERIODS: f64 = 1.5;

/// Largest change of force a late tick or a tick settling a lag after one may make beyond what
/// the limited stiffness allows over the displacement, N. It lets the force follow a slow change
/// that is not motion (damping, a ramp) and settle the lag a stall left within a few ticks.
const LATE_SETTLE_STEP_N: f64 = 0.25;

/// Time the warm-motors limit takes to rise back from the continuous force to the peak once the
/// device no longer reports its motors warm: a release, not a step, of up to the peak force.
pub const WARM_RELEASE_NS: u64 = 500_000_000;

impl ForceRenderer {
    /// A renderer of the paper's law for `tool` on `material`.
    pub fn new(
        tool: ToolShape,
        material: Material,
        config: ForceConfig,
        limits: DeviceLimits,
    ) -> Self {
        Self::with_model(ForceModel::paper(tool, material), config, limits)
    }

    /// A renderer of `model` (the scene's contact model).
    pub fn with_model(model: ForceModel, config: ForceConfig, limits: DeviceLimits) -> Self {
        let geometry = LocalGeometry::FLAT;
        let cap_depth_m = model.depth_at_stiffness_m(limits.max_stiffness_n_per_m, &geometry);
        let cap_force_n = model.force_n(cap_depth_m, &geometry);
        let damping = if config.damping_n_s_per_m.is_finite() {
            config
                .damping_n_s_per_m
                .clamp(0.0, limits.damping_n_s_per_m.max(0.0))
        } else {
            0.0
        };
        let k_max = limits.max_stiffness_n_per_m;
        Self {
            tip_height_m: shape::max_depth_m(model.tool()),
            beyond_tip_stiffness_n_per_m: if k_max.is_finite() {
                k_max.max(0.0)
            } else {
                0.0
            },
            model,
            config,
            limits,
            geometry,
            cap_depth_m,
            cap_geometry: geometry,
            cap_force_n,
            damping_n_s_per_m: damping,
            observer: PassivityObserver::new(),
            previous_force_n: DVec3::ZERO,
            previous_position_m: None,
            ramp_start_ns: None,
            previous_ramp_scale: 1.0,
            resume_pending: false,
            was_in_contact: false,
            previous_time_ns: None,
            thermal: if config.continuous_force_limit {
                ContinuousForceLimiter::for_device(&limits).ok()
            } else {
                None
            },
            thermal_time_ns: None,
            warm_last_ns: None,
            late_lag: false,
            previous_bounded_n: DVec3::ZERO,
            guidance_n: DVec3::ZERO,
            previous_guidance_n: DVec3::ZERO,
            inclusion_ratio: 1.0,
            inclusion_gradient_1_per_m: DVec3::ZERO,
            inclusion_ratio_per_depth_1_per_m: 0.0,
            cap_inclusion_ratio: 1.0,
        }
    }

    pub fn config(&self) -> &ForceConfig {
        &self.config
    }

    pub fn limits(&self) -> &DeviceLimits {
        &self.limits
    }

    /// The contact model the renderer evaluates.
    pub fn model(&self) -> &ForceModel {
        &self.model
    }

    pub fn tool(&self) -> &ToolShape {
        self.model.tool()
    }

    pub fn material(&self) -> &Material {
        self.model.material()
    }

    /// The local geometry the model is evaluated at (the last contact's; flat before any).
    pub fn geometry(&self) -> &LocalGeometry {
        &self.geometry
    }

    /// δ* of the stiffness cap for this model, device and the current geometry.
    pub fn cap_depth_m(&self) -> f64 {
        self.cap_depth_m
    }

    /// Sets the local geometry the model is evaluated at from a contact's curvature and the
    /// tool's inclination; finds δ* again when the geometry has moved past the tolerances
    /// (module docs). Non-finite inputs count as flat and perpendicular.
    pub fn set_geometry(&mut self, curvature_1_per_m: f64, inclination_rad: f64) {
        if !self.model.uses_geometry() {
            return;
        }
        let spec = self.model.spec();
        let finite = |x: f64| if x.is_finite() { x } else { 0.0 };
        let geometry = LocalGeometry {
            curvature_1_per_m: if spec.curvature {
                finite(curvature_1_per_m)
            } else {
                0.0
            },
            inclination_rad: if spec.inclination && matches!(self.tool(), ToolShape::Cone { .. }) {
                finite(inclination_rad)
            } else {
                0.0
            },
        };
        let curvature_moved = (geometry.curvature_1_per_m - self.cap_geometry.curvature_1_per_m)
            .abs()
            * self.tool().radius_m()
            > CAP_CURVATURE_TOLERANCE;
        let inclination_moved = (geometry.inclination_rad - self.cap_geometry.inclination_rad)
            .abs()
            > CAP_INCLINATION_TOLERANCE_RAD;
        let cap_moved = curvature_moved || inclination_moved;
        if cap_moved {
            self.cap_depth_m = self.model.depth_at_stiffness_m(
                self.limits.max_stiffness_n_per_m / self.cap_inclusion_ratio,
                &geometry,
            );
            self.cap_geometry = geometry;
        }
        if cap_moved || geometry != self.geometry {
            self.geometry = geometry;
            self.cap_force_n =
                self.inclusion_ratio * self.model.force_n(self.cap_depth_m, &geometry);
        }
    }

    /// Sets the inclusions' force ratio at this tick's contact, its gradient with respect to
    /// the contact point (world frame, 1/m) and its derivative with respect to the indentation
    /// (1/m); call before [`ForceRenderer::render`]. The normal force gains U_model ∂ratio/∂δ,
    /// the potential's own derivative along the normal. The model's
    /// force and its energy are scaled by the ratio, so the elastic potential is
    /// U = ratio(x) · U_model(δ); its sideways part −U_model ∇ratio is added to the force, which
    /// makes the field conservative in position (sliding from soft to stiff tissue at one depth
    /// and back creates no energy), and is what a trainee feels as a lump's edge pushing the
    /// tool off it. δ* is found again for K_max / ratio when the ratio has moved past
    /// [`CAP_INCLUSION_TOLERANCE`]. A non-finite or non-positive ratio counts as 1.
    pub fn set_inclusion(
        &mut self,
        ratio: f64,
        gradient_1_per_m: DVec3,
        ratio_per_depth_1_per_m: f64,
    ) {
        self.inclusion_ratio_per_depth_1_per_m = if ratio_per_depth_1_per_m.is_finite() {
            ratio_per_depth_1_per_m
        } else {
            0.0
        };
        let ratio = if ratio.is_finite() && ratio > 0.0 {
            ratio
        } else {
            1.0
        };
        self.inclusion_gradient_1_per_m = if gradient_1_per_m.is_finite() {
            gradient_1_per_m
        } else {
            DVec3::ZERO
        };
        if ratio == self.inclusion_ratio {
            return;
        }
        self.inclusion_ratio = ratio;
        if (ratio - self.cap_inclusion_ratio).abs()
            > CAP_INCLUSION_TOLERANCE * self.cap_inclusion_ratio
        {
            self.cap_inclusion_ratio = ratio;
            self.cap_depth_m = self
                .model
                .depth_at_stiffness_m(self.limits.max_stiffness_n_per_m / ratio, &self.geometry);
            self.cap_geometry = self.geometry;
        }
        self.cap_force_n = ratio * self.model.force_n(self.cap_depth_m, &self.geometry);
    }

    /// Energy the environment has absorbed in the current contact (passivity observer).
    pub fn passivity_energy_j(&self) -> f64 {
        self.observer.energy_j()
    }

    /// The elastic force magnitude at `depth_m` and the current geometry, with the stiffness
    /// cap when it is on; the flag says whether the cap acted.
    ///
    /// Past the tip's height the force continues from its value there with slope K_max. Only a
    /// contact held after a push-through gets there ([`crate::tracking`]); the tool is then
    /// deeper than any indentation the law describes, and the object's one job left is to
    /// push it back out the way it came, as hard as the device can stably push: with the
    /// stiffness cap on and δ* below the tip's height this is the cap's own line, continued.
    /// Extrapolating the law instead was rejected: for a small tool on soft tissue it grows so
    /// slowly (Hertz for a 0.5 mm sphere on 50 kPa: 1.7 N at 10 mm, twenty times its height)
    /// that a strong hand would sink the tool centimetres into the organ before the device
    /// pushed back in earnest.
    pub fn elastic_force_n(&self, depth_m: f64) -> (f64, bool) {
        let beyond_m = depth_m - self.tip_height_m;
        if beyond_m > 0.0 {
            let (at_height_n, capped) = self.law_force_n(self.tip_height_m);
            return (
                at_height_n + self.beyond_tip_stiffness_n_per_m * beyond_m,
                capped,
            );
        }
        self.law_force_n(depth_m)
    }

    /// The model, or its capped extension past δ*, at `depth_m`.
    fn law_force_n(&self, depth_m: f64) -> (f64, bool) {
        if self.config.stiffness_cap && depth_m > self.cap_depth_m {
            let extension = (depth_m - self.cap_depth_m) * self.limits.max_stiffness_n_per_m;
            (self.cap_force_n + extension, true)
        } else {
            (
                self.inclusion_ratio * self.model.force_n(depth_m, &self.geometry),
                false,
            )
        }
    }

    /// Elastic energy stored in the rendered contact at `depth_m`: ∫ F dδ of
    /// [`ForceRenderer::elastic_force_n`] (the model's [`ForceModel::energy_j`], plus the
    /// trapezoids of the capped extension and of the line past the tip's height).
    pub fn elastic_energy_j(&self, depth_m: f64) -> f64 {
        let beyond_m = depth_m - self.tip_height_m;
        if beyond_m > 0.0 {
            return self.law_energy_j(self.tip_height_m)
                + self.law_force_n(self.tip_height_m).0 * beyond_m
                + 0.5 * self.beyond_tip_stiffness_n_per_m * beyond_m * beyond_m;
        }
        self.law_energy_j(depth_m)
    }

    /// ∫ F dδ of [`ForceRenderer::law_force_n`].
    fn law_energy_j(&self, depth_m: f64) -> f64 {
        if self.config.stiffness_cap && depth_m > self.cap_depth_m {
            let extra = depth_m - self.cap_depth_m;
            self.inclusion_ratio * self.model.energy_j(self.cap_depth_m, &self.geometry)
                + self.cap_force_n * extra
                + 0.5 * self.limits.max_stiffness_n_per_m * extra * extra
        } else {
            self.inclusion_ratio * self.model.energy_j(depth_m, &self.geometry)
        }
    }

    /// The device failed or reported an impossible sample: zero force, and a ramp when it comes
    /// back.
    pub fn fault(&mut self) -> RenderedForce {
        self.resume_pending = true;
        self.ramp_start_ns = None;
        self.was_in_contact = false;
        self.previous_time_ns = None;
        self.previous_force_n = DVec3::ZERO;
        self.previous_guidance_n = DVec3::ZERO;
        self.previous_position_m = None;
        self.late_lag = false;
        self.previous_bounded_n = DVec3::ZERO;
        self.observer.reset();
        RenderedForce {
            force_n: DVec3::ZERO,
            flags: ContactFlags::DEVICE_FAULT,
        }
    }

    /// The guiding force of this tick ([`crate::guide`]), world frame: added to the contact's
    /// before the late-tick, heating and warm-motors limits, and the sum saturated at the
    /// device's peak. A non-finite force is taken as zero. Call it before
    /// [`ForceRenderer::render`]; it holds until the next call.
    pub fn set_guidance(&mut self, force_n: DVec3) {
        self.guidance_n = if force_n.is_finite() {
            force_n
        } else {
            DVec3::ZERO
        };
    }

    /// Renders one tick. `contact` is `None` out of contact; `position_m` and `velocity_m_s` are
    /// the tip's; `tool_axis` is the tool's +y axis (tip toward shaft), all in the world frame;
    /// `time_ns` is the sample's device time.
    pub fn render(
        &mut self,
        contact: Option<&WorldContact>,
        position_m: DVec3,
        velocity_m_s: DVec3,
        tool_axis: DVec3,
        time_ns: u64,
    ) -> RenderedForce {
        // Book the work of last tick's force over the displacement the device really made.
        let displacement_m = self
            .previous_position_m
            .map(|previous| position_m - previous);
        if let Some(d) = displacement_m {
            // The contact's share of last tick's force: the guide books its own share in its
            // own observer (crate::guide), so its pull never makes the contact's controller
            // damp, and the two observers together book the whole force.
            self.observer
                .observe(self.previous_force_n - self.previous_guidance_n, d);
        }
        self.previous_position_m = Some(position_m);
        let interval_ns = match self.previous_time_ns {
            Some(previous) if time_ns > previous => time_ns - previous,
            _ => 0,
        };
        let mut rendered = self.render_force(contact, velocity_m_s, tool_axis, time_ns);
        if self.guidance_n != DVec3::ZERO && !rendered.flags.contains(ContactFlags::DEVICE_FAULT) {
            // The guide has its own cap below the peak; the sum with the contact's is held to
            // the peak here, before every later limit, which then bounds the whole.
            let mut total_n = rendered.force_n + self.guidance_n;
            let size = total_n.length();
            let peak = self.limits.peak_force_n;
            if size > peak {
                total_n *= peak / size;
                rendered.flags |= ContactFlags::SATURATED;
            }
            rendered.force_n = total_n;
        }
        if let Some(d) = displacement_m {
            self.limit_late_step(&mut rendered, d, interval_ns);
        }
        self.previous_bounded_n = rendered.force_n;
        if let Some(thermal) = self.thermal.as_mut() {
            // Last in the pipeline, after the saturation: it books what the device delivers. The
            // force is held until the next tick, estimated as long as the last interval; after a
            // fault that interval spans it, and the ramp's first, near-zero force is booked over
            // it, which is how the motors cooled.
            let period_s = match self.thermal_time_ns {
                Some(previous) if time_ns > previous => (time_ns - previous) as f64 * 1e-9,
                _ => 0.0,
            };
            self.thermal_time_ns = Some(time_ns);
            let (limited_n, acted) = thermal.apply(rendered.force_n, period_s);
            rendered.force_n = limited_n;
            if acted {
                rendered.flags |= ContactFlags::CONTINUOUS_FORCE_LIMITED;
            }
        }
        if let Some(cap_n) = self.warm_cap_n(time_ns) {
            let size = rendered.force_n.length();
            if size > cap_n {
                rendered.force_n *= cap_n / size;
                rendered.flags |= ContactFlags::CONTINUOUS_FORCE_LIMITED;
            }
        }
        self.previous_force_n = rendered.force_n;
        self.previous_guidance_n = if rendered.flags.contains(ContactFlags::DEVICE_FAULT) {
            DVec3::ZERO
        } else {
            self.guidance_n
        };
        rendered
    }

    /// Bounds what a late tick changes, as a virtual coupling would: over an interval of r
    /// nominal periods the force moves by at most K_max / r times the tip's displacement (plus
    /// [`LATE_SETTLE_STEP_N`]), so that stiffness × interval stays at its rated value. Without
    /// it a stiff contact held for 10 ms per tick by a loose grip chatters between zero and the
    /// peak. The lag this leaves is settled on the following ticks under the same bound at the
    /// nominal stiffness, where the law itself never moves faster. A contact that begins, ends or
    /// faults is not limited: its own ramp and zero apply.
    fn limit_late_step(
        &mut self,
        rendered: &mut RenderedForce,
        displacement_m: DVec3,
        interval_ns: u64,
    ) {
        let lateness = interval_ns as f64 / NOMINAL_PERIOD_NS as f64;
        let late = lateness > LATE_TICK_PERIODS;
        let both_in_contact =
            rendered.force_n != DVec3::ZERO && self.previous_bounded_n != DVec3::ZERO;
        if !both_in_contact
            || rendered.flags.contains(ContactFlags::DEVICE_FAULT)
            || !(late || self.late_lag)
        {
            self.late_lag = false;
            return;
        }
        let stiffness_n_per_m = self.beyond_tip_stiffness_n_per_m / lateness.max(1.0);
        let allowed_n = stiffness_n_per_m * displacement_m.length() + LATE_SETTLE_STEP_N;
        let step_n = rendered.force_n - self.previous_bounded_n;
        let size_n = step_n.length();
        if size_n > allowed_n && size_n.is_finite() {
            rendered.force_n = self.previous_bounded_n + step_n * (allowed_n / size_n);
            rendered.flags |= ContactFlags::LATE_TICK_LIMITED;
            self.late_lag = true;
        } else {
            self.late_lag = late;
        }
    }

    /// The device reports (on this tick) whether its motors are warm. The driver keeps rendering
    /// while they are, and asks for less force: the force is held to the device's continuous
    /// rating from that tick on, and released back to the peak over [`WARM_RELEASE_NS`] once the
    /// reports stop. Call it before [`ForceRenderer::render`].
    pub fn set_motors_warm(&mut self, warm: bool, time_ns: u64) {
        if warm {
            self.warm_last_ns = Some(time_ns);
        }
    }

    /// The warm-motors limit at `time_ns`, `None` when none applies.
    fn warm_cap_n(&mut self, time_ns: u64) -> Option<f64> {
        let last = self.warm_last_ns?;
        let continuous = self.limits.continuous_force_n.min(self.limits.peak_force_n);
        let since = time_ns.saturating_sub(last);
        if since >= WARM_RELEASE_NS {
            self.warm_last_ns = None;
            return None;
        }
        let released = since as f64 / WARM_RELEASE_NS as f64;
        Some(continuous + (self.limits.peak_force_n - continuous).max(0.0) * released)
    }

    fn render_force(
        &mut self,
        contact: Option<&WorldContact>,
        velocity_m_s: DVec3,
        tool_axis: DVec3,
        time_ns: u64,
    ) -> RenderedForce {
        let period_s = match self.previous_time_ns {
            Some(prev) if time_ns > prev => (time_ns - prev) as f64 * 1e-9,
            _ => 0.0,
        };
        self.previous_time_ns = Some(time_ns);
        if self.resume_pending {
            self.resume_pending = false;
            self.ramp_start_ns = Some(time_ns);
            self.previous_ramp_scale = 0.0;
        }

        let Some(contact) = contact.filter(|c| c.depth_m.is_finite() && c.normal.is_finite())
        else {
            if self.was_in_contact {
                self.observer.end_contact();
            }
            self.was_in_contact = false;
            // No elastic energy is stored out of contact: a ramp still running restores none.
            self.previous_ramp_scale = self.ramp_scale(time_ns);
            return RenderedForce::ZERO;
        };

        let mut flags = ContactFlags::empty();
        if contact.degenerate_normal {
            flags |= ContactFlags::DEGENERATE_NORMAL;
        }
        // A normal that is not unit length would scale the force; renormalise, or fall back to
        // the tool axis, which is the direction the tool presses along.
        let normal = match contact.normal.try_normalize() {
            Some(n) => n,
            None => {
                flags |= ContactFlags::DEGENERATE_NORMAL;
                tool_axis.try_normalize().unwrap_or(DVec3::Y)
            }
        };
        let depth_m = contact.depth_m.max(0.0);
        if depth_m > self.config.valid_depth_m {
            flags |= ContactFlags::BEYOND_VALID_DEPTH;
        }
        let cos_incl = tool_axis.try_normalize().map_or(1.0, |a| a.dot(normal));
        let inclination_rad = cos_incl.clamp(-1.0, 1.0).acos();
        if inclination_rad > self.config.valid_inclination_rad {
            flags |= ContactFlags::BEYOND_VALID_INCLINATION;
        }
        self.set_geometry(contact.curvature_1_per_m, inclination_rad);

        let (mut elastic_n, capped) = self.elastic_force_n(depth_m);
        if self.inclusion_ratio_per_depth_1_per_m != 0.0 {
            elastic_n += self.inclusion_ratio_per_depth_1_per_m * self.elastic_energy_j(depth_m)
                / self.inclusion_ratio;
        }
        if capped {
            flags |= ContactFlags::STIFFNESS_CAPPED;
        }
        let normal_speed_m_s = velocity_m_s.dot(normal);
        let mut magnitude_n = (elastic_n - self.damping_n_s_per_m * normal_speed_m_s).max(0.0);
        // Saturate the normal force here already: an uncapped law at an absurd depth can reach
        // +∞, and ∞ · 0 would turn into NaN below.
        let peak = self.limits.peak_force_n;
        if magnitude_n > peak {
            magnitude_n = peak;
            flags |= ContactFlags::SATURATED;
        }

        // Contact onset: a force that would step from zero is ramped in.
        if !self.was_in_contact
            && self.ramp_start_ns.is_none()
            && magnitude_n > self.config.ramp_threshold_n
        {
            self.ramp_start_ns = Some(time_ns);
            self.previous_ramp_scale = 0.0;
        }
        self.was_in_contact = true;
        let ramp_scale = self.ramp_scale(time_ns);
        if ramp_scale < 1.0 {
            magnitude_n *= ramp_scale;
            flags |= ContactFlags::RAMPING;
        }
        // A ramp raises the force at a fixed depth: it restores the contact's elastic energy
        // without the user doing that work. That energy is credited, so the controller does not
        // fight the ramp, and only energy beyond it counts as created.
        if ramp_scale > self.previous_ramp_scale {
            self.observer
                .credit((ramp_scale - self.previous_ramp_scale) * self.elastic_energy_j(depth_m));
        }
        self.previous_ramp_scale = ramp_scale;
        let mut force_n = normal * magnitude_n;
        if self.inclusion_gradient_1_per_m != DVec3::ZERO {
            // The potential's sideways part (ForceRenderer::set_inclusion), ramped with the rest.
            let model_energy_j = self.elastic_energy_j(depth_m) / self.inclusion_ratio;
            let sideways = -model_energy_j * ramp_scale * self.inclusion_gradient_1_per_m;
            force_n += sideways - sideways.dot(normal) * normal;
        }

        if self.config.passivity {
            let c = self.observer.correct(
                force_n,
                velocity_m_s,
                period_s,
                self.limits.damping_n_s_per_m,
            );
            if c.added_damping_n_s_per_m > 0.0 {
                flags |= ContactFlags::PASSIVITY_DAMPING;
                force_n = c.force_n;
                // The controller damps every direction of motion but must not pull either.
                let along = force_n.dot(normal);
                if along < 0.0 {
                    force_n -= along * normal;
                }
            }
        }

        // The controller's damping may add a tangential part: saturate the whole vector.
        let size = force_n.length();
        if size > peak {
            force_n *= peak / size;
            flags |= ContactFlags::SATURATED;
        }
        if !force_n.is_finite() {
            // Unreachable with finite inputs (checked above); kept so that no arithmetic corner
            // can ever command a non-finite force.
            force_n = DVec3::ZERO;
            flags |= ContactFlags::DEVICE_FAULT;
        }
        RenderedForce { force_n, flags }
    }

    /// Ramp factor in [0, 1] at `time_ns`; ends the ramp once it reaches 1.
    fn ramp_scale(&mut self, time_ns: u64) -> f64 {
        let Some(start) = self.ramp_start_ns else {
            return 1.0;
        };
        let elapsed = time_ns.saturating_sub(start);
        if self.config.ramp_ns == 0 || elapsed >= self.config.ramp_ns {
            self.ramp_start_ns = None;
            1.0
        } else {
            elapsed as f64 / self.config.ramp_ns as f64
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use crate::law;
    use proptest::prelude::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn every_preset_gives_a_stiffness_cap_the_renderer_can_use() {
        use softhaptic_proto::Material;
        let tool = ToolShape::sphere(0.01).unwrap();
        for l in [
            DeviceLimits::PHANTOM_DESKTOP,
            DeviceLimits::TOUCH,
            DeviceLimits::OMNI,
        ] {
            // A stable stiffness that puts the cap's depth δ* inside the tool's reach on soft
            // tissue, and a force there below the peak.
            let r = ForceRenderer::new(tool, Material::PAPER_SOFT, ForceConfig::for_tool(&tool), l);
            let cap = r.cap_depth_m();
            assert!(
                cap.is_finite() && cap > 0.0 && cap < 0.02,
                "{}: δ* = {cap}",
                l.name
            );
            let (force_at_cap, _) = r.elastic_force_n(cap);
            assert!(
                force_at_cap < l.peak_force_n,
                "{}: {force_at_cap} N",
                l.name
            );
        }
    }

    fn sphere() -> ToolShape {
        ToolShape::sphere(0.01).unwrap()
    }

    fn renderer(material: Material, config: impl FnOnce(&mut ForceConfig)) -> ForceRenderer {
        let mut c = ForceConfig::for_tool(&sphere());
        config(&mut c);
        ForceRenderer::new(sphere(), material, c, DeviceLimits::PHANTOM_DESKTOP)
    }

    fn contact(depth_m: f64) -> WorldContact {
        WorldContact {
            depth_m,
            normal: DVec3::Y,
            degenerate_normal: false,
            curvature_1_per_m: 0.0,
        }
    }

    /// Tip position of a contact at `depth_m` under a horizontal surface at y = 0.
    fn at(depth_m: f64) -> DVec3 {
        DVec3::new(0.0, -depth_m, 0.0)
    }

    /// Brings a renderer into a steady contact at `depth_m` (past any onset ramp).
    fn settle(r: &mut ForceRenderer, depth_m: f64) -> u64 {
        let mut t = 0;
        for _ in 0..200 {
            r.render(
                Some(&contact(depth_m)),
                at(depth_m),
                DVec3::ZERO,
                DVec3::Y,
                t,
            );
            t += MS;
        }
        t
    }

    #[test]
    fn soft_contact_renders_the_law_without_flags() {
        let mut r = renderer(Material::PAPER_SOFT, |_| {});
        let t = settle(&mut r, 0.002);
        let f = r.render(Some(&contact(0.002)), at(0.002), DVec3::ZERO, DVec3::Y, t);
        let expected = law::contact_force_n(&sphere(), &Material::PAPER_SOFT, 0.002);
        assert!((f.force_n.y - expected).abs() < 1e-12);
        assert_eq!(f.force_n.x, 0.0);
        assert!(f.flags.is_empty(), "{:?}", f.flags);
    }

    #[test]
    fn damping_opposes_normal_velocity_and_never_pulls() {
        let mut r = renderer(Material::PAPER_SOFT, |c| c.passivity = false);
        let t = settle(&mut r, 0.002);
        let still = r
            .render(Some(&contact(0.002)), at(0.002), DVec3::ZERO, DVec3::Y, t)
            .force_n
            .y;
        let pressing = r
            .render(
                Some(&contact(0.002)),
                at(0.002),
                DVec3::NEG_Y * 0.1,
                DVec3::Y,
                t + MS,
            )
            .force_n
            .y;
        assert!(
            (pressing - still - 0.1).abs() < 1e-9,
            "b = 1 N·s/m at 0.1 m/s"
        );
        let leaving_fast = r.render(
            Some(&contact(0.002)),
            at(0.002),
            DVec3::Y * 10.0,
            DVec3::Y,
            t + 2 * MS,
        );
        assert_eq!(leaving_fast.force_n, DVec3::ZERO);
    }

    #[test]
    fn damping_is_bounded_by_the_device() {
        let r = renderer(Material::PAPER_SOFT, |c| c.damping_n_s_per_m = 50.0);
        assert_eq!(r.damping_n_s_per_m, 5.0);
        let r = renderer(Material::PAPER_SOFT, |c| c.damping_n_s_per_m = f64::NAN);
        assert_eq!(r.damping_n_s_per_m, 0.0);
    }

    #[test]
    fn stiffness_cap_extends_linearly_beyond_cap_depth() {
        let mut r = renderer(Material::PAPER_STIFF, |_| {});
        let d_star = r.cap_depth_m();
        assert!(d_star > 0.0 && d_star < 1e-4, "δ* = {d_star}");
        let (below, capped_below) = r.elastic_force_n(d_star * 0.5);
        assert!(!capped_below && below > 0.0);
        let (f1, c1) = r.elastic_force_n(d_star + 1e-3);
        let (f2, _) = r.elastic_force_n(d_star + 2e-3);
        assert!(c1);
        assert!((f2 - f1 - 1.0).abs() < 1e-9, "slope K_max = 1000 N/m");
        // Continuous at δ*.
        let (at_cap, _) = r.elastic_force_n(d_star);
        let (just_past, _) = r.elastic_force_n(d_star * (1.0 + 1e-9));
        assert!((just_past - at_cap).abs() < 1e-9);
        let t = settle(&mut r, 0.003);
        let f = r.render(Some(&contact(0.003)), at(0.003), DVec3::ZERO, DVec3::Y, t);
        assert!(f.flags.contains(ContactFlags::STIFFNESS_CAPPED));
        assert!(f.force_n.y < 3.1 && f.force_n.y > 2.9, "{}", f.force_n.y);
    }

    #[test]
    fn without_cap_the_law_runs_unbounded_until_saturation() {
        // The continuous-force limit would take over after 0.13 s at the peak: this is about
        // the saturation alone.
        let mut r = renderer(Material::PAPER_STIFF, |c| {
            c.stiffness_cap = false;
            c.continuous_force_limit = false;
        });
        let t = settle(&mut r, 0.003);
        let f = r.render(Some(&contact(0.003)), at(0.003), DVec3::ZERO, DVec3::Y, t);
        assert!(!f.flags.contains(ContactFlags::STIFFNESS_CAPPED));
        assert!(f.flags.contains(ContactFlags::SATURATED));
        assert!((f.force_n.length() - 7.9).abs() < 1e-12);
    }

    #[test]
    fn absurd_depth_without_cap_saturates_instead_of_failing() {
        let mut r = renderer(Material::new(1e9, 0.4999).unwrap(), |c| {
            c.stiffness_cap = false;
            c.continuous_force_limit = false;
        });
        let t = settle(&mut r, 1e200);
        let f = r.render(Some(&contact(1e200)), at(1e200), DVec3::ZERO, DVec3::Y, t);
        assert_eq!(f.force_n, DVec3::Y * 7.9);
        assert!(f.flags.contains(ContactFlags::SATURATED));
        assert!(!f.flags.contains(ContactFlags::DEVICE_FAULT));
    }

    #[test]
    fn a_long_hard_press_is_held_to_the_continuous_rating_and_released_after() {
        // 10 mm sphere 5.5 mm into 50 kPa: about 3 N, held for 8 s on a PHANTOM Desktop
        // (1.75 N continuous). A short press passes untouched; the long one is brought down
        // smoothly, flagged, and its RMS settles at the rating; after release the limiter lets
        // go again.
        let depth = 0.0055;
        let mut r = renderer(Material::PAPER_SOFT, |c| c.passivity = false);
        let law_n = law::contact_force_n(&sphere(), &Material::PAPER_SOFT, depth);
        assert!(law_n > 2.5, "{law_n}");
        let mut t = 0;
        let mut previous = 0.0_f64;
        let mut largest_step = 0.0_f64;
        let mut first_limited_ms = None;
        let mut last = RenderedForce::ZERO;
        for ms in 0..8000 {
            last = r.render(Some(&contact(depth)), at(depth), DVec3::ZERO, DVec3::Y, t);
            let f = last.force_n.y;
            if ms > 100 {
                largest_step = largest_step.max((f - previous).abs());
            }
            previous = f;
            if first_limited_ms.is_none()
                && last.flags.contains(ContactFlags::CONTINUOUS_FORCE_LIMITED)
            {
                first_limited_ms = Some(ms);
            }
            t += MS;
        }
        let first = first_limited_ms.expect("an 8 s press at 3 N is limited");
        assert!(
            first > 300,
            "a press shorter than 0.3 s passes untouched: {first} ms"
        );
        assert!(last.flags.contains(ContactFlags::CONTINUOUS_FORCE_LIMITED));
        assert!(
            last.force_n.y <= 1.75 + 1e-3 && last.force_n.y > 1.6,
            "held at the rating: {}",
            last.force_n.y
        );
        assert!(
            largest_step < 0.02,
            "no step of the limiter's own: {largest_step} N"
        );
        // Released for 20 s (the motors cool), then pressed again: full force at once.
        for _ in 0..20_000 {
            r.render(None, at(-0.01), DVec3::ZERO, DVec3::Y, t);
            t += MS;
        }
        let again = r.render(Some(&contact(depth)), at(depth), DVec3::ZERO, DVec3::Y, t);
        assert!(!again.flags.contains(ContactFlags::CONTINUOUS_FORCE_LIMITED));
    }

    #[test]
    fn validity_limits_are_flagged() {
        let mut r = renderer(Material::PAPER_SOFT, |_| {});
        let t = settle(&mut r, 0.005);
        let deep = r.render(Some(&contact(0.005)), at(0.005), DVec3::ZERO, DVec3::Y, t);
        assert!(deep.flags.contains(ContactFlags::BEYOND_VALID_DEPTH));
        let tilted_axis = DVec3::new(30f64.to_radians().sin(), 30f64.to_radians().cos(), 0.0);
        let tilted = r.render(
            Some(&contact(0.001)),
            at(0.001),
            DVec3::ZERO,
            tilted_axis,
            t + MS,
        );
        assert!(
            tilted
                .flags
                .contains(ContactFlags::BEYOND_VALID_INCLINATION)
        );
        assert!(!tilted.flags.contains(ContactFlags::BEYOND_VALID_DEPTH));
        let slight = DVec3::new(10f64.to_radians().sin(), 10f64.to_radians().cos(), 0.0);
        let ok = r.render(
            Some(&contact(0.001)),
            at(0.001),
            DVec3::ZERO,
            slight,
            t + 2 * MS,
        );
        assert!(!ok.flags.contains(ContactFlags::BEYOND_VALID_INCLINATION));
    }

    #[test]
    fn degenerate_normal_is_flagged_and_force_stays_finite() {
        let mut r = renderer(Material::PAPER_SOFT, |_| {});
        let t = settle(&mut r, 0.001);
        let fallback = WorldContact {
            depth_m: 0.001,
            normal: DVec3::Y,
            degenerate_normal: true,
            curvature_1_per_m: 0.0,
        };
        let f = r.render(Some(&fallback), at(0.001), DVec3::ZERO, DVec3::Y, t);
        assert!(f.flags.contains(ContactFlags::DEGENERATE_NORMAL));
        let zero_normal = WorldContact {
            depth_m: 0.001,
            normal: DVec3::ZERO,
            degenerate_normal: false,
            curvature_1_per_m: 0.0,
        };
        let f = r.render(Some(&zero_normal), at(0.001), DVec3::ZERO, DVec3::Y, t + MS);
        assert!(f.flags.contains(ContactFlags::DEGENERATE_NORMAL));
        assert!(f.force_n.is_finite() && f.force_n.y > 0.0);
    }

    #[test]
    fn a_late_tick_changes_the_force_by_at_most_the_stiffness_its_interval_allows() {
        let mut r = renderer(Material::PAPER_STIFF, |c| c.passivity = false);
        let t = settle(&mut r, 0.001);
        let before = r.render(Some(&contact(0.001)), at(0.001), DVec3::ZERO, DVec3::Y, t);
        // 10 ms late, 2 mm deeper: the law's force rises by several newtons.
        let law = {
            let mut fresh = renderer(Material::PAPER_STIFF, |c| c.passivity = false);
            let t = settle(&mut fresh, 0.003);
            fresh.render(Some(&contact(0.003)), at(0.003), DVec3::ZERO, DVec3::Y, t)
        };
        assert!(law.force_n.y - before.force_n.y > 2.0, "{law:?}");
        let late_ns = t + 10 * MS;
        let f = r.render(
            Some(&contact(0.003)),
            at(0.003),
            DVec3::ZERO,
            DVec3::Y,
            late_ns,
        );
        let k_max = DeviceLimits::PHANTOM_DESKTOP.max_stiffness_n_per_m;
        let allowed = k_max / 10.0 * 0.002 + LATE_SETTLE_STEP_N;
        assert!(f.flags.contains(ContactFlags::LATE_TICK_LIMITED));
        assert!(
            (f.force_n.y - before.force_n.y - allowed).abs() < 1e-9,
            "{} N after {} N",
            f.force_n.y,
            before.force_n.y
        );
        // On time again, held still: the lag settles by the settling step per tick, and the
        // force reaches the law's within a few ticks.
        let mut previous = f.force_n.y;
        let mut settled_after = None;
        for k in 1..=40u64 {
            let g = r.render(
                Some(&contact(0.003)),
                at(0.003),
                DVec3::ZERO,
                DVec3::Y,
                late_ns + k * MS,
            );
            assert!(g.force_n.y - previous <= LATE_SETTLE_STEP_N + 1e-9);
            previous = g.force_n.y;
            if !g.flags.contains(ContactFlags::LATE_TICK_LIMITED) {
                settled_after.get_or_insert(k);
            }
        }
        let settled_after = settled_after.unwrap();
        assert!((previous - law.force_n.y).abs() < 1e-9);
        assert!(settled_after <= 20, "{settled_after} ticks");
        // An on-time tick of ordinary motion is never limited.
        let g = r.render(
            Some(&contact(0.0031)),
            at(0.0031),
            DVec3::ZERO,
            DVec3::Y,
            late_ns + 41 * MS,
        );
        assert!(!g.flags.contains(ContactFlags::LATE_TICK_LIMITED));
    }

    #[test]
    fn the_lag_a_late_tick_leaves_settles_while_the_heating_limit_holds_the_press_down() {
        let mut r = renderer(Material::PAPER_STIFF, |c| c.passivity = false);
        let depth = 0.004;
        // A hard press held for 3 s: the heating model holds it down to the continuous rating.
        let mut t = 0;
        let mut held = RenderedForce::ZERO;
        for _ in 0..3_000 {
            held = r.render(Some(&contact(depth)), at(depth), DVec3::ZERO, DVec3::Y, t);
            t += MS;
        }
        assert!(
            held.flags.contains(ContactFlags::CONTINUOUS_FORCE_LIMITED),
            "{held:?}"
        );
        // 10 ms late and 2 mm deeper, then on time and still.
        let deeper = depth + 0.002;
        t += 9 * MS;
        let f = r.render(Some(&contact(deeper)), at(deeper), DVec3::ZERO, DVec3::Y, t);
        assert!(f.flags.contains(ContactFlags::LATE_TICK_LIMITED), "{f:?}");
        let mut settled_after = None;
        for k in 1..=100u64 {
            let g = r.render(
                Some(&contact(deeper)),
                at(deeper),
                DVec3::ZERO,
                DVec3::Y,
                t + k * MS,
            );
            assert!(g.flags.contains(ContactFlags::CONTINUOUS_FORCE_LIMITED));
            let limited = g.flags.contains(ContactFlags::LATE_TICK_LIMITED);
            match settled_after {
                None if !limited => settled_after = Some(k),
                Some(_) => assert!(!limited, "limited again at tick {k}"),
                None => {}
            }
        }
        // The lag is the law's force less the bounded one (before the heating limit scales
        // either): settled at the settling step per tick, not held by the heating limit's gain.
        let settled_after = settled_after.expect("the lag never settles");
        assert!(settled_after <= 40, "{settled_after} ticks");
    }

    #[test]
    fn jumping_onset_is_ramped_not_stepped() {
        let mut r = renderer(Material::PAPER_STIFF, |c| c.passivity = false);
        r.render(None, DVec3::Y, DVec3::ZERO, DVec3::Y, 0);
        // 1.5 MPa at 3 mm capped: ≈ 3 N would appear in one tick.
        let mut previous = 0.0;
        let mut max_step: f64 = 0.0;
        let mut saw_ramp = false;
        for k in 1..=120u64 {
            let f = r.render(
                Some(&contact(0.003)),
                at(0.003),
                DVec3::ZERO,
                DVec3::Y,
                k * MS,
            );
            saw_ramp |= f.flags.contains(ContactFlags::RAMPING);
            max_step = max_step.max(f.force_n.y - previous);
            previous = f.force_n.y;
        }
        assert!(saw_ramp);
        assert!(max_step < 0.05, "largest step {max_step} N");
        assert!(previous > 2.9, "ramp reaches the full force: {previous}");
    }

    #[test]
    fn gentle_onset_is_not_ramped() {
        let mut r = renderer(Material::PAPER_SOFT, |_| {});
        r.render(None, DVec3::Y, DVec3::ZERO, DVec3::Y, 0);
        let f = r.render(Some(&contact(1e-4)), at(1e-4), DVec3::ZERO, DVec3::Y, MS);
        assert!(!f.flags.contains(ContactFlags::RAMPING));
        assert!(f.force_n.y > 0.0);
    }

    #[test]
    fn fault_gives_zero_force_then_a_ramp() {
        let mut r = renderer(Material::PAPER_SOFT, |c| c.passivity = false);
        let t = settle(&mut r, 0.003);
        let steady = r
            .render(Some(&contact(0.003)), at(0.003), DVec3::ZERO, DVec3::Y, t)
            .force_n
            .y;
        let f = r.fault();
        assert_eq!(f.force_n, DVec3::ZERO);
        assert_eq!(f.flags, ContactFlags::DEVICE_FAULT);
        let mut previous = 0.0;
        for k in 1..=100u64 {
            let f = r.render(
                Some(&contact(0.003)),
                at(0.003),
                DVec3::ZERO,
                DVec3::Y,
                t + k * MS,
            );
            assert!(
                f.force_n.y - previous <= steady / 80.0 + 1e-9,
                "no spike at tick {k}"
            );
            if k < 80 {
                assert!(f.flags.contains(ContactFlags::RAMPING), "tick {k}");
            }
            previous = f.force_n.y;
        }
        assert!((previous - steady).abs() < 1e-9);
    }

    /// Runs an undamped stiff contact in at constant speed and straight back out, the depth
    /// always consistent with the position: the sample-and-hold alone creates energy.
    fn in_and_out(passivity: bool) -> (ForceRenderer, bool) {
        let mut r = renderer(Material::PAPER_STIFF, |c| {
            c.damping_n_s_per_m = 0.0;
            c.passivity = passivity;
            c.ramp_threshold_n = f64::INFINITY;
        });
        let speed = 0.05;
        let mut engaged = false;
        let mut t = 0;
        let mut depth: f64 = 0.0;
        for k in 0..120 {
            let v = if k < 60 { -speed } else { speed };
            depth -= v * 1e-3;
            t += MS;
            let c = (depth > 0.0).then(|| contact(depth));
            let f = r.render(c.as_ref(), at(depth), DVec3::Y * v, DVec3::Y, t);
            engaged |= f.flags.contains(ContactFlags::PASSIVITY_DAMPING);
        }
        (r, engaged)
    }

    #[test]
    fn passivity_controller_removes_the_energy_sample_and_hold_creates() {
        let (without, engaged) = in_and_out(false);
        assert!(!engaged);
        // Still in contact at the last tick (depth ≈ 0): the observer shows the created energy.
        assert!(
            without.passivity_energy_j() < -5e-5,
            "{}",
            without.passivity_energy_j()
        );
        let (with, engaged) = in_and_out(true);
        assert!(engaged);
        // The controller removes most of it. What remains accrues in the last ticks before the
        // tip leaves, where the spring force is too small to damp the motion without pulling.
        assert!(
            with.passivity_energy_j() > 0.35 * without.passivity_energy_j(),
            "with {} J, without {} J",
            with.passivity_energy_j(),
            without.passivity_energy_j()
        );
    }

    #[test]
    fn elastic_energy_integrates_the_rendered_force() {
        for (material, cap) in [
            (Material::PAPER_SOFT, true),
            (Material::PAPER_STIFF, true),
            (Material::PAPER_STIFF, false),
        ] {
            let r = renderer(material, |c| c.stiffness_cap = cap);
            let depth = 0.004;
            let n = 20_000;
            let h = depth / n as f64;
            let numeric: f64 = (0..n)
                .map(|i| r.elastic_force_n((i as f64 + 0.5) * h).0 * h)
                .sum();
            assert!((r.elastic_energy_j(depth) / numeric - 1.0).abs() < 1e-6);
        }
    }

    #[test]
    fn past_the_tips_height_the_force_keeps_rising_with_the_devices_stable_stiffness() {
        let k_max = DeviceLimits::PHANTOM_DESKTOP.max_stiffness_n_per_m;
        // A 1 mm sphere on soft tissue, whose law never reaches K_max within its 2 mm height,
        // and the default sphere on stiff tissue, capped long before its 20 mm.
        let small = ToolShape::sphere(0.001).unwrap();
        let cases = [
            ForceRenderer::new(
                small,
                Material::PAPER_SOFT,
                ForceConfig::for_tool(&small),
                DeviceLimits::PHANTOM_DESKTOP,
            ),
            renderer(Material::PAPER_STIFF, |_| {}),
        ];
        for r in cases {
            let height = shape::max_depth_m(r.tool());
            let (at, _) = r.elastic_force_n(height);
            let (just_past, _) = r.elastic_force_n(height * (1.0 + 1e-9));
            assert!(
                (just_past - at).abs() < 1e-6,
                "continuous: {at} → {just_past}"
            );
            let (deeper, _) = r.elastic_force_n(height + 0.005);
            assert!(
                (deeper - at - 5.0 * k_max * 1e-3).abs() < 1e-9,
                "{at} → {deeper}"
            );
            // Where the cap already acts, this is the cap's own line, continued.
            if r.cap_depth_m() < height {
                let line = r.cap_force_n + k_max * (height + 0.005 - r.cap_depth_m());
                assert!((deeper - line).abs() < 1e-9);
            }
            // The energy still integrates the rendered force, across the height.
            let depth = height + 0.005;
            let n = 20_000;
            let h = depth / n as f64;
            let numeric: f64 = (0..n)
                .map(|i| r.elastic_force_n((i as f64 + 0.5) * h).0 * h)
                .sum();
            assert!((r.elastic_energy_j(depth) / numeric - 1.0).abs() < 1e-6);
        }
    }

    /// A renderer of a corrected model (curvature + exact sphere) on the stiff material, whose
    /// stiffness reaches K_max within a few micrometres, so the cap acts.
    fn corrected_renderer() -> ForceRenderer {
        let spec = softhaptic_proto::ModelSpec {
            exact_sphere: true,
            curvature: true,
            ..softhaptic_proto::ModelSpec::PAPER
        };
        let model = ForceModel::new(sphere(), Material::PAPER_STIFF, spec).unwrap();
        ForceRenderer::with_model(
            model,
            ForceConfig::for_tool(&sphere()),
            DeviceLimits::PHANTOM_DESKTOP,
        )
    }

    #[test]
    fn a_corrected_model_is_rendered_with_its_own_cap_continuous_in_depth() {
        let mut r = corrected_renderer();
        let k_max = DeviceLimits::PHANTOM_DESKTOP.max_stiffness_n_per_m;
        for curvature in [0.0, 20.0, -40.0] {
            r.set_geometry(curvature, 0.0);
            let g = *r.geometry();
            assert_eq!(g.curvature_1_per_m, curvature);
            let model = r.model().clone();
            let star = r.cap_depth_m();
            assert_eq!(star, model.depth_at_stiffness_m(k_max, &g));
            assert!((model.stiffness_n_per_m(star, &g) / k_max - 1.0).abs() < 1e-3);
            let (below, capped) = r.elastic_force_n(0.5 * star);
            assert!(!capped);
            assert_eq!(below, model.force_n(0.5 * star, &g));
            let (at, _) = r.elastic_force_n(star);
            let (past, capped) = r.elastic_force_n(star * (1.0 + 1e-9));
            assert!(capped && (past - at).abs() < 1e-9, "{at} → {past}");
            // The energy integrates the rendered force, across the cap.
            let depth = 4.0 * star;
            let n = 20_000;
            let h = depth / n as f64;
            let numeric: f64 = (0..n)
                .map(|i| r.elastic_force_n((i as f64 + 0.5) * h).0 * h)
                .sum();
            assert!(
                (r.elastic_energy_j(depth) / numeric - 1.0).abs() < 1e-5,
                "κ = {curvature}"
            );
        }
        // Curvature softens the contact, so the stiffness reaches K_max deeper.
        r.set_geometry(0.0, 0.0);
        let flat = r.cap_depth_m();
        r.set_geometry(50.0, 0.0);
        assert!(r.cap_depth_m() > flat);
    }

    #[test]
    fn the_cap_is_found_again_only_when_the_geometry_moves() {
        let mut r = corrected_renderer();
        r.set_geometry(20.0, 0.0);
        let star = r.cap_depth_m();
        // Within the tolerance (|Δκ| R ≤ 1e-3): δ* is kept, but F(δ*) follows the geometry.
        r.set_geometry(20.05, 0.0);
        assert_eq!(r.cap_depth_m(), star);
        assert_eq!(r.geometry().curvature_1_per_m, 20.05);
        let f_star = r.model().force_n(star, r.geometry());
        let (past, capped) = r.elastic_force_n(star * (1.0 + 1e-9));
        assert!(
            capped && (past / f_star - 1.0).abs() < 1e-6,
            "{past} vs {f_star}"
        );
        // Past it: found again.
        r.set_geometry(20.2, 0.0);
        assert_ne!(r.cap_depth_m(), star);
        // Inclination does not move a sphere's model: it is not even recorded.
        r.set_geometry(20.2, 0.4);
        assert_eq!(r.geometry().inclination_rad, 0.0);
        // Non-finite input counts as flat.
        r.set_geometry(f64::NAN, f64::INFINITY);
        assert_eq!(*r.geometry(), LocalGeometry::FLAT);
        // The paper's law ignores the geometry altogether.
        let mut paper = renderer(Material::PAPER_STIFF, |_| {});
        let star = paper.cap_depth_m();
        paper.set_geometry(50.0, 0.3);
        assert_eq!(*paper.geometry(), LocalGeometry::FLAT);
        assert_eq!(paper.cap_depth_m(), star);
    }

    #[test]
    fn the_renderer_evaluates_the_tilted_cone_at_the_tools_inclination() {
        let cone = ToolShape::cone(std::f64::consts::FRAC_PI_4, 0.01).unwrap();
        let spec = softhaptic_proto::ModelSpec {
            inclination: true,
            ..softhaptic_proto::ModelSpec::PAPER
        };
        let model = ForceModel::new(cone, Material::PAPER_SOFT, spec).unwrap();
        let mut config = ForceConfig::for_tool(&cone);
        config.passivity = false;
        let mut r = ForceRenderer::with_model(model.clone(), config, DeviceLimits::PHANTOM_DESKTOP);
        let tilt = 0.3f64;
        let axis = DVec3::new(tilt.sin(), tilt.cos(), 0.0);
        let mut f = RenderedForce::ZERO;
        for k in 0..200 {
            f = r.render(Some(&contact(0.003)), at(0.003), DVec3::ZERO, axis, k * MS);
        }
        let g = LocalGeometry {
            curvature_1_per_m: 0.0,
            inclination_rad: tilt,
        };
        assert!((r.geometry().inclination_rad - tilt).abs() < 1e-12);
        assert!((f.force_n.y / model.force_n(0.003, &g) - 1.0).abs() < 1e-9);
        assert!(f.force_n.y > model.force_n(0.003, &LocalGeometry::FLAT));
        // 0.3 rad is past the paper's 9° for the cone.
        assert!(f.flags.contains(ContactFlags::BEYOND_VALID_INCLINATION));
    }

    #[test]
    fn validity_flags_follow_the_configured_limits() {
        // A measured limit of 1 mm and 5°: flagged past them, not before.
        let limits = softhaptic_proto::ValidityLimits {
            valid_depth_m: 0.001,
            valid_inclination_rad: 5f64.to_radians(),
            source: "test".into(),
        };
        let mut r = renderer(Material::PAPER_SOFT, |c| *c = c.with_limits(&limits));
        let t = settle(&mut r, 0.0009);
        let shallow = r.render(Some(&contact(0.0009)), at(0.0009), DVec3::ZERO, DVec3::Y, t);
        assert!(!shallow.flags.contains(ContactFlags::BEYOND_VALID_DEPTH));
        let deeper = r.render(
            Some(&contact(0.0011)),
            at(0.0011),
            DVec3::ZERO,
            DVec3::Y,
            t + MS,
        );
        assert!(deeper.flags.contains(ContactFlags::BEYOND_VALID_DEPTH));
        let six = DVec3::new(6f64.to_radians().sin(), 6f64.to_radians().cos(), 0.0);
        let tilted = r.render(
            Some(&contact(0.0009)),
            at(0.0009),
            DVec3::ZERO,
            six,
            t + 2 * MS,
        );
        assert!(
            tilted
                .flags
                .contains(ContactFlags::BEYOND_VALID_INCLINATION)
        );
    }

    #[test]
    fn out_of_contact_is_zero() {
        let mut r = renderer(Material::PAPER_SOFT, |_| {});
        let f = r.render(None, DVec3::Y, DVec3::ONE, DVec3::Y, 0);
        assert_eq!(f, RenderedForce::ZERO);
        let nan = WorldContact {
            depth_m: f64::NAN,
            normal: DVec3::Y,
            degenerate_normal: false,
            curvature_1_per_m: 0.0,
        };
        assert_eq!(
            r.render(Some(&nan), DVec3::ZERO, DVec3::ZERO, DVec3::Y, MS)
                .force_n,
            DVec3::ZERO
        );
    }

    proptest! {
        #[test]
        fn force_is_finite_bounded_and_pushes(
            e in 1.0f64..1e9, nu in 0.0f64..0.4999, depth in -0.01f64..0.05,
            vx in -2.0f64..2.0, vy in -2.0f64..2.0, vz in -2.0f64..2.0,
            nx in -1.0f64..1.0, ny in -1.0f64..1.0, nz in -1.0f64..1.0,
            cap in any::<bool>(), passivity in any::<bool>(), in_contact in any::<bool>(),
            ticks in 1usize..20,
        ) {
            let m = Material::new(e, nu).unwrap();
            let mut c = ForceConfig::for_tool(&sphere());
            c.stiffness_cap = cap;
            c.passivity = passivity;
            let mut r = ForceRenderer::new(sphere(), m, c, DeviceLimits::PHANTOM_DESKTOP);
            let normal = DVec3::new(nx, ny, nz);
            let v = DVec3::new(vx, vy, vz);
            let wc = WorldContact { depth_m: depth, normal, degenerate_normal: false, curvature_1_per_m: 0.0 };
            for k in 0..ticks as u64 {
                let f = r.render(in_contact.then_some(&wc), v * (k as f64 * 1e-3), v, DVec3::Y, k * MS);
                prop_assert!(f.force_n.is_finite());
                prop_assert!(f.force_n.length() <= 7.9 * (1.0 + 1e-12));
                if !in_contact {
                    prop_assert_eq!(f.force_n, DVec3::ZERO);
                } else if let Some(n) = normal.try_normalize() {
                    prop_assert!(f.force_n.dot(n) >= -1e-12);
                }
            }
        }
    }
}
