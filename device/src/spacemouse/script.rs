//! A recorded SpaceMouse report stream, played back in real time as a [`Transport`].
//!
//! The file is text, one event per line, times in milliseconds from the start of playback:
//!
//! ```text
//! # a comment
//! model 046d:c626                 # the product the stream came from (default: SpaceNavigator)
//! 0      01 00 00 00 00 00 00     # a report: its bytes in hex, the report id first
//! 16.7   01 5e 01 00 00 00 00
//! 2000   unplug                   # the device goes away ...
//! 2600   replug                   # ... and comes back
//! ```
//!
//! Playback starts when the device is first opened. Each report is handed to the reader at its
//! time; an `unplug` makes the transport fail (as a pulled cable does) and the connector find
//! nothing until the `replug`; after the last event the device stays plugged in and silent.
//! Tests drive the whole backend with it; a scene can name one (`[device] report_script`) to
//! rehearse with no SpaceMouse on the desk.

use std::path::Path;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use super::report::{MODELS, Model, find_model};
use super::{Connector, Transport, TransportError};

/// One event of a stream.
#[derive(Debug, Clone, PartialEq)]
pub enum ScriptEvent {
    Report(Vec<u8>),
    Unplug,
    Replug,
}

/// A report stream: the model and its timed events, in time order.
#[derive(Debug, Clone, PartialEq)]
pub struct ReportScript {
    pub model: &'static Model,
    pub events: Vec<(Duration, ScriptEvent)>,
}

/// Why a report script was refused: the line and what is wrong with it.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("line {line}: {reason}")]
pub struct ScriptError {
    pub line: usize,
    pub reason: String,
}

/// Longest report a script may hold (HID full-speed reports are at most 64 bytes).
const MAX_REPORT_BYTES: usize = 64;
/// The shortest interval [`ReportScript::hold_translation`] puts between reports, s: a
/// full-speed HID device is polled at most once a millisecond.
pub const MIN_REPORT_INTERVAL_S: f64 = 1e-3;
/// The longest hold [`ReportScript::hold_translation`] writes out, s (an hour of reports).
pub const MAX_HOLD_S: f64 = 3600.0;

/// `t_s` seconds as an offset from the stream's start: negative and NaN are the start, a time
/// too large for a [`Duration`] (∞ among them) the end of time.
fn stream_offset(t_s: f64) -> Duration {
    if t_s.is_nan() || t_s <= 0.0 {
        Duration::ZERO
    } else {
        Duration::try_from_secs_f64(t_s).unwrap_or(Duration::MAX)
    }
}

impl ReportScript {
    /// An empty stream from `model`.
    pub fn new(model: &'static Model) -> Self {
        Self {
            model,
            events: Vec::new(),
        }
    }

    /// Adds a report at `t_s` seconds.
    pub fn report(self, t_s: f64, bytes: &[u8]) -> Self {
        self.at(t_s, ScriptEvent::Report(bytes.to_vec()))
    }

    /// Adds an unplug at `t_s` seconds.
    pub fn unplug(self, t_s: f64) -> Self {
        self.at(t_s, ScriptEvent::Unplug)
    }

    /// Adds a replug at `t_s` seconds.
    pub fn replug(self, t_s: f64) -> Self {
        self.at(t_s, ScriptEvent::Replug)
    }

    /// Adds `event` at `t_s` seconds, in time order: playback hands out the events in the order
    /// they are stored, so an event added at an earlier time than the last goes before it (after
    /// any at the same time). A time before the start or NaN is the start, and one beyond what a
    /// [`Duration`] holds is the end of time: a builder never panics on a time.
    fn at(mut self, t_s: f64, event: ScriptEvent) -> Self {
        let time = stream_offset(t_s);
        let index = self.events.partition_point(|(t, _)| *t <= time);
        self.events.insert(index, (time, event));
        self
    }

    /// Reports of a puck held at `translation` (raw HID values, three-report layout) from
    /// `from_s` to `to_s` every `every_s` (at least [`MIN_REPORT_INTERVAL_S`]; the hold at most
    /// [`MAX_HOLD_S`]), then a release to zero at `to_s`.
    pub fn hold_translation(mut self, from_s: f64, to_s: f64, every_s: f64, raw: [i16; 3]) -> Self {
        // NaN and anything faster than a full-speed HID device become its fastest rate, so the
        // loop below always advances and ends.
        let every_s = every_s.max(MIN_REPORT_INTERVAL_S);
        let end_s = to_s.min(from_s + MAX_HOLD_S);
        let mut t = from_s;
        while t < end_s {
            self = self.report(t, &axis_report(1, raw));
            t += every_s;
        }
        self.report(to_s, &axis_report(1, [0; 3]))
    }

