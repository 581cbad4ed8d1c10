//! The teaching lab on NATS: stations publish their session, hubs relay it to browsers.
//!
//! ```text
//!  station (device host)                       NATS                         hub (any machine)
//!  loop → StreamHub ─┬─ local viewers           softhaptic.stations.<s>      StationFeed per station
//!                    └─ station task ─publish─► softhaptic.station.<s>.*  ─► StreamHub ─► viewers
//!                         scene / mesh ◄─request─────────────────────────── (on first viewer)
//! ```
//!
//! - [`station`]: `softhaptic --nats URL --station NAME`: a task beside the local viewers
//!   that publishes the stream's pre-encoded frames and stats, its exercise, marks and
//!   inclusions messages, a heartbeat with the station's state, and answers the hubs' requests
//!   for the session (the scene, where the exercise, marks and inclusions stand) and its meshes. It reads the stream
//!   hub's broadcasts like any viewer, so the loop never waits for it and a lost NATS costs
//!   only the frames not published (counted, and logged when NATS is back).
//! - [`hub`]: `softhaptic hub --nats URL`: lists the stations from their heartbeats and relays
//!   any station's stream to browsers through a [`StreamHub`](crate::stream::StreamHub) of its
//!   own per station, fed from one NATS subscription, behind the same access rules (tokens,
//!   Origin, Host, TLS) as a station. Hubs hold no state NATS does not have.
//! - [`listing`]: the archive's listing a hub serves, kept in memory from the object store's
//!   change feed (one consumer per station's bucket, advisories for buckets made later).
//! - [`replays`]: the archived recordings a hub has decoded for replays, loaded for an
//!   instructor's viewer only, in a cache bounded in bytes with an expiry.
//! - [`archive`]: a station's recordings uploaded to the lab's object store, part by part and
//!   resumed, and removed locally once kept there.
//! - [`permissions`]: what each party may publish and subscribe (`softhaptic nats-config`).
//! - here: connecting to NATS with a party's credentials, the subjects, the station's status.
//!
//! The crate stands on `softhaptic-serve` (the hub serves viewers as a station does) and
//! `softhaptic-session` (a hub replays archived recordings), imported under their modules' names
//! (`crate::stream`, `crate::session`, …); the live server uses it to publish a station.
//!
//! Subjects (`NAME` a station's name, `[A-Za-z0-9_-]`, at most 64 characters):
//!
//! | subject | what |
//! |---|---|
//! | `softhaptic.stations.NAME` | heartbeat, once a second: [`StationStatus`] (JSON) |
//! | `softhaptic.station.NAME.contact` | each contact frame, the text viewers get |
//! | `softhaptic.station.NAME.stats` | each stats message, the text viewers get |
//! | `softhaptic.station.NAME.exercise` | each `exercise` message, the text viewers get |
//! | `softhaptic.station.NAME.marks` | each instructor's `mark` message, as viewers get it |
//! | `softhaptic.station.NAME.inclusions` | [`InclusionsState`] (JSON) each time it changes |
//! | `softhaptic.station.NAME.session` | request → [`StationSession`]: hello, scene, and where the exercise, marks and inclusions stand |
//! | `softhaptic.station.NAME.action` | request [`ActionCall`] → [`ActionResult`](softhaptic_proto::wire::ActionResult): an instructor's action from a hub's dashboard |
//! | `softhaptic.station.NAME.mesh` | request `{"name", "offset"}` → a piece of a render mesh |

pub mod archive;
pub mod dashboard;
pub mod hub;
pub mod listing;
pub mod permissions;
pub mod replays;
pub mod station;

use std::path::{Path, PathBuf};
use std::time::Duration;

use softhaptic_io::files;
use softhaptic_serve::{access, routes, stream, tls, viewer};
use softhaptic_session as session;

use serde::{Deserialize, Serialize};

/// The subject of every station's heartbeat (`*`: the station's name).
pub const STATUS_SUBJECTS: &str = "softhaptic.stations.*";
/// A station's heartbeat period.
pub const STATUS_PERIOD: Duration = Duration::from_secs(1);
/// A station whose heartbeat has not come for this long is offline.
pub const OFFLINE_AFTER: Duration = Duration::from_secs(3);
/// Largest piece of a mesh in one reply: well under NATS's default 1 MiB payload limit.
pub const MESH_PIECE_BYTES: usize = 512 << 10;

