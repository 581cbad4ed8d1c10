//! The doctor's verdicts and fixes on fixture trees: fragments of `/proc` and `/sys` as a stock
//! distribution kernel, a PREEMPT_RT kernel with an isolated CPU, and a container without
//! real-time permissions show them.
//!
//! # Why one file
//! About 800 lines: three fixtures and the tests that read them. Each test asserts one check's
//! verdicts and fix texts on the same fixtures, so a fixture and all that is predicted of it
//! are read in one place; split by check, every file would need the fixtures too.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use softhaptic_device::rt::CpuChoice;
use softhaptic_device::spacemouse::hid;

use super::checks::*;
use super::*;

#[path = "stock_verdicts.rs"]
mod stock_verdicts;
use stock_verdicts::{STOCK_PREEMPTION_NAMES, STOCK_VERDICTS};

/// A fake root directory.
struct Fixture {
    dir: tempfile::TempDir,
}

impl Fixture {
    fn empty() -> Self {
        Self {
            dir: tempfile::tempdir().unwrap(),
        }
    }

    fn file(&self, rel: &str, text: &str) -> &Self {
        let path = self.dir.path().join(rel.trim_start_matches('/'));
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, text).unwrap();
        self
    }

    /// `/rel` as gzip holds `text`, as the kernel publishes `/proc/config.gz`.
    fn gzip_file(&self, rel: &str, text: &str) -> &Self {
        use std::io::Write as _;
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        gz.write_all(text.as_bytes()).unwrap();
        self.file_bytes(rel, &gz.finish().unwrap())
    }

    fn file_bytes(&self, rel: &str, bytes: &[u8]) -> &Self {
        let path = self.dir.path().join(rel.trim_start_matches('/'));
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, bytes).unwrap();
        self
    }

    fn remove(&self, rel: &str) -> &Self {
        let _ = std::fs::remove_file(self.dir.path().join(rel.trim_start_matches('/')));
        self
    }

    fn tree(&self) -> Tree {
        Tree::new(self.dir.path())
    }

    /// A desktop distribution's kernel on 4 CPUs: PREEMPT_DYNAMIC booted without `preempt=`,
    /// its build default voluntary, a user without real-time limits, no isolation, the
    /// powersave governor, swap on, a disk interrupt on every CPU.
    fn stock() -> Self {
        let f = Self::empty();
        f.file(
            "/proc/version",
            "Linux version 6.8.0-45-generic (buildd@lcy02-amd64-115) (gcc 13.2.0) #45-Ubuntu SMP PREEMPT_DYNAMIC Fri Aug 30 12:02:04 UTC 2024\n",
        )
        .file("/proc/sys/kernel/osrelease", "6.8.0-45-generic\n")
        .file(
            "/boot/config-6.8.0-45-generic",
            "CONFIG_PREEMPT_BUILD=y\n# CONFIG_PREEMPT_NONE is not set\nCONFIG_PREEMPT_VOLUNTARY=y\nCONFIG_PREEMPT_DYNAMIC=y\n",
        )
        .file(
            "/proc/cmdline",
            "BOOT_IMAGE=/vmlinuz-6.8.0-45-generic root=UUID=1234 ro quiet splash\n",
        )
        .file(
            "/proc/self/limits",
            "Limit                     Soft Limit           Hard Limit           Units     \n\
             Max cpu time              unlimited            unlimited            seconds   \n\
             Max locked memory         8388608              8388608              bytes     \n\
             Max realtime priority     0                    0                    \n\
             Max realtime timeout      unlimited            unlimited            us        \n",
        )
        .file(
            "/proc/self/status",
            "Name:\tsofthaptic\nUid:\t1000\t1000\t1000\t1000\nCapEff:\t0000000000000000\nCpus_allowed_list:\t0-3\n",
        )
        .file("/proc/self/cgroup", "0::/user.slice/user-1000.slice/session-2.scope\n")
        .file(
            "/etc/passwd",
            "root:x:0:0:root:/root:/bin/bash\nlab:x:1000:1000:Lab:/home/lab:/bin/bash\n",
        )
        .file("/sys/devices/system/cpu/online", "0-3\n")
        .file("/sys/devices/system/cpu/isolated", "\n")
        .file(
            "/proc/swaps",
            "Filename\t\t\t\tType\t\tSize\t\tUsed\t\tPriority\n/swap.img                               file\t\t2097148\t\t0\t\t-2\n",
        )
        .file(
            "/proc/interrupts",
            "            CPU0       CPU1       CPU2       CPU3       \n   0:         44          0          0          0   IO-APIC   2-edge      timer\n 128:       1200        800        300      95123  IR-PCI-MSIX-0000:02:00.0    1-edge      nvme0q1\n 130:         10          0          0       7000  IR-PCI-MSI-0000:00:1f.6    0-edge      enp0s31f6\n LOC:    1000000    1000000    1000000    1000000   Local timer interrupts\n",
        )
        .file("/proc/irq/128/smp_affinity_list", "0-3\n")
        .file("/proc/irq/130/smp_affinity_list", "0-3\n")
        .file("/proc/irq/0/smp_affinity_list", "0\n")
        .file("/proc/cpuinfo", "processor\t: 0\nflags\t\t: fpu vme sse sse2\n");
        for cpu in 0..4 {
            f.file(
                &format!("/sys/devices/system/cpu/cpu{cpu}/cpufreq/scaling_governor"),
                "powersave\n",
            );
        }
        f
    }

    /// A PREEMPT_RT kernel with CPU 3 kept for the loop, its interrupts moved, the performance
    /// governor, no swap, and a user with rtprio 99 and unlimited memlock.
    fn rt_isolated() -> Self {
        let f = Self::stock();
        f.file(
            "/proc/version",
            "Linux version 6.1.0-25-rt-amd64 (debian-kernel@lists.debian.org) #1 SMP PREEMPT_RT Debian 6.1.106-3 (2024-08-26)\n",
        )
        .file("/proc/sys/kernel/osrelease", "6.1.0-25-rt-amd64\n")
        .file("/sys/kernel/realtime", "1\n")
        .file(
            "/proc/cmdline",
            "BOOT_IMAGE=/vmlinuz root=/dev/sda1 ro isolcpus=managed_irq,domain,3 nohz_full=3 rcu_nocbs=3 irqaffinity=0-2\n",
        )
        .file("/sys/devices/system/cpu/isolated", "3\n")
        .file("/sys/devices/system/cpu/nohz_full", "3\n")
        .file(
            "/proc/self/limits",
            "Limit                     Soft Limit           Hard Limit           Units     \n\
             Max locked memory         unlimited            unlimited            bytes     \n\
             Max realtime priority     99                   99                   \n",
        )
        .file(
            "/proc/self/status",
            "Name:\tsofthaptic\nUid:\t1000\t1000\t1000\t1000\nCapEff:\t0000000000000000\nCpus_allowed_list:\t0-2\n",
        )
        .file("/proc/swaps", "Filename\t\t\t\tType\t\tSize\t\tUsed\t\tPriority\n")
        .file("/proc/irq/128/smp_affinity_list", "0-2\n")
        .file("/proc/irq/130/smp_affinity_list", "0-2\n");
        for cpu in 0..4 {
            f.file(
                &format!("/sys/devices/system/cpu/cpu{cpu}/cpufreq/scaling_governor"),
                "performance\n",
            );
        }
        f
    }

    /// A container: root without capabilities, in a cgroup given no real-time time.
    fn container() -> Self {
        let f = Self::stock();
        f.file(
            "/proc/self/status",
            "Name:\tsofthaptic\nUid:\t0\t0\t0\t0\nCapEff:\t00000000a80425fb\nCpus_allowed_list:\t0-3\n",
        )
        .file(
            "/proc/self/cgroup",
            "12:cpu,cpuacct:/docker/abc\n11:cpuset:/docker/abc\n0::/\n",
        )
        .file("/sys/fs/cgroup/cpu,cpuacct/docker/abc/cpu.rt_runtime_us", "0\n")
        .file("/sys/fs/cgroup/cpuset/docker/abc/cpuset.cpus", "0-1\n");
        f
    }
}

