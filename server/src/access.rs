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
//! - [`Token`], [`Tokens`]: generation from the OS's random source, parsing, the constant-time
//!   role lookup; [`read_token_file`] for `--token-file`.
//! - [`AccessArgs`]: the command-line options shared by `softhaptic run` and `replay`, resolved
//!   into an [`AccessConfig`] (tokens from the file, the environment or generated; origins;
//!   host names; limits), which [`AccessConfig::check_bind`] holds against the address.
//! - [`Access`]: what the running server consults: the Host rule ([`guard_host`]), the bearer
//!   token of the session-data routes ([`require_token`]), the Origin rule of an upgrade
//!   ([`Access::check_origin`]), the connection counts ([`Access::admit`]) and the
//!   Content-Security-Policy of the served page ([`content_security_policy`],
//!   [`with_security_headers`]).
//! - [`MessageRate`]: the per-connection limit on incoming messages.
//! - [`Connection`]: one viewer's admission and the audit line logged when it ends.

use std::collections::HashMap;
use std::fmt;
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::Router;
use axum::extract::connect_info::ConnectInfo;
use axum::extract::{Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use base64::Engine;
use sha2::{Digest, Sha256};
use softhaptic_proto::wire::Role;
use subtle::ConstantTimeEq;
use tower_http::set_header::SetResponseHeaderLayer;

/// The variable holding the instructor's token (with [`OBSERVER_TOKEN_ENV`]).
pub const INSTRUCTOR_TOKEN_ENV: &str = "SOFTHAPTIC_INSTRUCTOR_TOKEN";
/// The variable holding the observer's token (with [`INSTRUCTOR_TOKEN_ENV`]).
pub const OBSERVER_TOKEN_ENV: &str = "SOFTHAPTIC_OBSERVER_TOKEN";
/// The shortest token accepted: 32 characters, as the 128 bits of a generated one in hex.
pub const MIN_TOKEN_CHARS: usize = 32;
/// The longest token accepted (a bound on what a token file can make the server hold).
pub const MAX_TOKEN_CHARS: usize = 512;
/// Bytes drawn from the OS for a generated token: 128 bits.
const GENERATED_TOKEN_BYTES: usize = 16;

/// Close code of a WebSocket whose viewer presented no valid token (4000–4999 are the
/// application's; 4401 echoes HTTP's 401).
pub const CLOSE_UNAUTHORIZED: u16 = 4401;
/// Close code of a WebSocket refused by a connection limit (echoes HTTP's 429).
pub const CLOSE_TOO_MANY: u16 = 4429;
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

/// What is wrong with a token, said without quoting it.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TokenProblem {
    #[error("the {role} token is empty")]
    Empty { role: &'static str },
    #[error(
        "the {role} token is {chars} characters long; a token needs at least {MIN_TOKEN_CHARS} \
         (e.g. 32 hex digits: `openssl rand -hex 16`)"
    )]
    TooShort { role: &'static str, chars: usize },
    #[error("the {role} token is {chars} characters long; at most {MAX_TOKEN_CHARS} are accepted")]
    TooLong { role: &'static str, chars: usize },
    #[error(
        "the {role} token has a character other than a letter, a digit, `-`, `.`, `_` or `~` \
         (it must go into a link unchanged)"
    )]
    Character { role: &'static str },
    #[error("expected `instructor = <token>` or `observer = <token>`")]
    NotAnAssignment,
    #[error("the name before `=` is neither `instructor` nor `observer`")]
    UnknownRole,
    #[error("the {role} token is given a second time (first on line {first_line})")]
    Repeated {
        role: &'static str,
        first_line: usize,
    },
}

/// One role's secret. Never displayed: see the module's first promise. Its memory is wiped when
/// it is dropped, so a freed token does not linger for a core dump or a later allocation.
#[derive(Clone, PartialEq, Eq)]
pub struct Token(zeroize::Zeroizing<String>);

impl fmt::Debug for Token {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Token(<redacted>)")
    }
}

impl Token {
    /// 128 bits from the operating system's random source, as 32 lowercase hex digits.
    pub fn generate() -> Result<Token, AccessError> {
        let mut bytes = [0u8; GENERATED_TOKEN_BYTES];
        getrandom::fill(&mut bytes).map_err(|e| AccessError::Random(e.to_string()))?;
        let mut text = String::with_capacity(2 * GENERATED_TOKEN_BYTES);
        for b in bytes {
            text.push(hex_digit(b >> 4));
            text.push(hex_digit(b & 0x0f));
        }
        Ok(Token(zeroize::Zeroizing::new(text)))
    }

    /// A token given by a person (file, variable) for `role`: at least [`MIN_TOKEN_CHARS`]
    /// characters, each one that goes into a URL unchanged (RFC 3986's unreserved set), so the
    /// printed link works as printed.
    pub fn parse(text: &str, role: Role) -> Result<Token, TokenProblem> {
        let role = role.as_str();
        let chars = text.chars().count();
        if chars == 0 {
            return Err(TokenProblem::Empty { role });
        }
        if !text
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'.' | b'_' | b'~'))
        {
            return Err(TokenProblem::Character { role });
        }
        if chars < MIN_TOKEN_CHARS {
            return Err(TokenProblem::TooShort { role, chars });
        }
        if chars > MAX_TOKEN_CHARS {
            return Err(TokenProblem::TooLong { role, chars });
        }
        Ok(Token(zeroize::Zeroizing::new(text.to_owned())))
    }

    /// The secret itself, for the one place that must show it: the links printed at start.
    pub fn expose_secret(&self) -> &str {
        &self.0
    }

    fn digest(&self) -> [u8; 32] {
        Sha256::digest(self.0.as_bytes()).into()
    }
}

fn hex_digit(nibble: u8) -> char {
    char::from(b"0123456789abcdef"[usize::from(nibble & 0x0f)])
}

/// Where the tokens came from (logged; the tokens themselves never are).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TokenSource {
    File(PathBuf),
    Environment,
    Generated,
}

impl fmt::Display for TokenSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TokenSource::File(path) => write!(f, "token file {}", path.display()),
            TokenSource::Environment => {
                write!(f, "{INSTRUCTOR_TOKEN_ENV} and {OBSERVER_TOKEN_ENV}")
            }
            TokenSource::Generated => f.write_str("generated at start (--tokens)"),
        }
    }
}

