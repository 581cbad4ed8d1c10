//! The running kernel: its preemption model (how soon a waking real-time thread gets its CPU)
//! and whether it runs in a virtual machine, whose host can take the CPU away (steal time).

use std::collections::BTreeSet;
use std::fmt::Write as _;

use super::Tree;
use super::formats::kernel_param;
use crate::{Check, Verdict};

/// How the running kernel lets a waking real-time thread take its CPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Preemption {
    /// PREEMPT_RT: nearly all kernel code preemptible, interrupts in threads.
    Rt,
    /// Fully preemptible (`preempt=full`, CONFIG_PREEMPT).
    Full,
    /// Lazy preemption: ordinary threads are preempted at the next tick, real-time ones at once.
    Lazy,
    /// Preemption only at the kernel's explicit rescheduling points.
    Voluntary,
    /// No preemption in the kernel.
    None,
    /// A kernel built with no preemption or voluntary preemption: `/proc/version` says the same
    /// for both and the build configuration is not readable.
    NoneOrVoluntary,
    /// PREEMPT_DYNAMIC, and the mode chosen at boot could not be read.
    DynamicUnknown,
    /// Nothing about the kernel could be read.
    Unknown,
}

impl Preemption {
    fn from_name(name: &str) -> Option<Preemption> {
        Some(match name {
            "rt" => Preemption::Rt,
            "full" => Preemption::Full,
            "lazy" => Preemption::Lazy,
            "voluntary" => Preemption::Voluntary,
            "none" => Preemption::None,
            _ => return None,
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            Preemption::Rt => "PREEMPT_RT",
            Preemption::Full => "full (preempt=full)",
            Preemption::Lazy => "lazy (preempt=lazy)",
            Preemption::Voluntary => "voluntary (preempt=voluntary)",
            Preemption::None => "none (preempt=none)",
            Preemption::NoneOrVoluntary => "none or voluntary",
            Preemption::DynamicUnknown => "PREEMPT_DYNAMIC, mode unknown",
            Preemption::Unknown => "unknown",
        }
    }
}

/// The model the kernel runs, how it was told, and whether it can be changed at boot.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PreemptionFinding {
    pub model: Preemption,
    /// Where it was read.
    pub source: String,
    /// PREEMPT_DYNAMIC: `preempt=` on the command line chooses the model.
    pub dynamic: bool,
    pub release: Option<String>,
}

/// Where the running kernel's build configuration was read, and its text.
struct BuildConfig {
    source: String,
    text: String,
}

/// The running kernel's build configuration: `/proc/config.gz` first, the kernel's own copy
/// (CONFIG_IKCONFIG_PROC), which is always the running kernel's and is often the only one on a
/// machine without a `/boot` of its own (a virtual machine booted by its host, a container);
/// else `/boot/config-<release>`, installed beside the kernel by distributions' packages.
fn build_config(tree: &Tree, release: Option<&str>) -> Option<BuildConfig> {
    let proc = "/proc/config.gz";
    tree.read_gzip(proc)
        .map(|text| BuildConfig {
            source: proc.to_owned(),
            text,
        })
        .or_else(|| {
            let boot = format!("/boot/config-{}", release?);
            tree.read(&boot)
                .map(|text| BuildConfig { source: boot, text })
        })
}

