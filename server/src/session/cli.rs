//! The session subcommands of `softhaptic`, and the recording of a live session.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context;
use softhaptic_device::haptic_loop::TickRecord;
use softhaptic_proto::record::{BuildRecord, RecordingStats, SESSION_FORMAT_VERSION, SceneRecord};
use softhaptic_proto::wire::{PROTOCOL_VERSION, ServerMessage};
use tokio::sync::broadcast;

use super::check::{CheckOverrides, check};
use super::reader::Recording;
use super::replay::{self, ReplayOptions};
use super::script::{ScriptName, record_script};
use super::tools::{Info, export};
use super::writer::{Recorder, StreamTap, TICK_RING_CAPACITY, recording_file_name};
use crate::access::AccessArgs;
use crate::app::RunningServer;
pub use crate::logging::print_report;
use crate::routes::SERVER_NAME;
use crate::scene::Scene;
use crate::stream::{EncodedFrame, ViewerLimits};

/// Recording options of `softhaptic run`.
#[derive(clap::Args, Debug, Clone)]
pub struct RecordArgs {
    /// Do not record the session.
    #[arg(long)]
    pub no_record: bool,
    /// Directory of the session recordings (created if missing); one MCAP file per session,
    /// named by its UTC start time and session id.
    #[arg(long, default_value = "sessions", value_name = "DIR")]
    pub record_dir: PathBuf,
}

/// The session subcommands.
// Parsed once, at start: a larger variant costs nothing worth boxing it for.
#[allow(clippy::large_enum_variant)]
#[derive(clap::Subcommand, Debug, Clone)]
pub enum SessionCommand {
    /// What a recording holds: duration, ticks, losses, contacts, peak force, flags, the trainee's
    /// metrics, the instructors' marks, the attempts at exercises, and whether the file is complete or was recovered from a
    /// truncated one.
    Info {
        /// The recording (.mcap).
        file: PathBuf,
    },
    /// Write the device and contact channels of a recording as CSV (device.csv, contact.csv), the
    /// trainee's metrics (metrics.json), the instructors' marks (marks.json) and the results of
    /// the attempts at exercises (attempts.json).
    Export {
        /// The recording (.mcap).
        file: PathBuf,
        /// Output directory (created).
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// Write over the files above already in the directory (without it they are kept and the
        /// export refused).
        #[arg(long)]
        replace: bool,
    },
    /// Replay the recorded device readings through this build's haptic world and check that
    /// every force is identical bit for bit; exits non-zero naming the first differing tick.
    Check {
        /// The recording (.mcap).
        file: PathBuf,
        /// Replace the scene's damping (N·s/m) for the replay: a deliberate change to test the
        /// check itself.
        // A negative number is this option's value (refused with the reason), not another
        // option: clap's own hint for it would be wrong here.
        #[arg(long, value_name = "N_S_PER_M", allow_negative_numbers = true)]
        damping: Option<f64>,
    },
    /// Stream a recording to web viewers exactly as a live session, with pause, play and seek
    /// from the viewer.
    Replay {
        /// The recording (.mcap).
        file: PathBuf,
        /// Playback speed (1.0 = real time).
        #[arg(long, default_value_t = 1.0)]
        speed: f64,
        /// Start paused at the beginning.
        #[arg(long)]
        paused: bool,
        /// Address to serve the viewer on; port 0 picks a free port.
        #[arg(long, default_value = "127.0.0.1:8080", value_name = "HOST:PORT")]
        addr: SocketAddr,
        /// Serve the viewer from this checkout's web/ (index.html, src/, node_modules/three)
        /// instead of the copy built into the binary [default: as for `run`].
        #[arg(long, value_name = "DIR")]
        web_dir: Option<PathBuf>,
        #[command(flatten)]
        access: AccessArgs,
        #[command(flatten)]
        tls: crate::tls::TlsArgs,
    },
    /// Record a scripted session with the simulated device, tick by tick without a clock (the
    /// test recordings of tests/sessions/).
    ///
    /// `--script NAME --out FILE` writes one; `--out DIR` without `--script` writes every script
    /// as DIR/NAME.mcap (how tests/sessions/ is regenerated after a deliberate change of the
    /// forces: `softhaptic record-script --out tests/sessions --replace`).
    RecordScript {
        /// The script; every script when omitted.
        #[arg(long, value_enum)]
        script: Option<ScriptName>,
        /// The file to write (with --script) or the directory (without).
        #[arg(long, value_name = "PATH")]
        out: PathBuf,
        /// Replace existing files (written beside and renamed over, so a failure leaves the old
        /// file).
        #[arg(long)]
        replace: bool,
    },
    /// Measure what recording costs the 1 kHz loop: the loop's period error without and with
    /// the recorder, the same time each, and the recording's size per minute.
    RecordingOverhead {
        /// Length of each run, seconds.
        #[arg(long, default_value_t = 30.0)]
        seconds: f64,
        /// Do not ask for real-time scheduling for the loop thread.
        #[arg(long)]
        no_realtime: bool,
        /// Where the measurement's recording is written.
        #[arg(long, default_value = "sessions", value_name = "DIR")]
        dir: PathBuf,
    },
}

