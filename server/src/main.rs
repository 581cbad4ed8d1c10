//! `softhaptic`: the device-host server's command line.

use std::net::SocketAddr;
use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, CommandFactory, Parser, Subcommand};
use softhaptic_server::access::AccessArgs;
use softhaptic_server::app::{self, ServerOptions};
use softhaptic_server::devices;
use softhaptic_server::scene::{DeviceChoice, Scene};
use softhaptic_server::session;
use softhaptic_server::vectors;

/// Haptic simulator of soft objects: runs the 1 kHz force loop next to the device and streams the
/// contact to web viewers. With no subcommand, `run`.
#[derive(Parser, Debug)]
#[command(name = "softhaptic", version, args_conflicts_with_subcommands = true)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    run: RunArgs,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Load a scene, start the haptic loop and serve the viewer (the default).
    Run(Box<RunArgs>),
    /// List the haptic devices this machine can drive: the OpenHaptics library (found or not,
    /// and why), each device it can open with its model, serial, limits and calibration state,
    /// the Force Dimension SDK and each device it sees (type, serial, limits), the SpaceMice found (with the udev rule when /dev/hidraw* is not readable), and the
    /// simulated device. Exits 0 with a listing on a machine with no hardware.
    Devices {
        /// Also try this OpenHaptics device configuration (repeatable); the default device is
        /// always tried.
        #[arg(long, value_name = "NAME")]
        name: Vec<String>,
    },
    /// Is this machine ready for the 1 kHz loop? Inspects the kernel's preemption model, the
    /// real-time limits, CPU isolation, interrupts, the frequency governor, swap and the haptic
    /// devices, then measures the loop idle and beside a loaded neighbour; prints what it found,
    /// whether it is good and the fix. Exits 0 when ready, 1 with warnings or an item it could
    /// not read, 2 when the loop cannot run as configured or the doctor itself could not run.
    Doctor(softhaptic_server::doctor::DoctorArgs),
    /// A teaching lab's hub: lists the stations that publish to NATS (`--nats URL --station
    /// NAME` on each device host), relays any of them to browsers with the same wire, roles,
    /// tokens, Origin checks and TLS as a station, and serves the class's dashboard
    /// (`/dashboard`: a tile per station, alerts, an instructor's actions). Prints the viewer's
    /// and the dashboard's links at start. Run several behind a load balancer: a hub keeps
    /// nothing NATS does not have.
    Hub(HubArgs),
    /// The shared test vectors of the viewer and the server (proto/vectors/*.json).
    Vectors {
        #[command(subcommand)]
        action: VectorsAction,
    },
    /// Session recordings: info, export, check, replay, record-script.
    #[command(flatten)]
    Session(session::cli::SessionCommand),
    /// Exercise files: check them, and score recordings as attempts.
    Exercise {
        #[command(subcommand)]
        command: softhaptic_server::exercise::cli::ExerciseCommand,
    },
    /// Pass marks from experts: score experts' recordings of an exercise and set each metric's
    /// mark at the experts' mean, loosened by one standard deviation (at least five recordings).
    Benchmark(softhaptic_server::exercise::cli::BenchmarkArgs),
    /// A trainee's or a class's attempts at an exercise: one CSV row per attempt, and an HTML
    /// report with a plot per metric against its pass mark.
    Results(softhaptic_server::exercise::cli::ResultsArgs),
    /// A teaching lab's NATS sign-in: a user nkey seed per station and one for the hubs in DIR
    /// (mode 0600; seeds already there are kept), and DIR/authorization.conf, the
    /// nats-server `authorization` block that lets each station publish only its own subjects
    /// and archive bucket, and the hubs only read. Include it in the server's configuration;
    /// give each station `--nats-credentials DIR/station-NAME.nk`, each hub DIR/hub.nk.
    NatsConfig {
        /// A station's name (repeatable).
        #[arg(long = "station", value_name = "NAME", required = true)]
        stations: Vec<String>,
        /// Where to write the seeds and the configuration.
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
    },
    /// Print the shell completion script for SHELL (the package installs bash's, zsh's and
    /// fish's).
    Completions {
        #[arg(value_enum)]
        shell: clap_complete::Shell,
    },
    /// Write the manual pages into DIR: softhaptic.1 and one softhaptic-COMMAND.1 per
    /// subcommand, made from this command line (the package installs them).
    Manpages {
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
    },
}