/// A station's subjects.
#[derive(Debug, Clone)]
pub struct Subjects {
    pub status: String,
    pub contact: String,
    pub stats: String,
    pub session: String,
    pub mesh: String,
    pub exercise: String,
    pub marks: String,
    pub inclusions: String,
    pub action: String,
}

impl Subjects {
    pub fn of(station: &str) -> Self {
        let base = format!("softhaptic.station.{station}");
        Self {
            status: format!("softhaptic.stations.{station}"),
            contact: format!("{base}.contact"),
            stats: format!("{base}.stats"),
            session: format!("{base}.session"),
            mesh: format!("{base}.mesh"),
            exercise: format!("{base}.exercise"),
            marks: format!("{base}.marks"),
            inclusions: format!("{base}.inclusions"),
            action: format!("{base}.action"),
        }
    }
}

/// Why a station name cannot be used (it is a NATS subject token and part of URLs).
pub fn check_station_name(name: &str) -> Result<(), String> {
    let ok = !name.is_empty()
        && name.len() <= 64
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
    if ok {
        Ok(())
    } else {
        Err(format!(
            "station name {name:?}: use 1 to 64 letters, digits, '-' or '_'"
        ))
    }
}

/// What a station says of itself once a second.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StationStatus {
    pub name: String,
    /// The session it runs (the recording's id when it records).
    pub session_id: String,
    /// The trainee's scene: the object, the tool and the device, in words.
    pub scene: String,
    /// `live` (a trainee's tool is in contact or moving recently) or `idle`.
    pub state: StationState,
    /// Since when it is in that state, Unix milliseconds.
    pub since_unix_ms: u64,
    /// Viewers on the station itself.
    pub viewers: u32,
    /// Frames not published since the start (NATS unreachable, or slower than 50 Hz).
    pub unpublished_frames: u64,
    /// The trainee, exercise, force, device and alerts, for the hubs' dashboards; absent from
    /// stations that predate them.
    #[serde(default)]
    pub summary: Option<softhaptic_proto::wire::StationSummary>,
}

/// An instructor's action on a station, as a hub asks the station to carry it out.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ActionCall {
    pub action: softhaptic_proto::wire::StationAction,
    /// Who asks, in words for the station's log and an acknowledgement (`instructor at
    /// ADDRESS on a hub`); never a token.
    pub by: String,
}

/// Whether a station's trainee is at work.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StationState {
    /// The tool touched the object within the last minute.
    Live,
    /// Running, no contact for a minute.
    Idle,
}

/// A station's answer to a hub that starts relaying it: what its `hello` and `scene` say, and
/// what a viewer connecting to the station now would be told of its exercise, marks and
/// inclusions (later ones come on their subjects).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct StationSession {
    pub session_id: String,
    pub force_feedback: bool,
    /// The `scene` message's text, as the station's viewers get it.
    pub scene: String,
    /// The latest `exercise` message, if the station runs exercises.
    #[serde(default)]
    pub exercise: Option<String>,
    /// Every `mark` message so far.
    #[serde(default)]
    pub marks: Vec<String>,
    #[serde(default)]
    pub inclusions: InclusionsState,
}

/// Where a palpation scene's inclusions stand on a station: the two `inclusions` messages its
/// viewers may be told (module `stream::inclusions`). Crosses NATS only between a station and
/// the hubs (the permissions let no station read another's subjects); a hub tells each viewer
/// what the station would.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct InclusionsState {
    /// The answer while an attempt runs (`revealed: false`), for instructors on a lab with
    /// tokens; `None` when the scene has no inclusions.
    pub hidden: Option<String>,
    /// The answer once a palpation attempt has ended (`revealed: true`), for everyone; `None`
    /// before the end.
    pub public: Option<String>,
}

/// A request for a piece of a render mesh.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MeshRequest {
    pub name: String,
    pub offset: u64,
}

