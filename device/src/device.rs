//! The haptic device abstraction: what a backend reports each tick and what it accepts back.
//!
//! A backend (the simulated PHANTOM in [`crate::sim`], a replayed session, a real device through
//! its vendor library) implements [`HapticDevice`]. The loop calls [`HapticDevice::read`] then
//! [`HapticDevice::command_force`] once per tick, so both must return within a few microseconds
//! and must not allocate, lock or log: they run on the 1 kHz thread.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use glam::DVec3;
use softhaptic_proto::{ContactFlags, Pose};

/// What a device can do safely. Every limit the force renderer enforces comes from here.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceLimits {
    /// Human-readable model name, shown to viewers.
    pub name: &'static str,
    /// Largest force the device may be commanded, briefly (saturation bound).
    pub peak_force_n: f64,
    /// Force the motors sustain without overheating (the RMS force at which the windings settle
    /// at their temperature limit).
    pub continuous_force_n: f64,
    /// Time constant of the first-order heating model of the motors that the continuous-force
    /// limiter (`thermal.rs`) uses to hold the RMS force at `continuous_force_n`.
    pub thermal_time_constant_s: f64,
    /// Largest virtual stiffness the device renders stably at 1 kHz (the stiffness cap).
    pub max_stiffness_n_per_m: f64,
    /// Largest virtual damping the device renders stably (bounds the configured damping).
    pub damping_n_s_per_m: f64,
    /// Radius of the reachable workspace around the device origin.
    pub workspace_radius_m: f64,
}

/// Time constant of the motors' heating model of every preset, seconds: faster than the
/// windings of a desktop arm's coreless motors heat, so the model errs on the safe side (the
/// choice is argued in `thermal.rs`, which holds the model).
pub const MOTOR_TIME_CONSTANT_S: f64 = 5.0;

impl DeviceLimits {
    /// PHANTOM Desktop: peak force, stable stiffness, damping and workspace as CHAI3D's
    /// `CPhantomDevices.cpp` uses them; continuous force from the datasheet (docs/physics.md).
    pub const PHANTOM_DESKTOP: DeviceLimits = DeviceLimits {
        name: "PHANTOM Desktop",
        peak_force_n: 7.9,
        continuous_force_n: 1.75,
        thermal_time_constant_s: MOTOR_TIME_CONSTANT_S,
        max_stiffness_n_per_m: 1000.0,
        damping_n_s_per_m: 5.0,
        workspace_radius_m: 0.10,
    };

    /// Touch (the PHANTOM Omni's successor): 3.3 N peak and 400 N/m as in docs/physics.md;
    /// 0.88 N continuous from the vendor datasheet; damping chosen with the stiffness' ratio to
    /// the Desktop's (the Touch's lighter arm tolerates less); workspace 160 × 120 × 70 mm.
    pub const TOUCH: DeviceLimits = DeviceLimits {
        name: "Touch",
        peak_force_n: 3.3,
        continuous_force_n: 0.88,
        thermal_time_constant_s: MOTOR_TIME_CONSTANT_S,
        max_stiffness_n_per_m: 400.0,
        damping_n_s_per_m: 2.0,
        workspace_radius_m: 0.075,
    };

    /// PHANTOM Omni: 3.3 N peak and 700 N/m as in docs/physics.md; 0.88 N continuous from the
    /// datasheet; 5 N·s/m damping as CHAI3D's older PHANTOM driver gives the Omni.
    pub const OMNI: DeviceLimits = DeviceLimits {
        name: "PHANTOM Omni",
        peak_force_n: 3.3,
        continuous_force_n: 0.88,
        thermal_time_constant_s: MOTOR_TIME_CONSTANT_S,
        max_stiffness_n_per_m: 700.0,
        damping_n_s_per_m: 5.0,
        workspace_radius_m: 0.08,
    };
}

/// Continuous force of a Force Dimension preset as a fraction of its peak: the SDK reports no
/// continuous rating, so the PHANTOM Desktop's ratio (1.75 N of 7.9 N) rounded down is taken, which
/// errs on the cool side.
pub const FORCE_DIMENSION_CONTINUOUS_FRACTION: f64 = 0.2;

