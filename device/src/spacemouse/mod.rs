//! A 3Dconnexion SpaceMouse as the tool's input: a 6-DoF puck that renders no force.
//!
//! ```text
//!  HID reports (~60 Hz)          reader thread                     1 kHz loop thread
//!  ──────────────────► Transport ──► Parser ─► PuckState ─► SeqCell ─try_read─► RateControl ─► DeviceSample
//!                      (hidraw,         (report.rs)          (wait-free      (rate.rs: dead band, gain,
//!                       or a script)                          for the loop)   filter, box, reset)
//! ```
//!
//! - [`report`]: the products, the two report layouts, normalisation per model.
//! - [`rate`]: the deflection as a velocity, integrated and smoothed on the 1 kHz side.
//! - [`hid`]: the hidapi transport (Linux hidraw) and the `softhaptic devices` listing.
//! - [`script`]: a recorded report stream played back in real time (the tests' transport, and a
//!   way to rehearse a scene with no device).
//!
//! The reader thread owns the transport: it blocks in the transport's read (with a timeout, so
//! it notices a stop), parses each report and publishes the puck's state through a seqlock the
//! loop only ever *tries* to read ([`SeqCell::try_read`]): the loop never waits for HID. A
//! transport error is an unplug: the reader publishes "disconnected" and asks its connector for
//! the device again every [`RECONNECT_INTERVAL`], so a replug is picked up without a restart.
//! While disconnected, [`HapticDevice::read`] returns [`DeviceError::Disconnected`]: the loop
//! gives zero force, flags the tick and holds the last pose, so the tool holds still.
//!
//! The force is computed, streamed and recorded as for any device;
//! [`HapticDevice::renders_force`] is false, and [`HapticDevice::command_force`] accepts it
//! without sending it anywhere.

pub mod hid;
pub mod rate;
pub mod report;
pub mod script;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use glam::DVec3;

use crate::cells::{SeqCell, Words, WordsReader};
use crate::device::{DeviceError, DeviceLimits, DeviceSample, HapticDevice};
use crate::rt;
use rate::{RateConfig, RateControl};
use report::{Axes, Model, Parser, PuckState};

/// How often the reader asks for an unplugged device again.
pub const RECONNECT_INTERVAL: Duration = Duration::from_millis(500);
/// How long one transport read may block before the reader checks for a stop.
const READ_TIMEOUT_MS: i32 = 50;
/// Reports older than this are taken to have stopped (a device sends ~60 a second while its puck
/// is off centre): the target velocity is then zero and the tool comes to rest.
pub const REPORTS_STALE_AFTER_NS: u64 = 250_000_000;
/// The longest step the integration takes, s: a loop that lost ticks (or a read after a long
/// pause) moves the tool by at most the speed limit times this, never teleports it.
pub const MAX_STEP_S: f64 = 0.02;

/// Why the transport could not go on.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TransportError {
    /// No listed SpaceMouse is plugged in (or it went away).
    #[error("no SpaceMouse found: {0}")]
    NotFound(String),
    /// A SpaceMouse is there but could not be opened (permissions: see the udev rule).
    #[error("{0}")]
    Open(String),
    /// The device stopped answering (unplugged).
    #[error("SpaceMouse disconnected: {0}")]
    Disconnected(String),
}

/// A source of HID reports from one device.
pub trait Transport: Send {
    /// Reads one report (the report id first) into `buf`, waiting at most `timeout_ms`;
    /// `Ok(0)` when none came in time. An error means the device is gone.
    fn read(&mut self, buf: &mut [u8], timeout_ms: i32) -> Result<usize, TransportError>;
}

/// Finds and opens the device, at the start and after every unplug.
pub trait Connector: Send {
    /// The opened device's transport and model.
    fn connect(&mut self) -> Result<(Box<dyn Transport>, &'static Model), TransportError>;
}

/// Why the SpaceMouse backend could not start.
#[derive(Debug, thiserror::Error)]
pub enum SpaceMouseError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error("the SpaceMouse settings in the scene: {0}")]
    Config(String),
    #[error("could not start the SpaceMouse reader thread: {0}")]
    Spawn(#[source] std::io::Error),
}

/// Words of the puck state shared with the loop: report count, connected, report time,
/// translation (3), rotation (3), buttons.
const PUCK_WORDS: usize = 10;

