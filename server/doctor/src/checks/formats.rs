//! The kernel's file formats that more than one check reads: CPU lists, the kernel command line,
//! `/proc/self/limits`, `/proc/<pid>/status` fields, and the process's cgroup paths.

use std::collections::BTreeSet;

use super::Tree;

/// The highest CPU number a CPU list may name: lists naming more are treated as damaged rather
/// than allocated.
const MAX_CPU: usize = 8191;

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
pub(super) fn isolcpus_cpus(value: &str) -> Option<Vec<usize>> {
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

    pub(super) fn at_least(self, n: u64) -> bool {
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

/// The cgroup path of the process for the v1 controller `controller`, from `/proc/self/cgroup`.
pub(super) fn cgroup_v1_path(tree: &Tree, controller: &str) -> Option<String> {
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
pub(super) fn cgroup_v2_path(tree: &Tree) -> Option<String> {
    tree.read("/proc/self/cgroup")?
        .lines()
        .find_map(|l| l.strip_prefix("0::").map(str::to_owned))
}