/// How to reach NATS: its URL and, for a server that wants them, credentials.
#[derive(Debug, Clone)]
pub struct NatsOptions {
    pub url: String,
    /// A file with the credentials: a NATS `.creds` file (a user JWT and its nkey seed), a user
    /// nkey seed file (`SU…`, as `nk -gen user` writes it), or TOML with `token = "…"`, `user =
    /// "…"` and `password = "…"`, or `nkey = "SU…"`.
    pub credentials: Option<PathBuf>,
    /// The certificate (PEM) of the CA that signed the NATS server's: TLS to NATS, the server
    /// verified against this CA alone (`--nats-ca`).
    pub tls_ca: Option<PathBuf>,
}

impl NatsOptions {
    /// The NATS at `url`, without credentials or a CA.
    pub fn new(url: impl Into<String>) -> Self {
        NatsOptions {
            url: url.into(),
            credentials: None,
            tls_ca: None,
        }
    }

    /// Whether the connection is encrypted: a CA is given, or every URL is `tls://`.
    pub fn uses_tls(&self) -> bool {
        self.tls_ca.is_some()
            || self
                .url
                .split(',')
                .all(|u| u.trim().to_ascii_lowercase().starts_with("tls://"))
    }

    /// Refused when credentials would cross a network in plain text: given credentials, TLS is
    /// required unless every server is on this machine (loopback).
    pub fn check_transport(&self) -> Result<(), LabError> {
        if self.credentials.is_none() || self.uses_tls() || all_loopback(&self.url) {
            return Ok(());
        }
        Err(LabError::Plaintext {
            url: self.url.clone(),
        })
    }
}

/// Whether every server of a `--nats` URL list is this machine (`localhost`, `127.x`, `::1`).
fn all_loopback(urls: &str) -> bool {
    urls.split(',').all(|url| {
        let url = url.trim();
        let authority = url.split_once("://").map_or(url, |(_, rest)| rest);
        let authority = authority.split(['/', '?', '#']).next().unwrap_or_default();
        // `[::1]:4222`, `127.0.0.1:4222`, `localhost`.
        let host = match authority.strip_prefix('[') {
            Some(rest) => rest.split(']').next().unwrap_or_default(),
            None => authority.split(':').next().unwrap_or_default(),
        };
        host.eq_ignore_ascii_case("localhost")
            || host
                .parse::<std::net::IpAddr>()
                .is_ok_and(|ip| ip.is_loopback())
    })
}

/// Who connects to NATS. Each party's replies (to its requests, JetStream's answers, the
/// objects it reads) come to an inbox subject of its own, which NATS's permissions let no other
/// party subscribe to ([`permissions`]): a station cannot read what the hub is sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Party<'a> {
    /// The station of this name.
    Station(&'a str),
    /// A hub (every hub of the lab alike).
    Hub,
}

impl Party<'_> {
    /// The party in words, for errors.
    pub fn role(&self) -> &'static str {
        match self {
            Party::Station(_) => "station",
            Party::Hub => "hub",
        }
    }

    /// The start of its inbox subjects: `_INBOX.station.NAME` or `_INBOX.hub` (a station's name
    /// has no `.`, so no station's is a hub's).
    pub fn inbox_prefix(&self) -> String {
        match self {
            Party::Station(name) => format!("_INBOX.station.{name}"),
            Party::Hub => "_INBOX.hub".to_owned(),
        }
    }
}

/// A `--nats` URL (or a comma-separated list of them), refused when it carries credentials
/// (`nats://user:password@host`, `nats://token@host`): in a URL they would show in the process
/// list, in shell history and in every log line and error that names the server, so they go in
/// the file given with `--nats-credentials`.
pub fn parse_nats_url(text: &str) -> Result<String, String> {
    for url in text.split(',') {
        let url = url.trim();
        if url.is_empty() {
            return Err("an empty URL".to_owned());
        }
        let authority = url.split_once("://").map_or(url, |(_, rest)| rest);
        let authority = authority.split(['/', '?', '#']).next().unwrap_or_default();
        if authority.contains('@') {
            return Err(
                "the URL carries credentials (user:password@ or token@); give the bare URL and \
                 put the credentials in a file named with --nats-credentials FILE (TOML: \
                 user = \"…\" and password = \"…\", or token = \"…\")"
                    .to_owned(),
            );
        }
    }
    Ok(text.to_owned())
}

