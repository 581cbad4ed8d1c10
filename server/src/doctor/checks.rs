//! The host inspections of `softhaptic doctor`: each reads its files through a [`Tree`] (the real
//! `/` or a copy of `/proc` and `/sys` fragments in a test) and returns a [`Check`]. Nothing here
//! writes anything or asks the kernel for more than a file read; an entry that is missing or
//! unreadable makes its part of a finding "unknown", never an error.

use std::collections::BTreeSet;
use std::fmt::Write as _;
use std::io::Read as _;
use std::path::{Path, PathBuf};

use softhaptic_device::rt::{CpuChoice, LOOP_PRIORITY};
use softhaptic_device::spacemouse::hid;

use super::{Check, LoopPlan, Verdict};

/// The largest file a check reads (`/proc/interrupts` of a machine with hundreds of CPUs is the
/// largest of them, a few MiB); the rest of a longer one is ignored.
const MAX_FILE_BYTES: u64 = 8 << 20;

/// The highest CPU number a CPU list may name: lists naming more are treated as damaged rather
/// than allocated.
const MAX_CPU: usize = 8191;

/// The real-time priority the fixes ask for: above the loop's own ([`LOOP_PRIORITY`]), leaving
/// room below the kernel's watchdogs.
const RTPRIO_FIX: i32 = 95;

/// Linux capability bits in `CapEff` (include/uapi/linux/capability.h).
const CAP_IPC_LOCK: u32 = 14;
const CAP_SYS_NICE: u32 = 23;

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

    /// The text of `/rel` (lossy UTF-8, at most [`MAX_FILE_BYTES`]), or `None` when it is
    /// missing or unreadable.
    pub fn read(&self, rel: &str) -> Option<String> {
        let file = std::fs::File::open(self.path(rel)).ok()?;
        let mut bytes = Vec::new();
        file.take(MAX_FILE_BYTES).read_to_end(&mut bytes).ok()?;
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

// ---------------------------------------------------------------------------------------------
// Parsers of the kernel's formats.

/// A kernel CPU list (`0-3,8,10-11`) as CPU numbers; `None` when a part is not a CPU or a range
/// of them. An empty list is an empty set.
pub fn parse_cpu_list(text: &str) -> Option<Vec<usize>> {
    let mut cpus = BTreeSet::new();
    for part in text.trim().split(',').map(str::trim) {
        if part.is_empty() {
            continue;
        }
        let (from, to) = match part.split_once('-') {
            Some((a, b)) => (a.parse().ok()?, b.parse().ok()?),
            None => {
                let n: usize = part.parse().ok()?;
                (n, n)
            }
        };
        if from > to || to > MAX_CPU {
            return None;
        }
        cpus.extend(from..=to);
    }
    Some(cpus.into_iter().collect())
}

/// CPU numbers written back as a kernel CPU list, runs as ranges.
pub fn format_cpu_list(cpus: &[usize]) -> String {
    let mut parts = Vec::new();
    let mut i = 0;
    while i < cpus.len() {
        let mut j = i;
        while j + 1 < cpus.len() && cpus[j + 1] == cpus[j] + 1 {
            j += 1;
        }
        parts.push(if i == j {
            cpus[i].to_string()
        } else {
            format!("{}-{}", cpus[i], cpus[j])
        });
        i = j + 1;
    }
    parts.join(",")
}

/// The value of the last `name=` on the kernel command line (before a ` -- `, after which the
/// arguments are init's).
pub fn kernel_param<'a>(cmdline: &'a str, name: &str) -> Option<&'a str> {
    cmdline
        .split_whitespace()
        .take_while(|w| *w != "--")
        .filter_map(|w| w.strip_prefix(name)?.strip_prefix('='))
        .last()
}

/// The CPUs of an `isolcpus=` value, whose flags (`nohz`, `domain`, `managed_irq`) come before
/// the list, comma-separated like it.
fn isolcpus_cpus(value: &str) -> Option<Vec<usize>> {
    let list: Vec<&str> = value
        .split(',')
        .filter(|p| p.starts_with(|c: char| c.is_ascii_digit()))
        .collect();
    parse_cpu_list(&list.join(","))
}

/// A value of `/proc/self/limits`: a number, or unlimited.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Limit {
    Value(u64),
    Unlimited,
}

impl Limit {
    fn parse(text: &str) -> Option<Limit> {
        if text == "unlimited" {
            Some(Limit::Unlimited)
        } else {
            text.parse().ok().map(Limit::Value)
        }
    }

    fn at_least(self, n: u64) -> bool {
        match self {
            Limit::Unlimited => true,
            Limit::Value(v) => v >= n,
        }
    }
}

impl std::fmt::Display for Limit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Limit::Unlimited => f.write_str("unlimited"),
            Limit::Value(v) => write!(f, "{v}"),
        }
    }
}

/// The soft and hard value of one limit of `/proc/self/limits` (the same numbers `getrlimit`
/// gives), e.g. `Max realtime priority`.
pub fn parse_limit(limits: &str, name: &str) -> Option<(Limit, Limit)> {
    let rest = limits.lines().find_map(|l| l.strip_prefix(name))?;
    let mut values = rest.split_whitespace();
    Some((Limit::parse(values.next()?)?, Limit::parse(values.next()?)?))
}

