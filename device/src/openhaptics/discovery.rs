//! What `softhaptic devices` (and the doctor) learn of the OpenHaptics side of a machine: the
//! library, and each device configuration opened in turn with its calibration state.
//!
//! The calibration is read in one frame of a briefly started scheduler, through an asynchronous
//! callback that is waited for with a deadline: a scheduler that does not start (the OS refused
//! its timer) is reported with the driver's error within [`START_DEADLINE`], never waited for.

use std::ffi::c_void;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::time::{Duration, Instant};

use super::ffi::{HdCallbackCode, HdLibrary};
use super::hd::*;
use super::mapping::{Calibration, DeviceDescription};
use super::servo::{Inner, START_DEADLINE, StartFailure, start_failure_text};
use super::{OpenHapticsConfig, OpenHapticsDevice, OpenHapticsError};
use crate::device::DeviceLimits;

/// What opening one device configuration gave: its description and calibration state, or why
/// it could not be opened.
pub type Probe = Result<(DeviceDescription, Calibration), OpenHapticsError>;

/// What `softhaptic devices` reports about the OpenHaptics side of this machine.
#[derive(Debug)]
pub enum Discovery {
    /// The library could not be loaded.
    NoLibrary(OpenHapticsError),
    /// The library loaded; each named configuration tried, with what it gave.
    Library {
        path: PathBuf,
        devices: Vec<(String, Probe)>,
    },
}

/// The one frame a calibration probe runs, and its answer.
struct CalibrationProbe<'a> {
    inner: &'a Inner,
    handle: u32,
    status: AtomicU32,
    done: AtomicBool,
}

/// One frame that reads the calibration state, for a device that is not running a loop.
unsafe extern "C" fn calibration_frame(user: *mut c_void) -> HdCallbackCode {
    // SAFETY: `user` is the probe `probe_calibration` scheduled; it outlives the scheduler's
    // run (stopped and joined before the probe is dropped).
    let probe = unsafe { &*user.cast::<CalibrationProbe<'_>>() };
    let api = &probe.inner.lib.api;
    // SAFETY: functions of the loaded library on its servo thread.
    let status = unsafe {
        (api.begin_frame)(probe.handle);
        let status = (api.check_calibration)();
        (api.end_frame)(probe.handle);
        status
    };
    probe.status.store(status, Ordering::Release);
    probe.done.store(true, Ordering::Release);
    HD_CALLBACK_DONE
}

impl OpenHapticsDevice {
    /// Reads the calibration state in one frame of a briefly started scheduler (for a device
    /// that is not running a loop: `softhaptic devices`); a scheduler that does not start is
    /// reported with the driver's error (module docs).
    pub fn probe_calibration(&self) -> Result<Calibration, OpenHapticsError> {
        if self.clock_taken {
            return Ok(if self.calibrated {
                Calibration::Ok
            } else {
                Calibration::NeedsManualInput
            });
        }
        let inner: &Inner = &self.inner;
        let api = &inner.lib.api;
        let probe = CalibrationProbe {
            inner,
            handle: inner.current_handle(),
            status: AtomicU32::new(0),
            done: AtomicBool::new(false),
        };
        // The scheduler is stopped: this thread owns the error stack.
        let _ = inner.lib.take_errors();
        // SAFETY: `probe` outlives the scheduler's run: it is stopped (joined) below before the
        // probe goes out of scope.
        let handle = unsafe {
            (api.schedule_asynchronous)(
                calibration_frame,
                (&probe as *const CalibrationProbe<'_>).cast_mut().cast(),
                HD_MAX_SCHEDULER_PRIORITY,
            )
        };
        if let Some(code) = inner.lib.take_errors().worst() {
            // SAFETY: unscheduling an unknown handle is harmless.
            unsafe { (api.unschedule)(handle) };
            return Err(inner.setup_error("a calibration check", code));
        }
        // SAFETY: a function of the loaded library.
        unsafe { (api.start_scheduler)() };
        let deadline = Instant::now() + START_DEADLINE;
        while !probe.done.load(Ordering::Acquire) && Instant::now() < deadline {
            std::thread::park_timeout(Duration::from_millis(1));
        }
        // SAFETY: as above; once the scheduler has stopped the callback does not run.
        unsafe {
            (api.unschedule)(handle);
            (api.stop_scheduler)();
        }
        let seen = inner.lib.take_errors();
        if !probe.done.load(Ordering::Acquire) {
            return Err(OpenHapticsError::SchedulerStart {
                text: start_failure_text(
                    inner,
                    StartFailure {
                        step: "hdStartScheduler",
                        code: seen.worst(),
                    },
                ),
            });
        }
        if let Some(code) = seen.gone {
            return Err(inner.setup_error("a calibration check", code));
        }
        Ok(match probe.status.load(Ordering::Acquire) {
            HD_CALIBRATION_OK => Calibration::Ok,
            HD_CALIBRATION_NEEDS_UPDATE => Calibration::NeedsUpdate,
            _ => Calibration::NeedsManualInput,
        })
    }
}

/// Loads the library and tries to open the default device and each of `names` in turn (each
/// closed again before the next).
pub fn discover(names: &[String]) -> Discovery {
    let path = match HdLibrary::load() {
        Ok(lib) => lib.path().to_path_buf(),
        Err(e) => return Discovery::NoLibrary(e),
    };
    let mut tried: Vec<Option<String>> = vec![None];
    tried.extend(names.iter().cloned().map(Some));
    tried.dedup();
    let devices = tried
        .into_iter()
        .map(|name| {
            let label = name.clone().unwrap_or_else(|| "Default Device".into());
            let config = OpenHapticsConfig {
                name,
                ..OpenHapticsConfig::new(DeviceLimits::PHANTOM_DESKTOP)
            };
            let result = OpenHapticsDevice::open(&config).and_then(|device| {
                let calibration = device.probe_calibration()?;
                Ok((device.description().clone(), calibration))
            });
            (label, result)
        })
        .collect();
    Discovery::Library { path, devices }
}
