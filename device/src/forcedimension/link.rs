//! The connection to the device: opening and setting it up, the hand-over of the device between
//! the loop and the reconnection thread, and that thread.
//!
//! # One user of the device at a time
//! The device is used by one thread at a time, and who it is is one atomic word
//! (`Shared::owner`): [`Owner::Loop`] while the loop renders (its tick, on the loop's thread
//! or its standby, never both at once), [`Owner::Recovery`] once the loop has given it up as
//! lost. Only the loop moves it from `Loop` to `Recovery`, and only the reconnection thread back,
//! so neither ever waits for the other, and the loop's side is one load per tick.
//!
//! # Setup
//! Opening a device: `dhdOpenID(index)` (or `dhdOpen` for the default), its type, name and
//! serial, then the watchdog ([`super::WATCHDOG_UNITS`] by default), gravity compensation on (the SDK
//! applies it only while forces are sent, which the loop does every tick), the brakes off and
//! the force on. A step that fails closes the device again.
//!
//! # Close
//! At the end (the server's stop, whatever signal asked for it) the device is sent zero force,
//! its brakes are put on (the arm does not fall when the force goes) and it is closed. A process
//! that dies without that sends no more forces, and the watchdog stops the motors.

use std::ffi::c_char;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicI32, AtomicU8, AtomicU32, Ordering};
use std::time::Duration;

use super::dhd::*;
use super::ffi::{DhdLibrary, Failed};
use super::{DeviceDescription, ForceDimensionError, VELOCITY_WINDOW_MS, type_limits};
use crate::backend::reconnect::{Backoff, RECONNECT_BACKOFF_MAX, sleep_unless};

/// Who uses the device now (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Owner {
    /// The loop renders with it.
    Loop = 0,
    /// The loop gave it up as lost: the reconnection thread reopens it.
    Recovery = 1,
    /// Closed: nobody.
    Closed = 2,
}

/// State shared by the device (the loop's side) and its reconnection thread.
pub(crate) struct Shared {
    pub lib: &'static DhdLibrary,
    index: Option<u8>,
    pub which: String,
    /// The watchdog set at each open, in the SDK's units.
    watchdog_units: u8,
    /// The SDK's id of the open device (-1: none).
    id: AtomicI32,
    owner: AtomicU8,
    /// +1 per reconnection: the loop's side counts its ticks afresh.
    pub generation: AtomicU32,
    /// Set by the loop's side once a connection has proved working; taken by the reconnection
    /// thread, whose backoff restarts only then.
    pub working: AtomicBool,
    pub shutting_down: AtomicBool,
    /// The last error the loop's side saw (for the reconnection thread's log line).
    pub last_error: AtomicI32,
}

impl Shared {
    pub fn owner(&self) -> Owner {
        match self.owner.load(Ordering::Acquire) {
            0 => Owner::Loop,
            1 => Owner::Recovery,
            _ => Owner::Closed,
        }
    }

    /// The SDK id of the open device, as the SDK's `char`.
    pub fn id(&self) -> c_char {
        self.id.load(Ordering::Acquire) as c_char
    }

    /// The loop's side gives the device up (it is lost): from here only the reconnection
    /// thread touches it.
    pub fn hand_to_recovery(&self) {
        let _ = self.owner.compare_exchange(
            Owner::Loop as u8,
            Owner::Recovery as u8,
            Ordering::AcqRel,
            Ordering::Acquire,
        );
    }

    fn error(&self, step: &'static str, Failed(code): Failed) -> ForceDimensionError {
        ForceDimensionError::Setup {
            which: self.which.clone(),
            step,
            reason: self.lib.error_text(code),
            code_name: error_name(code),
        }
    }

