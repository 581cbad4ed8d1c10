//! Starting and stopping the whole server: scene → haptic world → loop thread → HTTP and
//! WebSocket.
//!
//! The start and the stop of every part of the live server, in the order they happen.
//!
//! [`start`] builds everything from a loaded [`Scene`], binds the address and returns a
//! [`RunningServer`] that knows its real address (port 0 is allowed) and shuts everything down
//! in order: stop producing frames and stats, stop the haptic loop (which commands zero force
//! first), send every viewer the session's final metrics (the stopped loop's, the ones the
//! recording closes with), close every viewer once it has sent them, and stop the HTTP server.
//!
//! The routes it serves, behind the access rules, are those every server shares
//! ([`crate::routes`]).

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::body::Bytes;
use axum::extract::ws::Utf8Bytes;
use softhaptic_device::device::HapticDevice;
use softhaptic_device::haptic_loop::{HapticLoop, LoopConfig, LoopError, TickRecord};
use softhaptic_device::stats::LoopStats;
use softhaptic_proto::ToolShape;
use softhaptic_proto::wire::{Hello, Mode, PROTOCOL_VERSION, Role, SceneMessage, ServerMessage};
use tokio::sync::watch;
use tokio::task::JoinHandle;

use crate::access::{Access, AccessConfig, AccessError};
use crate::routes::{SERVER_NAME, VIEWERS_CLOSE_WAIT, serve_http, viewer_router};
use crate::scene::Scene;
use crate::stream::{self, StreamHub, ViewerLimits};
use crate::viewer::Viewer;

/// The frame and stats tasks, first in [`RunningServer`]'s tasks: they stop before the loop.
const STREAM_TASKS: usize = 2;