fn plan(cpu: CpuChoice) -> LoopPlan {
    LoopPlan {
        realtime: true,
        cpu,
    }
}

fn check<'a>(checks: &'a [Check], id: &str) -> &'a Check {
    checks.iter().find(|c| c.id == id).unwrap()
}

fn no_devices() -> DeviceFacts {
    DeviceFacts {
        openhaptics: OpenHapticsFacts::NoLibrary(
            "the OpenHaptics HD library (libHD.so) was not found; looked in:\n- /usr/lib".into(),
        ),
        spacemice: hid::Listing {
            found: vec![],
            error: None,
            hidraw_unreadable: false,
        },
    }
}

fn inspect_fixture(f: &Fixture, plan: LoopPlan) -> Vec<Check> {
    inspect(&f.tree(), &plan, &no_devices())
}

#[test]
fn cpu_lists_and_kernel_parameters_parse_as_the_kernel_writes_them() {
    assert_eq!(
        parse_cpu_list("0-3,8,10-11\n"),
        Some(vec![0, 1, 2, 3, 8, 10, 11])
    );
    assert_eq!(parse_cpu_list(""), Some(vec![]));
    assert_eq!(parse_cpu_list("3-1"), None);
    assert_eq!(parse_cpu_list("0-99999999"), None, "no huge allocation");
    assert_eq!(parse_cpu_list("x"), None);
    assert_eq!(format_cpu_list(&[0, 1, 2, 5, 7, 8]), "0-2,5,7-8");
    let cmdline = "ro preempt=none isolcpus=nohz,domain,2-3 preempt=full -- preempt=none";
    assert_eq!(
        kernel_param(cmdline, "preempt"),
        Some("full"),
        "the last before --"
    );
    assert_eq!(kernel_param(cmdline, "isolcpus"), Some("nohz,domain,2-3"));
    assert_eq!(kernel_param(cmdline, "nohz_full"), None);
}