#[derive(Subcommand, Debug)]
enum VectorsAction {
    /// Write the vector files from the reference code.
    Write {
        /// Only compare the files with the code; fail if they differ.
        #[arg(long)]
        check: bool,
        /// Directory of the files [default: the source tree's proto/vectors].
        #[arg(long)]
        dir: Option<PathBuf>,
    },
}

#[derive(Args, Debug, Clone)]
struct RunArgs {
    /// Scene file (TOML; see scenes/default.toml): as given, else under the installed scenes
    /// (the binary's ../share/softhaptic/scenes, then /usr/share/softhaptic/scenes: `--scene
    /// cone.toml`).
    /// Without it, the built-in default scene: the procedural liver, a 10 mm sphere, E = 50 kPa,
    /// ν = 0.33, a simulated PHANTOM Desktop.
    #[arg(long, value_name = "FILE")]
    scene: Option<PathBuf>,
    /// The haptic device, replacing the scene's `[device] kind`: `simulated`, `openhaptics`
    /// (OpenHaptics' default device), `openhaptics:<configuration name>`, `spacemouse` (the
    /// first 3Dconnexion SpaceMouse found; input only, the force is shown but not felt),
    /// `spacemouse:<serial>`, `forcedimension` (the Force Dimension SDK's default device: omega,
    /// delta, sigma, Novint Falcon) or `forcedimension:<index>`. OpenHaptics' libHD.so and Force
    /// Dimension's libdhd.so are loaded at start; SOFTHAPTIC_HD_LIBRARY and
    /// SOFTHAPTIC_DHD_LIBRARY name them when they are not on the system's library path.
    /// `softhaptic devices` shows what this machine has.
    #[arg(long, value_name = "DEVICE")]
    device: Option<DeviceChoice>,
    /// Address to serve the viewer and the WebSocket stream on; port 0 picks a free port.
    #[arg(long, default_value = "127.0.0.1:8080", value_name = "HOST:PORT")]
    addr: SocketAddr,
    /// Serve the viewer from this checkout's web/ (index.html, src/, node_modules/three), for
    /// developing it without rebuilding [default: the viewer built into the binary].
    #[arg(long, value_name = "DIR")]
    web_dir: Option<PathBuf>,
    /// Do not ask for real-time scheduling (SCHED_FIFO, locked memory) for the haptic thread.
    #[arg(long)]
    no_realtime: bool,
    /// CPU of the haptic thread: `none` (unbound), `auto` (the last CPU when real-time is
    /// granted), `last` or a CPU number. Bind it to a CPU kept free of other work and interrupts;
    /// on a shared machine unbound measured better (`loop-timing --cpu`).
    #[arg(long, default_value = "none", value_name = "CPU")]
    loop_cpu: softhaptic_device::rt::CpuChoice,
    /// Run the haptic loop without its standby thread. By default a second thread, bound to
    /// another CPU, runs a tick the haptic thread has not started a quarter period after its
    /// deadline, so a stall of one CPU costs 250 µs instead of a lost tick.
    #[arg(long)]
    no_loop_standby: bool,
    #[command(flatten)]
    record: session::cli::RecordArgs,
    #[command(flatten)]
    access: AccessArgs,
    #[command(flatten)]
    tls: softhaptic_server::tls::TlsArgs,
    /// Publish this session to a teaching lab's NATS (e.g. nats://lab-server:4222), for the
    /// lab's hubs; needs --station. NATS down does not stop the station: it serves its own
    /// viewers and publishes again once NATS is back.
    #[arg(long, value_name = "URL", requires = "station")]
    nats: Option<String>,
    /// This station's name in the lab (letters, digits, '-' and '_').
    #[arg(long, value_name = "NAME", requires = "nats")]
    station: Option<String>,
    /// NATS credentials: a NATS .creds file, a user nkey seed file (`SU…`, as `nk -gen user`
    /// or `softhaptic nats-config` writes it), or TOML with `token = "…"`, `user = "…"` and
    /// `password = "…"`, or `nkey = "SU…"`. Beyond this machine they need TLS (--nats-ca or
    /// tls:// URLs).
    #[arg(long, value_name = "FILE", requires = "nats")]
    nats_credentials: Option<PathBuf>,
    /// TLS to NATS, the server's certificate verified against this CA's (PEM) alone.
    #[arg(long, value_name = "FILE", requires = "nats")]
    nats_ca: Option<PathBuf>,
    /// Run these exercises (exercises/*.toml, made for this station's scene; as given, else
    /// under the installed exercises: `--exercises press-hold.toml`) for --trainee, in order: the first starts with the session, each next one after the pause that follows the
    /// last one's result; an instructor's viewer may start the next, repeat or stop one. Every
    /// attempt's result is recorded (so not with --no-record).
    #[arg(long, value_name = "FILE", num_args = 1.., requires = "trainee")]
    exercises: Vec<PathBuf>,
    /// The trainee the exercises are run for: shown on the viewers, written into every result.
    #[arg(long, value_name = "NAME", requires = "exercises")]
    trainee: Option<String>,
    /// Seconds between an attempt's result and the next exercise starting by itself; `wait`
    /// leaves it to an instructor's viewer.
    #[arg(
        long,
        default_value = "10",
        value_name = "SECONDS|wait",
        requires = "exercises"
    )]
    exercise_pause: ExercisePause,
    /// Guide the trainee along the tool path of this recording: an expert's session (live,
    /// shipped or archived) made with this scene's object and tool. The tool is pulled toward
    /// where the expert's was by a spring of its own, capped at 1.5 N, that engages within
    /// 15 mm of the path, lets go beyond 30 mm, and never pushes deeper than the expert went.
    /// The viewers draw the expert's tool as a ghost with the path ahead; the recording keeps
    /// the path.
    #[arg(long, value_name = "EXPERT.mcap")]
    guide: Option<PathBuf>,
    /// The guidance's gain: a number from 0 (no pull) to 1 held all session; a list, one gain
    /// per pass along the path (`1,0.6,0.3,0`: a pass ends when the trainee reaches the path's
    /// end and lifts away; the last gain holds after the list); or `as-needed`: full at first,
    /// then every half second 0.9 × itself + 10 /m × the trainee's mean distance from the path
    /// (it settles at 0.2 for a 2 mm error, at 1 for 10 mm).
    #[arg(
        long,
        default_value = "1",
        value_name = "GAIN|GAIN,GAIN,…|as-needed",
        requires = "guide"
    )]
    guide_gain: GuideGainArg,
}

