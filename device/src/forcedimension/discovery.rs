//! What `softhaptic devices` (and the doctor) learn of the Force Dimension side of a machine:
//! the library, how many devices the SDK sees, and each one opened in turn (type, name, serial,
//! the limits its type implies), closed again before the next.

use std::path::PathBuf;

use super::ffi::DhdLibrary;
use super::{DeviceDescription, ForceDimensionConfig, ForceDimensionDevice, ForceDimensionError};
use crate::device::DeviceLimits;

/// What `softhaptic devices` reports about the Force Dimension side of this machine.
#[derive(Debug)]
pub enum Discovery {
    /// The library could not be loaded.
    NoLibrary(ForceDimensionError),
    /// The library loaded; the devices it sees, each with what opening it gave.
    Library {
        path: PathBuf,
        /// `dhdGetDeviceCount`, or the SDK's words for why it could not count.
        count: Result<usize, String>,
        devices: Vec<(u8, Result<DeviceDescription, ForceDimensionError>)>,
    },
}

/// Loads the library, counts the devices and opens each (closed again before the next).
pub fn discover() -> Discovery {
    let lib = match DhdLibrary::load() {
        Ok(lib) => lib,
        Err(e) => return Discovery::NoLibrary(e),
    };
    let count = lib
        .device_count()
        .map(|n| usize::try_from(n).unwrap_or(0))
        .map_err(|f| lib.error_text(f.0));
    let devices = match &count {
        Ok(n) => (0..(*n).min(16) as u8)
            .map(|index| {
                let config = ForceDimensionConfig {
                    index: Some(index),
                    ..ForceDimensionConfig::new(DeviceLimits::OMEGA3)
                };
                let opened = ForceDimensionDevice::open(&config).map(|mut device| {
                    device.close();
                    device.description().clone()
                });
                (index, opened)
            })
            .collect(),
        Err(_) => Vec::new(),
    };
    Discovery::Library {
        path: lib.path().to_path_buf(),
        count,
        devices,
    }
}
