//! The reconnection thread: it reopens a device the servo side has lost, off the servo path.
//!
//! It wakes every few milliseconds and acts when the servo side asked (`Inner::reconnect_wanted`,
//! after [`RECONNECT_AFTER_FAILED_TICKS`](super::RECONNECT_AFTER_FAILED_TICKS) unreachable ticks) or when the
//! driver stopped calling the servo callback for [`CALLBACK_SILENCE_RECONNECT`] (no error tick
//! would ever come then). It stops the scheduler (the loop's watchdog then runs fault ticks),
//! disables the old handle, initialises the device again until it answers, and restarts the
//! scheduler.
//!
//! The waits between attempts follow the policy every backend shares
//! ([`crate::backend::reconnect`]): a device that opens but is lost again before
//! [`RECONNECTED_AFTER_GOOD_TICKS`](super::RECONNECTED_AFTER_GOOD_TICKS) good ticks
//! (`Inner::working`) is reopened only after the next, doubled, wait, so a device that keeps
//! failing is not stopped and restarted every few milliseconds.

use std::sync::atomic::Ordering;
use std::time::Duration;

use super::RECONNECT_BACKOFF_MAX;
use super::hd::error_name;
use super::servo::{Inner, start_failure_text};
use crate::backend::reconnect::{Backoff, sleep_unless};
use crate::rt;

/// A running scheduler whose callback has not been called for this long is taken to have
/// stopped calling back, and the device is reconnected.
pub const CALLBACK_SILENCE_RECONNECT: Duration = Duration::from_millis(500);

/// The body of the reconnection thread (module docs).
pub(crate) fn reconnect_when_asked(inner: &Inner) {
    let mut backoff = Backoff::default();
    while !inner.shutting_down.load(Ordering::Acquire) {
        std::thread::park_timeout(Duration::from_millis(5));
        let silent_ns = rt::now_ns().saturating_sub(inner.last_callback_ns.load(Ordering::Acquire));
        if inner.fatal.load(Ordering::Acquire) {
            // A failed tick stays failed: nothing to reconnect.
            continue;
        }
        let silent = inner.servo_running.load(Ordering::Acquire)
            && !inner.fatal.load(Ordering::Acquire)
            && silent_ns > CALLBACK_SILENCE_RECONNECT.as_nanos() as u64;
        if !inner.reconnect_wanted.load(Ordering::Acquire) && !silent {
            continue;
        }
        let reconnected_unproven = backoff.lost(inner.working.swap(false, Ordering::AcqRel));
        let code = inner.last_error.load(Ordering::Relaxed);
        if silent {
            tracing::warn!(
                device = %inner.display_name,
                silent_ms = silent_ns / 1_000_000,
                "the haptic device's driver stopped calling the servo loop: force is off; \
                 reconnecting"
            );
        } else if reconnected_unproven {
            tracing::warn!(
                device = %inner.display_name,
                error = %inner.lib.error_text(code),
                code = error_name(code),
                wait_ms = backoff.next_wait().as_millis() as u64,
                "haptic device lost again right after reconnecting: force is off; reconnecting \
                 after a longer wait"
            );
        } else {
            tracing::warn!(
                device = %inner.display_name,
                error = %inner.lib.error_text(code),
                code = error_name(code),
                "haptic device lost: force is off; reconnecting"
            );
        }
        {
            let mut control = inner.control();
            inner.stop_servo(&mut control);
        }
        if inner.fatal.load(Ordering::Acquire) {
            // The tick failed while the callback was silent (a panic being reported can take
            // that long): a failed tick is never restarted.
            tracing::error!(
                device = %inner.display_name,
                "the haptic loop's servo tick failed: no force until the server restarts"
            );
            return;
        }
        inner.disable_device();
        let mut attempts = 0u32;
        loop {
            if let Some(wait) = backoff.before_attempt(attempts)
                && !sleep_unless(wait, &inner.shutting_down)
            {
                return;
            }
            if inner.shutting_down.load(Ordering::Acquire) {
                return;
            }
            attempts += 1;
            match inner.init_device() {
                Ok(_) => {
                    inner.generation.fetch_add(1, Ordering::AcqRel);
                    let mut control = inner.control();
                    inner.reconnect_wanted.store(false, Ordering::Release);
                    match inner.start_servo(&mut control) {
                        Ok(()) => {
                            tracing::info!(
                                device = %inner.display_name,
                                attempts,
                                "haptic device reconnected: force ramps in again"
                            );
                            backoff.reconnected();
                            break;
                        }
                        Err(failure) => {
                            inner.reconnect_wanted.store(true, Ordering::Release);
                            drop(control);
                            inner.disable_device();
                            tracing::debug!("{}", start_failure_text(inner, failure));
                        }
                    }
                }
                Err(code) if attempts == 1 => tracing::info!(
                    device = %inner.display_name,
                    error = %inner.lib.error_text(code),
                    "haptic device not back yet; retrying with backoff up to every {} s",
                    RECONNECT_BACKOFF_MAX.as_secs()
                ),
                Err(_) => {}
            }
        }
    }
}
