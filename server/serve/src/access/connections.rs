//! The connection limits at run time: the counts behind them ([`Access::admit`], an
//! [`Admission`] holding a connection's places until dropped), the per-connection message rate
//! ([`MessageRate`]), and one viewer's [`Connection`] with the audit line logged when it ends.
//! The counts are a few integers under a `std` mutex, never held across an `.await`.

use std::collections::HashMap;
use std::fmt;
use std::net::{IpAddr, SocketAddr};
use std::sync::Arc;
use std::time::Instant;

use softhaptic_proto::wire::Role;

use super::{Access, ConnectionLimits};

/// Why a connection was not admitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LimitRefusal {
    TooManyViewers,
    TooManyFromAddress,
    TooManyPending,
    TooManyPendingFromAddress,
}

impl LimitRefusal {
    /// The close reason (at most 123 bytes, as a close frame allows).
    pub fn reason(self) -> &'static str {
        match self {
            LimitRefusal::TooManyViewers => "too many viewers",
            LimitRefusal::TooManyFromAddress => "too many viewers from this address",
            LimitRefusal::TooManyPending => "too many connections waiting to authenticate",
            LimitRefusal::TooManyPendingFromAddress => {
                "too many connections from this address waiting to authenticate"
            }
        }
    }
}

/// The connection counts behind the limits.
#[derive(Debug, Default)]
pub(super) struct Counts {
    viewers: u32,
    pending: u32,
    per_address: HashMap<IpAddr, u32>,
    /// Connections waiting for their token, per address (loopback, a reverse proxy's, not
    /// counted): two addresses holding every waiting place would lock everyone else out.
    pending_per_address: HashMap<IpAddr, u32>,
}

impl Access {
    /// Admits a connection from `ip` (unknown: only the overall limits apply), or says which
    /// limit it would break. The admission holds its places until dropped.
    pub fn admit(self: &Arc<Self>, ip: Option<IpAddr>) -> Result<Admission, LimitRefusal> {
        let limits = self.config.limits;
        let ip = ip.map(super::failures::counted_as);
        let pending = self.config.tokens.is_some();
        // Loopback is a reverse proxy's: every viewer behind it comes from there.
        let pending_ip = ip.filter(|ip| pending && !ip.is_loopback());
        let mut counts = self.counts.lock().unwrap_or_else(|e| e.into_inner());
        if counts.viewers >= limits.max_viewers {
            return Err(LimitRefusal::TooManyViewers);
        }
        if let Some(ip) = ip
            && counts.per_address.get(&ip).copied().unwrap_or(0) >= limits.max_per_address
        {
            return Err(LimitRefusal::TooManyFromAddress);
        }
        if pending && counts.pending >= limits.max_pending {
            return Err(LimitRefusal::TooManyPending);
        }
        if let Some(ip) = pending_ip
            && counts.pending_per_address.get(&ip).copied().unwrap_or(0)
                >= limits.max_pending_per_address
        {
            return Err(LimitRefusal::TooManyPendingFromAddress);
        }
        counts.viewers += 1;
        if let Some(ip) = ip {
            *counts.per_address.entry(ip).or_insert(0) += 1;
        }
        if pending {
            counts.pending += 1;
        }
        if let Some(ip) = pending_ip {
            *counts.pending_per_address.entry(ip).or_insert(0) += 1;
        }
        Ok(Admission {
            access: Arc::clone(self),
            ip,
            pending,
            pending_ip,
        })
    }

    /// Viewers admitted now (authenticated or not).
    pub fn viewers(&self) -> u32 {
        self.counts
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .viewers
    }

    /// Connections admitted that have not presented their token yet.
    pub fn pending(&self) -> u32 {
        self.counts
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .pending
    }
}

/// A connection's places in the counts; given back when dropped.
#[derive(Debug)]
pub struct Admission {
    access: Arc<Access>,
    ip: Option<IpAddr>,
    pending: bool,
    /// The address its waiting place is counted under, while it waits.
    pending_ip: Option<IpAddr>,
}