#[test]
fn the_preemption_model_is_read_from_the_running_kernel() {
    let f = Fixture::stock();
    let p = preemption(&f.tree());
    assert_eq!(p.model, Preemption::Voluntary, "{p:?}");
    assert!(p.dynamic && p.source.contains("/boot/config"), "{p:?}");
    let c = preemption_check(&f.tree());
    assert_eq!(c.verdict, Verdict::Warn);
    let fix = c.fix.unwrap();
    assert!(
        fix.contains("preempt=full") && fix.contains("GRUB_CMDLINE_LINUX"),
        "{fix}"
    );

    // Without the build configuration the mode is not known, said so, and how to read it.
    f.remove("/boot/config-6.8.0-45-generic");
    let c = preemption_check(&f.tree());
    assert_eq!(preemption(&f.tree()).model, Preemption::DynamicUnknown);
    assert_eq!(c.verdict, Verdict::Warn);
    assert!(
        c.found.contains("/proc/config.gz") && c.found.contains("root only"),
        "{}",
        c.found
    );
    let fix = c.fix.unwrap();
    assert!(
        fix.contains("dmesg | grep 'Dynamic Preempt'")
            && fix.contains("mount -t debugfs none /sys/kernel/debug"),
        "{fix}"
    );

    // preempt=full on the command line is good.
    f.file("/proc/cmdline", "ro quiet preempt=full\n");
    let c = preemption_check(&f.tree());
    assert_eq!(
        (preemption(&f.tree()).model, c.verdict),
        (Preemption::Full, Verdict::Good)
    );
    assert!(c.fix.is_none());

    // debugfs, when readable, names the mode in force.
    f.file(
        "/sys/kernel/debug/sched/preempt",
        "none (voluntary) full lazy\n",
    );
    assert_eq!(preemption(&f.tree()).model, Preemption::Voluntary);

    // A kernel built without PREEMPT_DYNAMIC cannot be changed at boot.
    let plain = Fixture::empty();
    plain.file(
        "/proc/version",
        "Linux version 5.10.0-30-amd64 (debian-kernel@lists.debian.org) #1 SMP Debian 5.10.218-1\n",
    );
    let c = preemption_check(&plain.tree());
    assert_eq!(preemption(&plain.tree()).model, Preemption::NoneOrVoluntary);
    assert_eq!(c.verdict, Verdict::Warn);
    assert!(c.fix.unwrap().contains("PREEMPT_RT kernel"));

    let rt = Fixture::rt_isolated();
    let c = preemption_check(&rt.tree());
    assert_eq!(preemption(&rt.tree()).model, Preemption::Rt);
    assert_eq!(c.verdict, Verdict::Good, "{c:?}");
}