/// `--guide-gain`: a fixed gain, or guidance as needed.
#[derive(Debug, Clone)]
struct GuideGainArg(softhaptic_proto::GuideGain);

impl std::str::FromStr for GuideGainArg {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        use softhaptic_proto::GuideGain;
        if s == "as-needed" {
            return Ok(Self(GuideGain::AS_NEEDED));
        }
        let gains = s
            .split(',')
            .map(|g| {
                g.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|g| (0.0..=1.0).contains(g))
            })
            .collect::<Option<Vec<f64>>>()
            .filter(|g| (1..=softhaptic_proto::guide::MAX_SCHEDULED_PASSES).contains(&g.len()));
        match gains.as_deref() {
            Some([gain]) => Ok(Self(GuideGain::Fixed { gain: *gain })),
            Some(_) => Ok(Self(GuideGain::Schedule {
                gains: gains.unwrap_or_default(),
            })),
            None => Err(format!(
                "`{s}` is neither a gain from 0 to 1, a list of at most {} of them (one per \
                 pass along the path), nor `as-needed`",
                softhaptic_proto::guide::MAX_SCHEDULED_PASSES
            )),
        }
    }
}

/// `--exercise-pause`: seconds, or `wait` for an instructor.
#[derive(Debug, Clone, Copy)]
struct ExercisePause(Option<f64>);

impl std::str::FromStr for ExercisePause {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if s == "wait" {
            return Ok(Self(None));
        }
        match s.parse::<f64>() {
            Ok(v) if v.is_finite() && (0.0..=3600.0).contains(&v) => Ok(Self(Some(v))),
            _ => Err(format!(
                "{s:?}: seconds from 0 to 3600, or `wait` for an instructor"
            )),
        }
    }
}

