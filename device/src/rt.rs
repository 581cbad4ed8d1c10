//! Real-time plumbing for the loop thread: the monotonic clock, absolute-deadline sleeps, and the
//! request for SCHED_FIFO, locked memory, a CPU of its own and a prefaulted stack.
//!
//! Privileges: SCHED_FIFO needs `CAP_SYS_NICE` (or an `rtprio` entry in
//! `/etc/security/limits.conf`, or root); `mlockall` needs `CAP_IPC_LOCK` or a large enough
//! `RLIMIT_MEMLOCK`. Binding the thread to one CPU needs no privilege (only that the CPU is in
//! the process's affinity mask). Without them the loop still runs, at normal priority, and says
//! so once at start ([`RealtimeStatus`]). On an idle machine that is usually good enough; under
//! load the period error grows (the `loop-timing` report measures both).
//!
//! # What SCHED_FIFO cannot do
//! A real-time thread preempts any ordinary thread at once only if the kernel may preempt that
//! thread wherever it is. A kernel built or booted with `preempt=none` or `preempt=voluntary` lets
//! a thread in a long system call (writing a large file, unmapping a large heap) keep its CPU
//! until the call reaches a rescheduling point, which can take milliseconds: the loop's timer
//! fires on time, the loop is woken on time, and it runs only when the call ends. No setting of
//! the thread helps; the remedy is the machine's: boot with `preempt=full` (kernels built with
//! `PREEMPT_DYNAMIC`) or run a `PREEMPT_RT` kernel, and keep other work off the loop's CPU
//! (`isolcpus=`, a cpuset). Virtual machines add the host's own scheduling of their virtual
//! CPUs, which no guest setting reaches.
//!
//! What the loop itself can do is not depend on a single CPU: such stalls mostly hold one CPU at
//! a time, so the loop keeps a standby thread on a second CPU that runs a tick the loop thread
//! has not started in time ([`standby_placement`], `crate::haptic_loop`). A stall of every CPU
//! at once (a host pausing the whole virtual machine) still loses ticks; `loop-timing`'s witness
//! threads tell the two apart.

use std::fmt;

/// SCHED_FIFO priority of the haptic thread: above most user threads and IRQ threads of lesser
/// devices, below the kernel's own watchdogs (99).
pub const LOOP_PRIORITY: i32 = 80;

/// Stack the loop thread is given, bytes. Set explicitly (not left to `RUST_MIN_STACK`) because
/// [`prefault_stack`] touches [`PREFAULT_STACK_BYTES`] of it.
pub const LOOP_STACK_BYTES: usize = 2 << 20;

/// How much of the loop thread's stack is touched before the first tick: far more than one tick
/// uses (collision and force are a few kB of frames), so no tick meets an unmapped stack page.
pub const PREFAULT_STACK_BYTES: usize = 256 << 10;

/// Which CPU the loop thread is bound to.
///
/// Bound, the thread never migrates (a migration costs a cold cache and, on a busy machine, a
/// wait for the new CPU), and its timer, its wake-up and its work stay on one CPU. That pays
/// only where the CPU is kept quiet (isolated, its interrupts steered elsewhere): on a shared
/// machine whose disk interrupts land on the chosen CPU, binding measured more overruns than
/// leaving the thread free, so unbound is the default (`loop-timing --cpu` measures a host).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CpuChoice {
    /// [`CpuChoice::Last`] when real-time scheduling is requested, [`CpuChoice::Unpinned`]
    /// otherwise.
    Auto,
    /// Leave the thread free to run on any CPU of the process.
    #[default]
    Unpinned,
    /// The highest-numbered CPU of the process's affinity mask.
    Last,
    /// This CPU (it must be in the process's affinity mask).
    Index(usize),
    /// Any CPU of the process but this one (where the loop's standby thread is bound, see
    /// [`crate::haptic_loop`]).
    Except(usize),
}

impl std::str::FromStr for CpuChoice {
    type Err = String;

    /// `auto`, `last`, `none` (unbound) or a CPU number, as the command lines spell it.
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        match text {
            "auto" => Ok(CpuChoice::Auto),
            "last" => Ok(CpuChoice::Last),
            "none" => Ok(CpuChoice::Unpinned),
            n => n
                .parse()
                .map(CpuChoice::Index)
                .map_err(|_| format!("expected auto, last, none or a CPU number, got {n:?}")),
        }
    }
}