#[derive(Debug, Clone, Copy, PartialEq)]
struct Shared {
    /// Reports parsed since the start (a change tells the loop a new report came).
    reports: u64,
    connected: bool,
    /// CLOCK_MONOTONIC of the last report.
    report_ns: u64,
    puck: PuckState,
}

impl Shared {
    fn to_words(self) -> [u64; PUCK_WORDS] {
        let mut w = Words::new();
        w.u64(self.reports).bool(self.connected).u64(self.report_ns);
        for v in self
            .puck
            .axes
            .translation
            .into_iter()
            .chain(self.puck.axes.rotation)
        {
            w.f64(v);
        }
        w.u64(u64::from(self.puck.buttons));
        w.finish()
    }

    fn from_words(words: [u64; PUCK_WORDS]) -> Self {
        let mut r = WordsReader::new(&words);
        let shared = Shared {
            reports: r.u64(),
            connected: r.bool(),
            report_ns: r.u64(),
            puck: PuckState {
                axes: Axes {
                    translation: [r.f64(), r.f64(), r.f64()],
                    rotation: [r.f64(), r.f64(), r.f64()],
                },
                buttons: r.u64() as u32,
            },
        };
        r.finish();
        shared
    }
}

/// The SpaceMouse as a [`HapticDevice`].
pub struct SpaceMouseDevice {
    rate: RateControl,
    shared: Arc<SeqCell<PUCK_WORDS>>,
    latest: Shared,
    opened_ns: u64,
    last_read_ns: Option<u64>,
    limits: DeviceLimits,
    model: &'static Model,
    stop: Arc<AtomicBool>,
    reader: Option<JoinHandle<()>>,
}

impl SpaceMouseDevice {
    /// Opens the device through `connector` (an error when none answers: the start fails with
    /// the reason) and starts the reader thread. `limits` are the scene's preset: the loop's
    /// safety layer still bounds the force it computes, though none is rendered.
    pub fn open(
        mut connector: Box<dyn Connector>,
        config: RateConfig,
        limits: DeviceLimits,
    ) -> Result<Self, SpaceMouseError> {
        if let Some(problem) = config.problem() {
            return Err(SpaceMouseError::Config(problem));
        }
        let (transport, model) = connector.connect()?;
        let opened_ns = rt::now_ns();
        let first = Shared {
            reports: 0,
            connected: true,
            report_ns: opened_ns,
            puck: PuckState::default(),
        };
        let shared = Arc::new(SeqCell::new(first.to_words()));
        let stop = Arc::new(AtomicBool::new(false));
        let reader = {
            let shared = Arc::clone(&shared);
            let stop = Arc::clone(&stop);
            std::thread::Builder::new()
                .name("softhaptic-spacemouse".into())
                .spawn(move || {
                    Reader {
                        connector,
                        shared,
                        stop,
                        state: first,
                    }
                    .run(transport, model)
                })
                .map_err(SpaceMouseError::Spawn)?
        };
        Ok(Self {
            rate: RateControl::new(config),
            shared,
            latest: first,
            opened_ns,
            last_read_ns: None,
            limits,
            model,
            stop,
            reader: Some(reader),
        })
    }

    /// The model that was opened.
    pub fn model(&self) -> &'static Model {
        self.model
    }

    /// CLOCK_MONOTONIC when the device was opened: its samples' `time_ns` count from it.
    pub fn opened_ns(&self) -> u64 {
        self.opened_ns
    }

    /// The rate control's settings.
    pub fn rate_config(&self) -> &RateConfig {
        self.rate.config()
    }
}

impl HapticDevice for SpaceMouseDevice {
    fn limits(&self) -> DeviceLimits {
        self.limits
    }

    fn read(&mut self) -> Result<DeviceSample, DeviceError> {
        let now = rt::now_ns();
        // Mid-write by the reader: this tick keeps the previous copy rather than wait.
        if let Some(words) = self.shared.try_read() {
            self.latest = Shared::from_words(words);
        }
        let dt_s = self
            .last_read_ns
            .map_or(0.0, |t| now.saturating_sub(t) as f64 * 1e-9)
            .min(MAX_STEP_S);
        self.last_read_ns = Some(now);
        if !self.latest.connected {
            self.rate.hold();
            return Err(DeviceError::Disconnected);
        }
        let live = now.saturating_sub(self.latest.report_ns) <= REPORTS_STALE_AFTER_NS;
        let puck = self.latest.puck;
        self.rate.step(dt_s, &puck.axes, puck.buttons, live);
        Ok(DeviceSample {
            time_ns: now.saturating_sub(self.opened_ns),
            tip_in_world: self.rate.pose(),
            tip_velocity_m_s: self.rate.velocity_m_s(),
            buttons: puck.buttons,
            flags: softhaptic_proto::ContactFlags::empty(),
        })
    }

