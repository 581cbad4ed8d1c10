//! What `softhaptic doctor` predicts for a stock distribution kernel, run as `softhaptic run`
//! runs the loop by default (real time, `--loop-cpu none`): the verdict of every item on the
//! unit tests' `stock` fixture, and which of them any host with such a kernel must give too.
//!
//! Two tests read this table: the unit tests (`tests.rs`) hold the `stock` fixture to every row,
//! and the end-to-end test (`server/tests/doctor_cli.rs`) holds the machine it runs on to the
//! rows that do not depend on the machine, whenever that machine's kernel preempts none or
//! voluntary. Both include this file by its path, so it is plain data with no path into the
//! crate: the verdicts are spelled as the JSON report spells them.

/// One item's verdict on the `stock` fixture.
pub struct StockVerdict {
    /// The check's id, as in the report.
    pub id: &'static str,
    /// Its verdict, as the JSON report spells it (`good`, `info`, `unknown`, `warn`, `fail`).
    pub verdict: &'static str,
    /// What on another stock host may give another verdict; `None` when every host whose kernel
    /// preempts none or voluntary gives this one.
    pub depends_on: Option<&'static str>,
}

/// The names the preemption item gives a kernel that preempts none or voluntary (the `stock`
/// fixture's is the second): a host whose report names one of them is a stock kernel here.
pub const STOCK_PREEMPTION_NAMES: [&str; 3] = [
    "none (preempt=none)",
    "voluntary (preempt=voluntary)",
    "none or voluntary",
];

/// Every item of the report on the `stock` fixture, in the order they are printed.
pub const STOCK_VERDICTS: [StockVerdict; 11] = [
    StockVerdict {
        id: "preemption",
        verdict: "warn",
        // What makes a kernel stock here: its model is the verdict.
        depends_on: None,
    },
    StockVerdict {
        id: "virtualisation",
        verdict: "good",
        depends_on: Some("whether the host is a virtual machine"),
    },
    StockVerdict {
        id: "sched_fifo",
        verdict: "fail",
        depends_on: Some("the user's rtprio limit and capabilities (root, a service's limits)"),
    },
    StockVerdict {
        id: "memory_lock",
        verdict: "warn",
        depends_on: Some("the user's memlock limit and CAP_IPC_LOCK"),
    },
    StockVerdict {
        id: "swap",
        verdict: "warn",
        depends_on: Some("whether swap is on, and whether memory can be locked"),
    },
    StockVerdict {
        id: "cpu_isolation",
        verdict: "warn",
        // With the loop unbound no CPU is kept for it, isolated CPUs or not: a warning on any
        // host whose CPUs can be read.
        depends_on: None,
    },
    StockVerdict {
        id: "irq_affinity",
        verdict: "warn",
        depends_on: Some("which interrupts the host's devices send to its last CPU"),
    },
    StockVerdict {
        id: "cpu_governor",
        verdict: "warn",
        depends_on: Some("the governor set, or none where the hypervisor sets the clock"),
    },
    StockVerdict {
        id: "haptic_device",
        verdict: "warn",
        depends_on: Some("whether OpenHaptics or a SpaceMouse is installed"),
    },
    StockVerdict {
        id: "hidraw",
        verdict: "info",
        depends_on: Some("whether a HID device is plugged in, and who may open it"),
    },
    StockVerdict {
        id: "forcedimension_usb",
        verdict: "info",
        depends_on: Some("whether a Force Dimension device or Falcon is plugged in"),
    },
];
