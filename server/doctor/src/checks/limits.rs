//! What the kernel lets the process do for the loop: real-time scheduling (the `rtprio` limit,
//! `CAP_SYS_NICE`, a cgroup's real-time budget), memory locking (the `memlock` limit,
//! `CAP_IPC_LOCK`), and swap, which matters only when the loop's memory cannot be locked.

use std::fmt::Write as _;

use softhaptic_device::rt::LOOP_PRIORITY;

use super::Tree;
use super::formats::{Limit, cgroup_v1_path, parse_limit, status_field};
use crate::{Check, LoopPlan, Verdict};

/// The real-time priority the fixes ask for: above the loop's own ([`LOOP_PRIORITY`]), leaving
/// room below the kernel's watchdogs.
const RTPRIO_FIX: i32 = 95;

/// Linux capability bits in `CapEff` (include/uapi/linux/capability.h).
const CAP_IPC_LOCK: u32 = 14;
const CAP_SYS_NICE: u32 = 23;

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

fn limits_conf_fix(p: &Privileges) -> String {
    let user = p.user_or_placeholder();
    format!(
        "add to /etc/security/limits.d/99-softhaptic.conf the lines `{user} - rtprio {RTPRIO_FIX}` \
         and `{user} - memlock unlimited`, then log in again (check with `ulimit -r -l`: \
         {RTPRIO_FIX} and unlimited); a systemd service ignores limits.conf: put \
         `LimitRTPRIO={RTPRIO_FIX}` and `LimitMEMLOCK=infinity` in its [Service] section \
         (docs/operating.md, \"The service\")"
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