    fn command_force(&mut self, _force_n: DVec3) -> Result<(), DeviceError> {
        // No motors: the force is the loop's to show and record.
        Ok(())
    }

    fn renders_force(&self) -> bool {
        false
    }
}

impl Drop for SpaceMouseDevice {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(reader) = self.reader.take() {
            // The reader notices the stop within one read timeout or reconnect interval.
            let _ = reader.join();
        }
    }
}

/// The reader thread: reports in, puck state out.
struct Reader {
    connector: Box<dyn Connector>,
    shared: Arc<SeqCell<PUCK_WORDS>>,
    stop: Arc<AtomicBool>,
    state: Shared,
}

impl Reader {
    fn run(mut self, transport: Box<dyn Transport>, model: &'static Model) {
        let mut current = Some((transport, model));
        while !self.stop.load(Ordering::Relaxed) {
            match current.take() {
                Some((transport, model)) => {
                    if let Err(e) = self.read_until_gone(transport, model) {
                        tracing::warn!("{e}; the tool holds still until it is plugged in again");
                        self.publish_connected(false);
                    }
                }
                None => {
                    self.sleep(RECONNECT_INTERVAL);
                    if self.stop.load(Ordering::Relaxed) {
                        break;
                    }
                    if let Ok((transport, model)) = self.connector.connect() {
                        tracing::info!("{} connected again", model.name);
                        current = Some((transport, model));
                    }
                }
            }
        }
    }

    /// Reads reports until the transport fails (`Err`) or a stop is asked for (`Ok`).
    fn read_until_gone(
        &mut self,
        mut transport: Box<dyn Transport>,
        model: &'static Model,
    ) -> Result<(), TransportError> {
        let parser = Parser::new(model);
        // A puck released while unplugged must not keep its old deflection.
        self.state.puck = PuckState::default();
        self.publish_connected(true);
        let mut buf = [0u8; 64];
        while !self.stop.load(Ordering::Relaxed) {
            let n = transport.read(&mut buf, READ_TIMEOUT_MS)?;
            if n == 0 {
                continue;
            }
            match parser.parse(&buf[..n.min(buf.len())]) {
                Ok(update) => {
                    self.state.puck.apply(update);
                    self.state.reports += 1;
                    self.state.report_ns = rt::now_ns();
                    self.shared.write(&self.state.to_words());
                }
                Err(e) => tracing::debug!("{} sent a report the parser refused: {e}", model.name),
            }
        }
        Ok(())
    }

    fn publish_connected(&mut self, connected: bool) {
        self.state.connected = connected;
        self.state.report_ns = rt::now_ns();
        self.shared.write(&self.state.to_words());
    }

