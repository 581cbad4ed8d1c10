//! Who may connect, and how much: roles and their tokens, the Origin and Host rules, the
//! security headers, and the connection limits (proto/WIRE.md, "Access").
//!
//! What this module promises, and why it holds:
//! - **A token is never shown.** [`Token`] has no `Display`, its `Debug` prints `<redacted>`,
//!   and every error of this module describes a token (its length, its line) without quoting
//!   it; the one way out is [`Token::expose_secret`], used to print the links on stdout and
//!   nowhere else. The tokens are not part of anything recorded.
//! - **Comparing a token tells an attacker nothing.** A presented token is hashed (SHA-256) and
//!   the digest is compared with both roles' digests in constant time (`subtle`), both always:
//!   hashing first makes the comparison independent of the presented length too, which a
//!   constant-time comparison of unequal slices is not.
//! - **No page on another site can drive a viewer's connection.** A WebSocket upgrade that
//!   carries an `Origin` (every browser's does) is accepted only from the server's own origin or
//!   an `--allow-origin`, and every request must name the server by an IP address, `localhost`
//!   or a `--host-name` (a DNS-rebinding page names its own domain).
//! - **Refusing is cheap and never waits.** The counts behind the limits are a few integers under
//!   a `std` mutex held for a handful of instructions and never across an `.await`; the rate
//!   limit is a token bucket owned by the connection's task. A refused client costs the others
//!   nothing, and none of this is on the haptic loop's side of the wait-free buffers.
//!
//! # Layout
//! - `tokens.rs`: [`Token`], [`Tokens`]: generation from the OS's random source, parsing, the
//!   constant-time role lookup; [`read_token_file`] for `--token-file` and the two variables.
//! - `config.rs`: [`AccessArgs`], the command-line options shared by `softhaptic run` and
//!   `replay`, resolved into an [`AccessConfig`] (tokens from the file, the environment or
//!   generated; origins; host names; [`ConnectionLimits`]), which [`AccessConfig::check_bind`]
//!   holds against the address.
//! - this file: [`Access`], what the running server consults, and [`AccessError`].
//! - `origin.rs`: the Host rule ([`Access::host_allowed`]) and the Origin rule of an upgrade
//!   ([`Access::check_origin`]), over a parsed [`Origin`].
//! - `connections.rs`: the connection counts ([`Access::admit`], [`Admission`]), the
//!   per-connection limit on incoming messages ([`MessageRate`]), and one viewer's
//!   [`Connection`] with the audit line logged when it ends.
//! - `refusal_log.rs`: the refusals' log lines, at most 20 in full per 10 s and a summary line
//!   of the rest ([`Access::log_refusal`]).
//! - `failures.rs`: wrong tokens counted per client address (IPv6 by /64), the next ones
//!   answered after a wait that doubles ([`Access::token_failed`]).
//! - `http.rs`: the middleware of the routes: the Host guard ([`guard_host`]) and the bearer
//!   token of the session-data routes ([`require_token`]).
//! - [`roles`]: who may do what ([`roles::Action`], [`roles::may`]), the one table the routes
//!   and the WebSocket messages consult (docs/roles.md).
//! - `headers.rs`: the security headers and the Content-Security-Policy of the served page
//!   ([`content_security_policy`], [`with_security_headers`]).

mod config;
mod connections;
mod failures;
mod headers;
mod http;
mod origin;
mod refusal_log;
pub mod roles;
pub mod strength;
#[cfg(test)]
mod testing;
mod tokens;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Mutex;

use axum::http::HeaderValue;

pub use config::{AccessArgs, AccessConfig, ConnectionLimits};
use connections::Counts;
pub use connections::{Admission, Connection, LimitRefusal, MessageRate};
/// The address a client is counted under by every per-address limit: IPv4 as it is (an
/// IPv4-mapped IPv6 address too), IPv6 by its /64.
pub fn client_key(ip: std::net::IpAddr) -> std::net::IpAddr {
    failures::counted_as(ip)
}

pub use headers::{content_security_policy, inline_script_hashes, with_security_headers};
pub use http::{guard_host, json_error, peer_of, refusal, require_token};
pub use origin::Origin;
pub use tokens::{
    INSTRUCTOR_TOKEN_ENV, MAX_TOKEN_CHARS, MIN_TOKEN_CHARS, OBSERVER_TOKEN_ENV, Token,
    TokenProblem, TokenSource, Tokens, read_token_file,
};

/// Close code of a WebSocket whose viewer presented no valid token (4000–4999 are the
/// application's; 4401 echoes HTTP's 401).
pub const CLOSE_UNAUTHORIZED: u16 = 4401;
/// Close code of a WebSocket refused by a connection limit (echoes HTTP's 429).
pub const CLOSE_TOO_MANY: u16 = 4429;
/// Close code of a WebSocket whose role may not do what it asked (echoes HTTP's 403): an
/// observer naming a hub's replay that no instructor has opened.
pub const CLOSE_FORBIDDEN: u16 = 4403;
/// The close reason of a wrong token.
pub const REASON_BAD_TOKEN: &str = "token not valid for this server";
/// The close reason of a connection that presented no token in time.
pub const REASON_NO_TOKEN: &str = "no token presented";