/// Runs a session subcommand.
pub fn run(command: SessionCommand) -> anyhow::Result<()> {
    match command {
        SessionCommand::Info { file } => {
            let recording = Recording::open(&file)?;
            print_report(format_args!("{}\n", Info::of(&recording)))
        }
        SessionCommand::Export { file, out, replace } => {
            let recording = Recording::open(&file)?;
            if !recording.is_complete() {
                eprintln!("{}", recording.recovery());
            }
            let written = export(&recording, &out, replace)?;
            for path in [
                &written.device,
                &written.contact,
                &written.metrics,
                &written.marks,
                &written.attempts,
            ] {
                println!("wrote {}", path.display());
            }
            Ok(())
        }
        SessionCommand::Check { file, damping } => {
            let recording = Recording::open(&file)?;
            if !recording.is_complete() {
                eprintln!("{}", recording.recovery());
            }
            let report = check(
                &recording,
                CheckOverrides {
                    damping_n_s_per_m: damping,
                },
            )?;
            if report.passed() {
                print_report(format_args!("{report}\n"))
            } else {
                anyhow::bail!("replay check failed: {report}")
            }
        }
        SessionCommand::Replay {
            file,
            speed,
            paused,
            addr,
            web_dir,
            access,
            tls,
        } => {
            // Before the recording is read: a replay that may not serve this address, or whose
            // certificate does not load, starts nothing.
            let mut access = access.resolve(addr)?;
            let tls_args_dir = tls.data_dir.clone();
            let tls = crate::tls::server_config(&tls, addr.ip())?;
            if let Some(t) = &tls {
                crate::logging::print_line(format_args!("{t}"));
            }
            access.strict_transport = tls.as_ref().is_some_and(|t| t.from_a_ca);
            access.links_dir = tls_args_dir.or_else(crate::tls::default_data_dir);
            let recording = Recording::open(&file)?;
            if !recording.is_complete() {
                eprintln!("{}", recording.recovery());
            }
            let options = ReplayOptions {
                addr,
                viewer: crate::viewer::Viewer::from_option(web_dir)?,
                speed,
                start_paused: paused,
                viewer_limits: ViewerLimits::default(),
                access: access.clone(),
                tls: tls.map(|t| t.config),
            };
            let runtime =
                tokio::runtime::Runtime::new().context("could not start the async runtime")?;
            runtime.block_on(async move {
                let mut stop = crate::app::StopSignals::listen()
                    .context("could not listen for the stop signals")?;
                let replay = replay::start(recording, options).await?;
                // The token is in the fragment, which no request carries; stdout only.
                let mut access = access;
                access.print_links(
                    &replay.viewer_url(),
                    replay.local_addr(),
                    ["replay", "observer"],
                );
                stop.recv().await;
                replay.shutdown().await;
                Ok(())
            })
        }
        SessionCommand::RecordScript {
            script,
            out,
            replace,
        } => {
            let jobs: Vec<(ScriptName, PathBuf)> = match script {
                Some(name) => vec![(name, out)],
                None => ScriptName::ALL
                    .iter()
                    .map(|&name| (name, out.join(format!("{}.mcap", name.label()))))
                    .collect(),
            };
            for (name, file) in jobs {
                if let Some(dir) = file.parent().filter(|d| !d.as_os_str().is_empty()) {
                    std::fs::create_dir_all(dir)
                        .with_context(|| format!("could not create {}", dir.display()))?;
                }
                let stats = if replace {
                    let mut tmp = file.clone().into_os_string();
                    tmp.push(".partial");
                    let tmp = PathBuf::from(tmp);
                    let _ = std::fs::remove_file(&tmp);
                    let stats = record_script(name, &tmp)?;
                    std::fs::rename(&tmp, &file).with_context(|| {
                        format!("could not move {} to {}", tmp.display(), file.display())
                    })?;
                    stats
                } else {
                    record_script(name, &file)?
                };
                println!(
                    "wrote {} ({} ticks, {} contact frames)",
                    file.display(),
                    stats.ticks_recorded,
                    stats.contact_frames_recorded
                );
            }
            Ok(())
        }
        SessionCommand::RecordingOverhead {
            seconds,
            no_realtime,
            dir,
        } => {
            let report = super::overhead::measure(seconds, !no_realtime, &dir)?;
            print_report(format_args!("{report}"))
        }
    }
}