#[derive(Args, Debug, Clone)]
struct HubArgs {
    /// The lab's NATS (e.g. nats://lab-server:4222).
    #[arg(long, value_name = "URL")]
    nats: String,
    /// NATS credentials: a NATS .creds file, a user nkey seed file (`SU…`, as `nk -gen user`
    /// or `softhaptic nats-config` writes it), or TOML with `token = "…"`, `user = "…"` and
    /// `password = "…"`, or `nkey = "SU…"`. Beyond this machine they need TLS (--nats-ca or
    /// tls:// URLs).
    #[arg(long, value_name = "FILE")]
    nats_credentials: Option<PathBuf>,
    /// TLS to NATS, the server's certificate verified against this CA's (PEM) alone.
    #[arg(long, value_name = "FILE")]
    nats_ca: Option<PathBuf>,
    /// Address to serve the page and the relayed streams on; port 0 picks a free port.
    #[arg(long, default_value = "127.0.0.1:8090", value_name = "HOST:PORT")]
    addr: SocketAddr,
    /// Serve the viewer from this checkout's web/ [default: the viewer built into the binary].
    #[arg(long, value_name = "DIR")]
    web_dir: Option<PathBuf>,
    #[command(flatten)]
    access: AccessArgs,
    #[command(flatten)]
    tls: softhaptic_server::tls::TlsArgs,
    /// Memory the hub keeps for archived recordings' replays, MiB: the replays open, and those
    /// closed in the last --replay-expiry seconds; a replay that does not fit is refused until
    /// one closes.
    #[arg(long, default_value_t = 1024, value_name = "MIB")]
    replay_memory_mib: u64,
    /// How long a closed replay's recording is kept for a viewer that comes back, seconds.
    #[arg(long, default_value_t = 600, value_name = "S")]
    replay_expiry: u64,
}

fn main() -> std::process::ExitCode {
    match try_main() {
        Ok(code) => code,
        Err(e) => {
            // The whole chain on one line, each cause once; no backtrace: these are
            // user-facing errors.
            eprintln!(
                "error: {}",
                softhaptic_server::logging::error_text(e.as_ref())
            );
            std::process::ExitCode::FAILURE
        }
    }
}

/// Runs the command; its exit status when it has one of its own (the doctor's 0, 1 or 2).
fn try_main() -> anyhow::Result<std::process::ExitCode> {
    softhaptic_server::logging::init();
    let cli = Cli::parse();
    let status = |code: i32| std::process::ExitCode::from(u8::try_from(code).unwrap_or(u8::MAX));
    let done = |r: anyhow::Result<()>| r.map(|()| std::process::ExitCode::SUCCESS);
    match cli.command {
        None => done(run(cli.run)),
        Some(Command::Run(args)) => done(run(*args)),
        Some(Command::Hub(args)) => done(hub(args)),
        Some(Command::Vectors {
            action: VectorsAction::Write { check, dir },
        }) => {
            let dir = dir.unwrap_or_else(vectors::default_dir);
            let files = vectors::write_or_check(&dir, check)?;
            for f in files {
                println!(
                    "{} {}",
                    if check { "up to date:" } else { "wrote" },
                    f.display()
                );
            }
            Ok(std::process::ExitCode::SUCCESS)
        }
        Some(Command::Session(command)) => done(session::cli::run(command)),
        Some(Command::Exercise { command }) => {
            done(softhaptic_server::exercise::cli::run_exercise(command))
        }
        Some(Command::Benchmark(args)) => {
            done(softhaptic_server::exercise::cli::run_benchmark(args))
        }
        Some(Command::Results(args)) => done(softhaptic_server::exercise::cli::run_results(args)),
        Some(Command::Doctor(args)) => Ok(status(softhaptic_server::doctor::run(&args)?)),
        Some(Command::Devices { name }) => done(session::cli::print_report(format_args!(
            "{}",
            devices::listing(&name)
        ))),
        Some(Command::NatsConfig { stations, out }) => {
            let written = softhaptic_server::lab::permissions::write_lab_config(&out, &stations)
                .map_err(|e| anyhow::anyhow!("nats-config: {e}"))?;
            for (who, path, made) in &written.seeds {
                println!(
                    "{} {who}'s seed: {}",
                    if *made { "made" } else { "kept" },
                    path.display()
                );
            }
            println!(
                "wrote {}: copy it beside nats-server's configuration and add the line \
                 `include \"{}\"` there (an include is read relative to the configuration)",
                written.authorization.display(),
                softhaptic_server::lab::permissions::AUTHORIZATION_FILE
            );
            Ok(std::process::ExitCode::SUCCESS)
        }
        Some(Command::Completions { shell }) => {
            let mut script = Vec::new();
            clap_complete::generate(shell, &mut Cli::command(), "softhaptic", &mut script);
            done(session::cli::print_report(format_args!(
                "{}",
                String::from_utf8_lossy(&script)
            )))
        }
        Some(Command::Manpages { out }) => {
            std::fs::create_dir_all(&out)
                .with_context(|| format!("could not create {}", out.display()))?;
            clap_mangen::generate_to(Cli::command(), &out).with_context(|| {
                format!("could not write the manual pages into {}", out.display())
            })?;
            println!("wrote the manual pages into {}", out.display());
            Ok(std::process::ExitCode::SUCCESS)
        }
    }
}