/// Why the access rules could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum AccessError {
    #[error("could not read the token file {path}: {source}")]
    TokenFileRead {
        path: PathBuf,
        #[source]
        source: crate::files::ReadError,
    },
    #[error("{path}:{line}: {problem}")]
    TokenFileLine {
        path: PathBuf,
        line: usize,
        problem: TokenProblem,
    },
    #[error("{path}: no `{role} = <token>` line; the file needs one for each role")]
    TokenFileMissing { path: PathBuf, role: &'static str },
    #[error("{name}: {problem}")]
    TokenVariable {
        name: &'static str,
        problem: TokenProblem,
    },
    #[error(
        "{set} is set but {unset} is not: give both tokens, or neither (then use --tokens or --token-file)"
    )]
    OneTokenVariable {
        set: &'static str,
        unset: &'static str,
    },
    #[error(
        "{source_name}: the instructor and observer tokens are the same; each role needs its own"
    )]
    SameTokens { source_name: String },
    #[error("could not draw a token from the operating system's random source: {0}")]
    Random(String),
    #[error(
        "refusing to serve {addr} without tokens: anyone who can reach it could watch the session. \
         Give --tokens (tokens are made at start and the links to open are printed), \
         --token-file FILE (lines `instructor = <token>` and `observer = <token>`), or set \
         {INSTRUCTOR_TOKEN_ENV} and {OBSERVER_TOKEN_ENV}; or serve this machine only with \
         --addr 127.0.0.1:PORT. On a network where everyone may watch and control the session, \
         --insecure-no-tokens starts anyway"
    )]
    NoTokensBeyondLoopback { addr: SocketAddr },
    #[error(
        "refusing to serve {names} without tokens: those names are how other machines reach \
         this server (through a reverse proxy), and without tokens anyone who reaches it could \
         watch the session and control replays. Give --tokens, --token-file FILE, or set \
         {INSTRUCTOR_TOKEN_ENV} and {OBSERVER_TOKEN_ENV}; on a network where everyone may watch \
         and control the session, --insecure-no-tokens starts anyway"
    )]
    NoTokensForRemoteNames { names: String },
    #[error("--allow-origin {value:?}: {problem}")]
    AllowOrigin {
        value: String,
        problem: &'static str,
    },
    #[error("--host-name {value:?}: {problem}")]
    HostName {
        value: String,
        problem: &'static str,
    },
}

/// The access rules of a running server and its connection counts.
#[derive(Debug)]
pub struct Access {
    pub config: AccessConfig,
    /// The Content-Security-Policy of every response, with the hashes of the served page's
    /// inline scripts.
    csp: HeaderValue,
    /// A `std` mutex, not tokio's: it is held for a few integer updates and never across an
    /// `.await`, so it cannot make a task wait on another's I/O.
    counts: Mutex<Counts>,
    /// The refusals' log lines, rate-limited (`refusal_log.rs`).
    refusals: std::sync::Arc<refusal_log::RefusalLog>,
    /// Wrong tokens per client address, to slow the next ones (`failures.rs`).
    failures: Mutex<failures::FailedTokens>,
    /// Woken when the last admitted connection has ended (a shutdown waits for it, so that
    /// every connection's audit line is written).
    idle: tokio::sync::Notify,
}

impl Access {
    /// The rules of `config` for the viewer page `page_html` (its inline scripts' hashes go
    /// into the CSP; see [`crate::viewer::Viewer::page_html`]).
    pub fn new(config: AccessConfig, page_html: &str) -> Self {
        let policy = content_security_policy(page_html);
        // Only ASCII goes into the policy (base64 and fixed words), so it is a valid header.
        let csp = HeaderValue::from_str(&policy)
            .unwrap_or_else(|_| HeaderValue::from_static("default-src 'self'"));
        let refusals = std::sync::Arc::new(refusal_log::RefusalLog::default());
        // The summary of a storm that has ended is written within an interval, not only by the
        // next refusal (when the rules run in a runtime: the servers' always do).
        if let Ok(runtime) = tokio::runtime::Handle::try_current() {
            let weak = std::sync::Arc::downgrade(&refusals);
            runtime.spawn(async move {
                let mut ticks = tokio::time::interval(refusal_log::INTERVAL);
                loop {
                    ticks.tick().await;
                    let Some(log) = weak.upgrade() else { break };
                    log.flush(std::time::Instant::now(), false);
                }
            });
        }
        Self {
            config,
            csp,
            refusals,
            counts: Mutex::new(Counts::default()),
            failures: Mutex::new(failures::FailedTokens::default()),
            idle: tokio::sync::Notify::new(),
        }
    }

    /// Resolves once no admitted connection is left.
    pub async fn until_no_connections(&self) {
        loop {
            // Registered before the count is read, so a connection ending in between still
            // wakes this.
            let notified = self.idle.notified();
            tokio::pin!(notified);
            notified.as_mut().enable();
            if self.viewers() == 0 {
                return;
            }
            notified.await;
        }
    }

    /// Whether a refusal of `kind` (its status and what was wrong, in a few words) is to be
    /// logged in full now; when not, it is counted in the interval's summary line
    /// (`refusal_log.rs`).
    pub fn log_refusal(&self, kind: &'static str) -> bool {
        self.refusals.admit(kind, std::time::Instant::now())
    }

    /// Counts a wrong token presented from `client`: how long to wait before answering it
    /// (nothing for the first few; see `failures.rs`). An unknown address is not slowed.
    pub fn token_failed(&self, client: Option<std::net::IpAddr>) -> std::time::Duration {
        match client {
            Some(ip) => self
                .failures
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .failed(ip, std::time::Instant::now()),
            None => std::time::Duration::ZERO,
        }
    }

    /// The tokens, when the server has them.
    pub fn tokens(&self) -> Option<&Tokens> {
        self.config.tokens.as_deref()
    }

    /// The Content-Security-Policy header sent with every response.
    pub fn csp(&self) -> &HeaderValue {
        &self.csp
    }
}