/// Why NATS could not be used.
#[derive(Debug, thiserror::Error)]
pub enum LabError {
    #[error("NATS credentials {path}: {reason}")]
    Credentials { path: PathBuf, reason: String },
    #[error(
        "NATS at {url} refused this {role}: {reason} (give credentials with --nats-credentials FILE)"
    )]
    Refused {
        url: String,
        role: &'static str,
        reason: String,
    },
    #[error("NATS at {url}: {reason}")]
    Connect { url: String, reason: String },
    #[error(
        "--nats-credentials with NATS at {url} would send the credentials, and every frame, \
         across the network in plain text: give --nats-ca FILE (the CA that signed the NATS \
         server's certificate) or tls:// URLs"
    )]
    Plaintext { url: String },
    #[error("--nats-ca {path}: {reason}")]
    Ca { path: PathBuf, reason: String },
    #[error("{0}")]
    Name(String),
}

/// The fields of a TOML credentials file.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CredentialsFile {
    token: Option<String>,
    user: Option<String>,
    password: Option<String>,
    nkey: Option<String>,
}

/// What the credentials TOML may hold, for its errors.
const CREDENTIALS_FORMS: &str =
    "not a .creds file, nor a user nkey seed, nor TOML with token, user and password, or nkey";

/// A user nkey seed checked before it is used (a bad one would fail only when NATS asks for a
/// signature). The error never quotes the seed.
fn user_nkey_seed(seed: &str) -> Result<String, String> {
    let seed = seed.trim();
    if !seed.starts_with("SU") {
        return Err("the nkey is not a user seed (a user seed starts with SU)".into());
    }
    nkeys::KeyPair::from_seed(seed)
        .map(|_| seed.to_owned())
        .map_err(|_| "the nkey seed does not decode (a damaged or truncated seed)".into())
}

/// Connection options with the credentials of `path` (never logged, never in an error).
async fn with_credentials(
    options: async_nats::ConnectOptions,
    path: &Path,
) -> Result<async_nats::ConnectOptions, LabError> {
    let refused = |reason: String| LabError::Credentials {
        path: path.to_owned(),
        reason,
    };
    // Bounded, and wiped once the client has what it needs.
    let text = crate::files::read_text(path, crate::files::FileKind::Secrets)
        .map(zeroize::Zeroizing::new)
        .map_err(|e| refused(e.to_string()))?;
    crate::files::warn_if_others_may_read(path, "the NATS credentials file");
    if text.contains("-----BEGIN NATS USER JWT-----") {
        return options
            .credentials(&text)
            .map_err(|e| refused(format!("not a valid .creds file: {}", e.kind())));
    }
    // A seed file: the seed alone, on a line of its own (comment lines allowed around it).
    let lines: Vec<&str> = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#') && !l.starts_with("//"))
        .collect();
    if let [only] = lines[..]
        && only.starts_with("SU")
        && !only.contains('=')
    {
        return Ok(options.nkey(user_nkey_seed(only).map_err(refused)?));
    }
    // The TOML parser's message may quote the value it stopped at: keep only its position.
    let file: CredentialsFile = toml::from_str(&text).map_err(|e| {
        refused(match e.span() {
            Some(span) => format!("{CREDENTIALS_FORMS} (error at byte {})", span.start),
            None => CREDENTIALS_FORMS.into(),
        })
    })?;
    match file {
        CredentialsFile {
            token: Some(token),
            user: None,
            password: None,
            nkey: None,
        } => Ok(options.token(token)),
        CredentialsFile {
            token: None,
            user: Some(user),
            password: Some(password),
            nkey: None,
        } => Ok(options.user_and_password(user, password)),
        CredentialsFile {
            token: None,
            user: None,
            password: None,
            nkey: Some(seed),
        } => Ok(options.nkey(user_nkey_seed(&seed).map_err(refused)?)),
        _ => Err(refused(
            "give either token, or user and password, or nkey (and nothing else)".into(),
        )),
    }
}