    /// Parses a script's text; errors name the line.
    pub fn parse(text: &str) -> Result<Self, ScriptError> {
        let mut script = Self::new(&MODELS[6]);
        let mut last = Duration::ZERO;
        for (i, raw_line) in text.lines().enumerate() {
            let line = i + 1;
            let err = |reason: String| ScriptError { line, reason };
            let content = raw_line.split('#').next().unwrap_or("").trim();
            if content.is_empty() {
                continue;
            }
            let mut words = content.split_whitespace();
            let first = words.next().unwrap_or("");
            if first == "model" {
                let ids = words.next().unwrap_or("");
                let (v, p) = ids
                    .split_once(':')
                    .and_then(|(v, p)| {
                        Some((
                            u16::from_str_radix(v, 16).ok()?,
                            u16::from_str_radix(p, 16).ok()?,
                        ))
                    })
                    .ok_or_else(|| {
                        err(format!(
                            "model wants vendor:product in hex (e.g. 046d:c626), got {ids:?}"
                        ))
                    })?;
                script.model = find_model(v, p).ok_or_else(|| {
                    err(format!(
                        "{v:04x}:{p:04x} is not a SpaceMouse this backend knows"
                    ))
                })?;
                continue;
            }
            let t_ms: f64 = first
                .parse()
                .ok()
                .filter(|t: &f64| t.is_finite() && *t >= 0.0 && *t < 1e9)
                .ok_or_else(|| {
                    err(format!(
                        "expected a time in milliseconds (≥ 0) or `model`, got {first:?}"
                    ))
                })?;
            let time = Duration::from_secs_f64(t_ms * 1e-3);
            if time < last {
                return Err(err(format!(
                    "time {t_ms} ms is before the previous event's; events go in time order"
                )));
            }
            last = time;
            let rest: Vec<&str> = words.collect();
            let event = match rest.as_slice() {
                ["unplug"] => ScriptEvent::Unplug,
                ["replug"] => ScriptEvent::Replug,
                [] => return Err(err("a time with no event".into())),
                bytes => {
                    if bytes.len() > MAX_REPORT_BYTES {
                        return Err(err(format!(
                            "a report of {} bytes; HID reports are at most {MAX_REPORT_BYTES}",
                            bytes.len()
                        )));
                    }
                    let parsed: Result<Vec<u8>, _> = bytes
                        .iter()
                        .map(|b| u8::from_str_radix(b, 16).map_err(|_| *b))
                        .collect();
                    ScriptEvent::Report(parsed.map_err(|bad| {
                        err(format!(
                            "expected hex bytes, `unplug` or `replug`, got {bad:?}"
                        ))
                    })?)
                }
            };
            script.events.push((time, event));
        }
        Ok(script)
    }

    /// Reads and parses a script file (at most 16 MiB).
    pub fn from_file(path: &Path) -> Result<Self, String> {
        use std::io::Read;
        const LIMIT: u64 = 16 << 20;
        let show = path.display();
        let file = std::fs::File::open(path).map_err(|e| format!("{show}: {e}"))?;
        let meta = file.metadata().map_err(|e| format!("{show}: {e}"))?;
        if !meta.is_file() {
            return Err(format!("{show}: not a regular file"));
        }
        let mut text = String::new();
        file.take(LIMIT + 1)
            .read_to_string(&mut text)
            .map_err(|e| format!("{show}: {e}"))?;
        if text.len() as u64 > LIMIT {
            return Err(format!(
                "{show}: larger than the 16 MiB a report script may be"
            ));
        }
        Self::parse(&text).map_err(|e| format!("{show}: {e}"))
    }

    /// The connector that plays this stream; playback starts when the device is first opened.
    pub fn connector(self) -> ScriptConnector {
        ScriptConnector {
            playback: Arc::new(Mutex::new(Playback {
                script: self,
                next: 0,
                start: None,
                auto_start: true,
                plugged: true,
            })),
        }
    }

    /// The connector that plays this stream, and the clock that starts it: until
    /// [`ScriptClock::start`], the device is plugged in and only the events at time 0 are
    /// played (for a test that starts the stream once the loop it drives runs).
    pub fn connector_started_later(self) -> (ScriptConnector, ScriptClock) {
        let connector = self.connector();
        lock(&connector.playback).auto_start = false;
        let clock = ScriptClock {
            playback: Arc::clone(&connector.playback),
        };
        (connector, clock)
    }
}