/// The TLS setup `args` ask for on `addr` (said on the terminal when there is one), and what it
/// decides of `access`: HSTS only with a CA's certificate (a browser told to insist on https
/// for a self-signed one would lock its users out when it changes), and the data directory,
/// where the links go when standard output would keep them. The hub and a station alike.
fn tls_for(
    args: &softhaptic_server::tls::TlsArgs,
    addr: SocketAddr,
    access: &mut softhaptic_server::access::AccessConfig,
) -> anyhow::Result<Option<softhaptic_server::tls::TlsSetup>> {
    let tls = softhaptic_server::tls::server_config(args, addr.ip())?;
    if let Some(t) = &tls {
        softhaptic_server::logging::print_line(format_args!("{t}"));
    }
    access.strict_transport = tls.as_ref().is_some_and(|t| t.from_a_ca);
    access.links_dir = args
        .data_dir
        .clone()
        .or_else(softhaptic_server::tls::default_data_dir);
    Ok(tls)
}

fn hub(args: HubArgs) -> anyhow::Result<()> {
    let mut access = args.access.resolve(args.addr)?;
    let tls = tls_for(&args.tls, args.addr, &mut access)?;
    let viewer = softhaptic_server::viewer::Viewer::from_option(args.web_dir.clone())?;
    let runtime = tokio::runtime::Runtime::new().context("could not start the async runtime")?;
    runtime.block_on(async move {
        let mut stop =
            app::StopSignals::listen().context("could not listen for the stop signals")?;
        let hub = softhaptic_server::lab::hub::start(softhaptic_server::lab::hub::HubOptions {
            nats: softhaptic_server::lab::NatsOptions {
                url: softhaptic_server::lab::parse_nats_url(&args.nats)
                    .map_err(|e| anyhow::anyhow!("--nats: {e}"))?,
                credentials: args.nats_credentials.clone(),
                tls_ca: args.nats_ca.clone(),
            },
            addr: args.addr,
            viewer,
            access: access.clone(),
            tls: tls.map(|t| t.config),
            viewer_limits: Default::default(),
            replay_cache: softhaptic_server::lab::replays::ReplayCacheLimits {
                max_bytes: args.replay_memory_mib.saturating_mul(1 << 20),
                idle_expiry: std::time::Duration::from_secs(args.replay_expiry),
            },
            archive_listing: Default::default(),
        })
        .await?;
        let mut access = access;
        access.print_page_links(
            &hub.viewer_url(),
            hub.local_addr(),
            &[
                ("", ["hub viewer", "hub observer"]),
                ("dashboard", ["hub dashboard", "hub observer dashboard"]),
            ],
        );
        let signal = stop.recv().await;
        tracing::info!(signal, "shutting down");
        hub.shutdown().await;
        Ok(())
    })
}

