//! The reconnection policy every vendor's backend follows: when a device counts as lost, how
//! long to wait between attempts to reopen it, and when a reopened device counts as working.
//!
//! The loop's side counts ticks ([`LinkHealth`]): [`RECONNECT_AFTER_FAILED_TICKS`] unreachable
//! ticks in a row ask for a reconnection (a shorter communication error is ridden out with zero
//! force), and [`RECONNECTED_AFTER_GOOD_TICKS`] good ones in a row prove a connection working.
//! The reconnection thread waits ([`Backoff`]): the first attempt after a working connection is
//! made at once, later ones after a wait that doubles from [`RECONNECT_BACKOFF_MIN`] up to
//! [`RECONNECT_BACKOFF_MAX`]. The backoff outlives one reconnection: a device that opens but is
//! lost again before it proved working is reopened only after the next, doubled, wait, so a
//! device that keeps failing is not reopened every few milliseconds.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Ticks in a row the device may stay unreachable before it is reconnected (a shorter
/// communication error is ridden out with zero force).
pub const RECONNECT_AFTER_FAILED_TICKS: u32 = 250;

/// First and longest wait between two reconnection attempts.
pub const RECONNECT_BACKOFF_MIN: Duration = Duration::from_millis(100);
pub const RECONNECT_BACKOFF_MAX: Duration = Duration::from_secs(2);

/// Good ticks in a row after which a reconnected device counts as working again: the next loss
/// is reconnected at once and its backoff starts again from [`RECONNECT_BACKOFF_MIN`]. A device
/// lost again before that (it opens, but does not work) is reconnected only after a wait that
/// keeps growing from one reconnection to the next.
pub const RECONNECTED_AFTER_GOOD_TICKS: u32 = 1_000;

/// The loop side's count of good and unreachable ticks (on the loop's thread: no allocation, no
/// lock).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkHealth {
    failed_ticks: u32,
    good_ticks: u32,
}

impl LinkHealth {
    /// Books an unreachable tick; true once there have been enough in a row to reconnect.
    pub fn unreachable_tick(&mut self) -> bool {
        self.failed_ticks = self.failed_ticks.saturating_add(1);
        self.good_ticks = 0;
        self.failed_ticks >= RECONNECT_AFTER_FAILED_TICKS
    }

    /// Books a good tick; true on the one that completes the run proving the connection works.
    pub fn good_tick(&mut self) -> bool {
        self.failed_ticks = 0;
        if self.good_ticks < RECONNECTED_AFTER_GOOD_TICKS {
            self.good_ticks += 1;
            return self.good_ticks == RECONNECTED_AFTER_GOOD_TICKS;
        }
        false
    }

    /// A new connection: its ticks are counted from zero.
    pub fn restart(&mut self) {
        *self = LinkHealth::default();
    }
}

/// The reconnection thread's waits (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Backoff {
    wait: Duration,
    /// The last loss ended in a reconnection that has not yet proved working.
    unproven: bool,
}

impl Default for Backoff {
    fn default() -> Self {
        Backoff {
            wait: RECONNECT_BACKOFF_MIN,
            unproven: false,
        }
    }
}

impl Backoff {
    /// A loss begins; `worked` says whether the connection before it proved working (which
    /// starts the waits over). True when the last reconnection had not proved working.
    pub fn lost(&mut self, worked: bool) -> bool {
        if worked {
            *self = Backoff::default();
        }
        self.unproven
    }

    /// The wait before attempt number `attempt` (from 0) of this loss, if any; each wait given
    /// doubles the next, up to [`RECONNECT_BACKOFF_MAX`].
    pub fn before_attempt(&mut self, attempt: u32) -> Option<Duration> {
        if attempt == 0 && !self.unproven {
            return None;
        }
        let wait = self.wait;
        self.wait = (self.wait * 2).min(RECONNECT_BACKOFF_MAX);
        Some(wait)
    }

    /// The device reopened: until it proves working, the next loss waits first.
    pub fn reconnected(&mut self) {
        self.unproven = true;
    }

    /// The wait the next one would be.
    pub fn next_wait(&self) -> Duration {
        self.wait
    }
}

/// Sleeps `wait` in slices, returning early (false) once `stop` is set, so that a stop does not
/// wait for a long backoff.
pub fn sleep_unless(wait: Duration, stop: &AtomicBool) -> bool {
    let wake = Instant::now() + wait;
    while Instant::now() < wake {
        if stop.load(Ordering::Acquire) {
            return false;
        }
        std::thread::park_timeout(Duration::from_millis(10).min(wake - Instant::now()));
    }
    !stop.load(Ordering::Acquire)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_device_that_keeps_failing_waits_longer_each_time() {
        let mut b = Backoff::default();
        // A working connection lost: the first attempt at once, then 100, 200, 400 ms.
        assert!(!b.lost(true));
        assert_eq!(b.before_attempt(0), None);
        assert_eq!(b.before_attempt(1), Some(Duration::from_millis(100)));
        assert_eq!(b.before_attempt(2), Some(Duration::from_millis(200)));
        b.reconnected();
        // Lost again before it proved working: a wait first, continuing to grow.
        assert!(b.lost(false));
        assert_eq!(b.before_attempt(0), Some(Duration::from_millis(400)));
        for attempt in 1..10 {
            assert!(b.before_attempt(attempt) <= Some(RECONNECT_BACKOFF_MAX));
        }
        assert_eq!(b.next_wait(), RECONNECT_BACKOFF_MAX);
        // Proved working: the waits start over.
        assert!(!b.lost(true));
        assert_eq!(b.before_attempt(0), None);
        assert_eq!(b.next_wait(), RECONNECT_BACKOFF_MIN);
    }

    #[test]
    fn ticks_in_a_row_decide_a_loss_and_a_working_connection() {
        let mut h = LinkHealth::default();
        for _ in 1..RECONNECT_AFTER_FAILED_TICKS {
            assert!(!h.unreachable_tick());
        }
        assert!(h.unreachable_tick());
        // A good tick between two failures starts the count over.
        assert!(!h.good_tick());
        assert!(!h.unreachable_tick());
        let proved = (0..2 * RECONNECTED_AFTER_GOOD_TICKS)
            .filter(|_| h.good_tick())
            .count();
        assert_eq!(proved, 1);
    }

    #[test]
    fn a_stop_cuts_a_long_wait_short() {
        let stop = AtomicBool::new(true);
        let start = Instant::now();
        assert!(!sleep_unless(Duration::from_secs(30), &stop));
        assert!(start.elapsed() < Duration::from_secs(5));
        let go = AtomicBool::new(false);
        assert!(sleep_unless(Duration::from_millis(1), &go));
    }
}