/// What the operating system granted when the loop thread asked for real-time treatment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RealtimeStatus {
    /// Real-time scheduling was asked for at all.
    pub requested: bool,
    /// SCHED_FIFO priority obtained, or `None`.
    pub fifo_priority: Option<i32>,
    /// errno of the refused scheduling request.
    pub fifo_errno: Option<i32>,
    /// Memory locked with `mlockall` (current pages, and future ones when the memlock limit is
    /// unlimited).
    pub memory_locked: bool,
    /// errno of the refused `mlockall`.
    pub mlock_errno: Option<i32>,
    /// The timer slack of the thread was lowered to 1 ns (non-real-time threads otherwise sleep
    /// up to 50 µs past their deadline).
    pub timer_slack_lowered: bool,
    /// The CPU the thread is bound to, or `None` (not asked, or refused).
    pub cpu: Option<usize>,
    /// errno of the refused binding to a CPU.
    pub cpu_errno: Option<i32>,
    /// The kernel's id of the loop thread (for `chrt -p`, `taskset -p`, `perf -t`, and
    /// `/proc/self/task/<id>`).
    pub os_thread_id: i32,
}

impl RealtimeStatus {
    /// Both SCHED_FIFO and locked memory were granted.
    pub fn granted(&self) -> bool {
        self.fifo_priority.is_some() && self.memory_locked
    }
}

impl fmt::Display for RealtimeStatus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.requested {
            match (self.fifo_priority, self.fifo_errno) {
                (Some(p), _) => write!(f, "SCHED_FIFO priority {p}")?,
                (None, Some(e)) => write!(
                    f,
                    "SCHED_FIFO refused ({}; needs CAP_SYS_NICE or an rtprio limit), normal priority",
                    std::io::Error::from_raw_os_error(e)
                )?,
                (None, None) => write!(f, "SCHED_FIFO not attempted")?,
            }
            match (self.memory_locked, self.mlock_errno) {
                (true, _) => write!(f, ", memory locked")?,
                (false, Some(e)) => write!(
                    f,
                    ", mlockall refused ({}; needs CAP_IPC_LOCK or RLIMIT_MEMLOCK)",
                    std::io::Error::from_raw_os_error(e)
                )?,
                (false, None) => write!(f, ", memory not locked")?,
            }
        } else {
            write!(f, "real-time scheduling not requested; normal priority")?;
        }
        match (self.cpu, self.cpu_errno) {
            (Some(cpu), _) => write!(f, ", bound to CPU {cpu}"),
            (None, Some(e)) => write!(
                f,
                ", binding to a CPU refused ({})",
                std::io::Error::from_raw_os_error(e)
            ),
            (None, None) => Ok(()),
        }
    }
}

fn errno() -> i32 {
    std::io::Error::last_os_error().raw_os_error().unwrap_or(0)
}

/// CLOCK_MONOTONIC in nanoseconds.
#[inline]
pub fn now_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux, so the
    // call cannot fail and fills `ts`.
    unsafe {
        libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts);
    }
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Sleeps until CLOCK_MONOTONIC reaches `deadline_ns` (absolute, so lateness never accumulates),
/// resuming after signals.
#[inline]
pub fn sleep_until_ns(deadline_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: `ts` is a valid timespec; with TIMER_ABSTIME the remaining-time pointer is
        // unused and may be null.
        let rc = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        // clock_nanosleep returns the error number directly; EINTR means a signal arrived first.
        if rc != libc::EINTR {
            return;
        }
    }
}

/// Waits until `deadline_ns`: sleeps until `spin_ns` before it, then spins, so that the wake-up
/// latency of the scheduler is absorbed by the sleep and the last stretch is exact. Returns how
/// late the sleep woke past its wake-up time (`None` when there was no time left to sleep).
#[inline]
pub fn wait_until_ns(deadline_ns: u64, spin_ns: u64) -> Option<u64> {
    let wake = deadline_ns.saturating_sub(spin_ns);
    let overshoot = if now_ns() < wake {
        sleep_until_ns(wake);
        Some(now_ns().saturating_sub(wake))
    } else {
        None
    };
    while now_ns() < deadline_ns {
        std::hint::spin_loop();
    }
    overshoot
}

/// How long before each deadline the loop stops sleeping and spins, adapted to the scheduler's
/// wake-up latency on this machine.
///
/// A fixed spin is either wasteful (an idle real-time kernel wakes within a few µs) or too short
/// (a loaded or virtualised one wakes 50–150 µs late at the 99th percentile). The budget jumps up
/// at once to cover any late wake-up it sees (plus a margin, bounded by `max_ns`) and decays back
/// toward `min_ns` with a time constant of about 1024 ticks, so it tracks the recent worst case
/// at a CPU cost of `spin_ns / period` of one core.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpinBudget {
    spin_ns: u64,
    min_ns: u64,
    max_ns: u64,
}