/// The two roles' tokens.
#[derive(Clone)]
pub struct Tokens {
    instructor: Token,
    observer: Token,
    /// SHA-256 of each token, what presented tokens are compared with (see the module doc).
    instructor_digest: [u8; 32],
    observer_digest: [u8; 32],
    source: TokenSource,
}

impl fmt::Debug for Tokens {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Tokens")
            .field("source", &self.source)
            .finish_non_exhaustive()
    }
}

impl Tokens {
    /// Both roles' tokens; refused when they are the same (the observer's link would then
    /// control the replay).
    pub fn new(
        instructor: Token,
        observer: Token,
        source: TokenSource,
    ) -> Result<Self, AccessError> {
        if instructor == observer {
            return Err(AccessError::SameTokens {
                source_name: source.to_string(),
            });
        }
        Ok(Self {
            instructor_digest: instructor.digest(),
            observer_digest: observer.digest(),
            instructor,
            observer,
            source,
        })
    }

    /// Two fresh tokens from the OS's random source (`--tokens`).
    pub fn generate() -> Result<Self, AccessError> {
        Self::new(
            Token::generate()?,
            Token::generate()?,
            TokenSource::Generated,
        )
    }

    /// The role whose token `presented` is, in constant time: both digests are always compared,
    /// and only then is the answer looked at.
    pub fn role_of(&self, presented: &str) -> Option<Role> {
        let digest: [u8; 32] = Sha256::digest(presented.as_bytes()).into();
        let instructor = digest.ct_eq(&self.instructor_digest);
        let observer = digest.ct_eq(&self.observer_digest);
        if bool::from(instructor) {
            Some(Role::Instructor)
        } else if bool::from(observer) {
            Some(Role::Observer)
        } else {
            None
        }
    }

    pub fn instructor(&self) -> &Token {
        &self.instructor
    }

    pub fn observer(&self) -> &Token {
        &self.observer
    }

    pub fn source(&self) -> &TokenSource {
        &self.source
    }
}

/// Reads a token file: `instructor = <token>` and `observer = <token>`, one per line; blank
/// lines and lines starting with `#` are skipped. Errors name the file and the line.
pub fn read_token_file(path: &Path) -> Result<Tokens, AccessError> {
    // Bounded (a token file is a few lines), and wiped once parsed.
    let text = crate::files::read_text(path, crate::files::FileKind::Secrets)
        .map(zeroize::Zeroizing::new)
        .map_err(|source| AccessError::TokenFileRead {
            path: path.to_path_buf(),
            source,
        })?;
    warn_if_others_may_read(path);
    parse_token_file(path, &text)
}

/// A token file others may read gives their links away: said once, at start.
fn warn_if_others_may_read(path: &Path) {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        if let Ok(meta) = std::fs::metadata(path)
            && meta.permissions().mode() & 0o077 != 0
        {
            tracing::warn!(
                file = %path.display(),
                "the token file may be read by other users of this machine (chmod 600 it)"
            );
        }
    }
}

fn parse_token_file(path: &Path, text: &str) -> Result<Tokens, AccessError> {
    let line_error = |line: usize, problem: TokenProblem| AccessError::TokenFileLine {
        path: path.to_path_buf(),
        line,
        problem,
    };
    let mut instructor: Option<(Token, usize)> = None;
    let mut observer: Option<(Token, usize)> = None;
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        let content = raw.trim();
        if content.is_empty() || content.starts_with('#') {
            continue;
        }
        let Some((name, value)) = content.split_once('=') else {
            return Err(line_error(line, TokenProblem::NotAnAssignment));
        };
        let (role, slot) = match name.trim() {
            "instructor" => (Role::Instructor, &mut instructor),
            "observer" => (Role::Observer, &mut observer),
            _ => return Err(line_error(line, TokenProblem::UnknownRole)),
        };
        if let Some((_, first_line)) = slot {
            return Err(line_error(
                line,
                TokenProblem::Repeated {
                    role: role.as_str(),
                    first_line: *first_line,
                },
            ));
        }
        let token = Token::parse(value.trim(), role).map_err(|p| line_error(line, p))?;
        *slot = Some((token, line));
    }
    let missing = |role: &'static str| AccessError::TokenFileMissing {
        path: path.to_path_buf(),
        role,
    };
    let (instructor, _) = instructor.ok_or_else(|| missing("instructor"))?;
    let (observer, _) = observer.ok_or_else(|| missing("observer"))?;
    Tokens::new(instructor, observer, TokenSource::File(path.to_path_buf()))
}

/// The tokens of [`INSTRUCTOR_TOKEN_ENV`] and [`OBSERVER_TOKEN_ENV`] as `env` gives them; `None`
/// when neither is set (an empty variable counts as unset).
fn tokens_from_environment(
    env: &dyn Fn(&str) -> Option<String>,
) -> Result<Option<Tokens>, AccessError> {
    let read = |name: &str| env(name).filter(|v| !v.is_empty());
    match (read(INSTRUCTOR_TOKEN_ENV), read(OBSERVER_TOKEN_ENV)) {
        (None, None) => Ok(None),
        (Some(_), None) => Err(AccessError::OneTokenVariable {
            set: INSTRUCTOR_TOKEN_ENV,
            unset: OBSERVER_TOKEN_ENV,
        }),
        (None, Some(_)) => Err(AccessError::OneTokenVariable {
            set: OBSERVER_TOKEN_ENV,
            unset: INSTRUCTOR_TOKEN_ENV,
        }),
        (Some(i), Some(o)) => {
            let parse = |text: &str, role, name| {
                Token::parse(text.trim(), role)
                    .map_err(|problem| AccessError::TokenVariable { name, problem })
            };
            let instructor = parse(&i, Role::Instructor, INSTRUCTOR_TOKEN_ENV)?;
            let observer = parse(&o, Role::Observer, OBSERVER_TOKEN_ENV)?;
            Tokens::new(instructor, observer, TokenSource::Environment).map(Some)
        }
    }
}