/// A three-axis report (`id` 1 translation, 2 rotation) of raw values.
pub fn axis_report(id: u8, raw: [i16; 3]) -> Vec<u8> {
    let mut r = vec![id];
    for v in raw {
        r.extend(v.to_le_bytes());
    }
    r
}

/// A combined six-axis report of raw values.
pub fn six_axis_report(translation: [i16; 3], rotation: [i16; 3]) -> Vec<u8> {
    let mut r = vec![1];
    for v in translation.into_iter().chain(rotation) {
        r.extend(v.to_le_bytes());
    }
    r
}

#[derive(Debug)]
struct Playback {
    script: ReportScript,
    next: usize,
    start: Option<Instant>,
    /// Whether the first open starts the playback (otherwise [`ScriptClock::start`] does).
    auto_start: bool,
    plugged: bool,
}

impl Playback {
    fn elapsed(&mut self) -> Duration {
        if self.start.is_none() && self.auto_start {
            self.start = Some(Instant::now());
        }
        self.start.map_or(Duration::ZERO, |s| s.elapsed())
    }
}

/// Starts a playback made with [`ReportScript::connector_started_later`].
pub struct ScriptClock {
    playback: Arc<Mutex<Playback>>,
}

impl ScriptClock {
    /// Starts the stream's time now (once; later calls do nothing).
    pub fn start(&self) {
        let mut p = lock(&self.playback);
        if p.start.is_none() {
            p.start = Some(Instant::now());
        }
    }
}

fn lock(p: &Mutex<Playback>) -> MutexGuard<'_, Playback> {
    // A panic elsewhere while holding it leaves plain data behind: keep playing.
    p.lock().unwrap_or_else(|e| e.into_inner())
}

/// Opens the scripted device: found while the script has it plugged in.
pub struct ScriptConnector {
    playback: Arc<Mutex<Playback>>,
}

impl Connector for ScriptConnector {
    fn connect(&mut self) -> Result<(Box<dyn Transport>, &'static Model), TransportError> {
        let mut p = lock(&self.playback);
        let now = p.elapsed();
        // Unplugged: only a replug whose time has come brings it back.
        while !p.plugged {
            match p.script.events.get(p.next) {
                Some((t, event)) if *t <= now => {
                    if *event == ScriptEvent::Replug {
                        p.plugged = true;
                    }
                    p.next += 1;
                }
                _ => {
                    return Err(TransportError::NotFound(
                        "the scripted device is unplugged".into(),
                    ));
                }
            }
        }
        let model = p.script.model;
        Ok((
            Box::new(ScriptTransport {
                playback: Arc::clone(&self.playback),
            }),
            model,
        ))
    }
}

struct ScriptTransport {
    playback: Arc<Mutex<Playback>>,
}

