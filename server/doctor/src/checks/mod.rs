//! The host inspections of `softhaptic doctor`: each reads its files through a [`Tree`] (the real
//! `/` or a copy of `/proc` and `/sys` fragments in a test) and returns a [`Check`]. Nothing here
//! writes anything or asks the kernel for more than a file read; an entry that is missing or
//! unreadable makes its part of a finding "unknown", never an error.
//!
//! # Layout
//! - this file: [`Tree`], through which every file is read, and [`inspect`], every check in the
//!   order they are printed.
//! - `formats.rs`: the kernel's formats read by more than one check (CPU lists, the command
//!   line, limits, status fields, cgroup paths).
//! - `kernel.rs`: the preemption model (from the running kernel and its build configuration)
//!   and virtualisation.
//! - `limits.rs`: real-time scheduling, memory locking and swap: the limits and capabilities.
//! - `cpus.rs`: CPU isolation and the loop's CPU, and the frequency governor.
//! - `interrupts.rs`: the interrupts delivered to the loop's CPU.
//! - `devices.rs`: the haptic device, the SpaceMouse's hidraw nodes and the USB nodes of a Force
//!   Dimension device.

mod cpus;
mod devices;
mod formats;
mod interrupts;
mod kernel;
mod limits;

use std::io::Read as _;
use std::path::{Path, PathBuf};

use crate::{Check, LoopPlan};

pub use cpus::{CpuLayout, cpu_isolation_check, governor_check};
pub use devices::{
    DeviceFacts, OpenHapticsFacts, forcedimension_usb_check, haptic_device_check, hidraw_check,
};
pub use formats::{
    Limit, format_cpu_list, kernel_param, parse_cpu_list, parse_limit, status_field,
};
pub use interrupts::{InterruptLine, Interrupts, irq_check, parse_interrupts};
pub use kernel::{
    Preemption, PreemptionFinding, preemption, preemption_check, virtualisation_check,
};
pub use limits::{Privileges, memory_lock_check, sched_fifo_check, swap_check};

/// The largest file a check reads (`/proc/interrupts` of a machine with hundreds of CPUs is the
/// largest of them, a few MiB); the rest of a longer one is ignored.
const MAX_FILE_BYTES: u64 = 8 << 20;

/// A file tree read as if it were `/`.
#[derive(Debug, Clone)]
pub struct Tree {
    root: PathBuf,
}

impl Tree {
    pub fn new(root: impl Into<PathBuf>) -> Self {
        Self { root: root.into() }
    }

    /// The host's own files.
    pub fn host() -> Self {
        Self::new("/")
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Where `/rel` is in this tree.
    pub fn path(&self, rel: &str) -> PathBuf {
        self.root.join(rel.trim_start_matches('/'))
    }

    /// The text of `/rel` (lossy UTF-8, at most `MAX_FILE_BYTES`), or `None` when it is
    /// missing or unreadable.
    pub fn read(&self, rel: &str) -> Option<String> {
        let file = std::fs::File::open(self.path(rel)).ok()?;
        let mut bytes = Vec::new();
        file.take(MAX_FILE_BYTES).read_to_end(&mut bytes).ok()?;
        Some(String::from_utf8_lossy(&bytes).into_owned())
    }

    /// The text of the gzip file `/rel` once inflated (`/proc/config.gz`), at most
    /// `MAX_FILE_BYTES` of it, so a file that inflates without end costs no more than that;
    /// `None` when it is missing, unreadable or not gzip.
    pub fn read_gzip(&self, rel: &str) -> Option<String> {
        let file = std::fs::File::open(self.path(rel)).ok()?;
        let mut bytes = Vec::new();
        flate2::read::GzDecoder::new(file.take(MAX_FILE_BYTES))
            .take(MAX_FILE_BYTES)
            .read_to_end(&mut bytes)
            .ok()?;
        Some(String::from_utf8_lossy(&bytes).into_owned())
    }

    /// The first line of `/rel`, trimmed.
    pub fn read_line(&self, rel: &str) -> Option<String> {
        self.read(rel)
            .map(|t| t.lines().next().unwrap_or("").trim().to_owned())
    }

    /// The names in the directory `/rel`, sorted; empty when it cannot be listed.
    pub fn entries(&self, rel: &str) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(self.path(rel))
            .map(|dir| {
                dir.flatten()
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .collect()
            })
            .unwrap_or_default();
        names.sort();
        names
    }
}

/// Every file-based check, in the order they are printed, and the device checks.
pub fn inspect(tree: &Tree, plan: &LoopPlan, devices: &DeviceFacts) -> Vec<Check> {
    let privileges = Privileges::read(tree);
    let layout = CpuLayout::read(tree, plan);
    vec![
        preemption_check(tree),
        virtualisation_check(tree),
        sched_fifo_check(&privileges, plan),
        memory_lock_check(&privileges, plan),
        swap_check(tree, &privileges, plan),
        cpu_isolation_check(&layout),
        irq_check(tree, &layout),
        governor_check(tree, &layout),
        haptic_device_check(devices),
        hidraw_check(tree, &devices.spacemice),
        forcedimension_usb_check(tree),
    ]
}