impl SpinBudget {
    /// Margin added above the latest late wake-up.
    const MARGIN_NS: u64 = 10_000;

    /// Starts at `max_ns`: the first second of a loop has not measured its machine yet.
    pub fn new(min_ns: u64, max_ns: u64) -> Self {
        let max_ns = max_ns.max(min_ns);
        Self {
            spin_ns: max_ns,
            min_ns,
            max_ns,
        }
    }

    /// The current spin before a deadline.
    pub fn spin_ns(&self) -> u64 {
        self.spin_ns
    }

    /// Feeds how late the last sleep woke past its wake-up time.
    pub fn observe(&mut self, overshoot_ns: u64) {
        let needed = overshoot_ns.saturating_add(Self::MARGIN_NS);
        if needed > self.spin_ns {
            self.spin_ns = needed.min(self.max_ns);
        } else {
            self.spin_ns -= (self.spin_ns - self.min_ns) / 1024;
        }
    }
}

/// The CPUs the calling thread may run on, in increasing order (errno on failure).
pub fn allowed_cpus() -> Result<Vec<usize>, i32> {
    // SAFETY: cpu_set_t is a plain bit array, valid when zeroed.
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    // SAFETY: `set` is valid and writable for the size passed; pid 0 is the calling thread.
    if unsafe { libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) } != 0
    {
        return Err(errno());
    }
    let setsize = libc::CPU_SETSIZE as usize;
    // SAFETY: every index is below CPU_SETSIZE, inside the set.
    Ok((0..setsize)
        .filter(|&cpu| unsafe { libc::CPU_ISSET(cpu, &set) })
        .collect())
}

/// The highest-numbered CPU the calling thread may run on.
fn last_allowed_cpu() -> Result<usize, i32> {
    allowed_cpus()?.last().copied().ok_or(libc::EINVAL)
}

/// Binds the calling thread to `cpu`.
fn bind_to_cpu(cpu: usize) -> Result<(), i32> {
    bind_to_cpus(&[cpu])
}

/// Binds the calling thread to the CPUs `cpus` (none may be at or above CPU_SETSIZE).
fn bind_to_cpus(cpus: &[usize]) -> Result<(), i32> {
    if cpus.is_empty() || cpus.iter().any(|&cpu| cpu >= libc::CPU_SETSIZE as usize) {
        return Err(libc::EINVAL);
    }
    // SAFETY: cpu_set_t is a plain bit array, valid when zeroed.
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    for &cpu in cpus {
        // SAFETY: `cpu` is below CPU_SETSIZE (checked above), inside the set.
        unsafe { libc::CPU_SET(cpu, &mut set) };
    }
    // SAFETY: `set` is valid for the size passed; pid 0 is the calling thread.
    if unsafe { libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) } != 0 {
        return Err(errno());
    }
    Ok(())
}

/// Binds the calling thread as `choice` says; returns the CPU, or the errno of the refusal.
fn apply_cpu_choice(choice: CpuChoice, realtime_requested: bool) -> (Option<usize>, Option<i32>) {
    let cpu = match choice {
        CpuChoice::Unpinned => return (None, None),
        CpuChoice::Auto if !realtime_requested => return (None, None),
        CpuChoice::Auto | CpuChoice::Last => match last_allowed_cpu() {
            Ok(cpu) => cpu,
            Err(e) => return (None, Some(e)),
        },
        CpuChoice::Index(cpu) => cpu,
        CpuChoice::Except(busy) => {
            let others: Vec<usize> = match allowed_cpus() {
                Ok(cpus) => cpus.into_iter().filter(|&c| c != busy).collect(),
                Err(e) => return (None, Some(e)),
            };
            // Reported as bound only when that leaves a single CPU.
            return match bind_to_cpus(&others) {
                Ok(()) => ((others.len() == 1).then(|| others[0]), None),
                Err(e) => (None, Some(e)),
            };
        }
    };
    match bind_to_cpu(cpu) {
        Ok(()) => (Some(cpu), None),
        Err(e) => (None, Some(e)),
    }
}