/// Reads the kernel's preemption model: `/sys/kernel/realtime`, debugfs's `sched/preempt` (root
/// only), `preempt=` on the command line of a PREEMPT_DYNAMIC kernel, the build configuration
/// (`/proc/config.gz` or `/boot/config-<release>`), and the build flags in `/proc/version` (what
/// `uname -v` shows).
pub fn preemption(tree: &Tree) -> PreemptionFinding {
    let version = tree.read("/proc/version").unwrap_or_default();
    let flags: BTreeSet<&str> = version.split_whitespace().collect();
    let release = tree
        .read_line("/proc/sys/kernel/osrelease")
        .filter(|r| !r.is_empty())
        .or_else(|| version.split_whitespace().nth(2).map(str::to_owned));
    let build = build_config(tree, release.as_deref());
    let (config, config_source) = build.as_ref().map_or(("", "no build configuration"), |b| {
        (b.text.as_str(), b.source.as_str())
    });
    let configured = |option: &str| config.lines().any(|l| l == format!("{option}=y"));
    let dynamic = flags.contains("PREEMPT_DYNAMIC") || configured("CONFIG_PREEMPT_DYNAMIC");
    let finding = |model, source: &str| PreemptionFinding {
        model,
        source: source.to_owned(),
        dynamic,
        release: release.clone(),
    };

    if tree.read_line("/sys/kernel/realtime").as_deref() == Some("1") {
        return finding(Preemption::Rt, "/sys/kernel/realtime");
    }
    if flags.contains("PREEMPT_RT") {
        return finding(Preemption::Rt, "/proc/version");
    }
    if configured("CONFIG_PREEMPT_RT") {
        return finding(Preemption::Rt, config_source);
    }
    // debugfs lists the modes with the current one in parentheses: `none voluntary (full) lazy`.
    if let Some(mode) = tree.read("/sys/kernel/debug/sched/preempt").and_then(|m| {
        m.split_whitespace()
            .find(|w| w.starts_with('('))
            .and_then(|w| Preemption::from_name(w.trim_matches(['(', ')'])))
    }) {
        return finding(mode, "/sys/kernel/debug/sched/preempt");
    }
    if dynamic {
        let cmdline = tree.read("/proc/cmdline").unwrap_or_default();
        if let Some(mode) = kernel_param(&cmdline, "preempt").and_then(Preemption::from_name) {
            return finding(mode, "preempt= on the kernel command line (/proc/cmdline)");
        }
        // Without preempt=, the model chosen when the kernel was built is the boot default.
        if let Some(mode) = build_choice(&configured) {
            return finding(
                mode,
                &format!("the build's default ({config_source}), no preempt= on the command line"),
            );
        }
        return finding(Preemption::DynamicUnknown, "/proc/version");
    }
    if flags.contains("PREEMPT_LAZY") {
        return finding(Preemption::Lazy, "/proc/version");
    }
    if flags.contains("PREEMPT") {
        return finding(Preemption::Full, "/proc/version");
    }
    if let Some(mode) = build_choice(&configured) {
        return finding(mode, config_source);
    }
    if version.is_empty() {
        return finding(Preemption::Unknown, "nothing (no /proc/version)");
    }
    finding(
        Preemption::NoneOrVoluntary,
        "/proc/version (no PREEMPT flag)",
    )
}

fn build_choice(configured: &dyn Fn(&str) -> bool) -> Option<Preemption> {
    [
        ("CONFIG_PREEMPT", Preemption::Full),
        ("CONFIG_PREEMPT_LAZY", Preemption::Lazy),
        ("CONFIG_PREEMPT_VOLUNTARY", Preemption::Voluntary),
        ("CONFIG_PREEMPT_NONE", Preemption::None),
    ]
    .into_iter()
    .find_map(|(option, mode)| configured(option).then_some(mode))
}

pub(super) const GRUB_STEPS: &str = "in /etc/default/grub add it to GRUB_CMDLINE_LINUX, run `sudo update-grub` \
(Debian, Ubuntu) or `sudo grub2-mkconfig -o /boot/grub2/grub.cfg` (Fedora, RHEL), and reboot";

/// How to read the mode a PREEMPT_DYNAMIC kernel runs in when the doctor could not.
const READ_DYNAMIC_MODE: &str = "`sudo dmesg | grep 'Dynamic Preempt'` (the kernel logs the \
mode at boot, while its log still holds the line), or `sudo cat /sys/kernel/debug/sched/preempt` \
(the mode in parentheses), mounting debugfs first when that directory is empty: `sudo mount -t \
debugfs none /sys/kernel/debug`";

const RT_KERNEL: &str = "install a PREEMPT_RT kernel (Debian: `sudo apt install \
linux-image-rt-amd64`; Ubuntu: `sudo pro enable realtime-kernel`; Fedora/RHEL: kernel-rt) and boot it";