impl DeviceLimits {
    /// Novint Falcon: 8 N, 3000 N/m, 20 N·s/m and a 0.04 m workspace radius as CHAI3D's
    /// Force Dimension driver gives it.
    pub const FALCON: DeviceLimits = DeviceLimits {
        name: "Novint Falcon",
        peak_force_n: 8.0,
        continuous_force_n: 8.0 * FORCE_DIMENSION_CONTINUOUS_FRACTION,
        thermal_time_constant_s: MOTOR_TIME_CONSTANT_S,
        max_stiffness_n_per_m: 3000.0,
        damping_n_s_per_m: 20.0,
        workspace_radius_m: 0.04,
    };

    /// omega.3: 12 N and 5000 N/m as CHAI3D gives it; the Falcon's damping (the smallest of the
    /// family's, so the safe side) and a 0.075 m radius (the datasheet's 160 mm sphere, less a
    /// margin).
    pub const OMEGA3: DeviceLimits = DeviceLimits {
        name: "omega.3",
        peak_force_n: 12.0,
        continuous_force_n: 12.0 * FORCE_DIMENSION_CONTINUOUS_FRACTION,
        thermal_time_constant_s: MOTOR_TIME_CONSTANT_S,
        max_stiffness_n_per_m: 5000.0,
        damping_n_s_per_m: 20.0,
        workspace_radius_m: 0.075,
    };

    /// delta.3: 20 N as CHAI3D gives it; the omega.3's stiffness and the Falcon's damping (not
    /// published for it: the family's most cautious values) and a 0.15 m radius (its 400 mm
    /// workspace, less a margin).
    pub const DELTA3: DeviceLimits = DeviceLimits {
        name: "delta.3",
        peak_force_n: 20.0,
        continuous_force_n: 20.0 * FORCE_DIMENSION_CONTINUOUS_FRACTION,
        thermal_time_constant_s: MOTOR_TIME_CONSTANT_S,
        max_stiffness_n_per_m: 5000.0,
        damping_n_s_per_m: 20.0,
        workspace_radius_m: 0.15,
    };

    /// sigma.7 (translation): 12 N as CHAI3D's driver limits it; stiffness, damping and radius
    /// as the omega.3's, whose parallel base it shares.
    pub const SIGMA7: DeviceLimits = DeviceLimits {
        name: "sigma.7",
        peak_force_n: 12.0,
        continuous_force_n: 12.0 * FORCE_DIMENSION_CONTINUOUS_FRACTION,
        thermal_time_constant_s: MOTOR_TIME_CONSTANT_S,
        max_stiffness_n_per_m: 5000.0,
        damping_n_s_per_m: 20.0,
        workspace_radius_m: 0.075,
    };
}

/// One reading of the device, already mapped into the world frame by the backend.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceSample {
    /// Device time of the reading, nanoseconds since the device was opened. Simulated and
    /// replayed devices count it in fixed steps so that a replay is bit-identical.
    pub time_ns: u64,
    /// Pose of the tool frame (origin at the tip's proximal point, +y up the shaft).
    pub tip_in_world: Pose,
    /// Linear velocity of the tip, world frame.
    pub tip_velocity_m_s: DVec3,
    /// Button bits, bit 0 the primary stylus button.
    pub buttons: u32,
    /// What the device reports about this reading beside the numbers, as the contact flags the
    /// tick carries: [`ContactFlags::MOTORS_WARM`] (the driver asks for less force; the world
    /// limits it to the continuous force) and [`ContactFlags::OUTSIDE_WORKSPACE`] (the tip is
    /// outside the device's usable box, where its readings are less accurate). Empty for most
    /// devices.
    pub flags: ContactFlags,
}

impl DeviceSample {
    /// True when every number in the sample is finite (NaN and ±∞ come from broken encoders
    /// or a broken driver, and must never reach the force law).
    pub fn is_finite(&self) -> bool {
        self.tip_in_world.is_finite() && self.tip_velocity_m_s.is_finite()
    }
}

