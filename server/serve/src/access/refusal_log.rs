//! The refusals' log lines, rate-limited: in each [`INTERVAL`] the first [`LINES_PER_INTERVAL`]
//! refusals are logged as they happen, with their client and reason; the rest are counted by
//! kind, and one summary line says how many of each were not logged. A storm of refusals (a
//! scanner, a client in a reconnect loop with a stale token) then writes at most
//! `LINES_PER_INTERVAL + 1` lines per interval instead of one per refusal, and the log still
//! says what happened. The audit line of a connection that never had a role is a refusal's too.
//!
//! The summary is written by the first refusal of the next interval, by a task that looks once
//! an interval (when the rules run in a runtime), and when the rules are dropped (the server's
//! end), whichever comes first.

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// The span over which refusal lines are counted.
pub const INTERVAL: Duration = Duration::from_secs(10);
/// Refusals logged in full per interval.
pub const LINES_PER_INTERVAL: u32 = 20;

#[derive(Debug)]
struct Window {
    started: Instant,
    logged: u32,
    /// Refusals not logged in this window, by kind.
    suppressed: BTreeMap<&'static str, u64>,
}

/// The limiter (see the module's documentation).
#[derive(Debug)]
pub(super) struct RefusalLog {
    window: Mutex<Window>,
}

impl Default for RefusalLog {
    fn default() -> Self {
        Self {
            window: Mutex::new(Window {
                started: Instant::now(),
                logged: 0,
                suppressed: BTreeMap::new(),
            }),
        }
    }
}

impl RefusalLog {
    /// Whether the refusal of `kind` happening at `now` is to be logged in full; when not, it
    /// is counted for the interval's summary. Writes the last interval's summary first when it
    /// is over.
    pub(super) fn admit(&self, kind: &'static str, now: Instant) -> bool {
        let mut window = self.window.lock().unwrap_or_else(|e| e.into_inner());
        roll(&mut window, now);
        if window.logged < LINES_PER_INTERVAL {
            window.logged += 1;
            true
        } else {
            *window.suppressed.entry(kind).or_insert(0) += 1;
            false
        }
    }

    /// Writes the summary of an interval that is over (`now`), or of everything when `all`.
    pub(super) fn flush(&self, now: Instant, all: bool) {
        let mut window = self.window.lock().unwrap_or_else(|e| e.into_inner());
        if all {
            summarise(&mut window);
        } else {
            roll(&mut window, now);
        }
    }
}

/// Starts a new window when the current one is over, summarising it.
fn roll(window: &mut Window, now: Instant) {
    if now.saturating_duration_since(window.started) >= INTERVAL {
        summarise(window);
        window.started = now;
        window.logged = 0;
    }
}

fn summarise(window: &mut Window) {
    if window.suppressed.is_empty() {
        return;
    }
    let total: u64 = window.suppressed.values().sum();
    let kinds: Vec<String> = window
        .suppressed
        .iter()
        .map(|(kind, n)| format!("{n} × {kind}"))
        .collect();
    tracing::warn!(
        not_logged = total,
        "refusals not logged one by one in the last {} s (more than {LINES_PER_INTERVAL} in it): {}",
        INTERVAL.as_secs(),
        kinds.join(", ")
    );
    window.suppressed.clear();
}

impl Drop for RefusalLog {
    fn drop(&mut self) {
        self.flush(Instant::now(), true);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_refusals_of_an_interval_are_logged_the_rest_counted_until_the_next() {
        let log = RefusalLog::default();
        let t0 = Instant::now();
        let logged = (0..100).filter(|_| log.admit("401", t0)).count();
        assert_eq!(logged, LINES_PER_INTERVAL as usize);
        assert_eq!(
            log.window.lock().unwrap().suppressed.get("401"),
            Some(&(100 - u64::from(LINES_PER_INTERVAL)))
        );
        // The next interval: logged again, the summary written and cleared.
        assert!(log.admit("421", t0 + INTERVAL));
        assert!(log.window.lock().unwrap().suppressed.is_empty());
    }
}