/// Checks the `--nats-ca` file before it is used: a readable PEM certificate (async-nats would
/// only fail at the first connection, and then as a TLS error without the file's name).
fn check_ca(path: &Path) -> Result<(), LabError> {
    let refused = |reason: String| LabError::Ca {
        path: path.to_owned(),
        reason,
    };
    let text = crate::files::read_text(path, crate::files::FileKind::Pem)
        .map_err(|e| refused(e.to_string()))?;
    if !text.contains("-----BEGIN CERTIFICATE-----") {
        return Err(refused(
            "no PEM certificate in it (-----BEGIN CERTIFICATE-----)".to_owned(),
        ));
    }
    Ok(())
}

/// Connects to NATS as `party`, named `name` (shown in the server's connection list). A server
/// that refuses the credentials stops the start with the reason, and so do credentials that
/// would cross a network without TLS ([`NatsOptions::check_transport`]). A server that cannot
/// be reached does not: the client keeps trying in the background (a station serves its own
/// viewers meanwhile).
pub async fn connect(
    options: &NatsOptions,
    name: String,
    party: Party<'_>,
) -> Result<async_nats::Client, LabError> {
    let role = party.role();
    options.check_transport()?;
    if let Some(ca) = &options.tls_ca {
        check_ca(ca)?;
    }
    let base = || async {
        let mut o = async_nats::ConnectOptions::new()
            .name(name.clone())
            .connection_timeout(Duration::from_secs(3))
            // Frames go out within one frame period or not at all: never a backlog of stale ones.
            .client_capacity(256)
            .custom_inbox_prefix(party.inbox_prefix());
        if let Some(ca) = &options.tls_ca {
            o = o.add_root_certificates(ca.clone()).require_tls(true);
        }
        if let Some(path) = &options.credentials {
            o = with_credentials(o, path).await?;
        }
        Ok::<_, LabError>(o)
    };
    match base().await?.connect(options.url.as_str()).await {
        Ok(client) => Ok(client),
        Err(e) => {
            use async_nats::ConnectErrorKind as K;
            match e.kind() {
                K::AuthorizationViolation | K::Authentication => Err(LabError::Refused {
                    url: options.url.clone(),
                    role,
                    reason: e.to_string(),
                }),
                K::ServerParse | K::Dns | K::Tls => Err(LabError::Connect {
                    url: options.url.clone(),
                    reason: e.to_string(),
                }),
                // A certificate not trusted (no --nats-ca, or another CA's) comes as an I/O
                // error: retrying would never help, so it stops the start too.
                K::Io if is_tls_failure(&e) => Err(LabError::Connect {
                    url: options.url.clone(),
                    reason: format!(
                        "{e} (TLS: is --nats-ca the CA that signed the NATS server's certificate?)"
                    ),
                }),
                _ => {
                    tracing::warn!(
                        "NATS at {} is not reachable ({e}); carrying on and connecting in the background",
                        options.url
                    );
                    base()
                        .await?
                        .retry_on_initial_connect()
                        .connect(options.url.as_str())
                        .await
                        .map_err(|e| LabError::Connect {
                            url: options.url.clone(),
                            reason: e.to_string(),
                        })
                }
            }
        }
    }
}