fn run(args: RunArgs) -> anyhow::Result<()> {
    // Refuse to serve an address beyond loopback without tokens, and bad token sources, before
    // anything starts.
    let mut access = args.access.resolve(args.addr)?;
    if let Some(url) = &args.nats {
        // Refused with the reason, never the URL: it would carry the credentials.
        softhaptic_server::lab::parse_nats_url(url).map_err(|e| anyhow::anyhow!("--nats: {e}"))?;
        // Credentials that would cross the network in plain text stop the start here, before
        // the device is opened and a recording begun.
        softhaptic_server::lab::NatsOptions {
            url: url.clone(),
            credentials: args.nats_credentials.clone(),
            tls_ca: args.nats_ca.clone(),
        }
        .check_transport()?;
    }
    // A certificate that does not load stops the start too, before a recording is begun.
    let tls = tls_for(&args.tls, args.addr, &mut access)?;
    // A page that could not run (a --web-dir without three.js) stops the start too.
    let viewer = softhaptic_server::viewer::Viewer::from_option(args.web_dir.clone())?;
    // Refuse a bad scene before anything starts. A scene not found as given is looked for
    // where the package installs them (datadir).
    let scene_file = args
        .scene
        .as_deref()
        .map(softhaptic_server::datadir::find_scene)
        .transpose()?;
    let mut scene = match &scene_file {
        Some(path) => Scene::load(path)?,
        None => Scene::builtin_default()?,
    };
    if let Some(choice) = &args.device {
        scene.choose_device(choice);
    }
    // A recording that cannot guide this scene stops the start, naming what differs.
    if let Some(expert) = &args.guide {
        let guide = softhaptic_server::session::guide::guide_from_file(
            expert,
            &scene,
            softhaptic_proto::GuideParams::default(),
            args.guide_gain.0.clone(),
        )?;
        tracing::info!(
            expert = %expert.display(),
            path_m = guide.spacing_m * guide.points_m.len().saturating_sub(1) as f64,
            gain = ?guide.gain,
            "guiding along the expert's path"
        );
        scene
            .set_guide(guide)
            .map_err(|reason| anyhow::anyhow!("--guide {}: {reason}", expert.display()))?;
    }
    let runtime = tokio::runtime::Runtime::new().context("could not start the async runtime")?;
    // Caught before the device is opened and the recording starts, so that no stop can leave
    // either open.
    let mut stop = {
        let _context = runtime.enter();
        app::StopSignals::listen().context("could not listen for the stop signals")?
    };
    // Before the device is opened: exercises that cannot run here start nothing.
    // Where the scene's inclusions are, for the viewers who may see them (none without).
    let inclusions_feed = softhaptic_server::exercise::run::inclusions_feed(&scene);
    let (exercise_run, exercise_feed) = exercise_run(
        &args,
        &scene,
        scene_file.as_deref(),
        inclusions_feed.clone(),
    )?;
    // Opened before the recording starts, so that the recording and the viewers are told the
    // limits the device really runs with; a device that cannot be opened stops here.
    let device = devices::open(&mut scene)?;
    tracing::info!(
        scene = %scene_file.as_deref().map(|p| p.display().to_string()).unwrap_or_else(|| "built-in default".into()),
        object = %scene.object_name,
        calibration = scene.calibration.source().as_str(),
        model = %scene.contact_model_info().label,
        limits = %scene.validity.source,
        "scene loaded"
    );
    let mut recording = session::cli::LiveRecording::start_observed(
        &args.record,
        &scene,
        scene_file.as_deref(),
        exercise_run,
    )?;
    runtime.block_on(async move {
        let mut options = ServerOptions::new(args.addr);
        options.viewer = viewer;
        options.realtime = !args.no_realtime;
        options.loop_cpu = args.loop_cpu;
        options.loop_standby = !args.no_loop_standby;
        options.tick_sink = recording.as_mut().and_then(|r| r.take_tick_sink());
        options.session_id = recording.as_ref().map(|r| r.session_id().to_owned());
        options.device = Some(device);
        options.access = access.clone();
        options.tls = tls.map(|t| t.config);
        options.exercises = exercise_feed;
        options.inclusions = inclusions_feed;
        let lab = args
            .nats
            .clone()
            .zip(args.station.clone())
            .map(
                |(url, name)| softhaptic_server::lab::station::StationOptions {
                    nats: softhaptic_server::lab::NatsOptions {
                        url,
                        credentials: args.nats_credentials.clone(),
                        tls_ca: args.nats_ca.clone(),
                    },
                    name,
                },
            );
        options.lab = lab.clone();
        let server = match app::start(scene, options).await {
            Ok(server) => server,
            Err(e) => {
                if let Some(r) = recording {
                    r.abandon();
                }
                return Err(e.into());
            }
        };
        if let Some(r) = &recording {
            r.attach(&server);
            softhaptic_server::logging::print_line(format_args!(
                "recording: {}",
                r.path().display()
            ));
        }
        // A lab station archives its finished recordings (earlier sessions now, and again while it
        // runs until none is left unarchived; this one when it stops); a file not verified there
        // by then is tried again at the next start.
        let archive = match (&lab, &recording) {
            (Some(lab), Some(r)) => {
                let client = softhaptic_server::lab::connect(
                    &lab.nats,
                    format!("softhaptic station {} archive", lab.name),
                    softhaptic_server::lab::Party::Station(&lab.name),
                )
                .await?;
                Some(softhaptic_server::lab::archive::StationArchive::start(
                    client,
                    lab.name.clone(),
                    args.record.record_dir.clone(),
                    Some(r.path().to_owned()),
                    Default::default(),
                ))
            }
            _ => None,
        };
        // The token is in the fragment, which no request carries; on a terminal or a pipe only
        // (else in a 0600 file the log names).
        let mut access = access;
        access.print_links(
            &server.viewer_url(),
            server.local_addr(),
            ["viewer", "observer"],
        );
        // For a supervisor: up, and where (the links, with their tokens, are never logged).
        tracing::info!(addr = %server.local_addr(), "serving viewers");
        let signal = stop.recv().await;
        tracing::info!(signal, "shutting down");
        let (stats, metrics) = server.shutdown_with_metrics().await;
        tracing::info!(
            ticks = stats.ticks,
            overruns = stats.overruns,
            ticks_by_standby = stats.standby_ticks,
            period_error_p99_us = stats.period_error_p99_ns as f64 * 1e-3,
            "haptic loop stopped"
        );
        if let Some(r) = recording {
            let (path, rec) = r.finish(&metrics)?;
            tracing::info!(
                file = %path.display(),
                ticks = rec.ticks_recorded,
                ticks_dropped = rec.ticks_dropped,
                contact_frames = rec.contact_frames_recorded,
                "recording closed"
            );
            if let Some(archive) = archive {
                match archive.finish(&path, std::time::Duration::from_secs(60)).await {
                    Ok(_) => tracing::info!(file = %path.display(), "recording archived in the lab (verified)"),
                    Err(e) => tracing::warn!("recording not archived ({e}): it is kept, and tried again at the next start"),
                }
            }
        }
        Ok(())
    })
}