    fn sleep(&self, total: Duration) {
        let step = Duration::from_millis(20);
        let mut slept = Duration::ZERO;
        while slept < total && !self.stop.load(Ordering::Relaxed) {
            std::thread::sleep(step);
            slept += step;
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    //! The backend through its reader thread and a scripted transport, read as the loop reads it.
    //! Time is real here (the reader stamps reports with CLOCK_MONOTONIC), so each test asserts
    //! what holds however late the threads run: a bound, or a condition polled for with a
    //! generous deadline.

    use std::time::Instant;

    use softhaptic_proto::Pose;

    use super::script::{ReportScript, axis_report};
    use super::*;

    const FULL_X: [i16; 3] = [350, 0, 0];

    /// A tool at the origin in a box of ±1 m: no face is reached in these tests.
    fn config() -> RateConfig {
        RateConfig::new(
            Pose::from_position(DVec3::ZERO),
            DVec3::splat(-1.0),
            DVec3::splat(1.0),
        )
    }

    fn open(script: ReportScript) -> SpaceMouseDevice {
        SpaceMouseDevice::open(
            Box::new(script.connector()),
            config(),
            DeviceLimits::PHANTOM_DESKTOP,
        )
        .unwrap()
    }

    /// Reads about once a millisecond, as the loop does, until `done` says so (a minute at most).
    fn read_until(
        device: &mut SpaceMouseDevice,
        mut done: impl FnMut(&[DeviceSample]) -> bool,
    ) -> Vec<DeviceSample> {
        let deadline = Instant::now() + Duration::from_secs(60);
        let mut samples = Vec::new();
        loop {
            samples.push(device.read().expect("the script keeps it plugged in"));
            if done(&samples) {
                return samples;
            }
            assert!(
                Instant::now() < deadline,
                "gave up after {} reads; the last {:?}",
                samples.len(),
                samples.last()
            );
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    #[test]
    fn a_deflection_whose_reports_stop_comes_to_rest_after_the_stale_time() {
        let gain = config().gain_m_s;
        // One report of a full push, then silence: a wireless link lost with the puck deflected.
        let mut device =
            open(ReportScript::new(&report::MODELS[6]).report(0.0, &axis_report(1, FULL_X)));
        let mut fastest = 0.0f64;
        let samples = read_until(&mut device, |s| {
            let v = s[s.len() - 1].tip_velocity_m_s.length();
            fastest = fastest.max(v);
            fastest > 0.5 * gain && v < gain * 1e-6
        });
        // The stale report moved the tool until it was REPORTS_STALE_AFTER_NS old, and only
        // then did the velocity fall: the report came after the device opened, so no sample
        // younger than the stale time may show a slower tool than the one before.
        let first_slower = samples
            .windows(2)
            .position(|w| w[1].tip_velocity_m_s.x < w[0].tip_velocity_m_s.x)
            .expect("the velocity decays");
        assert!(
            samples[first_slower + 1].time_ns >= REPORTS_STALE_AFTER_NS,
            "slowed at {} ns",
            samples[first_slower + 1].time_ns
        );
        // From then on it only decays, along x alone.
        for w in samples[first_slower..].windows(2) {
            assert!(w[1].tip_velocity_m_s.x <= w[0].tip_velocity_m_s.x, "{w:?}");
        }
        assert!(
            samples
                .iter()
                .all(|s| s.tip_velocity_m_s.y == 0.0 && s.tip_velocity_m_s.z == 0.0)
        );
        // The pose settles: what is left of a first-order decay's travel is its speed times τ.
        let at_rest = samples[samples.len() - 1].tip_in_world.position_m;
        // On its own, not against the box's face (which also stops a tool, 20 s of push away):
        // a quarter second of push and the filter's lag are about 15 mm.
        assert!(
            at_rest.x > 0.0 && at_rest.x < 0.5 * config().workspace_max_m.x,
            "at rest at {at_rest}"
        );
        let later = read_until(&mut device, |s| s.len() >= 50);
        for s in &later {
            let drift = (s.tip_in_world.position_m - at_rest).length();
            assert!(
                drift <= gain * 1e-6 * config().smoothing_s + 1e-15,
                "{drift} m"
            );
        }
    }

    #[test]
    fn a_long_gap_between_reads_moves_the_tool_by_at_most_the_longest_step() {
        let c = config();
        let mut device =
            open(ReportScript::new(&report::MODELS[6]).hold_translation(0.0, 60.0, 0.016, FULL_X));
        let samples = read_until(&mut device, |s| {
            s[s.len() - 1].tip_velocity_m_s.x >= 0.99 * c.gain_m_s
        });
        let before = samples[samples.len() - 1];
        // The loop stalls (or the machine does) for ten times the longest step.
        std::thread::sleep(Duration::from_secs_f64(10.0 * MAX_STEP_S));
        let after = device.read().unwrap();
        assert!(after.time_ns - before.time_ns >= (10.0 * MAX_STEP_S * 1e9) as u64);
        let moved_m = (after.tip_in_world.position_m - before.tip_in_world.position_m).length();
        assert!(
            moved_m <= c.max_speed_m_s * MAX_STEP_S + 1e-15,
            "moved {moved_m} m in one read"
        );
        // The step is the bound's, not nothing: the push still drives the tool (live or
        // decaying, its speed is more than half the gain over that one step).
        assert!(
            moved_m >= 0.5 * c.gain_m_s * MAX_STEP_S,
            "moved {moved_m} m"
        );
    }
}