/// The value after `key:` in a `/proc/<pid>/status`-style file.
pub fn status_field<'a>(status: &'a str, key: &str) -> Option<&'a str> {
    status
        .lines()
        .find_map(|l| l.strip_prefix(key)?.strip_prefix(':'))
        .map(str::trim)
}

/// What the kernel lets this process do about real-time scheduling and memory locking.
#[derive(Debug, Clone, Default)]
pub struct Privileges {
    /// RLIMIT_RTPRIO, soft and hard.
    pub rtprio: Option<(Limit, Limit)>,
    /// RLIMIT_MEMLOCK in bytes, soft and hard.
    pub memlock: Option<(Limit, Limit)>,
    /// The effective capability set.
    pub cap_eff: Option<u64>,
    /// The user's name (from the real user id and `/etc/passwd`).
    pub user: Option<String>,
    /// `cpu.rt_runtime_us` of the process's cgroup when real-time group scheduling is on
    /// (cgroup v1) and the process is not in the root group: 0 refuses SCHED_FIFO to everyone
    /// in it, root included.
    pub rt_group: Option<(String, i64)>,
}

impl Privileges {
    pub fn read(tree: &Tree) -> Self {
        let limits = tree.read("/proc/self/limits").unwrap_or_default();
        let status = tree.read("/proc/self/status").unwrap_or_default();
        let cap_eff = status_field(&status, "CapEff").and_then(|v| u64::from_str_radix(v, 16).ok());
        let uid = status_field(&status, "Uid")
            .and_then(|v| v.split_whitespace().next())
            .and_then(|v| v.parse::<u32>().ok());
        let user = uid.and_then(|uid| {
            tree.read("/etc/passwd")?.lines().find_map(|l| {
                let mut f = l.split(':');
                let name = f.next()?;
                (f.nth(1)?.parse::<u32>().ok()? == uid).then(|| name.to_owned())
            })
        });
        Self {
            rtprio: parse_limit(&limits, "Max realtime priority"),
            memlock: parse_limit(&limits, "Max locked memory"),
            cap_eff,
            user,
            rt_group: rt_group_runtime(tree),
        }
    }

    fn has_cap(&self, bit: u32) -> Option<bool> {
        self.cap_eff.map(|c| c >> bit & 1 == 1)
    }

    /// Whether `pthread_setschedparam(SCHED_FIFO, priority)` would be granted; `None` when
    /// neither the limits nor the capabilities could be read.
    pub fn fifo_allowed(&self, priority: i32) -> Option<bool> {
        if matches!(self.rt_group, Some((_, 0))) {
            return Some(false);
        }
        let by_cap = self.has_cap(CAP_SYS_NICE);
        // The kernel checks the soft limit (the one a process may raise up to the hard one).
        let by_limit = self.rtprio.map(|(soft, _)| soft.at_least(priority as u64));
        match (by_cap, by_limit) {
            (Some(true), _) | (_, Some(true)) => Some(true),
            (None, None) => None,
            _ => Some(false),
        }
    }

    /// Whether `mlockall` of the whole process would be granted: CAP_IPC_LOCK, or an unlimited
    /// RLIMIT_MEMLOCK (a finite one is far below what the server maps).
    pub fn mlock_allowed(&self) -> Option<bool> {
        let by_cap = self.has_cap(CAP_IPC_LOCK);
        let by_limit = self.memlock.map(|(soft, _)| soft == Limit::Unlimited);
        match (by_cap, by_limit) {
            (Some(true), _) | (_, Some(true)) => Some(true),
            (None, None) => None,
            _ => Some(false),
        }
    }

    fn user_or_placeholder(&self) -> &str {
        self.user.as_deref().unwrap_or("<user>")
    }
}

/// The cgroup path of the process for the v1 controller `controller`, from `/proc/self/cgroup`.
fn cgroup_v1_path(tree: &Tree, controller: &str) -> Option<String> {
    tree.read("/proc/self/cgroup")?.lines().find_map(|l| {
        let mut f = l.splitn(3, ':');
        let (_, controllers, path) = (f.next()?, f.next()?, f.next()?);
        controllers
            .split(',')
            .any(|c| c == controller)
            .then(|| path.to_owned())
    })
}

/// The cgroup v2 path of the process (the `0::` line).
fn cgroup_v2_path(tree: &Tree) -> Option<String> {
    tree.read("/proc/self/cgroup")?
        .lines()
        .find_map(|l| l.strip_prefix("0::").map(str::to_owned))
}

fn rt_group_runtime(tree: &Tree) -> Option<(String, i64)> {
    let path = cgroup_v1_path(tree, "cpu")?;
    if path == "/" {
        return None;
    }
    ["cpu", "cpu,cpuacct", "cpuacct,cpu"]
        .iter()
        .find_map(|dir| {
            tree.read_line(&format!("/sys/fs/cgroup/{dir}{path}/cpu.rt_runtime_us"))?
                .parse()
                .ok()
        })
        .map(|runtime| (path, runtime))
}

// ---------------------------------------------------------------------------------------------
// The kernel's preemption model.

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