impl Admission {
    /// The connection presented its token: it no longer waits.
    pub fn leave_pending(&mut self) {
        if std::mem::take(&mut self.pending) {
            let mut counts = self.access.counts.lock().unwrap_or_else(|e| e.into_inner());
            counts.pending = counts.pending.saturating_sub(1);
            if let Some(ip) = self.pending_ip.take() {
                release(&mut counts.pending_per_address, ip);
            }
        }
    }
}

impl Drop for Admission {
    fn drop(&mut self) {
        let mut counts = self.access.counts.lock().unwrap_or_else(|e| e.into_inner());
        counts.viewers = counts.viewers.saturating_sub(1);
        if counts.viewers == 0 {
            self.access.idle.notify_waiters();
        }
        if self.pending {
            counts.pending = counts.pending.saturating_sub(1);
        }
        if let Some(ip) = self.pending_ip {
            release(&mut counts.pending_per_address, ip);
        }
        if let Some(ip) = self.ip {
            release(&mut counts.per_address, ip);
        }
    }
}

/// Gives back one place of `ip` in `counts`, forgetting the address at zero.
fn release(counts: &mut HashMap<IpAddr, u32>, ip: IpAddr) {
    if let Some(n) = counts.get_mut(&ip) {
        *n = n.saturating_sub(1);
        if *n == 0 {
            counts.remove(&ip);
        }
    }
}

/// A token bucket on one connection's incoming messages: `rate` per second on average, `burst`
/// at once.
#[derive(Debug, Clone)]
pub struct MessageRate {
    allowance: f64,
    last: Instant,
    rate_per_s: f64,
    burst: f64,
}

impl MessageRate {
    pub fn new(limits: &ConnectionLimits, now: Instant) -> Self {
        Self {
            allowance: limits.message_burst,
            last: now,
            rate_per_s: limits.messages_per_s,
            burst: limits.message_burst,
        }
    }

    /// Takes one message's allowance at `now`; false when there is none left.
    pub fn allow(&mut self, now: Instant) -> bool {
        let elapsed_s = now.saturating_duration_since(self.last).as_secs_f64();
        self.last = now;
        self.allowance = (self.allowance + elapsed_s * self.rate_per_s).min(self.burst);
        if self.allowance >= 1.0 {
            self.allowance -= 1.0;
            true
        } else {
            false
        }
    }
}

/// One viewer connection, from its upgrade to its audit line.
#[derive(Debug)]
pub struct Connection {
    /// The client's address, when the server knows it.
    pub peer: Option<SocketAddr>,
    /// The `Origin` of the upgrade, as sent.
    pub origin: Option<String>,
    /// The role, once the connection has one.
    pub role: Option<Role>,
    started: Instant,
    admission: Option<Admission>,
    /// The rules whose refusal log the audit line of a connection without a role goes through.
    access: Arc<Access>,
}

impl Connection {
    pub fn new(
        access: &Arc<Access>,
        peer: Option<SocketAddr>,
        origin: Option<String>,
        admission: Option<Admission>,
    ) -> Self {
        Self {
            peer,
            origin,
            role: None,
            started: Instant::now(),
            admission,
            access: Arc::clone(access),
        }
    }

    /// The connection now has `role` (it presented a token, or the server has none).
    pub fn authenticated(&mut self, role: Role) {
        self.role = Some(role);
        if let Some(admission) = &mut self.admission {
            admission.leave_pending();
        }
    }