/// The station's exercises (`--exercises`, `--trainee`), checked against its scene before
/// anything starts: the scorer the recorder runs, and the feed the viewers see it through.
#[allow(clippy::type_complexity)]
fn exercise_run(
    args: &RunArgs,
    scene: &Scene,
    scene_file: Option<&std::path::Path>,
    inclusions: Option<std::sync::Arc<softhaptic_server::stream::InclusionsFeed>>,
) -> anyhow::Result<(
    Option<Box<dyn softhaptic_server::session::writer::TickObserver>>,
    Option<std::sync::Arc<softhaptic_server::stream::ExerciseFeed>>,
)> {
    use softhaptic_server::exercise::run::{ExerciseRun, check_trainee, station_exercises};
    if args.exercises.is_empty() {
        return Ok((None, None));
    }
    if args.record.no_record {
        anyhow::bail!(
            "--exercises with --no-record: every attempt's result is kept in the session's \
             recording; drop --no-record"
        );
    }
    let trainee = check_trainee(args.trainee.as_deref().unwrap_or_default())?;
    let paths = args
        .exercises
        .iter()
        .map(|p| softhaptic_server::datadir::find_exercise(p))
        .collect::<Result<Vec<_>, _>>()?;
    let exercises = station_exercises(&paths, scene, scene_file)?;
    let (feed, controls) = softhaptic_server::stream::ExerciseFeed::with_controls();
    let feed = std::sync::Arc::new(feed);
    let names: Vec<&str> = exercises.iter().map(|e| e.exercise.name.as_str()).collect();
    tracing::info!(trainee = %trainee, exercises = ?names, "running exercises");
    let run = ExerciseRun::new(
        trainee,
        exercises,
        std::sync::Arc::clone(&feed),
        controls,
        args.exercise_pause.0,
    )?
    .with_inclusions(inclusions, scene);
    Ok((Some(Box::new(run)), Some(feed)))
}