/// Reads the kernel's preemption model: `/sys/kernel/realtime`, debugfs's `sched/preempt` (root
/// only), `preempt=` on the command line of a PREEMPT_DYNAMIC kernel, the build configuration in
/// `/boot`, and the build flags in `/proc/version` (what `uname -v` shows).
pub fn preemption(tree: &Tree) -> PreemptionFinding {
    let version = tree.read("/proc/version").unwrap_or_default();
    let flags: BTreeSet<&str> = version.split_whitespace().collect();
    let release = tree
        .read_line("/proc/sys/kernel/osrelease")
        .filter(|r| !r.is_empty())
        .or_else(|| version.split_whitespace().nth(2).map(str::to_owned));
    let config = release
        .as_deref()
        .and_then(|r| tree.read(&format!("/boot/config-{r}")))
        .unwrap_or_default();
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
    if flags.contains("PREEMPT_RT") || configured("CONFIG_PREEMPT_RT") {
        return finding(Preemption::Rt, "/proc/version");
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
                "the build's default (/boot/config-*), no preempt= on the command line",
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
        return finding(mode, "/boot/config-*");
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

const GRUB_STEPS: &str = "in /etc/default/grub add it to GRUB_CMDLINE_LINUX, run `sudo update-grub` \
(Debian, Ubuntu) or `sudo grub2-mkconfig -o /boot/grub2/grub.cfg` (Fedora, RHEL), and reboot";

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
        Preemption::Unknown => (Verdict::Unknown, None),
        Preemption::Rt => (Verdict::Good, None),
        Preemption::Full | Preemption::Lazy => (Verdict::Good, None),
        Preemption::DynamicUnknown => {
            found.push_str(
                " (the mode is in /sys/kernel/debug/sched/preempt, readable by root only; no \
                 preempt= on the command line)",
            );
            (
                Verdict::Warn,
                Some(format!(
                    "boot with preempt=full to be sure of it: {GRUB_STEPS}; or {RT_KERNEL}. \
                     To read the mode now: `sudo cat /sys/kernel/debug/sched/preempt` (the one \
                     in parentheses)"
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

// ---------------------------------------------------------------------------------------------
// Virtualisation.

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

// ---------------------------------------------------------------------------------------------
// Real-time scheduling and memory locking.

fn limits_conf_fix(p: &Privileges) -> String {
    let user = p.user_or_placeholder();
    format!(
        "add to /etc/security/limits.d/99-softhaptic.conf the lines `{user} - rtprio {RTPRIO_FIX}` \
         and `{user} - memlock unlimited`, then log in again (check with `ulimit -r -l`: \
         {RTPRIO_FIX} and unlimited); a systemd service ignores limits.conf: put \
         `LimitRTPRIO={RTPRIO_FIX}` and `LimitMEMLOCK=infinity` in its [Service] section \
         (README, \"A device host\")"
    )
}

fn describe_privileges(p: &Privileges) -> String {
    let yes_no = |b: Option<bool>| match b {
        Some(true) => "yes",
        Some(false) => "no",
        None => "unknown",
    };
    let limit = |l: Option<(Limit, Limit)>| {
        l.map_or("unknown".to_owned(), |(s, h)| {
            if s == h {
                s.to_string()
            } else {
                format!("{s} (may be raised to {h})")
            }
        })
    };
    format!(
        "user {}: RLIMIT_RTPRIO {}, RLIMIT_MEMLOCK {} bytes, CAP_SYS_NICE {}, CAP_IPC_LOCK {}",
        p.user_or_placeholder(),
        limit(p.rtprio),
        limit(p.memlock),
        yes_no(p.has_cap(CAP_SYS_NICE)),
        yes_no(p.has_cap(CAP_IPC_LOCK)),
    )
}

pub fn sched_fifo_check(p: &Privileges, plan: &LoopPlan) -> Check {
    let why = "without SCHED_FIFO the loop thread competes with every ordinary thread for its \
               CPU; under load it waits behind them for milliseconds";
    let mut found = describe_privileges(p);
    if let Some((path, runtime)) = &p.rt_group {
        let _ = write!(found, "; cgroup {path} cpu.rt_runtime_us {runtime}");
    }
    if !plan.realtime {
        let _ = write!(
            found,
            "; real-time scheduling not requested (--no-realtime): the loop runs at normal priority"
        );
        return Check::new(
            "sched_fifo",
            "Real-time scheduling (SCHED_FIFO)",
            Verdict::Info,
            found,
            why,
            None,
        );
    }
    let title = "Real-time scheduling (SCHED_FIFO)";
    match p.fifo_allowed(LOOP_PRIORITY) {
        Some(true) => {
            let _ = write!(found, "; SCHED_FIFO priority {LOOP_PRIORITY} is permitted");
            Check::new("sched_fifo", title, Verdict::Good, found, why, None)
        }
        Some(false) => {
            let fix = match &p.rt_group {
                Some((path, 0)) => format!(
                    "the cgroup {path} is given no real-time time: set its cpu.rt_runtime_us \
                     (e.g. `echo 950000 | sudo tee /sys/fs/cgroup/cpu{path}/cpu.rt_runtime_us`) \
                     or start the server outside it"
                ),
                _ => limits_conf_fix(p),
            };
            let _ = write!(
                found,
                "; SCHED_FIFO priority {LOOP_PRIORITY} would be refused: the loop would run at \
                 normal priority, not as configured"
            );
            Check::new("sched_fifo", title, Verdict::Fail, found, why, Some(fix))
        }
        None => Check::new(
            "sched_fifo",
            title,
            Verdict::Unknown,
            found,
            why,
            Some(limits_conf_fix(p)),
        ),
    }
}

pub fn memory_lock_check(p: &Privileges, plan: &LoopPlan) -> Check {
    let why = "unlocked, a page of the loop's memory that the kernel reclaimed costs a page fault \
               on the next tick that touches it: tens of microseconds from memory, milliseconds \
               from disk";
    let title = "Memory locking (mlockall)";
    let mut found = match p.memlock {
        Some((soft, _)) => format!("RLIMIT_MEMLOCK {soft} bytes"),
        None => "RLIMIT_MEMLOCK unknown".to_owned(),
    };
    let _ = write!(
        found,
        ", CAP_IPC_LOCK {}",
        match p.has_cap(CAP_IPC_LOCK) {
            Some(true) => "yes",
            Some(false) => "no",
            None => "unknown",
        }
    );
    if !plan.realtime {
        found.push_str("; not requested (--no-realtime)");
        return Check::new("memory_lock", title, Verdict::Info, found, why, None);
    }
    match p.mlock_allowed() {
        Some(true) => {
            found.push_str("; the server's memory can be locked");
            Check::new("memory_lock", title, Verdict::Good, found, why, None)
        }
        Some(false) => {
            found.push_str(
                "; a finite limit is far below what the server maps, so mlockall would be refused",
            );
            Check::new(
                "memory_lock",
                title,
                Verdict::Warn,
                found,
                why,
                Some(limits_conf_fix(p)),
            )
        }
        None => Check::new(
            "memory_lock",
            title,
            Verdict::Unknown,
            found,
            why,
            Some(limits_conf_fix(p)),
        ),
    }
}

// ---------------------------------------------------------------------------------------------
// Swap.

pub fn swap_check(tree: &Tree, p: &Privileges, plan: &LoopPlan) -> Check {
    let why = "a page of the loop's memory swapped out costs milliseconds to read back, on the \
               tick that needs it";
    let title = "Swap";
    let Some(swaps) = tree.read("/proc/swaps") else {
        return Check::new(
            "swap",
            title,
            Verdict::Unknown,
            "unknown (no /proc/swaps)".into(),
            why,
            None,
        );
    };
    let areas: Vec<String> = swaps
        .lines()
        .skip(1)
        .filter_map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            let (name, kind) = (f.first()?, f.get(1)?);
            let size = f.get(2).and_then(|s| s.parse::<u64>().ok());
            Some(match size {
                Some(kib) => format!("{name} ({kind}, {:.1} GiB)", kib as f64 / (1 << 20) as f64),
                None => format!("{name} ({kind})"),
            })
        })
        .collect();
    if areas.is_empty() {
        return Check::new("swap", title, Verdict::Good, "off".into(), why, None);
    }
    let found = format!("on: {}", areas.join(", "));
    if plan.realtime && p.mlock_allowed() == Some(true) {
        return Check::new(
            "swap",
            title,
            Verdict::Good,
            format!("{found}; the loop's memory is locked, so it is never swapped out"),
            why,
            None,
        );
    }
    Check::new(
        "swap",
        title,
        Verdict::Warn,
        format!("{found}, and the loop's memory cannot be locked"),
        why,
        Some(format!(
            "let the server lock its memory ({}); or turn swap off: `sudo swapoff -a` and remove \
             the swap lines from /etc/fstab",
            limits_conf_fix(p)
        )),
    )
}

// ---------------------------------------------------------------------------------------------
// CPUs: isolation, the loop's CPU, its interrupts and its clock.

/// The CPUs of this machine and process, and where the loop would run.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct CpuLayout {
    pub online: Option<Vec<usize>>,
    /// The process's affinity (`Cpus_allowed_list`): where its threads start.
    pub allowed: Option<Vec<usize>>,
    /// The CPUs of the process's cpuset, where a thread may be bound.
    pub cpuset: Option<Vec<usize>>,
    /// CPUs kept free of the scheduler's balancing (`isolcpus=`, an isolated cpuset partition).
    pub isolated: Vec<usize>,
    pub nohz_full: Vec<usize>,
    /// The CPU the loop would be bound to, as configured.
    pub bound: Option<usize>,
    /// The CPU of the loop's standby thread.
    pub standby: Option<usize>,
    /// The CPU examined for interrupts and clock: the bound one, else the one to dedicate.
    pub loop_cpu: Option<usize>,
}

impl CpuLayout {
    pub fn read(tree: &Tree, plan: &LoopPlan) -> Self {
        let online = tree
            .read("/sys/devices/system/cpu/online")
            .and_then(|t| parse_cpu_list(&t));
        let allowed = tree
            .read("/proc/self/status")
            .and_then(|s| status_field(&s, "Cpus_allowed_list").and_then(parse_cpu_list));
        let cpuset = cpuset_cpus(tree);
        let cmdline = tree.read("/proc/cmdline").unwrap_or_default();
        let mut isolated: BTreeSet<usize> = match tree.read("/sys/devices/system/cpu/isolated") {
            Some(t) => parse_cpu_list(&t).unwrap_or_default().into_iter().collect(),
            None => kernel_param(&cmdline, "isolcpus")
                .and_then(isolcpus_cpus)
                .unwrap_or_default()
                .into_iter()
                .collect(),
        };
        if let Some(partition) = tree
            .read("/sys/fs/cgroup/cpuset.cpus.isolated")
            .and_then(|t| parse_cpu_list(&t))
        {
            isolated.extend(partition);
        }
        let nohz_full = tree
            .read("/sys/devices/system/cpu/nohz_full")
            .and_then(|t| parse_cpu_list(&t))
            .or_else(|| kernel_param(&cmdline, "nohz_full").and_then(parse_cpu_list))
            .unwrap_or_default();
        let usable = cpuset.clone().or_else(|| online.clone());
        let bound = match plan.cpu {
            CpuChoice::Index(n) => Some(n),
            CpuChoice::Last => allowed.as_ref().and_then(|a| a.last().copied()),
            CpuChoice::Auto if plan.realtime => allowed.as_ref().and_then(|a| a.last().copied()),
            CpuChoice::Auto | CpuChoice::Unpinned | CpuChoice::Except(_) => None,
        };
        // As `rt::standby_placement` places it: the first CPU of the process not the loop's.
        let standby = allowed
            .as_ref()
            .filter(|a| a.len() >= 2)
            .and_then(|a| a.iter().copied().find(|&c| Some(c) != bound));
        let loop_cpu = bound.or_else(|| {
            let usable = usable.as_ref()?;
            usable
                .iter()
                .copied()
                .find(|c| isolated.contains(c))
                .or_else(|| usable.last().copied())
        });
        Self {
            online,
            allowed,
            cpuset,
            isolated: isolated.into_iter().collect(),
            nohz_full,
            bound,
            standby,
            loop_cpu,
        }
    }

    /// The CPUs a thread may be bound to.
    fn usable(&self) -> Option<&Vec<usize>> {
        self.cpuset.as_ref().or(self.online.as_ref())
    }

    /// Every usable CPU but the loop's: where interrupts and other work should go.
    fn others(&self, cpu: usize) -> Vec<usize> {
        self.usable()
            .map(|u| u.iter().copied().filter(|&c| c != cpu).collect())
            .unwrap_or_default()
    }
}

/// The CPUs of the process's cpuset (cgroup v2 `cpuset.cpus.effective`, or v1 `cpuset.cpus`).
fn cpuset_cpus(tree: &Tree) -> Option<Vec<usize>> {
    let v2 = cgroup_v2_path(tree).and_then(|path| {
        let path = path.trim_end_matches('/');
        tree.read(&format!("/sys/fs/cgroup{path}/cpuset.cpus.effective"))
    });
    let v1 = || {
        let path = cgroup_v1_path(tree, "cpuset")?;
        let path = path.trim_end_matches('/');
        tree.read(&format!(
            "/sys/fs/cgroup/cpuset{path}/cpuset.effective_cpus"
        ))
        .or_else(|| tree.read(&format!("/sys/fs/cgroup/cpuset{path}/cpuset.cpus")))
    };
    v2.or_else(v1)
        .and_then(|t| parse_cpu_list(&t))
        .filter(|c| !c.is_empty())
}

fn list_or_unknown(cpus: Option<&Vec<usize>>) -> String {
    cpus.map_or("unknown".to_owned(), |c| format_cpu_list(c))
}

pub fn cpu_isolation_check(layout: &CpuLayout) -> Check {
    let title = "CPU isolation and the loop's CPU";
    let why = "on a shared CPU the loop waits behind other threads, the kernel's own work and \
               interrupts; a CPU kept for it (isolcpus, nohz_full, rcu_nocbs, interrupts moved \
               away) runs nothing else";
    let mut found = format!(
        "online CPUs {}, this process may use {}",
        list_or_unknown(layout.online.as_ref()),
        list_or_unknown(layout.allowed.as_ref()),
    );
    if let Some(cpuset) = &layout.cpuset {
        let _ = write!(found, " (cpuset {})", format_cpu_list(cpuset));
    }
    let _ = write!(
        found,
        "; isolated: {}; nohz_full: {}",
        if layout.isolated.is_empty() {
            "none".to_owned()
        } else {
            format_cpu_list(&layout.isolated)
        },
        if layout.nohz_full.is_empty() {
            "none".to_owned()
        } else {
            format_cpu_list(&layout.nohz_full)
        },
    );
    let standby = layout
        .standby
        .map_or(String::new(), |s| format!(", its standby on CPU {s}"));
    match layout.bound {
        Some(cpu) => {
            let _ = write!(found, "; the loop would be bound to CPU {cpu}{standby}");
        }
        None => {
            let _ = write!(
                found,
                "; the loop would run unbound (--loop-cpu none){}",
                if standby.is_empty() {
                    String::new()
                } else {
                    format!(" on any CPU but its standby's{standby}")
                }
            );
        }
    }
    let Some(usable) = layout.usable() else {
        return Check::new("cpu_isolation", title, Verdict::Unknown, found, why, None);
    };
    if let Some(cpu) = layout.bound
        && !usable.contains(&cpu)
    {
        return Check::new(
            "cpu_isolation",
            title,
            Verdict::Fail,
            format!("{found}; CPU {cpu} is not one this process can use"),
            why,
            Some(format!(
                "choose one of CPUs {} with --loop-cpu (or add CPU {cpu} to the process's \
                 cpuset)",
                format_cpu_list(usable)
            )),
        );
    }
    if usable.len() < 2 {
        return Check::new(
            "cpu_isolation",
            title,
            Verdict::Warn,
            format!("{found}; a single CPU: the loop shares it with everything and has no standby"),
            why,
            Some(
                "run the device host on a machine (or give the virtual machine) at least 2 CPUs, \
                 better 4: one for the loop, one for its standby, the rest for the server"
                    .into(),
            ),
        );
    }
    let Some(cpu) = layout.loop_cpu else {
        return Check::new("cpu_isolation", title, Verdict::Unknown, found, why, None);
    };
    let others = format_cpu_list(&layout.others(cpu));
    let isolated = layout.isolated.contains(&cpu);
    match (isolated, layout.bound == Some(cpu)) {
        (true, true) => Check::new("cpu_isolation", title, Verdict::Good, found, why, None),
        (true, false) => Check::new(
            "cpu_isolation",
            title,
            Verdict::Warn,
            format!("{found}; CPU {cpu} is isolated but the loop is not bound to it"),
            why,
            Some(format!("run the server with --loop-cpu {cpu}")),
        ),
        (false, _) => Check::new(
            "cpu_isolation",
            title,
            Verdict::Warn,
            format!("{found}; no CPU is kept for the loop"),
            why,
            Some(format!(
                "keep CPU {cpu} for the loop: boot with `isolcpus=managed_irq,domain,{cpu} \
                 nohz_full={cpu} rcu_nocbs={cpu} irqaffinity={others}` ({GRUB_STEPS}), then run \
                 the server with --loop-cpu {cpu} (a service: CPUAffinity={others}, which keeps \
                 the rest of the server off it, README \"A device host\")"
            )),
        ),
    }
}

/// One line of `/proc/interrupts`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InterruptLine {
    /// The IRQ number or the per-CPU kind (`LOC`, `RES`, …).
    pub irq: String,
    /// Count per CPU, in the order of [`Interrupts::cpus`].
    pub counts: Vec<u64>,
    /// The controller and the devices sharing it.
    pub description: String,
}

impl InterruptLine {
    /// The devices on the interrupt: what follows its trigger type (`edge`, `level`,
    /// `fasteoi`), else the whole description.
    pub fn device(&self) -> &str {
        let trigger = ["edge", "level", "fasteoi"];
        self.description
            .match_indices(' ')
            .map(|(i, _)| i)
            .rev()
            .find(|&i| {
                let before = self.description[..i].rsplit(' ').next().unwrap_or("");
                trigger
                    .iter()
                    .any(|t| before == *t || before.ends_with(&format!("-{t}")))
            })
            .map_or(&self.description, |i| self.description[i + 1..].trim())
    }
}

#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Interrupts {
    /// The CPU of each count column.
    pub cpus: Vec<usize>,
    pub lines: Vec<InterruptLine>,
}

/// Parses `/proc/interrupts`: a header of `CPUn` columns, then a line per interrupt.
pub fn parse_interrupts(text: &str) -> Interrupts {
    let mut lines = text.lines();
    let cpus: Vec<usize> = lines
        .next()
        .unwrap_or("")
        .split_whitespace()
        .filter_map(|w| w.strip_prefix("CPU")?.parse().ok())
        .collect();
    let lines = lines
        .filter_map(|l| {
            let (irq, rest) = l.split_once(':')?;
            let mut words = rest.split_whitespace().peekable();
            let mut counts = Vec::with_capacity(cpus.len());
            while counts.len() < cpus.len() {
                match words.peek().and_then(|w| w.parse::<u64>().ok()) {
                    Some(n) => {
                        counts.push(n);
                        words.next();
                    }
                    None => break,
                }
            }
            Some(InterruptLine {
                irq: irq.trim().to_owned(),
                counts,
                description: words.collect::<Vec<_>>().join(" "),
            })
        })
        .collect();
    Interrupts { cpus, lines }
}

/// The CPUs interrupt `irq` is delivered to (the effective affinity where the kernel publishes
/// it, else the allowed one).
fn irq_affinity(tree: &Tree, irq: &str) -> Option<Vec<usize>> {
    ["effective_affinity_list", "smp_affinity_list"]
        .iter()
        .find_map(|f| {
            tree.read(&format!("/proc/irq/{irq}/{f}"))
                .and_then(|t| parse_cpu_list(&t))
                .filter(|c| !c.is_empty())
        })
}

/// How many of the busiest interrupts on the loop's CPU are named.
const BUSIEST_SHOWN: usize = 5;

pub fn irq_check(tree: &Tree, layout: &CpuLayout) -> Check {
    let title = "Interrupts on the loop's CPU";
    let why = "each interrupt handled on the loop's CPU delays a tick that is due by the \
               handler's time, and a storage or network interrupt can bring softirq work of \
               hundreds of microseconds";
    let Some(cpu) = layout.loop_cpu else {
        return Check::new(
            "irq_affinity",
            title,
            Verdict::Unknown,
            "unknown (the loop's CPU is not known)".into(),
            why,
            None,
        );
    };
    let Some(text) = tree.read("/proc/interrupts") else {
        return Check::new(
            "irq_affinity",
            title,
            Verdict::Unknown,
            "unknown (no /proc/interrupts)".into(),
            why,
            None,
        );
    };
    let others = layout.others(cpu);
    if others.is_empty() {
        return Check::new(
            "irq_affinity",
            title,
            Verdict::Info,
            format!("CPU {cpu} is the only CPU: every interrupt is handled on it"),
            why,
            None,
        );
    }
    let table = parse_interrupts(&text);
    let Some(column) = table.cpus.iter().position(|&c| c == cpu) else {
        return Check::new(
            "irq_affinity",
            title,
            Verdict::Unknown,
            format!("unknown (CPU {cpu} has no column in /proc/interrupts)"),
            why,
            None,
        );
    };
    // Device interrupts (numbered) that were handled on the CPU and may still be sent there;
    // the per-CPU ones (timer, rescheduling, TLB shootdowns) cannot be moved.
    let mut busy: Vec<(u64, &InterruptLine)> = table
        .lines
        .iter()
        .filter(|l| l.irq.parse::<u32>().is_ok())
        .filter_map(|l| Some((*l.counts.get(column)?, l)))
        .filter(|(n, _)| *n > 0)
        .filter(|(_, l)| irq_affinity(tree, &l.irq).is_none_or(|a| a.contains(&cpu)))
        .collect();
    busy.sort_by_key(|b| std::cmp::Reverse(b.0));
    let watched = if layout.bound == Some(cpu) {
        format!("CPU {cpu} (the loop's)")
    } else {
        format!("CPU {cpu} (the one to keep for the loop)")
    };
    if busy.is_empty() {
        return Check::new(
            "irq_affinity",
            title,
            Verdict::Good,
            format!("{watched}: no device interrupt is sent to it"),
            why,
            None,
        );
    }
    let shown = &busy[..busy.len().min(BUSIEST_SHOWN)];
    let names: Vec<String> = shown
        .iter()
        .map(|(n, l)| format!("IRQ {} {} ({n} since boot)", l.irq, l.device()))
        .collect();
    let others = format_cpu_list(&others);
    let irqs: Vec<&str> = shown.iter().map(|(_, l)| l.irq.as_str()).collect();
    Check::new(
        "irq_affinity",
        title,
        Verdict::Warn,
        format!(
            "{watched}: {} device interrupt{} handled there and still sent to it; busiest: {}",
            busy.len(),
            if busy.len() == 1 { "" } else { "s" },
            names.join("; ")
        ),
        why,
        Some(format!(
            "move them now: `for irq in {}; do echo {others} | sudo tee \
             /proc/irq/$irq/smp_affinity_list; done`; to keep it so, boot with irqaffinity={others} and, where \
             irqbalance runs, add IRQBALANCE_BANNED_CPULIST={cpu} to /etc/default/irqbalance \
             (interrupts the kernel places itself, such as NVMe queues, follow \
             isolcpus=managed_irq,{cpu})",
            irqs.join(" ")
        )),
    )
}

pub fn governor_check(tree: &Tree, layout: &CpuLayout) -> Check {
    let title = "CPU frequency governor";
    let why = "a governor other than performance lowers the clock while the CPU idles between \
               ticks: the next tick then starts on a slow clock, and each frequency change can \
               stall the CPU for tens of microseconds";
    let cpus: Vec<usize> = layout
        .online
        .clone()
        .or_else(|| layout.loop_cpu.map(|c| vec![c]))
        .unwrap_or_default();
    let governors: Vec<(usize, String)> = cpus
        .iter()
        .filter_map(|&c| {
            tree.read_line(&format!(
                "/sys/devices/system/cpu/cpu{c}/cpufreq/scaling_governor"
            ))
            .filter(|g| !g.is_empty())
            .map(|g| (c, g))
        })
        .collect();
    if governors.is_empty() {
        return Check::new(
            "cpu_governor",
            title,
            Verdict::Info,
            "no cpufreq governor (the firmware or the hypervisor sets the clock)".into(),
            why,
            None,
        );
    }
    let distinct: BTreeSet<&str> = governors.iter().map(|(_, g)| g.as_str()).collect();
    let all = distinct.iter().copied().collect::<Vec<_>>().join(", ");
    let on_loop = layout
        .loop_cpu
        .and_then(|c| governors.iter().find(|(cpu, _)| *cpu == c));
    let (found, good) = match on_loop {
        Some((c, g)) => (
            format!("CPU {c}: {g} (all CPUs: {all})"),
            g == "performance",
        ),
        None => (
            format!("all CPUs: {all}"),
            distinct.len() == 1 && distinct.contains("performance"),
        ),
    };
    if good {
        return Check::new("cpu_governor", title, Verdict::Good, found, why, None);
    }
    Check::new(
        "cpu_governor",
        title,
        Verdict::Warn,
        found,
        why,
        Some(
            "`echo performance | sudo tee /sys/devices/system/cpu/cpu*/cpufreq/scaling_governor` \
             now; to keep it across reboots, `sudo cpupower frequency-set -g performance` at boot \
             (package linux-cpupower or kernel-tools, or a oneshot unit running it)"
                .into(),
        ),
    )
}

// ---------------------------------------------------------------------------------------------
// The haptic device.

/// What OpenHaptics gave on this machine, reduced to text.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum OpenHapticsFacts {
    NoLibrary(String),
    Library {
        path: PathBuf,
        /// Each configuration tried, with its description or why it did not open.
        devices: Vec<(String, Result<String, String>)>,
    },
}

