//! The access options of the command line ([`AccessArgs`]) and the rules they resolve into
//! ([`AccessConfig`]): the tokens, the accepted origins and host names, the connection limits,
//! and the refusal to serve beyond loopback without tokens.

use std::fmt::Write as _;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use softhaptic_proto::wire::Role;

use super::tokens::tokens_from_environment;
use super::{
    AccessError, INSTRUCTOR_TOKEN_ENV, OBSERVER_TOKEN_ENV, Origin, Token, Tokens, read_token_file,
};

/// The limits on connections (proto/WIRE.md, "Limits").
#[derive(Debug, Clone, Copy)]
pub struct ConnectionLimits {
    /// Viewers connected at once, whether authenticated yet or not.
    pub max_viewers: u32,
    /// Viewers connected at once from one client address.
    pub max_per_address: u32,
    /// Connections waiting to present their token.
    pub max_pending: u32,
    /// Connections waiting to present their token from one client address (IPv6: one /64;
    /// loopback, a reverse proxy's, is not capped).
    pub max_pending_per_address: u32,
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
            // A browser opens one connection at a time and presents its token within
            // milliseconds; a few more allow for tabs reconnecting at once.
            max_pending_per_address: 8,
            // A viewer sends a handful of messages per click; a person cannot click 50 times a
            // second, a script flooding the server can.
            messages_per_s: 50.0,
            message_burst: 100.0,
            // A page presents its token within milliseconds of the upgrade (a slow link: a few
            // hundred); every second beyond that is a second a connection that never will holds
            // one of the waiting places.
            auth_timeout: Duration::from_secs(5),
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
    /// Tell browsers to use https only for this host (`Strict-Transport-Security`): set when
    /// the certificate is a CA's (`--tls-cert`), which browsers trust without a click. Never
    /// with a self-signed one: a browser that has seen the header refuses the click-through.
    pub strict_transport: bool,
    /// Where the links with their tokens are written when standard output would keep them (a
    /// journal, a file): [`AccessConfig::print_links`]. The data directory.
    pub links_dir: Option<PathBuf>,
    pub limits: ConnectionLimits,
}

/// A name only this machine resolves to itself: `localhost` (and its subdomains) or a loopback
/// address.
fn is_local_name(host: &str) -> bool {
    let host = host.trim_start_matches('[').trim_end_matches(']');
    host == "localhost"
        || host.ends_with(".localhost")
        || host
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
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
            strict_transport: false,
            links_dir: None,
            limits: ConnectionLimits::default(),
        }
    }
}

impl AccessConfig {
    /// Refuses to serve `addr` beyond loopback without tokens, unless `--insecure-no-tokens`
    /// (then warns, loudly).
    pub fn check_bind(&self, addr: SocketAddr) -> Result<(), AccessError> {
        if !self.bind_needs_insecure(addr)? {
            return Ok(());
        }
        tracing::warn!(
            %addr,
            "INSECURE: serving beyond this machine WITHOUT TOKENS (--insecure-no-tokens): anyone \
             who can reach {addr} can watch the session and control replays"
        );
        Ok(())
    }

    /// [`AccessConfig::check_bind`] without its warning: whether serving `addr` is allowed only
    /// by `--insecure-no-tokens`. The command line checks this when it resolves the options, and
    /// the server warns when it starts: once.
    fn bind_needs_insecure(&self, addr: SocketAddr) -> Result<bool, AccessError> {
        if self.tokens.is_some() || addr.ip().is_loopback() {
            return Ok(false);
        }
        if !self.insecure_no_tokens {
            return Err(AccessError::NoTokensBeyondLoopback { addr });
        }
        Ok(true)
    }

    /// Refuses, without tokens, the `--allow-origin` and `--host-name` values that name other
    /// machines, unless `--insecure-no-tokens` (then warns). A server bound to loopback that is
    /// told a public name or origin is reached through a reverse proxy: every viewer arrives
    /// from 127.0.0.1, and without tokens each would be an instructor.
    pub fn check_remote_names(&self) -> Result<(), AccessError> {
        if self.tokens.is_some() {
            return Ok(());
        }
        let names: Vec<String> = self
            .allowed_origins
            .iter()
            .filter(|o| !is_local_name(o.host()))
            .map(|o| format!("--allow-origin {o}"))
            .chain(
                self.host_names
                    .iter()
                    .filter(|n| !is_local_name(n))
                    .map(|n| format!("--host-name {n}")),
            )
            .collect();
        if names.is_empty() {
            return Ok(());
        }
        let names = names.join(", ");
        if !self.insecure_no_tokens {
            return Err(AccessError::NoTokensForRemoteNames { names });
        }
        tracing::warn!(
            %names,
            "INSECURE: reachable from other machines WITHOUT TOKENS (--insecure-no-tokens): \
             anyone who reaches it can watch the session and control replays"
        );
        Ok(())
    }

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