#[test]
fn the_build_configuration_is_read_from_proc_config_gz_before_boot() {
    // A PREEMPT_DYNAMIC kernel with no /boot of its own, built with preemption none (a virtual
    // machine's kernel as its host boots it), booted without preempt=.
    let f = Fixture::stock();
    f.remove("/boot/config-6.8.0-45-generic").gzip_file(
        "/proc/config.gz",
        "CONFIG_PREEMPT_BUILD=y\nCONFIG_PREEMPT_NONE=y\n# CONFIG_PREEMPT_VOLUNTARY is not set\n\
         # CONFIG_PREEMPT is not set\nCONFIG_PREEMPTION=y\nCONFIG_PREEMPT_DYNAMIC=y\n",
    );
    let p = preemption(&f.tree());
    assert_eq!(p.model, Preemption::None, "{p:?}");
    assert!(p.dynamic && p.source.contains("/proc/config.gz"), "{p:?}");
    let c = preemption_check(&f.tree());
    assert_eq!(c.verdict, Verdict::Warn);
    assert!(c.found.contains("none (preempt=none)"), "{}", c.found);
    assert!(c.fix.unwrap().contains("boot with preempt=full"));

    // The running kernel's own copy wins over the file installed in /boot for its release.
    f.file(
        "/boot/config-6.8.0-45-generic",
        "CONFIG_PREEMPT_VOLUNTARY=y\nCONFIG_PREEMPT_DYNAMIC=y\n",
    );
    assert_eq!(preemption(&f.tree()).model, Preemption::None);
    // preempt= on the command line still chooses the mode of a PREEMPT_DYNAMIC kernel.
    f.file("/proc/cmdline", "ro preempt=full\n");
    assert_eq!(preemption(&f.tree()).model, Preemption::Full);
    f.file("/proc/cmdline", "ro quiet\n");

    // A /proc/config.gz that is not gzip is passed over for /boot's.
    f.file("/proc/config.gz", "CONFIG_PREEMPT_NONE=y\n");
    let p = preemption(&f.tree());
    assert_eq!(p.model, Preemption::Voluntary, "{p:?}");
    assert!(p.source.contains("/boot/config-6.8.0-45-generic"), "{p:?}");

    // A kernel built without PREEMPT_DYNAMIC, whose /proc/version cannot tell none from
    // voluntary, is told apart by its configuration; PREEMPT_RT is read there too.
    let plain = Fixture::empty();
    plain
        .file(
            "/proc/version",
            "Linux version 5.10.0-30-amd64 (debian-kernel@lists.debian.org) #1 SMP Debian 5.10.218-1\n",
        )
        .gzip_file("/proc/config.gz", "CONFIG_PREEMPT_VOLUNTARY=y\n");
    let p = preemption(&plain.tree());
    assert_eq!(
        (p.model, p.dynamic),
        (Preemption::Voluntary, false),
        "{p:?}"
    );
    assert_eq!(p.source, "/proc/config.gz");
    plain.gzip_file("/proc/config.gz", "CONFIG_PREEMPT_RT=y\n");
    assert_eq!(preemption(&plain.tree()).model, Preemption::Rt);
}

#[test]
fn a_gzip_file_is_read_no_further_than_the_file_size_bound() {
    // 9 MiB of configuration that compresses to a few KiB: only the first 8 MiB are inflated.
    let f = Fixture::empty();
    let line = "# padding\n";
    let text = line.repeat((9 << 20) / line.len());
    f.gzip_file("/proc/config.gz", &text);
    let read = f.tree().read_gzip("/proc/config.gz").unwrap();
    assert_eq!(read.len(), 8 << 20);
    assert!(f.tree().read_gzip("/proc/missing.gz").is_none());
}

#[test]
fn sched_fifo_needs_an_rtprio_limit_or_cap_sys_nice_and_says_what_to_add() {
    let stock = Fixture::stock();
    let checks = inspect_fixture(&stock, LoopPlan::default());
    let fifo = check(&checks, "sched_fifo");
    assert_eq!(
        fifo.verdict,
        Verdict::Fail,
        "rtprio 0, no capability: {fifo:?}"
    );
    let fix = fifo.fix.as_deref().unwrap();
    assert!(
        fix.contains("lab - rtprio 95") && fix.contains("lab - memlock unlimited"),
        "{fix}"
    );
    assert!(
        fix.contains("LimitRTPRIO=95") && fix.contains("LimitMEMLOCK=infinity"),
        "{fix}"
    );
    let mlock = check(&checks, "memory_lock");
    assert_eq!(mlock.verdict, Verdict::Warn, "8 MiB memlock: {mlock:?}");

    let rt = Fixture::rt_isolated();
    let checks = inspect_fixture(&rt, LoopPlan::default());
    assert_eq!(check(&checks, "sched_fifo").verdict, Verdict::Good);
    assert_eq!(check(&checks, "memory_lock").verdict, Verdict::Good);

    // CAP_SYS_NICE and CAP_IPC_LOCK alone are enough, whatever the limits.
    stock.file(
        "/proc/self/status",
        "Uid:\t1000\t1000\t1000\t1000\nCapEff:\t0000000000804000\nCpus_allowed_list:\t0-3\n",
    );
    let checks = inspect_fixture(&stock, LoopPlan::default());
    assert_eq!(check(&checks, "sched_fifo").verdict, Verdict::Good);
    assert_eq!(check(&checks, "memory_lock").verdict, Verdict::Good);

    // Not requested: nothing to judge.
    let checks = inspect_fixture(
        &Fixture::stock(),
        LoopPlan {
            realtime: false,
            cpu: CpuChoice::Unpinned,
        },
    );
    assert_eq!(check(&checks, "sched_fifo").verdict, Verdict::Info);
}

