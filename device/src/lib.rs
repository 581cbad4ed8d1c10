//! The part of the simulator that runs at 1 kHz next to the haptic device.
//!
//! This crate cannot name tokio or any networking crate: whatever happens on the network, nothing
//! here can wait for it (docs/design.md, invariant 1).
//!
//! # Layout
//! - [`law`]: the closed-form contact laws (Hertz sphere, Sneddon cone), contact radius and
//!   stiffness, as pure functions of depth.
//! - [`model`]: [`ForceModel`](model::ForceModel), the paper's law times the corrections a scene
//!   turns on (curvature, layer thickness, exact sphere, hyperelastic fit, inclination), fed the
//!   [`LocalGeometry`](model::LocalGeometry) of the contact.
//! - [`mesh`]: the coarse haptic mesh, the flat grids of the paper's timing study and the
//!   spheres of its curvature study.
//! - [`curvature`]: the mesh's mean curvature per vertex, estimated once for a model that uses it.
//! - [`collision`]: tool-tip collision with the haptic mesh (paper §4.1); each contact carries
//!   the surface's curvature when the collider was built with it.
//! - [`shape`]: the tool tip as a solid: implicit inside test, bounding box, support point.
//! - [`tracking`]: the contact followed across ticks: a tool pushed past what the collision
//!   measures is held on the side it entered (no pop-through).
//! - [`liver`]: the procedural liver-like organ, as a coarse haptic mesh and a fine render surface.
//! - [`device`]: the [`HapticDevice`](device::HapticDevice) trait, device limits, samples, errors.
//! - [`sim`]: a simulated PHANTOM Desktop moved by a scripted hand (mass–spring–damper).
//! - [`backend`]: what every vendor's backend shares: finding and loading its library, the
//!   mapping from its frame and units to the world and the limits it runs with, the
//!   reconnection policy.
//! - [`forcedimension`]: a Force Dimension device (omega, delta, sigma, Novint Falcon) through
//!   the `libdhd` SDK, loaded at run time; the loop's own thread clocks it, the SDK's watchdog
//!   stops the motors when forces stop coming, faults give zero force and a reconnection off the
//!   loop.
//! - [`openhaptics`]: a PHANTOM / Touch through OpenHaptics' HD API, loaded at run time; its
//!   servo scheduler clocks the loop, faults give zero force and a reconnection off the servo
//!   path.
//! - [`spacemouse`]: a 3Dconnexion SpaceMouse through hidapi (feature `spacemouse`, on by
//!   default): its reports read off the loop's thread, the puck's deflection as the tool's
//!   velocity (rate control); it renders no force.
//! - [`force`]: the scene's contact model at the contact's geometry (curvature, the tool's
//!   inclination) + damping, then the safety layer (stiffness cap at the model's δ*, ramp,
//!   passivity, saturation, fault guard) with a flag for every limit that acts, and the validity
//!   flags at the active model's limits.
//! - [`inclusion`]: stiffer inclusions inside the object (palpation): the FEM's force ratio at
//!   the contact, interpolated from the calibration's table; built only for a scene that has
//!   inclusions.
//! - [`metrics`]: the trainee's metrics (peak force, time above the safe force, time in
//!   contact, path, smoothness, pushes, faults, flags) from every tick, in constant time.
//! - [`exercise`]: [`Scorer`](exercise::Scorer), an exercise's score (press, trace, palpation) from the
//!   same ticks as the metrics, live or from a recording.
//! - [`deviation`]: a trainee's path and force against an expert's, aligned by dynamic time
//!   warping (offline: after an attempt, never in the loop).
//! - [`guide`]: haptic guidance along an expert's recorded path (a spring–damper toward a
//!   target that advances with the trainee's progress), and its gain: fixed, by pass, or as needed.
//! - [`passivity`]: the passivity observer and controller (Hannaford & Ryu 2002).
//! - [`thermal`]: [`ContinuousForceLimiter`](thermal::ContinuousForceLimiter), a model of the
//!   motors' heating that holds the RMS force at the device's continuous rating.
//! - [`world`]: [`HapticWorld`](world::HapticWorld), one tick as a synchronous function; built
//!   with the scene's [`ForceModel`](model::ForceModel) (or the paper's law).
//! - [`haptic_loop`]: the 1 kHz thread, its standby on a second CPU, and the wait-free publication
//!   of the latest contact.
//! - [`cells`]: [`SeqCell`](cells::SeqCell), the seqlock the loop and the device backends
//!   publish through, and [`Words`](cells::Words), the one way a state is packed into its words.
//! - [`stats`]: fixed-size timing histograms and the loop's [`LoopStats`](stats::LoopStats).
//! - [`rt`]: monotonic clock, absolute-deadline sleep, SCHED_FIFO and mlockall requests.
//! - [`replay`]: [`ReplayDevice`](replay::ReplayDevice), a recorded session played back as a
//!   device, and the exact conversions between device samples and session-log records.

pub mod backend;
pub mod cells;
pub mod collision;
pub mod curvature;
pub mod deviation;
pub mod device;
pub mod exercise;
pub mod force;
pub mod forcedimension;
pub mod guide;
pub mod haptic_loop;
pub mod inclusion;
pub mod law;
pub mod liver;
pub mod mesh;
pub mod metrics;
pub mod model;
pub mod openhaptics;
pub mod passivity;
pub mod replay;
pub mod rt;
pub mod shape;
pub mod sim;
#[cfg(feature = "spacemouse")]
pub mod spacemouse;
pub mod stats;
pub mod thermal;
pub mod tracking;
pub mod world;
