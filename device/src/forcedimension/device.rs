//! [`ForceDimensionDevice`]: what the loop reads and commands each tick, on its own thread.
//!
//! A tick reads the position and the velocity and, every [`STATUS_CHECK_TICKS`], the device's
//! status; the loop then sends the force. Each call's error is read at once on the thread that
//! made it (the SDK keeps errors per thread, and a tick may run on the loop's thread or its
//! standby). An unreachable device is zero force on that tick ([`DeviceError::Disconnected`]);
//! after a run of them the device goes to the reconnection thread ([`super::link`]) and ticks
//! touch nothing until it comes back. A force the device switched off (its force button, or the
//! firmware) is [`DeviceError::ForceDisabled`] on the tick that finds it, and switched on again:
//! the world ramps the force back in.

use std::sync::atomic::Ordering;

use glam::{DQuat, DVec3};
use softhaptic_proto::{ContactFlags, Pose};

use super::dhd::{DHD_ON, DHD_STATUS_FORCE, is_gone};
use super::ffi::Failed;
use super::link::{Link, Owner};
use super::{DeviceDescription, FORCE_MARGIN, STATUS_CHECK_TICKS};
use crate::backend::mapping::WorkspaceMapping;
use crate::backend::reconnect::LinkHealth;
use crate::device::{DeviceError, DeviceLimits, DeviceSample, HapticDevice};
use crate::rt;

/// A Force Dimension device (module docs of [`super`]).
pub struct ForceDimensionDevice {
    link: Link,
    description: DeviceDescription,
    mapping: WorkspaceMapping,
    limits: DeviceLimits,
    /// The tool's world orientation (the device has no wrist to read).
    tool_in_world: DQuat,
    opened_ns: u64,
    period_ns: u64,
    last_time_ns: Option<u64>,
    ticks: u64,
    health: LinkHealth,
    /// This tick's read already booked a failure (the force's failure then is not counted
    /// again).
    read_failed: bool,
    generation_seen: u32,
    /// Largest force magnitude sent, device axes, N.
    force_clamp_n: f64,
}

impl ForceDimensionDevice {
    pub(crate) fn new(
        link: Link,
        description: DeviceDescription,
        mapping: WorkspaceMapping,
        limits: DeviceLimits,
        tool_in_device: DQuat,
        period_ns: u64,
    ) -> ForceDimensionDevice {
        // The type's peak where it is known, else the limit in use.
        let peak_n = description
            .type_limits
            .map_or(limits.peak_force_n, |l| l.peak_force_n);
        ForceDimensionDevice {
            link,
            description,
            tool_in_world: (mapping.world_from_device.orientation * tool_in_device).normalize(),
            mapping,
            limits,
            opened_ns: rt::now_ns(),
            period_ns: period_ns.max(1),
            last_time_ns: None,
            ticks: 0,
            health: LinkHealth::default(),
            read_failed: false,
            generation_seen: 0,
            force_clamp_n: peak_n.min(limits.peak_force_n) * (1.0 - FORCE_MARGIN),
        }
    }

    /// What the device reported when it opened.
    pub fn description(&self) -> &DeviceDescription {
        &self.description
    }

    /// The mapping from the device's frame to the world.
    pub fn mapping(&self) -> &WorkspaceMapping {
        &self.mapping
    }

    /// The library's path.
    pub fn library_path(&self) -> &std::path::Path {
        self.link.shared.lib.path()
    }

    /// Sends zero force, puts the brakes on and closes the device (also done when it is
    /// dropped).
    pub fn close(&mut self) {
        self.link.close();
    }

    /// Whether the loop's side may use the device now; follows a reconnection.
    fn usable(&mut self) -> bool {
        let shared = &self.link.shared;
        if shared.owner() != Owner::Loop {
            return false;
        }
        let generation = shared.generation.load(Ordering::Acquire);
        if generation != self.generation_seen {
            self.generation_seen = generation;
            self.health.restart();
        }
        true
    }

    /// Books a failed call: an unreachable device counts toward a reconnection; the tick's
    /// error.
    fn failed(&mut self, Failed(code): Failed) -> DeviceError {
        let shared = &self.link.shared;
        shared.last_error.store(code, Ordering::Relaxed);
        if is_gone(code) {
            if self.health.unreachable_tick() {
                // The reconnection thread polls the owner every few milliseconds: the loop
                // signals nothing else (no lock, no system call).
                shared.hand_to_recovery();
            }
            DeviceError::Disconnected
        } else {
            DeviceError::Driver(code)
        }
    }