    /// The links to print: the instructor's and the observer's, the token in the fragment (a
    /// fragment never reaches a server's log or a proxy), then the role the link is for. The
    /// role is a hint for the viewer's words only (it says "this is an observer link" when the
    /// server grants another role than the link names); the server never sees it and decides
    /// the role from the token alone. `None` without tokens.
    pub fn links(&self, base_url: &str) -> Option<(String, String)> {
        let tokens = self.tokens.as_ref()?;
        let link = |t: &Token, role: Role| {
            format!(
                "{base_url}#token={}&role={}",
                t.expose_secret(),
                role.as_str()
            )
        };
        Some((
            link(tokens.instructor(), Role::Instructor),
            link(tokens.observer(), Role::Observer),
        ))
    }

    /// Prints the links to open for a server at `url` bound to `addr`: one per role when there
    /// are tokens, `{label}: URL` otherwise; `labels` are the instructor's and the observer's.
    /// Never in a log (the token is in the link), and on standard output only when it is a
    /// terminal, a pipe or a socket (a person, or a program that reads them): when it goes to the
    /// journal (a service), a file or nowhere, which would keep the tokens for whoever reads those, the
    /// links go to `links.txt` (mode 0600) in [`AccessConfig::links_dir`], which the log names.
    pub fn print_links(&mut self, url: &str, addr: SocketAddr, labels: [&str; 2]) {
        self.print_page_links(url, addr, &[("", labels)]);
    }

    /// [`AccessConfig::print_links`] for several pages of one server: each `(path, labels)`
    /// is a page at `path` below the server's base (`""` for the viewer), all in one file when
    /// the links go to a file.
    pub fn print_page_links(&mut self, url: &str, addr: SocketAddr, pages: &[(&str, [&str; 2])]) {
        self.secure_transport = url.starts_with("https:");
        let base = self.public_base(url, addr);
        // Written in place, in room enough never to move (a moved buffer is not zeroed).
        let mut lines = zeroize::Zeroizing::new(String::with_capacity(4096));
        for (path, labels) in pages {
            let page = format!("{base}{path}");
            match self.links(&page) {
                Some((instructor, observer)) => {
                    let _ = writeln!(lines, "{}: {instructor}", labels[0]);
                    let _ = writeln!(lines, "{}: {observer}", labels[1]);
                }
                None => {
                    // No token in it: printed wherever standard output goes.
                    crate::logging::print_line(format_args!("{}: {page}", labels[0]));
                }
            }
        }
        if lines.is_empty() {
            return;
        }
        if stdout_is_read_now() {
            for line in lines.lines() {
                crate::logging::print_line(format_args!("{line}"));
            }
            return;
        }
        match write_links_file(self.links_dir.as_deref(), &lines) {
            Ok(path) => tracing::warn!(
                file = %path.display(),
                "standard output is not a terminal or a pipe (a journal or a file would keep the \
                 tokens): the links to open are in this file (mode 0600) instead"
            ),
            Err(e) => tracing::error!(
                "standard output is not a terminal or a pipe, and the links could not be written \
                 to a file ({e}): they are not shown; give --data-dir, or the tokens with \
                 --token-file"
            ),
        }
    }
}

/// Whether standard output is read as it is written: a terminal, a pipe, or a socket (a
/// program reading it: node's pipes are socket pairs) other than the journal's. Anything else
/// (the journal, a regular file, /dev/null) keeps or drops what it is given. systemd names its
/// journal's stream in `JOURNAL_STREAM` (`device:inode`), as it documents for this purpose.
fn stdout_is_read_now() -> bool {
    use std::io::IsTerminal;
    use std::os::unix::fs::{FileTypeExt, MetadataExt};
    if std::io::stdout().is_terminal() {
        return true;
    }
    let Ok(meta) = std::fs::metadata("/proc/self/fd/1") else {
        return false;
    };
    let kind = meta.file_type();
    if kind.is_fifo() {
        return true;
    }
    if kind.is_socket() {
        let journal = std::env::var("JOURNAL_STREAM").ok().and_then(|v| {
            let (dev, ino) = v.split_once(':')?;
            Some((dev.parse::<u64>().ok()?, ino.parse::<u64>().ok()?))
        });
        return journal != Some((meta.dev(), meta.ino()));
    }
    false
}