/// An origin, `scheme://host[:port]`, with the host in lower case and the port made explicit,
/// so two spellings of the same origin compare equal.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Origin {
    scheme: String,
    host: String,
    port: u16,
}

impl fmt::Display for Origin {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}://{}:{}", self.scheme, self.host, self.port)
    }
}

impl Origin {
    /// Parses an `Origin` header or an `--allow-origin` value (one trailing `/` is tolerated in
    /// the latter's spelling).
    pub fn parse(text: &str) -> Result<Origin, &'static str> {
        let (scheme, rest) = text
            .split_once("://")
            .ok_or("an origin is scheme://host[:port], e.g. https://lab.example:8443")?;
        let scheme = scheme.to_ascii_lowercase();
        let default_port = match scheme.as_str() {
            "http" => 80,
            "https" => 443,
            _ => return Err("the scheme must be http or https"),
        };
        let rest = rest.strip_suffix('/').unwrap_or(rest);
        if rest.contains(['/', '?', '#', '@']) {
            return Err("an origin has no path, query, fragment or user");
        }
        let (host, port) = split_host_port(rest).ok_or("the host or the port is not valid")?;
        Ok(Origin {
            scheme,
            host,
            port: port.unwrap_or(default_port),
        })
    }
}

/// Splits `host[:port]` (an IPv6 address in brackets) into the lower-case host and the port;
/// `None` when either is malformed.
fn split_host_port(text: &str) -> Option<(String, Option<u16>)> {
    let (host, port) = if let Some(rest) = text.strip_prefix('[') {
        let (v6, after) = rest.split_once(']')?;
        v6.parse::<Ipv6Addr>().ok()?;
        let port = match after {
            "" => None,
            p => Some(p.strip_prefix(':')?),
        };
        (format!("[{v6}]"), port)
    } else {
        match text.rsplit_once(':') {
            Some((h, p)) => (h.to_owned(), Some(p)),
            None => (text.to_owned(), None),
        }
    };
    if host.is_empty()
        || !host.bytes().all(|b| {
            b.is_ascii_alphanumeric() || matches!(b, b'.' | b'-' | b'_' | b'[' | b']' | b':')
        })
    {
        return None;
    }
    let port = match port {
        None => None,
        Some(p) => Some(p.parse::<u16>().ok()?),
    };
    Some((host.to_ascii_lowercase(), port))
}

/// Whether `host` (a `Host` header's host, lower case, without the port) is an IP-address
/// literal: any address is a name the server may be reached by, while a DNS-rebinding page
/// always names its own domain.
fn is_ip_literal(host: &str) -> bool {
    if let Some(v6) = host.strip_prefix('[').and_then(|h| h.strip_suffix(']')) {
        return v6.parse::<Ipv6Addr>().is_ok();
    }
    host.parse::<Ipv4Addr>().is_ok()
}

/// The limits on connections (proto/WIRE.md, "Limits").
#[derive(Debug, Clone, Copy)]
pub struct ConnectionLimits {
    /// Viewers connected at once, whether authenticated yet or not.
    pub max_viewers: u32,
    /// Viewers connected at once from one client address.
    pub max_per_address: u32,
    /// Connections waiting to present their token.
    pub max_pending: u32,
    /// Incoming messages a connection may send per second, on average...
    pub messages_per_s: f64,
    /// ...and at once, after a quiet spell.
    pub message_burst: f64,
    /// How long a connection may take to present its token.
    pub auth_timeout: Duration,
}

impl Default for ConnectionLimits {
    fn default() -> Self {
        Self {
            max_viewers: 500,
            max_per_address: 50,
            max_pending: 64,
            // A viewer sends a handful of messages per click; a person cannot click 50 times a
            // second, a script flooding the server can.
            messages_per_s: 50.0,
            message_burst: 100.0,
            auth_timeout: Duration::from_secs(10),
        }
    }
}

/// The access rules a server runs with.
#[derive(Debug, Clone)]
pub struct AccessConfig {
    /// The roles' tokens; `None`: every connection is an instructor (loopback quick start, or
    /// `--insecure-no-tokens`).
    pub tokens: Option<Arc<Tokens>>,
    /// Allow serving beyond loopback without tokens.
    pub insecure_no_tokens: bool,
    /// Origins accepted besides the server's own.
    pub allowed_origins: Vec<Origin>,
    /// Names the server answers to besides IP-address literals and `localhost`, lower case.
    pub host_names: Vec<String>,
    /// The server speaks https and wss (TLS): its own origin's scheme is `https`.
    pub secure_transport: bool,
    pub limits: ConnectionLimits,
}

impl Default for AccessConfig {
    /// The loopback quick start: no tokens, own origin only, IP literals and `localhost`.
    fn default() -> Self {
        Self {
            tokens: None,
            insecure_no_tokens: false,
            allowed_origins: Vec::new(),
            host_names: Vec::new(),
            secure_transport: false,
            limits: ConnectionLimits::default(),
        }
    }
}

impl AccessConfig {
    /// Refuses to serve `addr` beyond loopback without tokens, unless `--insecure-no-tokens`
    /// (then warns, loudly).
    pub fn check_bind(&self, addr: SocketAddr) -> Result<(), AccessError> {
        if self.tokens.is_some() || addr.ip().is_loopback() {
            return Ok(());
        }
        if !self.insecure_no_tokens {
            return Err(AccessError::NoTokensBeyondLoopback { addr });
        }
        tracing::warn!(
            %addr,
            "INSECURE: serving beyond this machine WITHOUT TOKENS (--insecure-no-tokens): anyone \
             who can reach {addr} can watch the session and control replays"
        );
        Ok(())
    }

    /// The links to print: the instructor's and the observer's, the token in the fragment (a
    /// fragment never reaches a server's log or a proxy). `None` without tokens.
    /// The base of the links to hand out for a server at `base_url`: an address bound to every
    /// interface (`0.0.0.0`, `::`) names no machine a viewer can reach, so the first
    /// `--host-name` takes its place when there is one.
    pub fn public_base(&self, base_url: &str, local_addr: std::net::SocketAddr) -> String {
        match self.host_names.first() {
            Some(name) if local_addr.ip().is_unspecified() => {
                let scheme = if self.secure_transport {
                    "https"
                } else {
                    "http"
                };
                format!("{scheme}://{name}:{}/", local_addr.port())
            }
            _ => base_url.to_owned(),
        }
    }