/// The recording of a live session: start it before the server (it hands the loop its ring),
/// [`LiveRecording::attach`] it to the running server (to record what viewers are sent), and
/// [`LiveRecording::finish`] it after the server has stopped.
pub struct LiveRecording {
    recorder: Recorder,
    tick_sink: Option<rtrb::Producer<TickRecord>>,
    session_id: String,
}

impl LiveRecording {
    /// Opens a new recording in `args.record_dir` for `scene` (loaded from `scene_file`, or the
    /// built-in default when `None`); `None` with `--no-record`.
    pub fn start(
        args: &RecordArgs,
        scene: &Scene,
        scene_file: Option<&Path>,
    ) -> anyhow::Result<Option<LiveRecording>> {
        Self::start_observed(args, scene, scene_file, None)
    }

    /// [`LiveRecording::start`], showing every recorded tick to `observer` (a station's
    /// exercises) and recording what it says on the exercise channel.
    pub fn start_observed(
        args: &RecordArgs,
        scene: &Scene,
        scene_file: Option<&Path>,
        observer: Option<Box<dyn super::writer::TickObserver>>,
    ) -> anyhow::Result<Option<LiveRecording>> {
        if args.no_record {
            return Ok(None);
        }
        let dir = &args.record_dir;
        std::fs::create_dir_all(dir)
            .with_context(|| format!("could not create the record directory {}", dir.display()))?;
        // The text the scene was built from, not the file read again: it may have changed, or
        // be a FIFO, since.
        let scene_toml = scene.source_toml.clone();
        let scene_file = scene_file
            .map(|p| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf()))
            .map(|p| p.display().to_string());
        let started_unix_ns = super::unix_now_ns();
        let session_id = new_recording_id(started_unix_ns);
        let build = BuildRecord {
            session_format_version: SESSION_FORMAT_VERSION,
            protocol_version: PROTOCOL_VERSION,
            writer: SERVER_NAME.into(),
            git_commit: super::git_commit(),
            session_id: session_id.clone(),
            started_unix_ns,
        };
        let scene_record = SceneRecord {
            message: scene.message(),
            scene_toml,
            scene_file,
            period_ns: 1_000_000,
            meshes: scene.recorded_meshes(),
            inclusions: scene.recorded_inclusions(),
            guide: scene.recorded_guide(),
        };
        let path = dir.join(recording_file_name(started_unix_ns, &session_id));
        let (producer, consumer) = rtrb::RingBuffer::new(TICK_RING_CAPACITY);
        let recorder = Recorder::start_observed(&path, &build, &scene_record, consumer, observer)?;
        tracing::info!(file = %path.display(), "recording the session");
        Ok(Some(LiveRecording {
            recorder,
            tick_sink: Some(producer),
            session_id,
        }))
    }

    /// The ring the haptic loop pushes its ticks into (`ServerOptions::tick_sink`); once.
    pub fn take_tick_sink(&mut self) -> Option<rtrb::Producer<TickRecord>> {
        self.tick_sink.take()
    }

    /// The session id of the recording; the server's `hello` carries the same one, so a viewer
    /// and the file name the same session.
    pub fn session_id(&self) -> &str {
        &self.session_id
    }

    /// The file being written.
    pub fn path(&self) -> &Path {
        self.recorder.path()
    }

    /// Records every contact frame and stats message the server sends its viewers, until the
    /// server stops.
    pub fn attach(&self, server: &RunningServer) {
        let hub = server.hub();
        tokio::spawn(record_stream(
            hub.frames.subscribe(),
            hub.stats.subscribe(),
            hub.marks.subscribe(),
            hub.summary.alerts.subscribe(),
            self.recorder.stream_tap(),
        ));
    }

    /// Closes the file (after the server, and so the loop, has stopped), with the session's
    /// final trainee metrics as the loop computed them over every tick.
    pub fn finish(
        self,
        final_metrics: &softhaptic_device::metrics::TraineeMetrics,
    ) -> anyhow::Result<(PathBuf, RecordingStats)> {
        let path = self.recorder.path().to_path_buf();
        let message = ServerMessage::Metrics(crate::stream::metrics_message(final_metrics, true));
        let json = match message.encode() {
            Ok(json) => Some(json),
            Err(e) => {
                tracing::error!(error = %e, "could not encode the final metrics for the recording");
                None
            }
        };
        let stats = self.recorder.finish_with_metrics(json)?;
        Ok((path, stats))
    }

    /// Closes and removes the file of a session that never started (the server could not
    /// start): an empty recording would read as a complete session of nothing.
    pub fn abandon(self) {
        let path = self.recorder.path().to_path_buf();
        let _ = self.recorder.finish();
        if let Err(e) = std::fs::remove_file(&path) {
            tracing::warn!(file = %path.display(), error = %e, "could not remove the recording of a session that did not start");
        }
    }
}