/// Whether `error` comes from the TLS handshake (rustls refused the server, or the server us).
fn is_tls_failure(error: &(dyn std::error::Error + 'static)) -> bool {
    let mut cause = Some(error);
    while let Some(e) = cause {
        if e.is::<rustls::Error>()
            || e.downcast_ref::<std::io::Error>()
                .and_then(|io| io.get_ref())
                .is_some_and(|inner| inner.is::<rustls::Error>())
        {
            return true;
        }
        cause = e.source();
    }
    false
}

/// Whether the client is connected to NATS now.
pub fn is_connected(client: &async_nats::Client) -> bool {
    client.connection_state() == async_nats::connection::State::Connected
}

/// Unix time now, milliseconds.
pub(crate) fn unix_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_nats_url_with_credentials_is_refused_without_repeating_them() {
        for good in [
            "nats://lab-server:4222",
            "nats://10.0.0.5:4222,nats://10.0.0.6:4222",
            "tls://lab.example:4222/path?x=a@b",
            "lab-server:4222",
        ] {
            assert_eq!(parse_nats_url(good).unwrap(), good);
        }
        for bad in [
            "nats://desk:S3cretPassw0rd@127.0.0.1:4222",
            "nats://s3cr3t-token@lab:4222",
            "nats://a:4222, nats://desk:S3cretPassw0rd@b:4222",
        ] {
            let e = parse_nats_url(bad).unwrap_err();
            assert!(e.contains("--nats-credentials"), "{e}");
            assert!(!e.contains("S3cret") && !e.contains("s3cr3t"), "{e}");
        }
    }

    #[test]
    fn station_names_are_subject_tokens() {
        assert!(check_station_name("desk-3_b").is_ok());
        for bad in ["", "a.b", "a b", "*", ">", "ü", &"x".repeat(65)] {
            assert!(check_station_name(bad).is_err(), "{bad:?}");
        }
        let s = Subjects::of("desk-3");
        assert_eq!(s.contact, "softhaptic.station.desk-3.contact");
        assert_eq!(s.status, "softhaptic.stations.desk-3");
    }

    /// Writes a credentials file for a test; returns its path.
    fn write_file(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap_or_else(|e| panic!("{e}"));
        p
    }

    #[tokio::test]
    async fn credentials_files_are_read_and_their_errors_name_the_file_not_the_secret() {
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let write = |name: &str, text: &str| write_file(dir.path(), name, text);
        let o = async_nats::ConnectOptions::new();
        assert!(
            with_credentials(o, &write("t.toml", "token = \"s3cret\"\n"))
                .await
                .is_ok()
        );
        let o = async_nats::ConnectOptions::new();
        let up = write("up.toml", "user = \"desk\"\npassword = \"s3cret\"\n");
        assert!(with_credentials(o, &up).await.is_ok());
        for (name, text) in [
            ("both.toml", "token = \"s3cret\"\nuser = \"desk\"\n"),
            ("half.toml", "user = \"desk\"\n"),
            ("junk.toml", "s3cret"),
        ] {
            let path = write(name, text);
            let e = with_credentials(async_nats::ConnectOptions::new(), &path)
                .await
                .err()
                .unwrap_or_else(|| panic!("{name} accepted"))
                .to_string();
            assert!(e.contains(name), "{e}");
            assert!(!e.contains("s3cret"), "{e}");
        }
    }

    #[tokio::test]
    async fn a_user_nkey_seed_is_taken_alone_or_in_toml_and_a_bad_one_is_refused_unquoted() {
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let write = |name: &str, text: &str| write_file(dir.path(), name, text);
        let seed = nkeys::KeyPair::new_user()
            .seed()
            .unwrap_or_else(|e| panic!("{e}"));
        for (name, text) in [
            ("user.nk", format!("{seed}\n")),
            ("commented.nk", format!("# desk-3's key\n{seed}\n")),
            ("nkey.toml", format!("nkey = \"{seed}\"\n")),
        ] {
            let path = write(name, &text);
            let r = with_credentials(async_nats::ConnectOptions::new(), &path).await;
            assert!(r.is_ok(), "{name}: {:?}", r.err().map(|e| e.to_string()));
        }
        // A damaged seed, an account's seed, a seed with a password: refused, never quoted.
        let other = if &seed[20..21] == "A" { "B" } else { "A" };
        let damaged = format!("{}{other}{}", &seed[..20], &seed[21..]);
        let account = nkeys::KeyPair::new_account()
            .seed()
            .unwrap_or_else(|e| panic!("{e}"));
        for (name, text, secret) in [
            ("damaged.nk", damaged.clone(), damaged.as_str()),
            (
                "account.toml",
                format!("nkey = \"{account}\"\n"),
                account.as_str(),
            ),
            (
                "mixed.toml",
                format!("nkey = \"{seed}\"\npassword = \"x\"\n"),
                seed.as_str(),
            ),
        ] {
            let path = write(name, &text);
            let e = with_credentials(async_nats::ConnectOptions::new(), &path)
                .await
                .err()
                .unwrap_or_else(|| panic!("{name} accepted"))
                .to_string();
            assert!(e.contains(name), "{e}");
            assert!(!e.contains(&secret[2..12]), "{name}: {e}");
        }
    }
}