/// Why a device could not be read or commanded. `Copy` and allocation-free: it is created on the
/// 1 kHz thread.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum DeviceError {
    /// The device is gone (cable pulled, driver closed).
    #[error("haptic device disconnected")]
    Disconnected,
    /// The device did not answer within its servo period.
    #[error("haptic device did not answer within its servo period")]
    Timeout,
    /// The device's amplifiers were disabled (e.g. the motors overheated or the safety switch
    /// tripped), so it cannot render force.
    #[error("haptic device force output is disabled")]
    ForceDisabled,
    /// The vendor library reported an error code.
    #[error("haptic device driver error code {0}")]
    Driver(i32),
    /// The device's encoders are not calibrated: its positions cannot be trusted, so no force is
    /// rendered until the operator calibrates it (for a PHANTOM: puts the stylus in its inkwell).
    #[error("haptic device needs calibration: put the stylus in its inkwell")]
    NeedsCalibration,
    /// The tick ran past its servo period before the force could be sent; the device was sent
    /// zero force instead of a stale one.
    #[error("haptic device servo tick overran its period")]
    Overrun,
    /// The driver's force cut-out tripped more often than it may be re-armed automatically: the
    /// force output stays off until an instructor re-arms it ([`RearmHandle`]) or the server
    /// restarts.
    #[error(
        "haptic device force output latched off after repeated force trips: an instructor must          re-arm it"
    )]
    ForceLatched,
    /// The backend's servo tick failed (a bug caught in the driver's callback): zero force was
    /// sent and the device renders none until the server restarts.
    #[error("haptic device servo tick failed: no force until the server restarts")]
    Fatal,
    /// The device's encoders must be reset: the operator holds the stylus at its reset position
    /// and presses its button; no force until then.
    #[error(
        "haptic device needs calibration: hold the stylus at its reset position and press its          button"
    )]
    NeedsCalibrationReset,
    /// The driver is updating the device's calibration by itself; no force until it is done.
    #[error("haptic device is updating its calibration: force resumes when it is done")]
    CalibrationUpdating,
}

impl DeviceError {
    /// A nonzero word for publishing the error through an atomic (0 means "no error"); the
    /// inverse is [`DeviceError::from_word`].
    pub fn to_word(self) -> u64 {
        match self {
            DeviceError::Disconnected => 1,
            DeviceError::Timeout => 2,
            DeviceError::ForceDisabled => 3,
            DeviceError::NeedsCalibration => 4,
            DeviceError::Overrun => 5,
            DeviceError::ForceLatched => 7,
            DeviceError::Fatal => 8,
            DeviceError::NeedsCalibrationReset => 9,
            DeviceError::CalibrationUpdating => 10,
            // The code's 32 bits above the kind.
            DeviceError::Driver(code) => 6 | (u64::from(code as u32) << 8),
        }
    }

    /// The error a word from [`DeviceError::to_word`] stands for; `None` for 0 (no error) or a
    /// word no error encodes to.
    pub fn from_word(word: u64) -> Option<DeviceError> {
        Some(match word & 0xff {
            1 => DeviceError::Disconnected,
            2 => DeviceError::Timeout,
            3 => DeviceError::ForceDisabled,
            4 => DeviceError::NeedsCalibration,
            5 => DeviceError::Overrun,
            6 => DeviceError::Driver((word >> 8) as u32 as i32),
            7 => DeviceError::ForceLatched,
            8 => DeviceError::Fatal,
            9 => DeviceError::NeedsCalibrationReset,
            10 => DeviceError::CalibrationUpdating,
            _ => return None,
        })
    }
}

/// Why a driver's servo clock did not start: the driver's own error and what to do about it, in
/// words for the operator (the start is not on the 1 kHz path, so it may allocate).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct ServoStartError(pub String);

/// A request, from any thread, to re-arm a device whose force output latched off after repeated
/// force trips ([`DeviceError::ForceLatched`]). The device takes it on its next tick (one atomic
/// swap, wait-free); a request while nothing is latched is dropped.
#[derive(Debug, Clone, Default)]
pub struct RearmHandle(Arc<AtomicBool>);

impl RearmHandle {
    /// Asks the device to re-arm its force output on its next tick.
    pub fn request(&self) {
        self.0.store(true, Ordering::Release);
    }

    /// Takes a pending request (the device's side).
    pub fn take(&self) -> bool {
        self.0.swap(false, Ordering::AcqRel)
    }
}

