//! A real `nats-server` for the lab's tests: started on a free loopback port with JetStream and
//! a store in a scratch directory (and, for the tests that ask NATS what it holds, its HTTP
//! monitoring port), stopped (killed) when dropped, restartable on the same ports.
//! The test command installs Debian's `nats-server` (see the Makefile); without it the tests say
//! how to get it.

use std::net::{SocketAddr, TcpListener};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A running `nats-server`.
pub struct NatsServer {
    child: Option<Child>,
    pub port: u16,
    /// The HTTP monitoring port (`/connz`, `/subsz`, …), when started with one: what a test reads
    /// to see the connections and subscriptions the server itself holds.
    pub monitor_port: Option<u16>,
    store: PathBuf,
    auth: Option<Auth>,
}

/// Whom the server takes.
enum Auth {
    User {
        user: String,
        password: String,
    },
    /// The user whose nkey has this public key (`U…`).
    Nkey {
        public_key: String,
    },
    /// A configuration file's text (an `authorization` block, a `tls` block, `include`s of files
    /// in the store directory), given with `-c`; the flags still set the address, port and store.
    Config {
        text: String,
    },
    /// Decentralised auth: the operator's JWT, the system account's and one account's (public
    /// key, JWT), preloaded.
    Operator {
        operator_jwt: String,
        system: (String, String),
        account: (String, String),
    },
}

