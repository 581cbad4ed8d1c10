//! The interrupts still delivered to the loop's CPU: `/proc/interrupts` parsed, each busy
//! interrupt's affinity read, and the commands that move them elsewhere.
//!
//! Not every interrupt can be moved by hand: the kernel spreads the queues of multi-queue
//! devices (NVMe and virtio disks, many network cards) over the CPUs itself, and refuses a write
//! to their `smp_affinity_list` with EIO. Only debugfs (`/sys/kernel/debug/irq/irqs/N`, root)
//! says which interrupts those are; `/proc/irq/N` looks the same for both kinds (the effective
//! affinity is a subset of the allowed one either way). So the fix names the managed ones where
//! debugfs is readable, and otherwise says what a refused write means.

use std::fmt::Write as _;

use super::Tree;
use super::cpus::CpuLayout;
use super::formats::{format_cpu_list, parse_cpu_list};
use crate::{Check, Verdict};

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

/// Whether the kernel manages the affinity of interrupt `irq` itself (debugfs's
/// `IRQD_AFFINITY_MANAGED` flag); `None` when debugfs cannot be read.
fn irq_managed(tree: &Tree, irq: &str) -> Option<bool> {
    tree.read(&format!("/sys/kernel/debug/irq/irqs/{irq}"))
        .map(|t| t.split_whitespace().any(|w| w == "IRQD_AFFINITY_MANAGED"))
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
    let managed: Vec<Option<bool>> = shown
        .iter()
        .map(|(_, l)| irq_managed(tree, &l.irq))
        .collect();
    let names: Vec<String> = shown
        .iter()
        .zip(&managed)
        .map(|((n, l), m)| {
            format!(
                "IRQ {} {} ({n} since boot{})",
                l.irq,
                l.device(),
                if *m == Some(true) {
                    ", kernel-managed"
                } else {
                    ""
                }
            )
        })
        .collect();
    let others = format_cpu_list(&others);
    let irqs_where = |want: &dyn Fn(Option<bool>) -> bool| -> Vec<&str> {
        shown
            .iter()
            .zip(&managed)
            .filter(|(_, m)| want(**m))
            .map(|((_, l), _)| l.irq.as_str())
            .collect()
    };
    let movable = irqs_where(&|m| m != Some(true));
    let kernel_managed = irqs_where(&|m| m == Some(true));
    let mut fix = String::new();
    if !movable.is_empty() {
        let _ = write!(
            fix,
            "move them now: `for irq in {}; do echo {others} | sudo tee \
             /proc/irq/$irq/smp_affinity_list; done`; ",
            movable.join(" ")
        );
    }
    if !kernel_managed.is_empty() {
        let (are, them) = if kernel_managed.len() == 1 {
            ("is", "it")
        } else {
            ("are", "them")
        };
        let _ = write!(
            fix,
            "IRQ {} {are} managed by the kernel, which refuses a new affinity for {them} (EIO): \
             boot with isolcpus=managed_irq,{cpu} to keep {them} off CPU {cpu}; ",
            kernel_managed.join(", "),
        );
    }
    let _ = write!(
        fix,
        "to keep it so, boot with irqaffinity={others} and, where irqbalance runs, add \
         IRQBALANCE_BANNED_CPULIST={cpu} to /etc/default/irqbalance"
    );
    if managed.contains(&None) && !movable.is_empty() {
        let _ = write!(
            fix,
            ". A write refused with `Input/output error` is an interrupt the kernel manages \
             itself (the queues of NVMe and virtio disks, multi-queue network cards): it cannot \
             be moved by hand and follows isolcpus=managed_irq,{cpu} at boot (debugfs's \
             /sys/kernel/debug/irq/irqs/N lists IRQD_AFFINITY_MANAGED for those)"
        );
    } else if kernel_managed.is_empty() {
        let _ = write!(
            fix,
            " (interrupts the kernel places itself, such as NVMe queues, follow \
             isolcpus=managed_irq,{cpu})"
        );
    }
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
        Some(fix),
    )
}
