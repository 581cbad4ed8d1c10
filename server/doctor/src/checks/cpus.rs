//! The CPUs: which are online, allowed and isolated, where the loop would run
//! ([`CpuLayout`]), whether that CPU is kept for it, and its frequency governor.

use std::collections::BTreeSet;
use std::fmt::Write as _;

use softhaptic_device::rt::CpuChoice;

use super::Tree;
use super::formats::{
    cgroup_v1_path, cgroup_v2_path, format_cpu_list, isolcpus_cpus, kernel_param, parse_cpu_list,
    status_field,
};
use super::kernel::GRUB_STEPS;
use crate::{Check, LoopPlan, Verdict};

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
    pub(super) fn others(&self, cpu: usize) -> Vec<usize> {
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
                 the rest of the server off it, docs/operating.md \"A device host\")"
            )),
        ),
    }
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