/// Writes `text` to `links.txt` in `dir` (made 0700 if missing), mode 0600; its path.
fn write_links_file(dir: Option<&std::path::Path>, text: &str) -> std::io::Result<PathBuf> {
    use std::io::Write as _;
    use std::os::unix::fs::{DirBuilderExt, OpenOptionsExt, PermissionsExt};
    let dir = dir.ok_or_else(|| {
        std::io::Error::new(
            std::io::ErrorKind::NotFound,
            "no data directory (neither --data-dir, XDG_DATA_HOME nor HOME)",
        )
    })?;
    std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(dir)?;
    let path = dir.join("links.txt");
    let mut file = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .mode(0o600)
        .open(&path)?;
    // A file left with another mode keeps its mode when opened: set it before writing.
    file.set_permissions(std::fs::Permissions::from_mode(0o600))?;
    file.write_all(text.as_bytes())?;
    Ok(path)
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
    /// Serve an address beyond loopback, or answer to other machines' names and origins
    /// (`--host-name`, `--allow-origin` behind a reverse proxy), without tokens: anyone who
    /// reaches it watches the session and controls replays. Only for a network where that is
    /// wanted.
    #[arg(long, conflicts_with_all = ["tokens", "token_file"])]
    pub insecure_no_tokens: bool,
    /// Also accept WebSocket connections from pages of this origin (`scheme://host[:port]`);
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
            strict_transport: false,
            links_dir: None,
            limits: ConnectionLimits {
                max_viewers: self.max_viewers,
                max_per_address: self.max_viewers_per_address,
                max_pending: self.max_pending,
                ..ConnectionLimits::default()
            },
        };
        // Refused here, before anything starts; the warning of an insecure start is the
        // server's, when it starts.
        config.bind_needs_insecure(addr)?;
        config.check_remote_names()?;
        match &config.tokens {
            Some(tokens) => tracing::info!(source = %tokens.source(), "viewers need a token"),
            None => tracing::info!("no tokens: every viewer is an instructor"),
        }
        Ok(config)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use crate::access::TokenSource;
    use crate::access::testing::{I, O, tokens};

    #[test]
    fn a_new_connection_waits_at_most_5_s_for_its_token_and_holds_no_place_longer() {
        // A page sends its token as the socket opens; the wait only bounds how long one that
        // never will holds a waiting place (proto/WIRE.md says 5 s).
        let limits = ConnectionLimits::default();
        assert_eq!(limits.auth_timeout, std::time::Duration::from_secs(5));
        assert!(limits.max_pending_per_address < limits.max_pending);
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
        // Long enough, but made of words: refused, naming the variable, never quoting it.
        let hand_made = |name: &str| match name {
            OBSERVER_TOKEN_ENV => Some("observer-token-for-the-lab-2024".to_owned() + "x"),
            _ => Some(I.to_owned()),
        };
        let err = args
            .resolve_with_env(addr, &hand_made)
            .unwrap_err()
            .to_string();
        assert!(
            err.starts_with("SOFTHAPTIC_OBSERVER_TOKEN: the observer token looks made by hand"),
            "{err}"
        );
        assert!(!err.contains("token-for"), "{err}");
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
        assert_eq!(
            viewer,
            format!("http://lab:8080/#token={I}&role=instructor")
        );
        assert_eq!(
            observer,
            format!("http://lab:8080/#token={O}&role=observer")
        );
    }

    #[test]
    fn public_names_on_loopback_behind_a_proxy_need_tokens_or_the_insecure_option() {
        let loopback: SocketAddr = "127.0.0.1:8080".parse().unwrap();
        let args = |origins: &[&str], hosts: &[&str]| AccessArgs {
            token_file: None,
            tokens: false,
            insecure_no_tokens: false,
            allow_origin: origins.iter().map(|s| s.to_string()).collect(),
            host_name: hosts.iter().map(|s| s.to_string()).collect(),
            max_viewers: 500,
            max_viewers_per_address: 50,
            max_pending: 64,
        };
        let none = |_: &str| None;
        // Names only this machine has are the quick start's.
        args(
            &["http://localhost:5173"],
            &["localhost", "viewer.localhost"],
        )
        .resolve_with_env(loopback, &none)
        .unwrap();
        // The proxy setup of docs/operating.md without tokens: refused, naming what made it remote.
        let err = args(&["https://lab-pc.example"], &["lab-pc.example"])
            .resolve_with_env(loopback, &none)
            .unwrap_err()
            .to_string();
        for says in [
            "--allow-origin https://lab-pc.example:443",
            "--host-name lab-pc.example",
            "--tokens",
            "--insecure-no-tokens",
        ] {
            assert!(err.contains(says), "{err}");
        }
        // With tokens, or when the lab says so loudly, it starts.
        let with_tokens = AccessArgs {
            tokens: true,
            ..args(&["https://lab-pc.example"], &["lab-pc.example"])
        };
        assert!(
            with_tokens
                .resolve_with_env(loopback, &none)
                .unwrap()
                .tokens
                .is_some()
        );
        let insecure = AccessArgs {
            insecure_no_tokens: true,
            ..args(&[], &["lab-pc.example"])
        };
        insecure.resolve_with_env(loopback, &none).unwrap();
    }
}