/// The servo clock of a device whose vendor library runs its own servo thread (OpenHaptics'
/// scheduler). The loop hands it the tick and the driver calls it once per servo period, between
/// the frame's state read and its force write; see [`crate::haptic_loop`] for why the tick runs
/// inside the driver's callback.
pub trait ServoClock: Send {
    /// The servo period the driver was asked for, nanoseconds.
    fn period_ns(&self) -> u64;
    /// Starts calling `tick` from the driver's servo thread, once per servo period, with the
    /// CLOCK_MONOTONIC time at which that servo tick began. `tick` must return within the period
    /// and must not block.
    fn start(&mut self, tick: Box<dyn FnMut(u64) + Send>) -> Result<(), ServoStartError>;
    /// Sends zero force, disables force output and stops the servo thread; `tick` is not called
    /// after this returns. Idempotent.
    fn stop(&mut self);
}

/// A haptic device the 1 kHz loop drives. `Send` because the loop thread owns it.
pub trait HapticDevice: Send {
    /// The device's safe operating limits.
    fn limits(&self) -> DeviceLimits;
    /// Reads the latest pose, velocity and buttons. Called once per tick, before
    /// [`HapticDevice::command_force`].
    fn read(&mut self) -> Result<DeviceSample, DeviceError>;
    /// Commands the force, world frame, to hold until the next command. An error means the
    /// device did not take this force (it output zero instead); the loop flags the tick as a
    /// device fault.
    fn command_force(&mut self, force_n: DVec3) -> Result<(), DeviceError>;
    /// The driver's servo clock, for a device whose vendor library owns the servo thread; the
    /// loop then runs each tick from that thread ([`ServoClock`]). `None` (the default): the
    /// loop's own thread clocks the device. Called once, before the first tick.
    fn servo_clock(&mut self) -> Option<Box<dyn ServoClock>> {
        None
    }
    /// Whether the commanded force reaches a hand. False for an input-only device (a
    /// SpaceMouse): the loop still computes, streams and records the force, and viewers are
    /// told that the trainee does not feel it.
    fn renders_force(&self) -> bool {
        true
    }
    /// The handle an instructor's re-arm goes through, for a device whose force output can latch
    /// off ([`DeviceError::ForceLatched`]); `None` (the default) for one that cannot.
    fn rearm_handle(&self) -> Option<RearmHandle> {
        None
    }
}

impl<D: HapticDevice + ?Sized> HapticDevice for Box<D> {
    fn limits(&self) -> DeviceLimits {
        (**self).limits()
    }
    fn read(&mut self) -> Result<DeviceSample, DeviceError> {
        (**self).read()
    }
    fn command_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        (**self).command_force(force_n)
    }
    fn servo_clock(&mut self) -> Option<Box<dyn ServoClock>> {
        (**self).servo_clock()
    }
    fn renders_force(&self) -> bool {
        (**self).renders_force()
    }
    fn rearm_handle(&self) -> Option<RearmHandle> {
        (**self).rearm_handle()
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn non_finite_samples_are_detected() {
        let mut s = DeviceSample {
            time_ns: 0,
            tip_in_world: Pose::IDENTITY,
            tip_velocity_m_s: DVec3::ZERO,
            buttons: 0,
            flags: ContactFlags::empty(),
        };
        assert!(s.is_finite());
        s.tip_velocity_m_s.y = f64::INFINITY;
        assert!(!s.is_finite());
        s.tip_velocity_m_s.y = 0.0;
        s.tip_in_world.orientation.w = f64::NAN;
        assert!(!s.is_finite());
    }

    #[test]
    fn errors_survive_the_trip_through_a_word() {
        for e in [
            DeviceError::Disconnected,
            DeviceError::Timeout,
            DeviceError::ForceDisabled,
            DeviceError::NeedsCalibration,
            DeviceError::Overrun,
            DeviceError::ForceLatched,
            DeviceError::Fatal,
            DeviceError::NeedsCalibrationReset,
            DeviceError::CalibrationUpdating,
            DeviceError::Driver(0x302),
            DeviceError::Driver(-7),
        ] {
            assert_ne!(e.to_word(), 0);
            assert_eq!(DeviceError::from_word(e.to_word()), Some(e));
        }
        assert_eq!(DeviceError::from_word(0), None);
        assert_eq!(DeviceError::from_word(0xff), None);
    }

    #[test]
    fn errors_name_the_cause() {
        assert!(DeviceError::Driver(-7).to_string().contains("-7"));
        assert!(
            DeviceError::Disconnected
                .to_string()
                .contains("disconnected")
        );
    }
}