    /// Opens the device and sets it up (module docs); on an error after the open, closes it.
    fn open_device(&self) -> Result<(c_char, DeviceDescription), ForceDimensionError> {
        let lib = self.lib;
        let api = &lib.api;
        // SAFETY: functions of the loaded library with plain arguments.
        let opened = lib.check(unsafe {
            match self.index {
                Some(index) => (api.open_id)(index as c_char),
                None => (api.open)(),
            }
        });
        let id = match opened {
            Ok(id) => id as c_char,
            Err(Failed(code)) => {
                return Err(ForceDimensionError::Open {
                    which: self.which.clone(),
                    library: lib.path().to_path_buf(),
                    reason: lib.error_text(code),
                    code_name: error_name(code),
                });
            }
        };
        let set_up = || -> Result<DeviceDescription, ForceDimensionError> {
            // SAFETY: as above.
            let type_id = lib
                .check(unsafe { (api.get_system_type)(id) })
                .map_err(|e| self.error("dhdGetSystemType", e))?;
            // The watchdog is among the SDK's expert functions, so expert mode is on for that
            // call alone: in it the SDK checks fewer of the caller's commands, which nothing
            // else here needs.
            // SAFETY: as above.
            lib.check(unsafe { (api.enable_expert_mode)() })
                .map_err(|e| self.error("dhdEnableExpertMode", e))?;
            // SAFETY: as above.
            let watchdog = lib.check(unsafe { (api.set_watchdog)(self.watchdog_units, id) });
            // SAFETY: as above.
            let _ = unsafe { (api.disable_expert_mode)() };
            watchdog.map_err(|e| self.error("dhdSetWatchdog", e))?;
            // The velocity the damping multiplies: a short window, not the SDK's default
            // (`VELOCITY_WINDOW_MS`).
            // SAFETY: as above.
            lib.check(unsafe {
                (api.config_linear_velocity)(VELOCITY_WINDOW_MS, DHD_VELOCITY_WINDOWING, id)
            })
            .map_err(|e| self.error("dhdConfigLinearVelocity", e))?;
            // SAFETY: as above.
            lib.check(unsafe { (api.set_gravity_compensation)(DHD_ON, id) })
                .map_err(|e| self.error("dhdSetGravityCompensation", e))?;
            // SAFETY: as above.
            lib.check(unsafe { (api.set_brakes)(DHD_OFF, id) })
                .map_err(|e| self.error("dhdSetBrakes(off)", e))?;
            // SAFETY: as above.
            lib.check(unsafe { (api.enable_force)(DHD_ON as u8, id) })
                .map_err(|e| self.error("dhdEnableForce(on)", e))?;
            Ok(DeviceDescription {
                index: self.index,
                type_id,
                name: lib.system_name(id),
                serial: lib.serial_number(id),
                type_limits: type_limits(type_id),
            })
        };
        match set_up() {
            Ok(description) => Ok((id, description)),
            Err(e) => {
                self.release(id);
                Err(e)
            }
        }
    }

    /// Zero force, brakes on, closed (module docs); errors are ignored: the device may be gone.
    fn release(&self, id: c_char) {
        let api = &self.lib.api;
        // SAFETY: functions of the loaded library with plain arguments.
        unsafe {
            (api.set_force)(0.0, 0.0, 0.0, id);
            (api.set_brakes)(DHD_ON, id);
            (api.close)(id);
        }
    }
}

/// The connection, held by the device.
pub(crate) struct Link {
    pub shared: Arc<Shared>,
    reconnector: Option<std::thread::JoinHandle<()>>,
}