    /// Device time: whole loop periods since the device opened (a tick woken a little late,
    /// by less than half a period, does not move it), increasing from tick to tick. The force
    /// ramps and the heating model then see the loop's steps, not the host's wake-up jitter.
    fn device_time_ns(&mut self) -> u64 {
        let period = self.period_ns;
        let since_open = rt::now_ns().saturating_sub(self.opened_ns);
        let now = (since_open + period / 2) / period * period;
        let time_ns = self.last_time_ns.map_or(now, |last| now.max(last + 1));
        self.last_time_ns = Some(time_ns);
        time_ns
    }

    /// Reads the status now and then; a force found switched off is switched on again and
    /// fails this tick.
    fn check_force_switch(&mut self) -> Result<(), DeviceError> {
        if !self.ticks.is_multiple_of(STATUS_CHECK_TICKS) {
            return Ok(());
        }
        let lib = self.link.shared.lib;
        let id = self.link.shared.id();
        let status = lib.status(id).map_err(|e| self.failed(e))?;
        if status[DHD_STATUS_FORCE] == 0 {
            // SAFETY: a function of the loaded library with plain arguments.
            let enabled = lib.check(unsafe { (lib.api.enable_force)(DHD_ON as u8, id) });
            enabled.map_err(|e| self.failed(e))?;
            return Err(DeviceError::ForceDisabled);
        }
        Ok(())
    }
}

impl HapticDevice for ForceDimensionDevice {
    fn limits(&self) -> DeviceLimits {
        self.limits
    }

    fn read(&mut self) -> Result<DeviceSample, DeviceError> {
        self.read_failed = true;
        if !self.usable() {
            return Err(DeviceError::Disconnected);
        }
        self.ticks += 1;
        let lib = self.link.shared.lib;
        let id = self.link.shared.id();
        let position_m = lib.position(id).map_err(|e| self.failed(e))?;
        let velocity_m_s = lib.linear_velocity(id).map_err(|e| self.failed(e))?;
        // SAFETY: a function of the loaded library with a plain argument; it has no error
        // return (a lost device fails the position read above).
        let buttons = unsafe { (lib.api.get_button_mask)(id) };
        self.check_force_switch()?;
        self.read_failed = false;
        if self.health.good_tick() {
            self.link.shared.working.store(true, Ordering::Release);
        }
        let position = DVec3::from_array(position_m);
        let mut flags = ContactFlags::empty();
        if self.mapping.outside_usable(position) {
            flags |= ContactFlags::OUTSIDE_WORKSPACE;
        }
        Ok(DeviceSample {
            time_ns: self.device_time_ns(),
            tip_in_world: Pose {
                position_m: self.mapping.position_m(position),
                orientation: self.tool_in_world,
            },
            tip_velocity_m_s: self.mapping.velocity_m_s(DVec3::from_array(velocity_m_s)),
            buttons,
            flags,
        })
    }

    fn command_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        if !self.usable() {
            // The device is not the loop's: nothing is sent, and the watchdog has stopped the
            // motors (or the reconnection thread sent zero when it took the device).
            return if force_n == DVec3::ZERO {
                Ok(())
            } else {
                Err(DeviceError::Disconnected)
            };
        }
        let mut device_n = self.mapping.force_device_n(force_n);
        let size = device_n.length();
        if size > self.force_clamp_n {
            // The world saturates in its own axes; the rotation may round a hair above.
            device_n *= self.force_clamp_n / size;
        }
        if !device_n.is_finite() {
            device_n = DVec3::ZERO;
        }
        let lib = self.link.shared.lib;
        let id = self.link.shared.id();
        // SAFETY: a function of the loaded library with plain arguments.
        let sent = unsafe { (lib.api.set_force)(device_n.x, device_n.y, device_n.z, id) };
        // DHD_TIMEGUARD and DHD_MOTOR_SATURATED are positive: the force was taken.
        match lib.check(sent) {
            Ok(_) => Ok(()),
            Err(Failed(code)) if self.read_failed => Err(if is_gone(code) {
                DeviceError::Disconnected
            } else {
                DeviceError::Driver(code)
            }),
            Err(e) => Err(self.failed(e)),
        }
    }
}