/// Where the loop's standby thread goes when the loop itself is placed as `loop_cpu` says, and
/// where the loop then goes: the standby takes the lowest CPU the loop is not bound to, and an
/// unbound loop is kept off that CPU, so that no stall of one CPU holds both. `None` when the
/// process has a single CPU (or its CPUs cannot be read): no standby.
pub fn standby_placement(
    loop_cpu: CpuChoice,
    realtime_requested: bool,
) -> Option<(CpuChoice, usize)> {
    let cpus = allowed_cpus().ok()?;
    if cpus.len() < 2 {
        return None;
    }
    let loop_bound = match loop_cpu {
        CpuChoice::Index(cpu) => Some(cpu),
        CpuChoice::Last => cpus.last().copied(),
        CpuChoice::Auto if realtime_requested => cpus.last().copied(),
        CpuChoice::Auto | CpuChoice::Unpinned | CpuChoice::Except(_) => None,
    };
    match loop_bound {
        Some(cpu) => {
            let standby = cpus.iter().copied().find(|&c| c != cpu)?;
            Some((loop_cpu, standby))
        }
        None => Some((CpuChoice::Except(cpus[0]), cpus[0])),
    }
}

/// Touches [`PREFAULT_STACK_BYTES`] of the calling thread's stack, below this frame, so that the
/// pages the loop's deepest tick reaches are mapped before the first tick (`mlockall`, when
/// granted, maps and locks them too; without it this still spares the first ticks the faults).
/// The thread's stack must be larger than that ([`LOOP_STACK_BYTES`]).
#[inline(never)]
pub fn prefault_stack() {
    let mut probe = [0u8; PREFAULT_STACK_BYTES];
    for page in probe.chunks_mut(4096) {
        page[0] = 1;
    }
    // Keeps the writes: the optimiser may not assume nobody reads them.
    std::hint::black_box(&mut probe);
}

/// Prepares the calling thread to run the loop: prefaults its stack, lowers its timer slack to
/// 1 ns, binds it to a CPU (`cpu`), and when `requested` asks for SCHED_FIFO at `priority` and
/// locks the process's memory. Call it after the loop's state is allocated, so that
/// `mlockall(MCL_CURRENT)` locks that state too. Never fails: what was refused is in the
/// returned status.
pub fn request_realtime(requested: bool, priority: i32, cpu: CpuChoice) -> RealtimeStatus {
    prefault_stack();
    let mut status = RealtimeStatus {
        requested,
        // SAFETY: gettid has no preconditions.
        os_thread_id: unsafe { libc::gettid() },
        ..RealtimeStatus::default()
    };
    // SAFETY: PR_SET_TIMERSLACK takes an unsigned long and affects only the calling thread.
    status.timer_slack_lowered =
        unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong) } == 0;
    (status.cpu, status.cpu_errno) = apply_cpu_choice(cpu, requested);
    if !requested {
        return status;
    }
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: `pthread_self()` is the calling thread, alive for the call; `param` is valid.
    let rc = unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) };
    if rc == 0 {
        status.fifo_priority = Some(priority);
    } else {
        status.fifo_errno = Some(rc);
    }
    (status.memory_locked, status.mlock_errno) = lock_memory();
    status
}