impl Link {
    /// Opens the device and starts the reconnection thread.
    pub fn open(
        lib: &'static DhdLibrary,
        index: Option<u8>,
        which: String,
        watchdog_units: u8,
    ) -> Result<(Link, DeviceDescription), ForceDimensionError> {
        let shared = Arc::new(Shared {
            lib,
            index,
            which,
            watchdog_units,
            id: AtomicI32::new(-1),
            owner: AtomicU8::new(Owner::Closed as u8),
            generation: AtomicU32::new(0),
            working: AtomicBool::new(true),
            shutting_down: AtomicBool::new(false),
            last_error: AtomicI32::new(DHD_NO_ERROR),
        });
        let (id, description) = shared.open_device()?;
        shared.id.store(i32::from(id), Ordering::Release);
        shared.owner.store(Owner::Loop as u8, Ordering::Release);
        let thread_shared = Arc::clone(&shared);
        let reconnector = std::thread::Builder::new()
            .name("haptic-reconnect".into())
            .spawn(move || reconnect_when_lost(&thread_shared));
        let reconnector = match reconnector {
            Ok(handle) => Some(handle),
            Err(e) => {
                // Without it a lost device stays lost (zero force, flagged); the session goes on.
                tracing::warn!(error = %e, "no reconnection thread for the haptic device");
                None
            }
        };
        Ok((
            Link {
                shared,
                reconnector,
            },
            description,
        ))
    }

    /// Stops the reconnection thread, then sends zero force, puts the brakes on and closes the
    /// device, whoever had it. Idempotent.
    pub fn close(&mut self) {
        self.shared.shutting_down.store(true, Ordering::Release);
        if let Some(handle) = self.reconnector.take() {
            handle.thread().unpark();
            let _ = handle.join();
        }
        let previous = self
            .shared
            .owner
            .swap(Owner::Closed as u8, Ordering::AcqRel);
        let id = self.shared.id.swap(-1, Ordering::AcqRel);
        if previous != Owner::Closed as u8 && id >= 0 {
            self.shared.release(id as c_char);
            tracing::info!(device = %self.shared.which, "haptic device: zero force, brakes on, closed");
        }
    }
}

impl Drop for Link {
    fn drop(&mut self) {
        self.close();
    }
}

/// The reconnection thread: waits until the loop hands the device over, closes the lost
/// connection, and reopens the device with the shared backoff until it answers.
fn reconnect_when_lost(shared: &Shared) {
    let mut backoff = Backoff::default();
    while !shared.shutting_down.load(Ordering::Acquire) {
        std::thread::park_timeout(Duration::from_millis(5));
        if shared.owner() != Owner::Recovery {
            continue;
        }
        let unproven = backoff.lost(shared.working.swap(false, Ordering::AcqRel));
        let code = shared.last_error.load(Ordering::Relaxed);
        tracing::warn!(
            device = %shared.which,
            error = %shared.lib.error_text(code),
            code = error_name(code),
            again = unproven,
            "haptic device lost: force is off; reconnecting"
        );
        let old = shared.id.swap(-1, Ordering::AcqRel);
        if old >= 0 {
            shared.release(old as c_char);
        }
        let mut attempt = 0u32;
        loop {
            if let Some(wait) = backoff.before_attempt(attempt)
                && !sleep_unless(wait, &shared.shutting_down)
            {
                return;
            }
            if shared.shutting_down.load(Ordering::Acquire) {
                return;
            }
            match shared.open_device() {
                Ok((id, _)) => {
                    shared.id.store(i32::from(id), Ordering::Release);
                    shared.generation.fetch_add(1, Ordering::AcqRel);
                    backoff.reconnected();
                    // Hands the device back only if no stop came meanwhile (a stop closes it).
                    let back = shared.owner.compare_exchange(
                        Owner::Recovery as u8,
                        Owner::Loop as u8,
                        Ordering::AcqRel,
                        Ordering::Acquire,
                    );
                    if back.is_ok() {
                        tracing::info!(
                            device = %shared.which,
                            attempts = attempt + 1,
                            "haptic device reconnected: force ramps in again"
                        );
                    }
                    break;
                }
                Err(e) if attempt == 0 => tracing::info!(
                    device = %shared.which,
                    error = %e,
                    "haptic device not back yet; retrying with backoff up to every {} s",
                    RECONNECT_BACKOFF_MAX.as_secs()
                ),
                Err(_) => {}
            }
            attempt += 1;
        }
    }
}