    pub fn links(&self, base_url: &str) -> Option<(String, String)> {
        let tokens = self.tokens.as_ref()?;
        let link = |t: &Token| format!("{base_url}#token={}", t.expose_secret());
        Some((link(tokens.instructor()), link(tokens.observer())))
    }

    /// Prints on stdout (never in a log: the token is in the link) the links to open for a server
    /// at `url` bound to `addr`: one per role when there are tokens, `{label}: URL` otherwise;
    /// `labels` are the instructor's and the observer's.
    pub fn print_links(&mut self, url: &str, addr: SocketAddr, labels: [&str; 2]) {
        self.secure_transport = url.starts_with("https:");
        let base = self.public_base(url, addr);
        match self.links(&base) {
            Some((instructor, observer)) => {
                crate::logging::print_line(format_args!("{}: {instructor}", labels[0]));
                crate::logging::print_line(format_args!("{}: {observer}", labels[1]));
            }
            None => crate::logging::print_line(format_args!("{}: {base}", labels[0])),
        }
    }
}

/// The access options of `softhaptic run` and `softhaptic replay`.
#[derive(clap::Args, Debug, Clone)]
pub struct AccessArgs {
    /// Read the tokens from FILE: lines `instructor = <token>` and `observer = <token>` (each at
    /// least 32 letters, digits, `-`, `.`, `_` or `~`). Takes precedence over the
    /// SOFTHAPTIC_INSTRUCTOR_TOKEN and SOFTHAPTIC_OBSERVER_TOKEN variables, which give the
    /// tokens otherwise.
    #[arg(long, value_name = "FILE", conflicts_with = "tokens")]
    pub token_file: Option<PathBuf>,
    /// Make an instructor token and an observer token at start (128 random bits each) and print
    /// a link to open for each.
    #[arg(long)]
    pub tokens: bool,
    /// Serve an address beyond loopback without tokens: anyone who reaches it watches the
    /// session and controls replays. Only for a network where that is wanted.
    #[arg(long, conflicts_with_all = ["tokens", "token_file"])]
    pub insecure_no_tokens: bool,
    /// Also accept WebSocket connections from pages of this origin (scheme://host[:port]);
    /// repeatable. The server's own origin is always accepted.
    #[arg(long = "allow-origin", value_name = "ORIGIN")]
    pub allow_origin: Vec<String>,
    /// A DNS name this server is reached by (repeatable); requests naming any other host than
    /// these, an IP address or localhost are refused (421).
    #[arg(long = "host-name", value_name = "NAME")]
    pub host_name: Vec<String>,
    /// Viewers connected at once; more are refused (close code 4429).
    #[arg(long, default_value_t = 500, value_name = "N")]
    pub max_viewers: u32,
    /// Viewers connected at once from one client address; more are refused (4429).
    #[arg(long, default_value_t = 50, value_name = "N")]
    pub max_viewers_per_address: u32,
    /// Connections waiting to present their token; more are refused (4429).
    #[arg(long, default_value_t = 64, value_name = "N")]
    pub max_pending: u32,
}

impl AccessArgs {
    /// The rules for serving `addr`, with the tokens from the file, the process's environment or
    /// generated; refused as [`AccessConfig::check_bind`] says.
    pub fn resolve(&self, addr: SocketAddr) -> Result<AccessConfig, AccessError> {
        self.resolve_with_env(addr, &|name| std::env::var(name).ok())
    }

    /// [`AccessArgs::resolve`] with the environment given by `env`.
    pub fn resolve_with_env(
        &self,
        addr: SocketAddr,
        env: &dyn Fn(&str) -> Option<String>,
    ) -> Result<AccessConfig, AccessError> {
        let tokens = match &self.token_file {
            Some(path) => {
                if tokens_from_environment(env).ok().flatten().is_some() {
                    tracing::info!(
                        "a token file is given: {INSTRUCTOR_TOKEN_ENV} and {OBSERVER_TOKEN_ENV} are ignored"
                    );
                }
                Some(read_token_file(path)?)
            }
            None => match tokens_from_environment(env)? {
                Some(tokens) => Some(tokens),
                None if self.tokens => Some(Tokens::generate()?),
                None => None,
            },
        };
        let allowed_origins = self
            .allow_origin
            .iter()
            .map(|value| {
                Origin::parse(value).map_err(|problem| AccessError::AllowOrigin {
                    value: value.clone(),
                    problem,
                })
            })
            .collect::<Result<_, _>>()?;
        let host_names = self
            .host_name
            .iter()
            .map(|value| {
                let name = value.trim_end_matches('.').to_ascii_lowercase();
                let valid = !name.is_empty()
                    && name
                        .bytes()
                        .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'-' | b'_'));
                if valid {
                    Ok(name)
                } else {
                    Err(AccessError::HostName {
                        value: value.clone(),
                        problem: "a host name is letters, digits, `.`, `-` and `_` (no port)",
                    })
                }
            })
            .collect::<Result<_, _>>()?;
        let config = AccessConfig {
            tokens: tokens.map(Arc::new),
            insecure_no_tokens: self.insecure_no_tokens,
            allowed_origins,
            host_names,
            secure_transport: false,
            limits: ConnectionLimits {
                max_viewers: self.max_viewers,
                max_per_address: self.max_viewers_per_address,
                max_pending: self.max_pending,
                ..ConnectionLimits::default()
            },
        };
        config.check_bind(addr)?;
        match &config.tokens {
            Some(tokens) => tracing::info!(source = %tokens.source(), "viewers need a token"),
            None => tracing::info!("no tokens: every viewer is an instructor"),
        }
        Ok(config)
    }
}

/// Why a connection was not admitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LimitRefusal {
    TooManyViewers,
    TooManyFromAddress,
    TooManyPending,
}

impl LimitRefusal {
    /// The close reason (at most 123 bytes, as a close frame allows).
    pub fn reason(self) -> &'static str {
        match self {
            LimitRefusal::TooManyViewers => "too many viewers",
            LimitRefusal::TooManyFromAddress => "too many viewers from this address",
            LimitRefusal::TooManyPending => "too many connections waiting to authenticate",
        }
    }
}