#[test]
fn a_container_without_real_time_time_cannot_run_the_loop_as_configured() {
    let f = Fixture::container();
    let checks = inspect_fixture(&f, LoopPlan::default());
    let fifo = check(&checks, "sched_fifo");
    assert_eq!(fifo.verdict, Verdict::Fail, "{fifo:?}");
    assert!(fifo.found.contains("cpu.rt_runtime_us 0"), "{}", fifo.found);
    assert!(
        fifo.fix.as_deref().unwrap().contains("/docker/abc"),
        "{fifo:?}"
    );
    // Its cpuset holds CPUs 0-1 only: a loop asked onto CPU 3 cannot be bound there.
    let checks = inspect_fixture(&f, plan(CpuChoice::Index(3)));
    let cpu = check(&checks, "cpu_isolation");
    assert_eq!(cpu.verdict, Verdict::Fail, "{cpu:?}");
    assert!(cpu.fix.as_deref().unwrap().contains("0-1"), "{cpu:?}");
    assert_eq!(Report::new(checks, None).exit_code, 2);
}

#[test]
fn isolation_is_good_only_with_the_loop_bound_to_an_isolated_cpu() {
    let stock = Fixture::stock();
    let checks = inspect_fixture(&stock, LoopPlan::default());
    let c = check(&checks, "cpu_isolation");
    assert_eq!(c.verdict, Verdict::Warn);
    assert!(c.found.contains("isolated: none"), "{}", c.found);
    let fix = c.fix.as_deref().unwrap();
    assert!(
        fix.contains("isolcpus=managed_irq,domain,3 nohz_full=3 rcu_nocbs=3 irqaffinity=0-2")
            && fix.contains("--loop-cpu 3"),
        "{fix}"
    );

    let rt = Fixture::rt_isolated();
    let unbound = inspect_fixture(&rt, LoopPlan::default());
    let c = check(&unbound, "cpu_isolation");
    assert_eq!(c.verdict, Verdict::Warn);
    assert_eq!(c.fix.as_deref(), Some("run the server with --loop-cpu 3"));
    let bound = inspect_fixture(&rt, plan(CpuChoice::Index(3)));
    let c = check(&bound, "cpu_isolation");
    assert_eq!(c.verdict, Verdict::Good, "{c:?}");
    assert!(
        c.found.contains("bound to CPU 3, its standby on CPU 0"),
        "{}",
        c.found
    );

    // A CPU that is not there.
    let c = inspect_fixture(&rt, plan(CpuChoice::Index(9)));
    assert_eq!(check(&c, "cpu_isolation").verdict, Verdict::Fail);
}

#[test]
fn interrupts_still_sent_to_the_loops_cpu_are_named_with_the_commands_to_move_them() {
    let stock = Fixture::stock();
    let checks = inspect_fixture(&stock, plan(CpuChoice::Index(3)));
    let c = check(&checks, "irq_affinity");
    assert_eq!(c.verdict, Verdict::Warn, "{c:?}");
    assert!(
        c.found
            .contains("IRQ 128 nvme0q1 (95123 since boot); IRQ 130 enp0s31f6"),
        "busiest first: {}",
        c.found
    );
    assert!(!c.found.contains("timer"), "IRQ 0 is not sent to CPU 3");
    let fix = c.fix.as_deref().unwrap();
    assert!(
        fix.contains("for irq in 128 130; do echo 0-2 | sudo tee /proc/irq/$irq/smp_affinity_list")
            && fix.contains("irqaffinity=0-2"),
        "{fix}"
    );

    // Without debugfs nothing tells which interrupts the kernel manages: the fix says what a
    // refused write means.
    assert!(
        fix.contains("Input/output error") && fix.contains("isolcpus=managed_irq,3"),
        "{fix}"
    );

    // With debugfs readable, a kernel-managed interrupt is named as such and left out of the
    // writes, which the kernel would refuse.
    stock
        .file(
            "/sys/kernel/debug/irq/irqs/128",
            "handler:  handle_edge_irq\ndevice:   0000:02:00.0\ndstate:   0x3540a200\n\
             \x20           IRQD_ACTIVATED\n            IRQD_IRQ_STARTED\n\
             \x20           IRQD_AFFINITY_MANAGED\n",
        )
        .file(
            "/sys/kernel/debug/irq/irqs/130",
            "handler:  handle_edge_irq\ndstate:   0x00401200\n            IRQD_ACTIVATED\n",
        );
    let checks = inspect_fixture(&stock, plan(CpuChoice::Index(3)));
    let c = check(&checks, "irq_affinity");
    assert_eq!(c.verdict, Verdict::Warn);
    assert!(
        c.found
            .contains("IRQ 128 nvme0q1 (95123 since boot, kernel-managed)"),
        "{}",
        c.found
    );
    let fix = c.fix.as_deref().unwrap();
    assert!(
        fix.contains("for irq in 130; do")
            && fix.contains("IRQ 128 is managed by the kernel")
            && fix.contains("isolcpus=managed_irq,3")
            && !fix.contains("Input/output error"),
        "{fix}"
    );

    // Moved off (the counts since boot stay, the affinity no longer includes the CPU).
    let rt = Fixture::rt_isolated();
    let c = inspect_fixture(&rt, plan(CpuChoice::Index(3)));
    assert_eq!(check(&c, "irq_affinity").verdict, Verdict::Good);
}