/// A recording id: the start time in hex and the process id, enough to tell sessions apart.
fn new_recording_id(started_unix_ns: u64) -> String {
    format!("{:x}-{}", started_unix_ns / 1_000_000, std::process::id())
}

/// Forwards what viewers are sent to the recorder, as a viewer that never falls behind would
/// see it; frames lost because this task lagged are counted as dropped.
async fn record_stream(
    mut frames: broadcast::Receiver<Arc<EncodedFrame>>,
    mut stats: broadcast::Receiver<axum::extract::ws::Utf8Bytes>,
    mut marks: broadcast::Receiver<axum::extract::ws::Utf8Bytes>,
    mut alerts: broadcast::Receiver<axum::extract::ws::Utf8Bytes>,
    tap: StreamTap,
) {
    let mut stats_open = true;
    let mut marks_open = true;
    let mut alerts_open = true;
    loop {
        tokio::select! {
            frame = frames.recv() => match frame {
                Ok(frame) => {
                    let text = frame.text_for(0).to_string();
                    match ServerMessage::decode(&text) {
                        Ok(ServerMessage::Contact(c)) => tap.record_contact(c.time_ns, text),
                        _ => tracing::error!("the frame broadcast carried a non-contact message"),
                    }
                }
                Err(broadcast::error::RecvError::Lagged(n)) => tap.count_lost_contacts(n),
                Err(broadcast::error::RecvError::Closed) => return,
            },
            s = stats.recv(), if stats_open => match s {
                Ok(text) if text.as_str().starts_with(r#"{"type":"stats""#) => {
                    tap.record_loop_stats(text.to_string())
                }
                // The 1 Hz metrics as viewers saw them. The final one is written when the
                // recording closes (`finish`), after the last tick, not from this stream.
                Ok(text) if text.as_str().starts_with(r#"{"type":"metrics""#) => {
                    if !matches!(
                        ServerMessage::decode(text.as_str()),
                        Ok(ServerMessage::Metrics(m)) if m.is_final
                    ) {
                        tap.record_metrics(text.to_string())
                    }
                }
                Ok(_) => {}
                Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(broadcast::error::RecvError::Closed) => stats_open = false,
            },
            m = marks.recv(), if marks_open => match m {
                Ok(text) => tap.record_mark(text.to_string()),
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    tracing::warn!("{n} instructor marks were not recorded (the recorder fell behind)");
                }
                Err(broadcast::error::RecvError::Closed) => marks_open = false,
            },
            a = alerts.recv(), if alerts_open => match a {
                Ok(text) => tap.record_alert(text.to_string()),
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    tracing::warn!("{n} alerts were not recorded (the recorder fell behind)");
                }
                Err(broadcast::error::RecvError::Closed) => alerts_open = false,
            },
        }
    }
}