/// The devices found on this machine (the live part of the inspection).
#[derive(Debug, Clone)]
pub struct DeviceFacts {
    pub openhaptics: OpenHapticsFacts,
    pub spacemice: hid::Listing,
}

pub fn haptic_device_check(facts: &DeviceFacts) -> Check {
    let title = "Haptic device";
    let why = "without a device that opens, the server can run only the simulated device";
    let mut parts = Vec::new();
    let mut opened = Vec::new();
    let mut refused = Vec::new();
    match &facts.openhaptics {
        OpenHapticsFacts::NoLibrary(e) => {
            // The loader's message lists every place looked, one per line; `softhaptic devices`
            // prints it whole.
            let first = e.lines().next().unwrap_or("").split("; looked in").next();
            parts.push(format!(
                "OpenHaptics: not available ({}; `softhaptic devices` lists where it was looked for)",
                first.unwrap_or("").trim()
            ));
        }
        OpenHapticsFacts::Library { path, devices } => {
            parts.push(format!("OpenHaptics library {}", path.display()));
            for (name, result) in devices {
                match result {
                    Ok(d) => opened.push(format!("{name:?}: {d}")),
                    Err(e) => refused.push(format!("{name:?} cannot be opened: {e}")),
                }
            }
        }
    }
    let mice_open: Vec<String> = facts
        .spacemice
        .found
        .iter()
        .filter(|f| f.opens.is_ok())
        .map(|f| {
            format!(
                "{} at {} (input only, renders no force)",
                f.model.unwrap_or("3Dconnexion device"),
                f.path
            )
        })
        .collect();
    let found = {
        let mut all = parts;
        all.extend(opened.iter().cloned());
        all.extend(refused.iter().cloned());
        all.push(if facts.spacemice.found.is_empty() {
            "SpaceMouse: none found".to_owned()
        } else if mice_open.is_empty() {
            "SpaceMouse: found, cannot be opened (see HID access)".to_owned()
        } else {
            format!("SpaceMouse: {}", mice_open.join(", "))
        });
        all.join("; ")
    };
    if !opened.is_empty() || !mice_open.is_empty() {
        return Check::new("haptic_device", title, Verdict::Good, found, why, None);
    }
    let fix = if refused.is_empty() {
        "install the device driver and OpenHaptics (README, \"A real haptic device\"), or set \
         SOFTHAPTIC_HD_LIBRARY to its libHD.so; or plug in a SpaceMouse (input only). `softhaptic \
         devices` lists what is found"
    } else {
        "connect and power the device, check it in the vendor's Touch_Diagnostic, let your user \
         open it (`ls -l /dev/ttyACM*`: the dialout group or a udev rule, README \"A real haptic \
         device\"); a running softhaptic server holds the device, stop it before this check"
    };
    Check::new(
        "haptic_device",
        title,
        Verdict::Warn,
        found,
        why,
        Some(fix.into()),
    )
}