/// Why the server could not start.
#[derive(Debug, thiserror::Error)]
pub enum ServerError {
    // The OS's reason is the error's source: an error chain prints it once, after this.
    #[error(
        "could not listen on {addr} (another server on that port? `--addr 127.0.0.1:0` picks a free one)"
    )]
    Bind {
        addr: SocketAddr,
        #[source]
        source: std::io::Error,
    },
    #[error("haptic loop: {0}")]
    Loop(#[from] LoopError),
    #[error("haptic device: {0}")]
    Device(#[from] crate::devices::DeviceOpenError),
    #[error(transparent)]
    Access(#[from] AccessError),
    #[error(transparent)]
    Viewer(#[from] crate::viewer::ViewerError),
    #[error(transparent)]
    Lab(#[from] crate::lab::LabError),
    #[error("could not encode the {what} message: {source}")]
    Encode {
        what: &'static str,
        #[source]
        source: serde_json::Error,
    },
}

/// How to run the server.
pub struct ServerOptions {
    pub addr: SocketAddr,
    /// The viewer's files: built into the binary, or a checkout's `web/` (`--web-dir`).
    pub viewer: Viewer,
    /// Ask the OS for real-time scheduling of the haptic thread.
    pub realtime: bool,
    /// The CPU the haptic thread is bound to (unbound by default; see `softhaptic_device::rt`).
    pub loop_cpu: softhaptic_device::rt::CpuChoice,
    /// Run the haptic loop's standby thread on a second CPU (see
    /// `softhaptic_device::haptic_loop::HapticLoop::spawn_on`).
    pub loop_standby: bool,
    /// Contact frame period (20 ms: 50 Hz).
    pub frame_period: Duration,
    /// Stats period (1 s).
    pub stats_period: Duration,
    /// Per-viewer limits.
    pub viewer_limits: ViewerLimits,
    /// Kernel send buffer of each viewer's socket (inherited from the listening socket). `None`
    /// keeps the OS default, which autotunes for throughput (the meshes are megabytes); a small
    /// value bounds how stale a slow viewer's frames can be, and lets tests make a viewer that
    /// stops reading block within a second.
    pub send_buffer_bytes: Option<u32>,
    /// Every tick record goes here (session log, or a test comparing forces); a full ring drops
    /// records, never delays the loop.
    pub tick_sink: Option<rtrb::Producer<TickRecord>>,
    /// The session id `hello` announces; a fresh random one when `None`. A recorded session
    /// passes the recording's, so the file and the viewers name the same session.
    pub session_id: Option<String>,
    /// The device, already opened with [`crate::devices::open`] on the same scene (the command
    /// line opens it before the recording starts, so the recording names the limits it really
    /// runs with); opened by [`start`] when `None`.
    pub device: Option<Box<dyn HapticDevice>>,
    /// Who may connect (tokens, origins, host names, limits); the loopback quick start by
    /// default. [`start`] refuses an address beyond loopback without tokens.
    pub access: AccessConfig,
    /// Serve https and wss with this configuration ([`crate::tls::server_config`]); plain http
    /// when `None`.
    pub tls: Option<Arc<rustls::ServerConfig>>,
    /// Publish the session to a teaching lab's NATS as this station (`--nats`, `--station`).
    pub lab: Option<crate::lab::station::StationOptions>,
    /// The exercises' feed, when the station runs exercises (`--exercises`): their scorer
    /// publishes to it and instructors' controls reach the scorer through it.
    pub exercises: Option<Arc<stream::ExerciseFeed>>,
    /// Where the scene's inclusions are published for the viewers who may see them
    /// ([`crate::exercise::run::inclusions_feed`]); `None`: the scene has none.
    pub inclusions: Option<Arc<stream::InclusionsFeed>>,
}

impl ServerOptions {
    /// 50 Hz frames, 1 Hz stats, default viewer limits, real-time requested, no tick sink, the
    /// viewer built into the binary.
    pub fn new(addr: SocketAddr) -> Self {
        Self {
            addr,
            viewer: Viewer::embedded(),
            realtime: true,
            loop_cpu: softhaptic_device::rt::CpuChoice::Unpinned,
            loop_standby: true,
            frame_period: Duration::from_millis(20),
            stats_period: Duration::from_secs(1),
            viewer_limits: ViewerLimits::default(),
            send_buffer_bytes: None,
            tick_sink: None,
            session_id: None,
            device: None,
            access: AccessConfig::default(),
            tls: None,
            lab: None,
            exercises: None,
            inclusions: None,
        }
    }
}

/// The scene's inclusions for the frames' force ratio (`None` without inclusions).
fn frame_inclusions(scene: &Scene) -> Option<stream::FrameInclusions> {
    let table = scene.inclusion_table.clone()?;
    match softhaptic_device::inclusion::InclusionField::new(table, &scene.inclusions) {
        Ok(field) => Some(stream::FrameInclusions {
            field,
            object_in_world: scene.object_in_world,
        }),
        // The scene's loading checked the same: the haptic world refused it too.
        Err(reason) => {
            tracing::error!(%reason, "the inclusions' field for the frames");
            None
        }
    }
}

/// A running server. Dropping it without [`RunningServer::shutdown`] still stops the haptic
/// loop (its own drop does), but viewers are then cut rather than closed.
pub struct RunningServer {
    local_addr: SocketAddr,
    shutdown_tx: watch::Sender<bool>,
    /// Stops the frame and stats tasks alone, before the loop stops and before `shutdown_tx`
    /// closes the viewers: the final metrics are sent between the two.
    stop_tasks_tx: watch::Sender<bool>,
    http: JoinHandle<()>,
    tasks: Vec<JoinHandle<()>>,
    haptic_loop: Arc<HapticLoop>,
    hub: Arc<StreamHub>,
    scene_message: SceneMessage,
    /// Served over TLS: the viewer's URL is https.
    tls: bool,
}

impl RunningServer {
    /// The address actually bound.
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// The viewer's URL.
    pub fn viewer_url(&self) -> String {
        let scheme = if self.tls { "https" } else { "http" };
        format!("{scheme}://{}/", self.local_addr)
    }

    /// The scene as sent to viewers.
    pub fn scene_message(&self) -> &SceneMessage {
        &self.scene_message
    }

    /// The loop's latest timing summary.
    pub fn loop_stats(&self) -> LoopStats {
        self.haptic_loop.stats()
    }

    /// The stream hub: subscribe to its `frames` and `stats` to see what viewers are sent (the
    /// session recorder does).
    pub fn hub(&self) -> &Arc<StreamHub> {
        &self.hub
    }

    /// The stream's counters (viewers, dropped frames, unknown messages...).
    pub fn counters(&self) -> &stream::StreamCounters {
        &self.hub.counters
    }

    /// Stops the haptic loop, closes every viewer, stops the HTTP server; returns the loop's
    /// final statistics.
    pub async fn shutdown(self) -> LoopStats {
        self.shutdown_with_metrics().await.0
    }

    /// [`RunningServer::shutdown`], with the trainee's metrics over every tick the loop ran:
    /// the ones every viewer still connected is sent last, marked final, before it is closed.
    pub async fn shutdown_with_metrics(
        self,
    ) -> (LoopStats, softhaptic_device::metrics::TraineeMetrics) {
        // 1. No more frames or stats: the frame and stats tasks stop (and drop their handles on
        //    the loop). Receivers are alive as long as `self` is; a send error cannot happen.
        let _ = self.stop_tasks_tx.send(true);
        let mut tasks = self.tasks;
        let others = tasks.split_off(STREAM_TASKS.min(tasks.len()));
        for task in tasks {
            let _ = task.await;
        }
        // 2. The loop stops (zero force first); its metrics are then over every tick it ran.
        let (stats, metrics) = match Arc::try_unwrap(self.haptic_loop) {
            Ok(mut l) => tokio::task::spawn_blocking(move || {
                let stats = l.stop_ref();
                (stats, l.metrics())
            })
            .await
            .unwrap_or_default(),
            // Nothing else holds the loop once its two tasks have ended; were it still shared,
            // its latest publications are the best there is (its own drop stops it).
            Err(shared) => (shared.stats(), shared.metrics()),
        };
        // 3. Every viewer still connected gets them, queued before the close below.
        stream::send_final_metrics(&self.hub, &metrics);
        // 4. The viewers close (each sends what is queued for it first, within a bound) and the
        //    other tasks (a lab station's) stop; wait (briefly) for the viewers to be gone, so
        //    that each one's audit line is written before the process ends.
        let _ = self.shutdown_tx.send(true);
        for task in others {
            let _ = task.await;
        }
        let _ =
            tokio::time::timeout(VIEWERS_CLOSE_WAIT, self.hub.access.until_no_connections()).await;
        // Viewer tasks see the flag and close; give them a moment, then stop accepting.
        let _ = tokio::time::timeout(Duration::from_secs(5), self.http).await;
        drop(self.hub);
        (stats, metrics)
    }
}

/// A per-run identifier for `hello`: random, from the standard library's hasher seed.
fn new_session_id() -> String {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u128(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or_default(),
    );
    h.write_u32(std::process::id());
    format!("{:016x}", h.finish())
}

/// Starts the haptic loop and the server for `scene`.
pub async fn start(
    mut scene: Scene,
    mut options: ServerOptions,
) -> Result<RunningServer, ServerError> {
    // Before the device is touched: a server that may not serve this address, or would serve a
    // page that cannot run, starts nothing.
    options.access.check_bind(options.addr)?;
    options.viewer.check()?;
    let page_html = options.viewer.page_html()?;
    // Before the loop starts: NATS refusing the station's credentials stops the start.
    let nats = match &options.lab {
        Some(lab) => Some(crate::lab::station::connect(lab).await?),
        None => None,
    };
    let device = match options.device.take() {
        Some(device) => device,
        None => crate::devices::open(&mut scene)?,
    };
    scene.device_renders_force = device.renders_force();
    let rearm = device.rearm_handle();
    let message = scene.message();
    let encode = |what: &'static str, m: ServerMessage| {
        m.encode()
            .map_err(|source| ServerError::Encode { what, source })
    };
    let scene_text = encode("scene", ServerMessage::Scene(Box::new(message.clone())))?;
    let hello = Hello {
        protocol_version: PROTOCOL_VERSION,
        session_id: options.session_id.clone().unwrap_or_else(new_session_id),
        // Set per connection by the stream hub.
        role: Role::Instructor,
        mode: Mode::Live,
        server: SERVER_NAME.into(),
        force_feedback: message.device.force_feedback,
        accepts_marks: true,
    };
    let mut meshes = HashMap::new();
    meshes.insert(
        scene.object_name.clone(),
        Bytes::from(scene.render_surface.to_shm1()),
    );

    let listener =
        bind(options.addr, options.send_buffer_bytes).map_err(|source| ServerError::Bind {
            addr: options.addr,
            source,
        })?;
    let local_addr = listener.local_addr().map_err(|source| ServerError::Bind {
        addr: options.addr,
        source,
    })?;

    // The haptic side: world (with the scene's contact model and the device's limits), device,
    // loop thread.
    let world = scene.haptic_world();
    let haptic_loop = Arc::new(HapticLoop::spawn_on(
        device,
        world,
        LoopConfig {
            period_ns: 1_000_000,
            realtime: options.realtime,
            tick_sink: options.tick_sink,
            standby: options.loop_standby,
        },
        options.loop_cpu,
    )?);

    let (shutdown_tx, shutdown_rx) = watch::channel(false);
    let (stop_tasks_tx, stop_tasks_rx) = watch::channel(false);
    // The page's own origin is https when the server serves TLS.
    options.access.secure_transport = options.tls.is_some();
    let caps = crate::tls::ConnectionCaps::for_limits(&options.access.limits);
    let access = Arc::new(Access::new(options.access, &page_html));
    let hub = Arc::new(
        StreamHub::new(
            &hello,
            Utf8Bytes::from(scene_text.clone()),
            options.viewer_limits,
            shutdown_rx.clone(),
            None,
            access,
        )
        .map_err(|source| ServerError::Encode {
            what: "hello",
            source,
        })?
        .with_rearm(rearm)
        .with_exercises(options.exercises.take())
        .with_inclusions(options.inclusions.take())
        .with_safe_force(scene.safe_force_n),
    );
    let meshes = Arc::new(meshes);
    let mut tasks = vec![
        tokio::spawn(stream::frame_task(
            Arc::clone(&haptic_loop),
            scene.calibration.clone(),
            frame_inclusions(&scene),
            Arc::clone(&hub),
            options.frame_period,
            stop_tasks_rx.clone(),
        )),
        tokio::spawn(stream::stats_task(
            Arc::clone(&haptic_loop),
            Arc::clone(&hub),
            options.stats_period,
            stop_tasks_rx,
        )),
    ];
    debug_assert_eq!(tasks.len(), STREAM_TASKS);
    // The dashboard's summary and the session's alerts, from what the viewers are sent.
    tasks.push(tokio::spawn(stream::summary::track(Arc::clone(&hub))));

    if let (Some(client), Some(lab)) = (nats, &options.lab) {
        let data = crate::lab::station::StationData {
            session: crate::lab::StationSession {
                session_id: hello.session_id.clone(),
                force_feedback: hello.force_feedback,
                scene: scene_text.clone(),
                ..Default::default()
            },
            scene_label: format!(
                "{}, {}, {}",
                scene.object_name,
                match scene.tool {
                    ToolShape::Sphere { radius_m } => format!("sphere {:.0} mm", radius_m * 1e3),
                    ToolShape::Cone { half_angle_rad, .. } =>
                        format!("cone {:.0}°", half_angle_rad.to_degrees()),
                },
                message.device.name
            ),
            meshes: Arc::clone(&meshes),
        };
        tasks.extend(crate::lab::station::spawn(
            client,
            lab,
            Arc::clone(&hub),
            data,
            shutdown_rx.clone(),
        ));
    }
    let app = viewer_router(
        &options.viewer,
        // The same text as the WebSocket `scene` message (proto/WIRE.md).
        Bytes::from(scene_text),
        meshes,
        Arc::clone(&hub),
    );
    let tls = options.tls.is_some();
    let http = serve_http(listener, app, options.tls, caps, shutdown_rx);

    Ok(RunningServer {
        local_addr,
        shutdown_tx,
        stop_tasks_tx,
        http,
        tasks,
        haptic_loop,
        hub,
        scene_message: message,
        tls,
    })
}

/// Binds the listening socket (address reuse on, so a restarted server gets its port back).
fn bind(
    addr: SocketAddr,
    send_buffer_bytes: Option<u32>,
) -> std::io::Result<tokio::net::TcpListener> {
    let socket = if addr.is_ipv4() {
        tokio::net::TcpSocket::new_v4()?
    } else {
        tokio::net::TcpSocket::new_v6()?
    };
    socket.set_reuseaddr(true)?;
    if let Some(bytes) = send_buffer_bytes {
        socket.set_send_buffer_size(bytes)?;
    }
    socket.bind(addr)?;
    socket.listen(1024)
}

/// The signals that ask the process to stop: Ctrl-C (SIGINT), SIGTERM (a service manager,
/// `kill`), SIGHUP (the terminal or the SSH session closed) and SIGQUIT (Ctrl-\). Each ends the
/// session the same way: zero force, viewers closed, the recording closed; none may leave the
/// file unclosed. They are caught from the moment [`StopSignals::listen`] returns, so it is
/// called before anything a stop must close is started: a signal that comes earlier still has
/// its default action and ends the process while nothing is open.
pub struct StopSignals {
    interrupt: tokio::signal::unix::Signal,
    terminate: tokio::signal::unix::Signal,
    hangup: tokio::signal::unix::Signal,
    quit: tokio::signal::unix::Signal,
}

impl StopSignals {
    /// Starts catching the stop signals. Must run inside a tokio runtime (an async block, or
    /// after `Runtime::enter`).
    pub fn listen() -> std::io::Result<Self> {
        use tokio::signal::unix::{SignalKind, signal};
        Ok(Self {
            interrupt: signal(SignalKind::interrupt())?,
            terminate: signal(SignalKind::terminate())?,
            hangup: signal(SignalKind::hangup())?,
            quit: signal(SignalKind::quit())?,
        })
    }

    /// Resolves with the name of the first stop signal caught since `listen`.
    pub async fn recv(&mut self) -> &'static str {
        tokio::select! {
            _ = self.interrupt.recv() => "SIGINT",
            _ = self.terminate.recv() => "SIGTERM",
            _ = self.hangup.recv() => "SIGHUP",
            _ = self.quit.recv() => "SIGQUIT",
        }
    }
}
