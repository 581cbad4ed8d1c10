//! Failed token attempts, slowed per client address: the first few are answered at once (a
//! mistyped or expired link), then each further wrong token from that address waits before its
//! answer, twice as long each time up to a bound, until the address has made no wrong attempt
//! for a while. A right token is never slowed. The wait holds the attempt's connection, which
//! counts among those waiting for their token (`--max-pending`), so an address cannot make the
//! server guess faster by opening more connections.
//!
//! IPv6 addresses count by their /64 (one host is given a whole /64), IPv4 ones singly. The
//! table is bounded: when full, addresses not heard from for the forgetting time are dropped,
//! and if none are, the one that failed longest ago.

use std::collections::HashMap;
use std::net::IpAddr;
use std::time::{Duration, Instant};

/// Wrong tokens an address may present before its attempts are slowed.
pub const FREE_FAILURES: u32 = 5;
/// The wait before answering the first slowed attempt; it doubles with each further one...
pub const FIRST_DELAY: Duration = Duration::from_millis(250);
/// ...up to this.
pub const MAX_DELAY: Duration = Duration::from_secs(8);
/// An address that made no wrong attempt for this long starts afresh.
pub const FORGET_AFTER: Duration = Duration::from_secs(600);
/// Addresses tracked at most.
const MAX_ADDRESSES: usize = 4096;

#[derive(Debug, Clone, Copy)]
struct Failures {
    count: u32,
    last: Instant,
}

/// The wrong attempts per address (see the module's documentation).
#[derive(Debug, Default)]
pub(super) struct FailedTokens {
    by_address: HashMap<IpAddr, Failures>,
}

/// The address a client is counted under (its failures, its connections): IPv4 (and
/// IPv4-mapped IPv6) as it is, IPv6 by its /64, since one host is given a whole /64.
pub(super) fn counted_as(ip: IpAddr) -> IpAddr {
    match ip.to_canonical() {
        IpAddr::V6(v6) => {
            let prefix = u128::from(v6) & !((1u128 << 64) - 1);
            IpAddr::V6(prefix.into())
        }
        v4 => v4,
    }
}

impl FailedTokens {
    /// Counts a wrong token from `ip` at `now`; how long to wait before answering it.
    pub(super) fn failed(&mut self, ip: IpAddr, now: Instant) -> Duration {
        let key = counted_as(ip);
        if !self.by_address.contains_key(&key) && self.by_address.len() >= MAX_ADDRESSES {
            self.by_address
                .retain(|_, f| now.saturating_duration_since(f.last) < FORGET_AFTER);
            if self.by_address.len() >= MAX_ADDRESSES
                && let Some(oldest) = self
                    .by_address
                    .iter()
                    .min_by_key(|(_, f)| f.last)
                    .map(|(ip, _)| *ip)
            {
                self.by_address.remove(&oldest);
            }
        }
        let entry = self.by_address.entry(key).or_insert(Failures {
            count: 0,
            last: now,
        });
        if now.saturating_duration_since(entry.last) >= FORGET_AFTER {
            entry.count = 0;
        }
        entry.count = entry.count.saturating_add(1);
        entry.last = now;
        delay_after(entry.count)
    }
}

/// The wait before answering the `count`-th wrong token of an address.
pub fn delay_after(count: u32) -> Duration {
    match count.checked_sub(FREE_FAILURES + 1) {
        None => Duration::ZERO,
        Some(slowed) => FIRST_DELAY
            .saturating_mul(1u32.checked_shl(slowed.min(31)).unwrap_or(u32::MAX))
            .min(MAX_DELAY),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrong_tokens_are_free_then_slowed_doubling_up_to_the_bound_and_forgotten() {
        let mut failures = FailedTokens::default();
        let t0 = Instant::now();
        let ip: IpAddr = [192, 0, 2, 1].into();
        let delays: Vec<Duration> = (0..12).map(|_| failures.failed(ip, t0)).collect();
        let ms = |n| Duration::from_millis(n);
        assert_eq!(
            delays,
            [
                ms(0),
                ms(0),
                ms(0),
                ms(0),
                ms(0),
                ms(250),
                ms(500),
                ms(1000),
                ms(2000),
                ms(4000),
                ms(8000),
                ms(8000)
            ]
        );
        // Another address is not slowed by this one...
        assert_eq!(failures.failed([192, 0, 2, 2].into(), t0), ms(0));
        // ...but another address of the same IPv6 /64 is the same host.
        let a: IpAddr = "2001:db8:1:2::1".parse().unwrap();
        let b: IpAddr = "2001:db8:1:2:ffff::9".parse().unwrap();
        for _ in 0..FREE_FAILURES {
            failures.failed(a, t0);
        }
        assert_eq!(failures.failed(b, t0), FIRST_DELAY);
        // Quiet for long enough: forgiven.
        assert_eq!(failures.failed(ip, t0 + FORGET_AFTER), ms(0));
    }

    #[test]
    fn the_table_stays_bounded() {
        let mut failures = FailedTokens::default();
        let t0 = Instant::now();
        for n in 0..(MAX_ADDRESSES as u32 + 100) {
            failures.failed(IpAddr::from(n.to_be_bytes()), t0);
        }
        assert!(failures.by_address.len() <= MAX_ADDRESSES);
    }
}