#[test]
fn the_governor_is_good_only_at_performance() {
    let stock = Fixture::stock();
    let c = governor_check(
        &stock.tree(),
        &CpuLayout::read(&stock.tree(), &LoopPlan::default()),
    );
    assert_eq!(c.verdict, Verdict::Warn);
    assert!(c.found.contains("CPU 3: powersave"), "{}", c.found);
    assert!(c.fix.unwrap().contains("performance"));

    let rt = Fixture::rt_isolated();
    let c = governor_check(
        &rt.tree(),
        &CpuLayout::read(&rt.tree(), &LoopPlan::default()),
    );
    assert_eq!(c.verdict, Verdict::Good, "{c:?}");

    // No cpufreq at all (a virtual machine): nothing to change.
    let bare = Fixture::empty();
    bare.file("/sys/devices/system/cpu/online", "0-1\n");
    let c = governor_check(
        &bare.tree(),
        &CpuLayout::read(&bare.tree(), &LoopPlan::default()),
    );
    assert_eq!(c.verdict, Verdict::Info);
}

#[test]
fn swap_matters_only_when_the_loops_memory_cannot_be_locked() {
    let stock = Fixture::stock();
    let c = check(&inspect_fixture(&stock, LoopPlan::default()), "swap").clone();
    assert_eq!(c.verdict, Verdict::Warn);
    assert!(c.found.contains("/swap.img (file, 2.0 GiB)"), "{}", c.found);
    assert!(c.fix.unwrap().contains("swapoff -a"));

    stock.file(
        "/proc/self/limits",
        "Max locked memory         unlimited            unlimited            bytes\n\
         Max realtime priority     99                   99\n",
    );
    let c = check(&inspect_fixture(&stock, LoopPlan::default()), "swap").clone();
    assert_eq!(c.verdict, Verdict::Good, "{c:?}");
    assert!(c.found.contains("never swapped out"));

    let rt = Fixture::rt_isolated();
    let c = check(&inspect_fixture(&rt, LoopPlan::default()), "swap").clone();
    assert_eq!((c.verdict, c.found.as_str()), (Verdict::Good, "off"));
}

#[test]
fn the_devices_and_hid_access_give_the_install_steps_and_the_udev_rule() {
    let f = Fixture::stock();
    let none = no_devices();
    let c = haptic_device_check(&none);
    assert_eq!(c.verdict, Verdict::Warn);
    assert!(c.found.contains("libHD.so) was not found") && !c.found.contains("/usr/lib"));
    assert!(c.fix.unwrap().contains("SOFTHAPTIC_HD_LIBRARY"));

    let phantom = DeviceFacts {
        openhaptics: OpenHapticsFacts::Library {
            path: "/usr/lib/libHD.so".into(),
            devices: vec![(
                "Default Device".into(),
                Ok("PHANTOM Desktop, serial 123, calibrated".into()),
            )],
        },
        ..no_devices()
    };
    assert_eq!(haptic_device_check(&phantom).verdict, Verdict::Good);

    let refused = hid::Listing {
        found: vec![hid::Found {
            vendor_id: 0x256f,
            product_id: 0xc635,
            model: Some("SpaceMouse Compact"),
            path: "/dev/hidraw3".into(),
            serial: None,
            opens: Err("Permission denied".into()),
        }],
        error: None,
        hidraw_unreadable: true,
    };
    let c = hidraw_check(&f.tree(), &refused);
    assert_eq!(c.verdict, Verdict::Warn);
    assert!(
        c.found
            .contains("SpaceMouse Compact at /dev/hidraw3: Permission denied")
    );
    assert!(c.fix.unwrap().contains(hid::UDEV_RULE_PATH));
    let c = haptic_device_check(&DeviceFacts {
        spacemice: refused,
        ..no_devices()
    });
    assert_eq!(c.verdict, Verdict::Warn);

    assert_eq!(
        hidraw_check(&f.tree(), &none.spacemice).verdict,
        Verdict::Info
    );
    f.file("/dev/hidraw0", "");
    assert_eq!(
        hidraw_check(&f.tree(), &none.spacemice).verdict,
        Verdict::Good
    );
}