pub fn preemption_check(tree: &Tree) -> Check {
    let f = preemption(tree);
    let kernel = f
        .release
        .as_deref()
        .map_or_else(|| "the kernel".to_owned(), |r| format!("kernel {r}"));
    let dynamic = if f.dynamic && f.model != Preemption::DynamicUnknown {
        ", chosen at boot (PREEMPT_DYNAMIC)"
    } else {
        ""
    };
    let mut found = format!(
        "{kernel}: {}{dynamic}, read from {}",
        f.model.name(),
        f.source
    );
    let why = "with preemption none or voluntary, a thread in a long system call (writing a large \
               file, freeing a large heap) keeps its CPU until it reaches a rescheduling point, up \
               to milliseconds: the loop is woken on time and runs only then, a lost tick that no \
               priority prevents";
    let (verdict, fix) = match f.model {
        Preemption::Unknown => (
            Verdict::Unknown,
            Some(format!(
                "to name it: `uname -v` shows the build's flags (PREEMPT_RT, PREEMPT, \
                 PREEMPT_DYNAMIC) and {READ_DYNAMIC_MODE}"
            )),
        ),
        Preemption::Rt => (Verdict::Good, None),
        Preemption::Full | Preemption::Lazy => (Verdict::Good, None),
        Preemption::DynamicUnknown => {
            found.push_str(
                " (no preempt= on the command line, no build configuration naming it in \
                 /proc/config.gz or /boot, and debugfs's sched/preempt not readable: it is \
                 mounted and read by root only)",
            );
            (
                Verdict::Warn,
                Some(format!(
                    "boot with preempt=full to be sure of it: {GRUB_STEPS}; or {RT_KERNEL}. \
                     To read the mode now: {READ_DYNAMIC_MODE}"
                )),
            )
        }
        Preemption::Voluntary | Preemption::None | Preemption::NoneOrVoluntary => {
            let fix = if f.dynamic {
                format!("boot with preempt=full: {GRUB_STEPS}; or {RT_KERNEL}")
            } else {
                format!(
                    "this kernel cannot be made preemptible at boot: {RT_KERNEL}, or a kernel \
                     built with PREEMPT_DYNAMIC and boot it with preempt=full"
                )
            };
            (Verdict::Warn, Some(fix))
        }
    };
    Check::new(
        "preemption",
        "Kernel preemption model",
        verdict,
        found,
        why,
        fix,
    )
}

/// Steal time since boot as a fraction of all CPU time (`/proc/stat`'s first line).
fn steal_fraction(stat: &str) -> Option<f64> {
    let line = stat.lines().find(|l| l.starts_with("cpu "))?;
    let v: Vec<u64> = line
        .split_whitespace()
        .skip(1)
        .filter_map(|x| x.parse().ok())
        .collect();
    let total: u64 = v.iter().take(8).sum();
    (v.len() >= 8 && total > 0).then(|| v[7] as f64 / total as f64)
}

pub fn virtualisation_check(tree: &Tree) -> Check {
    let why = "the hypervisor schedules the virtual CPUs among its own work: while it runs \
               something else, every thread of the guest waits, the loop included, and no \
               setting inside the guest reaches that";
    let Some(cpuinfo) = tree.read("/proc/cpuinfo") else {
        return Check::new(
            "virtualisation",
            "Virtual machine",
            Verdict::Unknown,
            "unknown (no /proc/cpuinfo)".into(),
            why,
            None,
        );
    };
    let vm = cpuinfo
        .lines()
        .filter(|l| l.starts_with("flags") || l.starts_with("Features"))
        .any(|l| l.split_whitespace().any(|w| w == "hypervisor"));
    if !vm {
        return Check::new(
            "virtualisation",
            "Virtual machine",
            Verdict::Good,
            "no: runs on the hardware (no hypervisor flag in /proc/cpuinfo)".into(),
            why,
            None,
        );
    }
    let product = [
        "/sys/class/dmi/id/sys_vendor",
        "/sys/class/dmi/id/product_name",
    ]
    .iter()
    .filter_map(|p| tree.read_line(p).filter(|v| !v.is_empty()))
    .collect::<Vec<_>>()
    .join(" ");
    let mut found = "yes (hypervisor flag in /proc/cpuinfo)".to_owned();
    if !product.is_empty() {
        let _ = write!(found, ": {product}");
    }
    if let Some(steal) = tree.read("/proc/stat").as_deref().and_then(steal_fraction) {
        let _ = write!(
            found,
            "; steal time since boot {:.2} % of CPU time",
            steal * 100.0
        );
    }
    Check::new(
        "virtualisation",
        "Virtual machine",
        Verdict::Warn,
        found,
        why,
        Some(
            "run the device host on the hardware; if it must be a virtual machine, give each \
             virtual CPU a host CPU of its own (libvirt `<vcpupin>`, Proxmox `affinity`), keep \
             other guests and the host's work off those CPUs, and use a PREEMPT_RT kernel on \
             the host too"
                .into(),
        ),
    )
}