pub fn hidraw_check(tree: &Tree, spacemice: &hid::Listing) -> Check {
    let title = "HID access (/dev/hidraw*)";
    let why = "a SpaceMouse is read through /dev/hidraw*, which by default only root may open";
    let nodes: Vec<String> = tree
        .entries("/dev")
        .into_iter()
        .filter(|n| n.starts_with("hidraw"))
        .collect();
    let readable: Vec<&String> = nodes
        .iter()
        .filter(|n| std::fs::File::open(tree.path(&format!("/dev/{n}"))).is_ok())
        .collect();
    let refused_mice: Vec<&hid::Found> = spacemice
        .found
        .iter()
        .filter(|f| f.opens.is_err())
        .collect();
    let udev = hid::udev_hint().replace('\n', " ");
    let udev = udev.split_whitespace().collect::<Vec<_>>().join(" ");
    if !refused_mice.is_empty() {
        let names: Vec<String> = refused_mice
            .iter()
            .map(|f| {
                format!(
                    "{} at {}: {}",
                    f.model.unwrap_or("3Dconnexion device"),
                    f.path,
                    f.opens.as_ref().err().map_or("", String::as_str)
                )
            })
            .collect();
        return Check::new(
            "hidraw",
            title,
            Verdict::Warn,
            format!("a SpaceMouse that cannot be opened: {}", names.join("; ")),
            why,
            Some(udev),
        );
    }
    if nodes.is_empty() {
        return Check::new(
            "hidraw",
            title,
            Verdict::Info,
            "no /dev/hidraw* nodes: no HID device is plugged in".into(),
            why,
            None,
        );
    }
    if readable.is_empty() {
        return Check::new(
            "hidraw",
            title,
            Verdict::Info,
            format!(
                "{} node{}, none readable by this user; only a SpaceMouse needs them",
                nodes.len(),
                if nodes.len() == 1 { "" } else { "s" }
            ),
            why,
            Some(format!("before using a SpaceMouse, {udev}")),
        );
    }
    Check::new(
        "hidraw",
        title,
        Verdict::Good,
        format!(
            "{} of {} nodes readable by this user",
            readable.len(),
            nodes.len()
        ),
        why,
        None,
    )
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
    ]
}