#[test]
fn a_force_dimension_device_is_found_by_its_usb_ids_and_its_node_checked() {
    let f = Fixture::empty();
    assert_eq!(forcedimension_usb_check(&f.tree()).verdict, Verdict::Info);
    // A mouse, an omega.3 and a Falcon on the bus, as sysfs lists them.
    for (dir, vendor, product, bus, dev) in [
        ("1-1", "046d", "c077", "1", "2"),
        ("1-2", "1451", "0402", "1", "5"),
        ("3-1.4", "0403", "cb48", "3", "17"),
    ] {
        let base = format!("/sys/bus/usb/devices/{dir}");
        f.file(&format!("{base}/idVendor"), &format!("{vendor}\n"))
            .file(&format!("{base}/idProduct"), &format!("{product}\n"))
            .file(&format!("{base}/busnum"), &format!("{bus}\n"))
            .file(&format!("{base}/devnum"), &format!("{dev}\n"));
    }
    // Their nodes cannot be opened (absent here): the rule that lets this user.
    let c = forcedimension_usb_check(&f.tree());
    assert_eq!(c.verdict, Verdict::Warn, "{c:?}");
    assert!(
        c.found
            .contains("Force Dimension device [1451:0402] at /dev/bus/usb/001/005")
            && c.found
                .contains("Novint Falcon [0403:cb48] at /dev/bus/usb/003/017")
            && !c.found.contains("046d"),
        "{}",
        c.found
    );
    let fix = c.fix.unwrap();
    assert!(
        fix.contains("idVendor}==\"1451\"") && fix.contains("idProduct}==\"cb48\""),
        "{fix}"
    );
    f.file("/dev/bus/usb/001/005", "")
        .file("/dev/bus/usb/003/017", "");
    assert_eq!(forcedimension_usb_check(&f.tree()).verdict, Verdict::Good);
}

#[test]
fn missing_or_damaged_files_are_unknown_never_a_panic() {
    let empty = Fixture::empty();
    for plan in [
        LoopPlan::default(),
        plan(CpuChoice::Index(2)),
        plan(CpuChoice::Last),
    ] {
        let checks = inspect_fixture(&empty, plan);
        assert_eq!(checks.len(), 11);
        for c in &checks {
            assert!(!c.found.is_empty(), "{c:?}");
            assert_ne!(
                c.verdict,
                Verdict::Good,
                "nothing read cannot be good: {c:?}"
            );
        }
        assert_eq!(check(&checks, "sched_fifo").verdict, Verdict::Unknown);
    }

    let junk = Fixture::empty();
    for rel in [
        "/proc/version",
        "/proc/cmdline",
        "/proc/self/limits",
        "/proc/self/status",
        "/proc/self/cgroup",
        "/proc/swaps",
        "/proc/interrupts",
        "/proc/stat",
        "/proc/cpuinfo",
        "/sys/devices/system/cpu/online",
        "/sys/devices/system/cpu/isolated",
        "/sys/kernel/debug/sched/preempt",
        "/proc/config.gz",
    ] {
        junk.file(
            rel,
            "\u{0}\u{1}::: -- 9-2,x\nCPU9999999999 CPU\n 1: 5 5 5 5 5 5\n:\n",
        );
    }
    junk.file("/etc/passwd", "\u{fffd}:x:notanumber\n");
    let checks = inspect_fixture(&junk, plan(CpuChoice::Last));
    assert_eq!(checks.len(), 11);
    let report = Report::new(checks, None);
    assert!((0..=2).contains(&report.exit_code));
    let text = render(&report, &junk.tree());
    assert!(text.contains("verdict:"), "{text}");
}