/// Locks the process' memory (`mlockall`): `(true, None)` when granted, `(false, Some(errno))`
/// when refused. A device-clocked loop (the driver's servo thread runs the ticks) asks for it
/// as the self-clocked one does: a page fault on the servo thread is a late force either way.
pub fn lock_memory() -> (bool, Option<i32>) {
    // MCL_FUTURE makes every later mapping of the process count against RLIMIT_MEMLOCK; with a
    // finite limit that could make an unrelated allocation in the server fail, so it is only
    // asked for when the limit is unlimited. The loop needs only MCL_CURRENT: everything it
    // touches is allocated before this call.
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: `limit` is a valid, writable rlimit.
    let unlimited = unsafe { libc::getrlimit(libc::RLIMIT_MEMLOCK, &mut limit) } == 0
        && limit.rlim_cur == libc::RLIM_INFINITY;
    let flags = if unlimited {
        libc::MCL_CURRENT | libc::MCL_FUTURE
    } else {
        libc::MCL_CURRENT
    };
    // SAFETY: mlockall has no memory-safety preconditions.
    if unsafe { libc::mlockall(flags) } == 0 {
        (true, None)
    } else {
        (false, Some(errno()))
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn clock_is_monotonic_and_sleep_reaches_its_deadline() {
        let a = now_ns();
        let deadline = a + 2_000_000;
        wait_until_ns(deadline, 50_000);
        let b = now_ns();
        assert!(b >= deadline);
        sleep_until_ns(a); // a deadline in the past returns at once
        assert!(now_ns() >= b);
    }

    #[test]
    fn spin_budget_follows_late_wake_ups_and_decays() {
        let mut b = SpinBudget::new(20_000, 200_000);
        assert_eq!(b.spin_ns(), 200_000);
        for _ in 0..20_000 {
            b.observe(3_000);
        }
        assert!(
            b.spin_ns() < 22_000,
            "decays toward the minimum: {}",
            b.spin_ns()
        );
        b.observe(80_000);
        assert_eq!(
            b.spin_ns(),
            90_000,
            "covers a late wake-up at once, with margin"
        );
        b.observe(5_000_000);
        assert_eq!(b.spin_ns(), 200_000, "bounded");
        b.observe(1_000);
        assert!(b.spin_ns() < 200_000 && b.spin_ns() > 190_000);
    }

    #[test]
    fn the_standby_never_shares_the_loops_cpu() {
        let cpus = allowed_cpus().unwrap();
        assert!(!cpus.is_empty() && cpus.windows(2).all(|w| w[0] < w[1]));
        if cpus.len() < 2 {
            assert_eq!(standby_placement(CpuChoice::Unpinned, true), None);
            return;
        }
        // Unbound: the standby takes the first CPU and the loop any other.
        assert_eq!(
            standby_placement(CpuChoice::Unpinned, false),
            Some((CpuChoice::Except(cpus[0]), cpus[0]))
        );
        // Bound, to the first CPU or to the last: the standby goes elsewhere.
        for choice in [CpuChoice::Index(cpus[0]), CpuChoice::Last] {
            let (loop_cpu, standby) = standby_placement(choice, true).unwrap();
            assert_eq!(loop_cpu, choice);
            let bound = if choice == CpuChoice::Last {
                *cpus.last().unwrap()
            } else {
                cpus[0]
            };
            assert_ne!(standby, bound);
            assert!(cpus.contains(&standby));
        }
    }

    #[test]
    fn status_explains_refusals() {
        let refused = RealtimeStatus {
            requested: true,
            fifo_errno: Some(libc::EPERM),
            mlock_errno: Some(libc::ENOMEM),
            ..RealtimeStatus::default()
        };
        let text = refused.to_string();
        assert!(text.contains("SCHED_FIFO refused") && text.contains("CAP_SYS_NICE"));
        assert!(text.contains("mlockall refused"));
        assert!(!refused.granted());
        let granted = RealtimeStatus {
            requested: true,
            fifo_priority: Some(80),
            memory_locked: true,
            ..RealtimeStatus::default()
        };
        assert!(granted.granted() && granted.to_string().contains("priority 80"));
        assert!(
            RealtimeStatus::default()
                .to_string()
                .contains("not requested")
        );
    }

    #[test]
    fn unrequested_realtime_changes_no_policy() {
        let s = std::thread::spawn(|| request_realtime(false, LOOP_PRIORITY, CpuChoice::Auto))
            .join()
            .unwrap();
        assert!(!s.requested && s.fifo_priority.is_none() && !s.memory_locked);
        assert!(s.cpu.is_none() && s.cpu_errno.is_none(), "{s:?}");
        assert!(s.os_thread_id > 0);
    }

    #[test]
    fn threads_are_bound_to_the_cpu_asked_for_or_say_why_not() {
        // In a thread of its own: binding is per thread and must not leak into other tests.
        let (status, now_on) = std::thread::spawn(|| {
            let s = request_realtime(false, LOOP_PRIORITY, CpuChoice::Last);
            // SAFETY: sched_getcpu has no preconditions.
            (s, unsafe { libc::sched_getcpu() })
        })
        .join()
        .unwrap();
        let last = last_allowed_cpu().unwrap();
        assert_eq!(status.cpu, Some(last), "{status}");
        assert_eq!(now_on, last as i32);
        assert!(status.to_string().contains(&format!("bound to CPU {last}")));

        let refused = std::thread::spawn(|| {
            request_realtime(
                false,
                LOOP_PRIORITY,
                CpuChoice::Index(libc::CPU_SETSIZE as usize),
            )
        })
        .join()
        .unwrap();
        assert_eq!((refused.cpu, refused.cpu_errno), (None, Some(libc::EINVAL)));
        assert!(refused.to_string().contains("binding to a CPU refused"));

        let free =
            std::thread::spawn(|| request_realtime(false, LOOP_PRIORITY, CpuChoice::Unpinned))
                .join()
                .unwrap();
        assert!(free.cpu.is_none() && free.cpu_errno.is_none());
    }
}