    /// Logs the audit line (time, client address, role, Origin, how it ended, how long it
    /// lasted) and gives back the connection's places in the counts. A connection that never
    /// had a role was refused: its line is a refusal's, rate-limited as they are.
    pub fn finish(self, ended: &dyn fmt::Display) {
        if self.role.is_none() && !self.access.log_refusal("WebSocket closed before a role") {
            return;
        }
        tracing::info!(
            target: "softhaptic::audit",
            client = %self.peer.map_or_else(|| "unknown".to_owned(), |p| p.to_string()),
            role = self.role.map_or("none", Role::as_str),
            // Debug formatting escapes whatever a client put in its header.
            origin = ?self.origin.as_deref().unwrap_or("none"),
            ended = %ended,
            duration_s = self.started.elapsed().as_secs_f64(),
            "viewer connection ended"
        );
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use crate::access::testing::{access, tokens};
    use crate::access::{AccessConfig, LimitRefusal};
    use std::net::Ipv4Addr;
    use std::time::Duration;

    #[test]
    fn admissions_respect_every_cap_and_give_their_places_back() {
        let a = access(AccessConfig {
            tokens: Some(Arc::new(tokens())),
            limits: ConnectionLimits {
                max_viewers: 4,
                max_per_address: 2,
                max_pending: 3,
                ..ConnectionLimits::default()
            },
            ..AccessConfig::default()
        });
        let ip = |n: u8| Some(IpAddr::from([192, 0, 2, n]));
        let mut first = a.admit(ip(1)).unwrap();
        let _second = a.admit(ip(1)).unwrap();
        assert_eq!(
            a.admit(ip(1)).unwrap_err(),
            LimitRefusal::TooManyFromAddress
        );
        // The same client over IPv6 (IPv4-mapped) is the same address.
        let mapped = Some(IpAddr::from(Ipv4Addr::new(192, 0, 2, 1).to_ipv6_mapped()));
        assert_eq!(
            a.admit(mapped).unwrap_err(),
            LimitRefusal::TooManyFromAddress
        );
        let _third = a.admit(ip(2)).unwrap();
        assert_eq!(a.admit(ip(3)).unwrap_err(), LimitRefusal::TooManyPending);
        first.leave_pending();
        assert_eq!(a.pending(), 2);
        let fourth = a.admit(ip(3)).unwrap();
        assert_eq!(a.admit(ip(4)).unwrap_err(), LimitRefusal::TooManyViewers);
        drop(fourth);
        drop(first);
        assert_eq!((a.viewers(), a.pending()), (2, 2));
        assert!(a.admit(ip(1)).is_ok());
    }

    #[test]
    fn waiting_places_are_capped_per_address_and_ipv6_counts_by_its_64() {
        let a = access(AccessConfig {
            tokens: Some(Arc::new(tokens())),
            limits: ConnectionLimits {
                max_pending_per_address: 2,
                ..ConnectionLimits::default()
            },
            ..AccessConfig::default()
        });
        let v6 = |s: &str| Some(s.parse::<IpAddr>().unwrap());
        // Two addresses of one /64: one host.
        let mut first = a.admit(v6("2001:db8:0:1::1")).unwrap();
        let _second = a.admit(v6("2001:db8:0:1::2")).unwrap();
        assert_eq!(
            a.admit(v6("2001:db8:0:1:abcd::3")).unwrap_err(),
            LimitRefusal::TooManyPendingFromAddress
        );
        // Another /64, and loopback (a reverse proxy's), are not held back by it.
        let _other = a.admit(v6("2001:db8:0:2::1")).unwrap();
        let _proxied: Vec<_> = (0..5)
            .map(|_| a.admit(Some(IpAddr::from([127, 0, 0, 1]))).unwrap())
            .collect();
        // One that presented its token no longer waits: its place is free.
        first.leave_pending();
        let _third = a.admit(v6("2001:db8:0:1::3")).unwrap();
    }

    #[test]
    fn the_message_rate_allows_a_burst_then_the_average() {
        let limits = ConnectionLimits::default();
        let t0 = Instant::now();
        let mut rate = MessageRate::new(&limits, t0);
        assert!((0..100).all(|_| rate.allow(t0)));
        assert!(!rate.allow(t0));
        // 50 messages a second come back, a message per 20 ms.
        assert!(rate.allow(t0 + Duration::from_millis(21)));
        assert!(!rate.allow(t0 + Duration::from_millis(22)));
        let later = t0 + Duration::from_secs(10);
        assert!(
            (0..100).all(|_| rate.allow(later)),
            "the burst refills, no further"
        );
        assert!(!rate.allow(later));
    }
}