/// A NATS JWT (header, claims, signature; base64url without padding) signed by `signer`.
fn jwt(signer: &nkeys::KeyPair, claims: serde_json::Value) -> String {
    use base64::Engine;
    let b64 = base64::engine::general_purpose::URL_SAFE_NO_PAD;
    let header = b64.encode(br#"{"typ":"JWT","alg":"ed25519-nkey"}"#);
    let body = b64.encode(claims.to_string());
    let signed = format!("{header}.{body}");
    let signature = signer.sign(signed.as_bytes()).expect("an nkey signs");
    format!("{signed}.{}", b64.encode(signature))
}

/// The claims every JWT carries, for `subject` issued by `issuer`.
fn claims(
    issuer: &nkeys::KeyPair,
    subject: &str,
    name: &str,
    nats: serde_json::Value,
) -> serde_json::Value {
    serde_json::json!({
        "jti": format!("{name}-{subject}"),
        "iat": 1_700_000_000u64,
        "iss": issuer.public_key(),
        "name": name,
        "sub": subject,
        "nats": nats,
    })
}

impl NatsServer {
    /// Starts a server that takes anyone.
    pub fn start(name: &str) -> NatsServer {
        Self::start_with(name, None)
    }

    /// Starts a server that takes anyone and serves its monitoring endpoints over HTTP on
    /// [`NatsServer::monitor_port`].
    pub fn start_monitored(name: &str) -> NatsServer {
        let mut server = NatsServer {
            child: None,
            port: free_port(),
            monitor_port: Some(free_port()),
            store: crate::scratch_dir(&format!("nats-{name}")),
            auth: None,
        };
        server.restart();
        server
    }

    /// Starts a server that takes only `user` with `password`.
    pub fn start_with_user(name: &str, user: &str, password: &str) -> NatsServer {
        Self::start_with(
            name,
            Some(Auth::User {
                user: user.to_owned(),
                password: password.to_owned(),
            }),
        )
    }

    /// Starts a server that takes only the user of this nkey public key (`U…`), which proves
    /// itself by signing the server's nonce with its seed.
    pub fn start_with_nkey(name: &str, public_key: &str) -> NatsServer {
        Self::start_with(
            name,
            Some(Auth::Nkey {
                public_key: public_key.to_owned(),
            }),
        )
    }

    /// Starts a server with the configuration `text` (paths in it absolute).
    pub fn start_with_config(name: &str, text: String) -> NatsServer {
        Self::start_with(name, Some(Auth::Config { text }))
    }

    /// Starts a server in operator mode (decentralised JWT auth, as a managed NATS service runs)
    /// with one account, and returns it with a `.creds` file's text for one user of the account.
    pub fn start_with_operator(name: &str) -> (NatsServer, String) {
        let operator = nkeys::KeyPair::new_operator();
        let account = nkeys::KeyPair::new_account();
        // JetStream needs the server's own account for its internal subscriptions.
        let system = nkeys::KeyPair::new_account();
        let user = nkeys::KeyPair::new_user();
        let operator_jwt = jwt(
            &operator,
            claims(
                &operator,
                &operator.public_key(),
                "lab",
                serde_json::json!({
                    "type": "operator", "version": 2,
                    "system_account": system.public_key(),
                }),
            ),
        );
        let system_jwt = jwt(
            &operator,
            claims(
                &operator,
                &system.public_key(),
                "SYS",
                serde_json::json!({"type": "account", "version": 2}),
            ),
        );
        let unlimited = serde_json::json!({
            "subs": -1, "data": -1, "payload": -1, "imports": -1, "exports": -1,
            "wildcards": true, "conn": -1, "leaf": -1,
            "mem_storage": -1, "disk_storage": -1, "streams": -1, "consumer": -1,
        });
        let account_jwt = jwt(
            &operator,
            claims(
                &operator,
                &account.public_key(),
                "lab-account",
                serde_json::json!({"limits": unlimited, "type": "account", "version": 2}),
            ),
        );
        let user_jwt = jwt(
            &account,
            claims(
                &account,
                &user.public_key(),
                "desk",
                serde_json::json!({
                    "pub": {}, "sub": {}, "subs": -1, "data": -1, "payload": -1,
                    "type": "user", "version": 2,
                }),
            ),
        );
        let creds = format!(
            "-----BEGIN NATS USER JWT-----\n{user_jwt}\n------END NATS USER JWT------\n\n\
             ************************* IMPORTANT *************************\n\
             NKEY Seed printed below can be used to sign and prove identity.\n\n\
             -----BEGIN USER NKEY SEED-----\n{}\n------END USER NKEY SEED------\n",
            user.seed().expect("a user seed")
        );
        let server = Self::start_with(
            name,
            Some(Auth::Operator {
                operator_jwt,
                system: (system.public_key(), system_jwt),
                account: (account.public_key(), account_jwt),
            }),
        );
        (server, creds)
    }

    fn start_with(name: &str, auth: Option<Auth>) -> NatsServer {
        let mut server = NatsServer {
            child: None,
            port: free_port(),
            monitor_port: None,
            store: crate::scratch_dir(&format!("nats-{name}")),
            auth,
        };
        server.restart();
        server
    }

    /// `nats://127.0.0.1:PORT`.
    pub fn url(&self) -> String {
        format!("nats://127.0.0.1:{}", self.port)
    }

    /// Kills the server (as a crash would).
    pub fn kill(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }

    /// Starts it again on the same port and store; returns once it accepts connections.
    pub fn restart(&mut self) {
        self.kill();
        let mut command = Command::new(program());
        command
            .args([
                "-a",
                "127.0.0.1",
                "-p",
                &self.port.to_string(),
                "-js",
                "-sd",
            ])
            .arg(&self.store)
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        if let Some(monitor_port) = self.monitor_port {
            command.args(["-m", &monitor_port.to_string()]);
        }
        match &self.auth {
            Some(Auth::User { user, password }) => {
                command.args(["--user", user, "--pass", password]);
            }
            Some(Auth::Nkey { public_key }) => {
                // nkey users are set in a configuration file only; the flags above still apply.
                let config = self.store.join("nkey.conf");
                std::fs::create_dir_all(&self.store).expect("the store directory");
                std::fs::write(
                    &config,
                    format!("authorization {{ users = [ {{ nkey: \"{public_key}\" }} ] }}\n"),
                )
                .expect("the server's configuration");
                command.arg("-c").arg(&config);
            }
            Some(Auth::Config { text }) => {
                let config = self.store.join("softhaptic-test.conf");
                std::fs::create_dir_all(&self.store).expect("the store directory");
                std::fs::write(&config, text).expect("the server's configuration");
                command.arg("-c").arg(&config);
            }
            Some(Auth::Operator {
                operator_jwt,
                system: (system, system_jwt),
                account: (account, account_jwt),
            }) => {
                let config = self.store.join("operator.conf");
                std::fs::create_dir_all(&self.store).expect("the store directory");
                std::fs::write(
                    &config,
                    format!(
                        "operator: \"{operator_jwt}\"\nsystem_account: {system}\n\
                         resolver: MEMORY\nresolver_preload: {{ {system}: \"{system_jwt}\", \
                         {account}: \"{account_jwt}\" }}\n"
                    ),
                )
                .expect("the server's configuration");
                command.arg("-c").arg(&config);
            }
            None => {}
        }
        let child = command.spawn().unwrap_or_else(|e| {
            panic!(
                "cannot start nats-server ({e}): `make test` installs it (Debian's nats-server package)"
            )
        });
        self.child = Some(child);
        let addr = SocketAddr::from(([127, 0, 0, 1], self.port));
        // A configuration the server refuses ends it at once: said then, not after the wait.
        let child = self.child.as_mut().expect("just started");
        wait_for_listener(addr, || child.try_wait().ok().flatten());
        if let Some(monitor_port) = self.monitor_port {
            wait_for_listener(SocketAddr::from(([127, 0, 0, 1], monitor_port)), || None);
        }
    }

    /// The monitoring endpoint's address; panics for a server started without one.
    pub fn monitor_addr(&self) -> SocketAddr {
        let port = self
            .monitor_port
            .expect("a server started with a monitoring port (NatsServer::start_monitored)");
        SocketAddr::from(([127, 0, 0, 1], port))
    }
}

/// A port free on loopback now (the server binds it a moment later).
fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

/// Returns once `addr` accepts connections; panics after 30 s, or as soon as `exited` gives the
/// server's exit status (run it by hand with the same `-c` file to see why).
fn wait_for_listener(
    addr: SocketAddr,
    mut exited: impl FnMut() -> Option<std::process::ExitStatus>,
) {
    let deadline = Instant::now() + Duration::from_secs(30);
    while std::net::TcpStream::connect_timeout(&addr, Duration::from_millis(200)).is_err() {
        if let Some(status) = exited() {
            panic!("nats-server exited ({status}) before it listened on {addr}");
        }
        assert!(
            Instant::now() < deadline,
            "nats-server did not listen on {addr}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// `nats-server` on the PATH, or where Debian puts it (`/usr/sbin`, not on every user's PATH).
fn program() -> PathBuf {
    let on_path = std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|p| p.join("nats-server"))
            .find(|p| p.is_file())
    });
    on_path.unwrap_or_else(|| PathBuf::from("/usr/sbin/nats-server"))
}

impl Drop for NatsServer {
    fn drop(&mut self) {
        self.kill();
        let _ = std::fs::remove_dir_all(&self.store);
    }
}

/// Options for the NATS at `url`, without credentials.
pub fn options(url: String) -> softhaptic_server::lab::NatsOptions {
    softhaptic_server::lab::NatsOptions::new(url)
}

/// A simulated station named `name` on the built-in scene (the test options: loopback, a free
/// port, no recording), publishing to the NATS of `options`.
pub async fn start_station(
    name: &str,
    options: softhaptic_server::lab::NatsOptions,
) -> Result<softhaptic_server::app::RunningServer, softhaptic_server::app::ServerError> {
    let mut o = crate::test_options();
    o.lab = Some(softhaptic_server::lab::station::StationOptions {
        nats: options,
        name: name.to_owned(),
    });
    let scene =
        softhaptic_server::scene::Scene::builtin_default().expect("the built-in scene loads");
    softhaptic_server::app::start(scene, o).await
}

/// A hub on a free loopback port relaying the stations of the NATS of `options`, with the
/// tests' tokens when `tokens`.
pub async fn start_hub(
    options: softhaptic_server::lab::NatsOptions,
    tokens: bool,
) -> softhaptic_server::lab::hub::RunningHub {
    let access = softhaptic_server::access::AccessConfig {
        tokens: tokens.then(crate::test_tokens),
        ..Default::default()
    };
    softhaptic_server::lab::hub::start(softhaptic_server::lab::hub::HubOptions {
        nats: options,
        addr: ([127, 0, 0, 1], 0).into(),
        viewer: Default::default(),
        access,
        tls: None,
        viewer_limits: Default::default(),
        replay_cache: Default::default(),
        archive_listing: Default::default(),
    })
    .await
    .expect("the hub starts")
}

/// Archives `files` (`(name in the archive, file of tests/sessions)`) as station `station`'s,
/// signed in to the NATS of `options` as that station, as a station's start does.
pub async fn archive_sessions(
    options: softhaptic_server::lab::NatsOptions,
    station: &str,
    files: &[(&str, &str)],
) {
    // A directory of this call's own: tests of one binary run at once, and two archiving for
    // the same station would otherwise share one and remove each other's files.
    static CALLS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let call = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let dir = crate::scratch_dir(&format!("archive-{station}-{}-{call}", files.len()));
    let sessions = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("sessions");
    for (name, source) in files {
        std::fs::copy(sessions.join(source), dir.join(name)).expect("a shipped session copies");
    }
    let client = softhaptic_server::lab::connect(
        &options,
        format!("{station} archive (test)"),
        softhaptic_server::lab::Party::Station(station),
    )
    .await
    .expect("the station signs in to NATS");
    let report =
        softhaptic_server::lab::archive::upload_finished(&client, station, &dir, None).await;
    assert_eq!(report.uploaded.len(), files.len(), "{report:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