/// The connection counts behind the limits.
#[derive(Debug, Default)]
struct Counts {
    viewers: u32,
    pending: u32,
    per_address: HashMap<IpAddr, u32>,
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
    /// Woken when the last admitted connection has ended (a shutdown waits for it, so that
    /// every connection's audit line is written).
    idle: tokio::sync::Notify,
}

impl Access {
    /// The rules of `config` for the viewer in `web_dir` (its `index.html` gives the CSP's
    /// script hashes).
    pub fn new(config: AccessConfig, web_dir: &Path) -> Self {
        let index = web_dir.join("index.html");
        let page = match std::fs::read_to_string(&index) {
            Ok(page) => page,
            Err(e) => {
                tracing::debug!(file = %index.display(), error = %e, "no viewer page to hash for the CSP");
                String::new()
            }
        };
        let policy = content_security_policy(&page);
        // Only ASCII goes into the policy (base64 and fixed words), so it is a valid header.
        let csp = HeaderValue::from_str(&policy)
            .unwrap_or_else(|_| HeaderValue::from_static("default-src 'self'"));
        Self {
            config,
            csp,
            counts: Mutex::new(Counts::default()),
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

    /// The tokens, when the server has them.
    pub fn tokens(&self) -> Option<&Tokens> {
        self.config.tokens.as_deref()
    }

    /// The Content-Security-Policy header sent with every response.
    pub fn csp(&self) -> &HeaderValue {
        &self.csp
    }

    /// Whether a request naming `host` (a `Host` header, with or without port) is for this
    /// server: an IP-address literal, `localhost`, or a `--host-name`.
    pub fn host_allowed(&self, host: &str) -> bool {
        let Some((name, _)) = split_host_port(host) else {
            return false;
        };
        let name = name.trim_end_matches('.');
        is_ip_literal(name)
            || name == "localhost"
            || self.config.host_names.iter().any(|n| n == name)
    }

    /// The Origin rule of a WebSocket upgrade: no `Origin` (not a browser: the token guards
    /// it), the server's own (same scheme, host and port as the request's `Host`), or an
    /// `--allow-origin`. `Ok` carries the origin for the audit line; `Err` says why not.
    pub fn check_origin(&self, headers: &HeaderMap) -> Result<Option<String>, String> {
        let Some(value) = headers.get(header::ORIGIN) else {
            return Ok(None);
        };
        let text = value
            .to_str()
            .map_err(|_| "the Origin header is not text".to_owned())?;
        let origin = Origin::parse(text)
            .map_err(|problem| format!("Origin {text:?} is not an origin: {problem}"))?;
        if self.config.allowed_origins.contains(&origin) {
            return Ok(Some(text.to_owned()));
        }
        let scheme = if self.config.secure_transport {
            "https"
        } else {
            "http"
        };
        let own = request_host(headers)
            .and_then(|h| split_host_port(&h))
            .map(|(host, port)| Origin {
                scheme: scheme.to_owned(),
                host,
                port: port.unwrap_or(if self.config.secure_transport {
                    443
                } else {
                    80
                }),
            });
        match own {
            Some(own) if own == origin => Ok(Some(text.to_owned())),
            Some(own) => Err(format!(
                "Origin {text:?} is neither this server's own ({own}) nor given with --allow-origin"
            )),
            None => Err(format!("Origin {text:?} with no Host to compare it with")),
        }
    }

    /// Admits a connection from `ip` (unknown: only the overall limits apply), or says which
    /// limit it would break. The admission holds its places until dropped.
    pub fn admit(self: &Arc<Self>, ip: Option<IpAddr>) -> Result<Admission, LimitRefusal> {
        let limits = self.config.limits;
        let ip = ip.map(|ip| ip.to_canonical());
        let pending = self.config.tokens.is_some();
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
        counts.viewers += 1;
        if let Some(ip) = ip {
            *counts.per_address.entry(ip).or_insert(0) += 1;
        }
        if pending {
            counts.pending += 1;
        }
        Ok(Admission {
            access: Arc::clone(self),
            ip,
            pending,
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
}

impl Admission {
    /// The connection presented its token: it no longer waits.
    pub fn leave_pending(&mut self) {
        if std::mem::take(&mut self.pending) {
            let mut counts = self.access.counts.lock().unwrap_or_else(|e| e.into_inner());
            counts.pending = counts.pending.saturating_sub(1);
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
        if let Some(ip) = self.ip
            && let Some(n) = counts.per_address.get_mut(&ip)
        {
            *n = n.saturating_sub(1);
            if *n == 0 {
                counts.per_address.remove(&ip);
            }
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
}

impl Connection {
    pub fn new(
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
    /// lasted) and gives back the connection's places in the counts.
    pub fn finish(self, ended: &dyn fmt::Display) {
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

/// The host a request names: its `Host` header, else its URI's authority (HTTP/2).
fn request_host(headers: &HeaderMap) -> Option<String> {
    headers
        .get(header::HOST)
        .and_then(|h| h.to_str().ok())
        .map(str::to_owned)
}

/// The client's address of a request, when the server was started with connection info.
pub fn peer_of(request: &Request) -> Option<SocketAddr> {
    request
        .extensions()
        .get::<ConnectInfo<SocketAddr>>()
        .map(|c| c.0)
}

/// Middleware: a request whose `Host` is not one of the server's names is refused with 421
/// Misdirected Request (DNS rebinding: a page of another site that resolved its own name to
/// this address).
pub async fn guard_host(
    State(access): State<Arc<Access>>,
    request: Request,
    next: Next,
) -> Response {
    let host = request_host(request.headers())
        .or_else(|| request.uri().authority().map(|a| a.to_string()));
    match host {
        Some(host) if access.host_allowed(&host) => next.run(request).await,
        host => {
            tracing::warn!(
                client = %peer_of(&request).map_or_else(|| "unknown".to_owned(), |p| p.to_string()),
                host = ?host.as_deref().unwrap_or("none"),
                path = %request.uri().path(),
                "request refused (421): the Host is not a name of this server; give it with --host-name if it is"
            );
            json_error(
                StatusCode::MISDIRECTED_REQUEST,
                "this server is not reached by that host name",
            )
        }
    }
}

/// Middleware of the session-data routes: with tokens, `Authorization: Bearer <token>` of
/// either role, else 401 with `WWW-Authenticate: Bearer`.
pub async fn require_token(
    State(access): State<Arc<Access>>,
    request: Request,
    next: Next,
) -> Response {
    let Some(tokens) = access.tokens() else {
        return next.run(request).await;
    };
    let presented = request
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| {
            let (scheme, token) = v.trim().split_once(' ')?;
            scheme.eq_ignore_ascii_case("bearer").then(|| token.trim())
        });
    let (reason, challenge) = match presented.map(|t| tokens.role_of(t)) {
        Some(Some(_)) => return next.run(request).await,
        Some(None) => (REASON_BAD_TOKEN, "Bearer error=\"invalid_token\""),
        None => (REASON_NO_TOKEN, "Bearer"),
    };
    tracing::warn!(
        client = %peer_of(&request).map_or_else(|| "unknown".to_owned(), |p| p.to_string()),
        path = %request.uri().path(),
        "request refused (401): {reason}"
    );
    let mut response = json_error(StatusCode::UNAUTHORIZED, reason);
    response.headers_mut().insert(
        header::WWW_AUTHENTICATE,
        HeaderValue::from_static(challenge),
    );
    response
}

/// A JSON error response: `{"error": "<reason>"}`.
pub fn json_error(status: StatusCode, reason: &str) -> Response {
    let body = serde_json::json!({ "error": reason }).to_string();
    (status, [(header::CONTENT_TYPE, "application/json")], body).into_response()
}

/// The Content-Security-Policy for a viewer page: only the server's own scripts (and the page's
/// inline scripts, by their hashes), styles and WebSocket; no plugins, no framing, no forms.
pub fn content_security_policy(page_html: &str) -> String {
    let mut script_src = String::from("'self'");
    for hash in inline_script_hashes(page_html) {
        script_src.push_str(&format!(" 'sha256-{hash}'"));
    }
    format!(
        "default-src 'self'; script-src {script_src}; style-src 'self'; connect-src 'self'; \
         img-src 'self' data:; object-src 'none'; base-uri 'none'; form-action 'none'; \
         frame-ancestors 'none'"
    )
}

/// SHA-256 (base64) of the text of every inline `<script>` (one without `src`) of a page, as
/// CSP hashes them: the exact characters between the tags.
pub fn inline_script_hashes(page_html: &str) -> Vec<String> {
    // ASCII lower-casing keeps every byte offset, so positions found in `lower` index `page_html`.
    let lower = page_html.to_ascii_lowercase();
    let mut hashes = Vec::new();
    let mut at = 0;
    while let Some(found) = lower[at..].find("<script") {
        let tag_start = at + found;
        let Some(tag_len) = lower[tag_start..].find('>') else {
            break;
        };
        let tag = &lower[tag_start + "<script".len()..tag_start + tag_len];
        let content_start = tag_start + tag_len + 1;
        let Some(content_len) = lower[content_start..].find("</script") else {
            break;
        };
        let has_src = tag
            .split(|c: char| c.is_ascii_whitespace())
            .any(|attr| attr == "src" || attr.starts_with("src="));
        if !has_src {
            let content = &page_html[content_start..content_start + content_len];
            hashes.push(base64::engine::general_purpose::STANDARD.encode(Sha256::digest(content)));
        }
        at = content_start + content_len;
    }
    hashes
}

/// Adds the security headers to every response of `router` (pages, scripts, API, errors):
/// the CSP, `nosniff`, no referrer, no framing.
pub fn with_security_headers(router: Router, csp: HeaderValue) -> Router {
    router
        .layer(SetResponseHeaderLayer::overriding(
            header::CONTENT_SECURITY_POLICY,
            csp,
        ))
        .layer(SetResponseHeaderLayer::overriding(
            header::X_CONTENT_TYPE_OPTIONS,
            HeaderValue::from_static("nosniff"),
        ))
        .layer(SetResponseHeaderLayer::overriding(
            header::REFERRER_POLICY,
            HeaderValue::from_static("no-referrer"),
        ))
        .layer(SetResponseHeaderLayer::overriding(
            header::X_FRAME_OPTIONS,
            HeaderValue::from_static("DENY"),
        ))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    const I: &str = "0123456789abcdef0123456789abcdef";
    const O: &str = "fedcba9876543210fedcba9876543210";

    fn tokens() -> Tokens {
        Tokens::new(
            Token::parse(I, Role::Instructor).unwrap(),
            Token::parse(O, Role::Observer).unwrap(),
            TokenSource::Environment,
        )
        .unwrap()
    }

    fn access(config: AccessConfig) -> Arc<Access> {
        Arc::new(Access::new(config, Path::new("/nonexistent")))
    }

    #[test]
    fn links_name_the_host_name_when_the_server_listens_on_every_interface() {
        let mut config = AccessConfig {
            host_names: vec!["lab-pc.example".into()],
            ..AccessConfig::default()
        };
        let any: SocketAddr = ([0, 0, 0, 0], 8443).into();
        assert_eq!(
            config.public_base("http://0.0.0.0:8443/", any),
            "http://lab-pc.example:8443/"
        );
        config.secure_transport = true;
        assert_eq!(
            config.public_base("https://0.0.0.0:8443/", any),
            "https://lab-pc.example:8443/"
        );
        // A specific address is reachable as printed.
        let one: SocketAddr = ([192, 0, 2, 10], 8443).into();
        assert_eq!(
            config.public_base("https://192.0.2.10:8443/", one),
            "https://192.0.2.10:8443/"
        );
        config.host_names.clear();
        assert_eq!(
            config.public_base("http://0.0.0.0:8443/", any),
            "http://0.0.0.0:8443/"
        );
    }

    #[test]
    fn generated_tokens_are_32_lowercase_hex_digits_and_differ() {
        let a = Token::generate().unwrap();
        let b = Token::generate().unwrap();
        for t in [&a, &b] {
            assert_eq!(t.expose_secret().len(), 32);
            assert!(
                t.expose_secret()
                    .bytes()
                    .all(|c| c.is_ascii_digit() || (b'a'..=b'f').contains(&c))
            );
        }
        assert_ne!(a, b);
        let both = Tokens::generate().unwrap();
        assert_ne!(both.instructor(), both.observer());
    }

    #[test]
    fn each_token_gives_its_role_and_anything_else_none() {
        let t = tokens();
        assert_eq!(t.role_of(I), Some(Role::Instructor));
        assert_eq!(t.role_of(O), Some(Role::Observer));
        for wrong in [
            "",
            "0123456789abcdef0123456789abcdee",
            &I[..31],
            &format!("{I}0"),
        ] {
            assert_eq!(t.role_of(wrong), None, "{wrong:?}");
        }
    }

    #[test]
    fn nothing_that_debug_prints_shows_a_token() {
        let t = tokens();
        let shown = format!(
            "{t:?} {:?} {:?} {:?}",
            t.instructor(),
            AccessConfig {
                tokens: Some(Arc::new(t.clone())),
                ..AccessConfig::default()
            },
            Token::generate().unwrap()
        );
        assert!(!shown.contains(I) && !shown.contains(O), "{shown}");
    }

    #[test]
    fn a_token_file_is_read_within_a_bound_and_only_from_a_regular_file() {
        let dir = tempfile::tempdir().unwrap();
        let good = dir.path().join("tokens");
        std::fs::write(&good, format!("instructor = {I}\nobserver = {O}\n")).unwrap();
        assert_eq!(
            read_token_file(&good).unwrap().role_of(O),
            Some(Role::Observer)
        );
        // A device that never ends, a directory, a file far larger than a few lines of tokens:
        // refused by name, without reading them whole.
        let huge = dir.path().join("huge");
        std::fs::write(&huge, vec![b'#'; 100 << 10]).unwrap();
        for (path, expected) in [
            (Path::new("/dev/zero"), "not a regular file"),
            (dir.path(), "not a regular file"),
            (huge.as_path(), "a token or credentials file may be"),
        ] {
            let e = read_token_file(path).err().unwrap().to_string();
            assert!(e.contains(&path.display().to_string()), "{e}");
            assert!(e.contains(expected), "{e}");
        }
    }

    #[test]
    fn a_token_file_is_read_and_its_errors_name_file_line_and_problem_without_the_token() {
        let path = Path::new("/lab/tokens.txt");
        let good = format!("# the lab's links\n\ninstructor = {I}\n  observer={O}  \n");
        let t = parse_token_file(path, &good).unwrap();
        assert_eq!(t.role_of(I), Some(Role::Instructor));
        assert_eq!(t.role_of(O), Some(Role::Observer));
        assert_eq!(t.source(), &TokenSource::File(path.to_path_buf()));

        let short = "0123456789abcdef";
        let cases = [
            (
                format!("instructor = {short}\nobserver = {O}\n"),
                "/lab/tokens.txt:1: the instructor token is 16 characters long; a token needs at least 32",
            ),
            (
                format!("instructor = {I}\n{O}\n"),
                "/lab/tokens.txt:2: expected `instructor = <token>`",
            ),
            (
                format!("instructor = {I}\ntrainee = {O}\n"),
                "/lab/tokens.txt:2: the name before `=` is neither",
            ),
            (
                format!("instructor = {I}\ninstructor = {O}\n"),
                "/lab/tokens.txt:2: the instructor token is given a second time (first on line 1)",
            ),
            (
                format!("instructor = {I}\n"),
                "/lab/tokens.txt: no `observer = <token>` line",
            ),
            (
                format!("instructor = {I}\nobserver = {I}\n"),
                "the instructor and observer tokens are the same",
            ),
            (
                format!("instructor = {I}\nobserver = {O}#x\n"),
                "/lab/tokens.txt:2: the observer token has a character other than",
            ),
            (
                "instructor =\nobserver = x\n".to_owned(),
                "/lab/tokens.txt:1: the instructor token is empty",
            ),
        ];
        for (text, expected) in cases {
            let err = parse_token_file(path, &text).unwrap_err().to_string();
            assert!(
                err.starts_with(expected) || err.contains(expected),
                "{err}\nexpected: {expected}"
            );
            for secret in [I, O, short] {
                assert!(!err.contains(secret), "the error shows a token: {err}");
            }
        }
    }

    #[test]
    fn tokens_come_from_the_file_then_the_environment_then_generation() {
        let addr: SocketAddr = ([127, 0, 0, 1], 8080).into();
        let args = AccessArgs {
            token_file: None,
            tokens: false,
            insecure_no_tokens: false,
            allow_origin: Vec::new(),
            host_name: Vec::new(),
            max_viewers: 500,
            max_viewers_per_address: 50,
            max_pending: 64,
        };
        let no_env = |_: &str| None;
        assert!(
            args.resolve_with_env(addr, &no_env)
                .unwrap()
                .tokens
                .is_none()
        );
        let env = |name: &str| match name {
            INSTRUCTOR_TOKEN_ENV => Some(I.to_owned()),
            OBSERVER_TOKEN_ENV => Some(O.to_owned()),
            _ => None,
        };
        let config = args.resolve_with_env(addr, &env).unwrap();
        let t = config.tokens.unwrap();
        assert_eq!(
            (t.role_of(I), t.source()),
            (Some(Role::Instructor), &TokenSource::Environment)
        );
        let generated = AccessArgs {
            tokens: true,
            ..args.clone()
        };
        let config = generated.resolve_with_env(addr, &no_env).unwrap();
        assert_eq!(config.tokens.unwrap().source(), &TokenSource::Generated);
        // The environment wins over generation: a lab's stable links stay stable.
        let config = generated.resolve_with_env(addr, &env).unwrap();
        assert_eq!(config.tokens.unwrap().source(), &TokenSource::Environment);

        let one = |name: &str| (name == OBSERVER_TOKEN_ENV).then(|| O.to_owned());
        let err = args.resolve_with_env(addr, &one).unwrap_err().to_string();
        assert!(
            err.contains("SOFTHAPTIC_OBSERVER_TOKEN is set but SOFTHAPTIC_INSTRUCTOR_TOKEN is not"),
            "{err}"
        );
        let short = |name: &str| match name {
            INSTRUCTOR_TOKEN_ENV => Some("abc".to_owned()),
            _ => Some(O.to_owned()),
        };
        let err = args.resolve_with_env(addr, &short).unwrap_err().to_string();
        assert!(
            err.starts_with(
                "SOFTHAPTIC_INSTRUCTOR_TOKEN: the instructor token is 3 characters long"
            ),
            "{err}"
        );
    }

    #[test]
    fn serving_beyond_loopback_needs_tokens_or_the_insecure_option() {
        let config = AccessConfig::default();
        for loopback in ["127.0.0.1:8080", "[::1]:8080"] {
            config.check_bind(loopback.parse().unwrap()).unwrap();
        }
        for open in ["0.0.0.0:8080", "[::]:8080", "192.0.2.7:8080"] {
            let err = config
                .check_bind(open.parse().unwrap())
                .unwrap_err()
                .to_string();
            for says in [
                "--tokens",
                "--token-file",
                INSTRUCTOR_TOKEN_ENV,
                OBSERVER_TOKEN_ENV,
                "--insecure-no-tokens",
            ] {
                assert!(err.contains(says), "{err}");
            }
        }
        let insecure = AccessConfig {
            insecure_no_tokens: true,
            ..AccessConfig::default()
        };
        insecure
            .check_bind("0.0.0.0:8080".parse().unwrap())
            .unwrap();
        let with_tokens = AccessConfig {
            tokens: Some(Arc::new(tokens())),
            ..AccessConfig::default()
        };
        with_tokens
            .check_bind("0.0.0.0:8080".parse().unwrap())
            .unwrap();
        let (viewer, observer) = with_tokens.links("http://lab:8080/").unwrap();
        assert_eq!(viewer, format!("http://lab:8080/#token={I}"));
        assert_eq!(observer, format!("http://lab:8080/#token={O}"));
    }

    #[test]
    fn hosts_are_ip_literals_localhost_or_given_names() {
        let a = access(AccessConfig {
            host_names: vec!["lab.example".into()],
            ..AccessConfig::default()
        });
        for ok in [
            "127.0.0.1:8080",
            "10.1.2.3",
            "[::1]:8080",
            "[fe80::1]",
            "localhost:8080",
            "LOCALHOST",
            "localhost.",
            "lab.example:8443",
            "LAB.example",
        ] {
            assert!(a.host_allowed(ok), "{ok}");
        }
        for refused in [
            "evil.example",
            "evil.example:8080",
            "lab.example.evil.example",
            "127.0.0.1.nip.io",
            "2130706433",
            "",
            "[::1",
            "localhost:port",
            "a b",
        ] {
            assert!(!a.host_allowed(refused), "{refused}");
        }
    }

    fn headers(pairs: &[(header::HeaderName, &str)]) -> HeaderMap {
        let mut h = HeaderMap::new();
        for (name, value) in pairs {
            h.insert(name.clone(), HeaderValue::from_str(value).unwrap());
        }
        h
    }

    #[test]
    fn an_origin_is_accepted_when_it_is_the_servers_own_or_allowed() {
        let a = access(AccessConfig {
            allowed_origins: vec![Origin::parse("https://portal.example/").unwrap()],
            ..AccessConfig::default()
        });
        let check = |origin: Option<&str>, host: &str| {
            let mut pairs = vec![(header::HOST, host)];
            if let Some(o) = origin {
                pairs.push((header::ORIGIN, o));
            }
            a.check_origin(&headers(&pairs))
        };
        assert_eq!(check(None, "127.0.0.1:8080"), Ok(None));
        for (origin, host) in [
            ("http://127.0.0.1:8080", "127.0.0.1:8080"),
            ("http://LOCALHOST:8080", "localhost:8080"),
            ("http://lab", "lab:80"),
            ("http://[::1]:8080", "[::1]:8080"),
            ("https://portal.example", "127.0.0.1:8080"),
            ("https://portal.example:443", "127.0.0.1:8080"),
        ] {
            assert_eq!(
                check(Some(origin), host),
                Ok(Some(origin.to_owned())),
                "{origin} {host}"
            );
        }
        for (origin, host) in [
            ("http://evil.example", "127.0.0.1:8080"),
            ("http://127.0.0.1:8081", "127.0.0.1:8080"),
            ("https://127.0.0.1:8080", "127.0.0.1:8080"),
            ("null", "127.0.0.1:8080"),
            ("http://portal.example", "127.0.0.1:8080"),
        ] {
            assert!(check(Some(origin), host).is_err(), "{origin} {host}");
        }
        let tls = access(AccessConfig {
            secure_transport: true,
            ..AccessConfig::default()
        });
        let h = headers(&[
            (header::HOST, "lab:8443"),
            (header::ORIGIN, "https://lab:8443"),
        ]);
        assert!(tls.check_origin(&h).is_ok());
        let h = headers(&[
            (header::HOST, "lab:8443"),
            (header::ORIGIN, "http://lab:8443"),
        ]);
        assert!(tls.check_origin(&h).is_err());
        assert!(Origin::parse("ftp://x").is_err());
        assert!(Origin::parse("https://x/path").is_err());
    }

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

    #[test]
    fn the_csp_allows_exactly_the_pages_inline_script_by_its_hash() {
        let page = "<html><head><script type=\"importmap\">\n {\"imports\": {}}\n </script>\n\
                    <script type=\"module\" src=\"/src/main.js\"></script></head></html>";
        let hashes = inline_script_hashes(page);
        let expected = base64::engine::general_purpose::STANDARD
            .encode(Sha256::digest("\n {\"imports\": {}}\n "));
        assert_eq!(hashes, vec![expected.clone()]);
        let csp = content_security_policy(page);
        assert!(
            csp.contains(&format!("script-src 'self' 'sha256-{expected}';")),
            "{csp}"
        );
        assert!(csp.contains("frame-ancestors 'none'") && csp.contains("object-src 'none'"));
        assert_eq!(
            content_security_policy(""),
            content_security_policy("<p>no scripts</p>")
        );
    }
}