#[test]
fn the_exit_status_is_the_worst_verdict() {
    let good = |id| Check::new(id, "t", Verdict::Good, "f".into(), "w", None);
    let with = |v| Check::new("x", "t", v, "f".into(), "w", None);
    assert_eq!(
        Report::new(vec![good("a"), with(Verdict::Info)], None).exit_code,
        0
    );
    // What could not be read is not shown to be ready: a warning, naming it.
    let unread = Report::new(vec![good("a"), with(Verdict::Unknown)], None);
    assert_eq!((unread.exit_code, unread.status), (1, "warnings"));
    let text = render(&unread, &Tree::host());
    assert!(
        text.contains("verdict: 1 item not read (t): ") && !text.contains("verdict: ready"),
        "{text}"
    );
    let warn = Report::new(vec![good("a"), with(Verdict::Warn)], None);
    assert_eq!((warn.exit_code, warn.status), (1, "warnings"));
    let fail = Report::new(vec![with(Verdict::Warn), with(Verdict::Fail)], None);
    assert_eq!((fail.exit_code, fail.status), (2, "cannot_run"));
    let text = render(&fail, &Tree::host());
    assert!(text.contains("[FAIL]") && text.contains("exit 2"), "{text}");
}

#[test]
fn a_ready_host_reads_ready() {
    // The RT fixture with the loop on its isolated CPU and a device: nothing left to fix.
    let rt = Fixture::rt_isolated();
    let devices = DeviceFacts {
        openhaptics: OpenHapticsFacts::Library {
            path: "/usr/lib/libHD.so".into(),
            devices: vec![(
                "Default Device".into(),
                Ok("Touch, serial 7, calibrated".into()),
            )],
        },
        ..no_devices()
    };
    let checks = inspect(&rt.tree(), &plan(CpuChoice::Index(3)), &devices);
    let bad: Vec<&Check> = checks
        .iter()
        .filter(|c| c.verdict > Verdict::Info)
        .collect();
    assert!(bad.is_empty(), "{bad:#?}");
    let report = Report::new(checks, None);
    assert_eq!(report.exit_code, 0);
    assert!(render(&report, &rt.tree()).contains("verdict: ready for the 1 kHz loop (exit 0)"));
}

#[test]
fn the_stock_fixture_gives_the_verdicts_its_table_predicts() {
    // The table the end-to-end test holds this machine to: it must say what the stock fixture
    // gives, item by item, in the report's order and spelling.
    let checks = inspect_fixture(&Fixture::stock(), LoopPlan::default());
    let given: Vec<(&str, String)> = checks
        .iter()
        .map(|c| {
            (
                c.id,
                serde_json::to_value(c.verdict)
                    .unwrap()
                    .as_str()
                    .unwrap()
                    .to_owned(),
            )
        })
        .collect();
    let predicted: Vec<(&str, String)> = STOCK_VERDICTS
        .iter()
        .map(|v| (v.id, v.verdict.to_owned()))
        .collect();
    assert_eq!(given, predicted);

    // The names by which that test knows a stock kernel are the preemption item's own.
    assert_eq!(
        STOCK_PREEMPTION_NAMES,
        [
            Preemption::None.name(),
            Preemption::Voluntary.name(),
            Preemption::NoneOrVoluntary.name()
        ]
    );
    let found = &check(&checks, "preemption").found;
    assert!(found.contains(STOCK_PREEMPTION_NAMES[1]), "{found}");

    // The rows said to hold on any stock host do not move with what differs between hosts: as
    // root with every capability, swap off, no cpufreq, a hypervisor and a HID node.
    let other = Fixture::stock();
    other
        .file(
            "/proc/self/status",
            "Uid:\t0\t0\t0\t0\nCapEff:\t000001ffffffffff\nCpus_allowed_list:\t0-1\n",
        )
        .file("/sys/devices/system/cpu/online", "0-1\n")
        .file(
            "/proc/swaps",
            "Filename\t\t\t\tType\t\tSize\t\tUsed\t\tPriority\n",
        )
        .file(
            "/proc/cpuinfo",
            "processor\t: 0\nflags\t\t: fpu hypervisor\n",
        )
        .file("/dev/hidraw0", "");
    for cpu in 0..4 {
        other.remove(&format!(
            "/sys/devices/system/cpu/cpu{cpu}/cpufreq/scaling_governor"
        ));
    }
    let checks = inspect_fixture(&other, LoopPlan::default());
    let moved: Vec<&str> = STOCK_VERDICTS
        .iter()
        .filter(|v| serde_json::to_value(check(&checks, v.id).verdict).unwrap() != v.verdict)
        .map(|v| v.id)
        .collect();
    assert_eq!(
        moved,
        [
            "virtualisation",
            "sched_fifo",
            "memory_lock",
            "swap",
            "cpu_governor",
            "hidraw"
        ],
        "the other host differs where the table says hosts differ"
    );
    for row in STOCK_VERDICTS.iter().filter(|v| v.depends_on.is_none()) {
        let c = check(&checks, row.id);
        assert_eq!(
            serde_json::to_value(c.verdict).unwrap(),
            row.verdict,
            "{c:?}"
        );
    }
}