impl Transport for ScriptTransport {
    fn read(&mut self, buf: &mut [u8], timeout_ms: i32) -> Result<usize, TransportError> {
        let deadline = Duration::from_millis(timeout_ms.max(0) as u64);
        let waited_from = Instant::now();
        loop {
            let wait = {
                let mut p = lock(&self.playback);
                if !p.plugged {
                    return Err(TransportError::Disconnected("unplugged".into()));
                }
                let now = p.elapsed();
                match p.script.events.get(p.next).cloned() {
                    Some((t, event)) if t <= now => {
                        p.next += 1;
                        match event {
                            ScriptEvent::Report(bytes) => {
                                let n = bytes.len().min(buf.len());
                                buf[..n].copy_from_slice(&bytes[..n]);
                                return Ok(n);
                            }
                            ScriptEvent::Unplug => {
                                p.plugged = false;
                                return Err(TransportError::Disconnected(
                                    "the scripted device was unplugged".into(),
                                ));
                            }
                            ScriptEvent::Replug => continue,
                        }
                    }
                    Some((t, _)) => t - now,
                    None => Duration::from_millis(timeout_ms.max(0) as u64),
                }
            };
            let left = deadline.saturating_sub(waited_from.elapsed());
            if left.is_zero() {
                return Ok(0);
            }
            std::thread::sleep(wait.min(left));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_script_parses_with_its_model_and_events() {
        let s = ReportScript::parse(
            "# puck\nmodel 256f:c635\n0 01 00 00 00 00 00 00 00 00 00 00 00 00\n\
             16.5 03 01 # button\n100 unplug\n200 replug\n",
        )
        .expect("parses");
        assert_eq!(s.model.name, "SpaceMouse Compact");
        assert_eq!(s.events.len(), 4);
        assert_eq!(
            s.events[1],
            (
                Duration::from_micros(16_500),
                ScriptEvent::Report(vec![3, 1])
            )
        );
        assert_eq!(s.events[2].1, ScriptEvent::Unplug);
    }

    #[test]
    fn script_errors_name_the_line() {
        for (text, line, words) in [
            ("model 1234:5678", 1, "not a SpaceMouse"),
            ("model nonsense", 1, "vendor:product"),
            ("0 01\nten 01", 2, "time in milliseconds"),
            ("5 01\n4 01", 2, "time order"),
            ("5 zz", 1, "hex bytes"),
            ("5", 1, "no event"),
            ("-1 01", 1, "time in milliseconds"),
        ] {
            let e = ReportScript::parse(text).expect_err(text);
            assert_eq!(e.line, line, "{text}: {e}");
            assert!(e.reason.contains(words), "{text}: {e}");
        }
    }

    #[test]
    fn builder_times_outside_a_duration_are_clamped_and_kept_in_time_order() {
        let s = ReportScript::new(&MODELS[6])
            .report(0.5, &[3, 1])
            .report(-1.0, &[3, 2])
            .unplug(f64::NAN)
            .replug(f64::INFINITY)
            .report(1e300, &[3, 3])
            .report(0.25, &[3, 4])
            .report(f64::NEG_INFINITY, &[3, 5]);
        let times: Vec<Duration> = s.events.iter().map(|(t, _)| *t).collect();
        assert_eq!(
            times,
            [
                Duration::ZERO,
                Duration::ZERO,
                Duration::ZERO,
                Duration::from_millis(250),
                Duration::from_millis(500),
                Duration::MAX,
                Duration::MAX,
            ]
        );
        // Equal times keep the order they were added in.
        assert_eq!(s.events[0].1, ScriptEvent::Report(vec![3, 2]));
        assert_eq!(s.events[1].1, ScriptEvent::Unplug);
        assert_eq!(s.events[2].1, ScriptEvent::Report(vec![3, 5]));
        assert_eq!(s.events[5].1, ScriptEvent::Replug);
        assert_eq!(s.events[6].1, ScriptEvent::Report(vec![3, 3]));
    }

    #[test]
    fn a_hold_with_no_usable_interval_still_ends() {
        for every_s in [0.0, -0.016, f64::NAN] {
            let s =
                ReportScript::new(&MODELS[6]).hold_translation(0.0, 0.0105, every_s, [350, 0, 0]);
            // One report a millisecond at most (0 to 10 ms), and the release.
            assert_eq!(s.events.len(), 12, "every {every_s} s");
            assert_eq!(s.events[11].1, ScriptEvent::Report(axis_report(1, [0; 3])));
        }
        let s = ReportScript::new(&MODELS[6]).hold_translation(f64::NAN, 1.0, 0.016, [1, 0, 0]);
        assert_eq!(s.events.len(), 1);
        let s = ReportScript::new(&MODELS[6]).hold_translation(0.0, f64::INFINITY, 60.0, [1, 0, 0]);
        assert_eq!(s.events.len(), 61);
        assert_eq!(s.events[60].0, Duration::MAX);
    }

    #[test]
    fn playback_hands_out_reports_in_time_and_unplugs() {
        let script = ReportScript::new(&MODELS[6])
            .report(0.0, &[3, 1])
            .report(0.03, &[3, 0])
            .unplug(0.06)
            .replug(0.12);
        let mut connector = script.connector();
        let (mut t, model) = connector.connect().expect("plugged at the start");
        assert_eq!(model.name, "SpaceNavigator");
        let mut buf = [0u8; 64];
        let start = Instant::now();
        assert_eq!(t.read(&mut buf, 1000), Ok(2));
        assert_eq!(&buf[..2], &[3, 1]);
        assert_eq!(t.read(&mut buf, 1000), Ok(2));
        assert_eq!(&buf[..2], &[3, 0]);
        // Not before its time (whatever the machine's load, never early).
        assert!(start.elapsed() >= Duration::from_millis(25));
        assert!(matches!(
            t.read(&mut buf, 1000),
            Err(TransportError::Disconnected(_))
        ));
        assert!(matches!(
            t.read(&mut buf, 1),
            Err(TransportError::Disconnected(_))
        ));
        // Gone until the replug's time, then found again.
        let deadline = Instant::now() + Duration::from_secs(30);
        let mut refused = 0;
        while connector.connect().is_err() {
            refused += 1;
            assert!(Instant::now() < deadline, "never replugged");
            std::thread::sleep(Duration::from_millis(5));
        }
        assert!(refused > 0);
        assert!(start.elapsed() >= Duration::from_millis(115));
    }
}
