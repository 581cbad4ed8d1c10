//! [`Info`]: the summary `softhaptic info` prints of a recording.

use std::fmt::{self, Write as _};
use std::path::PathBuf;

use softhaptic_device::metrics::TraineeMetrics;
use softhaptic_proto::ContactFlags;
use softhaptic_proto::record::{DeviceErrorRecord, DeviceRecord};
use softhaptic_proto::wire::{MarkMessage, flag_names};

use super::recording_metrics;
use crate::reader::{Ending, Recording};

/// The summary `softhaptic info` prints.
#[derive(Debug, Clone, PartialEq)]
pub struct Info {
    pub path: PathBuf,
    pub file_len: u64,
    pub writer: String,
    pub git_commit: Option<String>,
    pub session_id: String,
    pub session_format_version: u32,
    pub protocol_version: u32,
    pub tool: String,
    pub duration_s: f64,
    pub ticks: u64,
    /// Ticks missing from the file (gaps in the tick counter).
    pub ticks_missing: u64,
    /// Ticks the recorder reported dropped in its last stats record.
    pub ticks_dropped_reported: Option<u64>,
    /// Ticks the loop lost (deadlines that passed with no tick; the device held its force), in
    /// how many runs, and the longest run with the tick that followed it.
    pub ticks_lost: u64,
    pub lost_runs: u64,
    pub longest_lost_run: Option<(u64, u64)>,
    pub contact_frames: u64,
    pub contact_frames_dropped_reported: Option<u64>,
    /// Ticks in contact with the object.
    pub ticks_in_contact: u64,
    /// The device the session ran with, as the viewers were told.
    pub device: String,
    /// Ticks flagged as device faults.
    pub device_fault_ticks: u64,
    /// The runs of consecutive faulted ticks: the gaps in the force the trainee felt.
    pub fault_spans: Vec<FaultSpan>,
    /// Largest commanded force magnitude and its tick.
    pub peak_force_n: f64,
    pub peak_force_tick: Option<u64>,
    /// Deepest indentation.
    pub max_depth_m: f64,
    /// Every flag seen on any tick, with how many ticks carried it.
    pub flags_seen: Vec<(&'static str, u64)>,
    pub ending: Ending,
    /// Damaged stretches of the file that were skipped.
    pub damaged_stretches: usize,
    pub recovery: String,
    /// The trainee's metrics, computed from the recorded ticks (as the live server computed them).
    pub metrics: TraineeMetrics,
    /// The final metrics the live loop recorded at the session's end, and whether they are the
    /// ones computed from the recorded ticks (`None`: the recording holds none).
    pub recorded_metrics: Option<(softhaptic_proto::wire::MetricsMessage, bool)>,
    /// The instructors' marks, in the order made.
    pub marks: Vec<MarkMessage>,
    /// Device time of the recording's first tick, ns: marks are printed in seconds from it, as
    /// the fault gaps are.
    pub start_time_ns: u64,
    /// The results of the attempts at exercises the station ran, in the order they ended.
    pub attempts: Vec<softhaptic_proto::exercise::AttemptResult>,
    /// How the guidance went, in a session guided along an expert's recording.
    pub guidance: Option<crate::guide::GuidanceSummary>,
    /// The alerts the session raised for its instructors, each as it last stood.
    pub alerts: Vec<softhaptic_proto::wire::Alert>,
}

/// A run of consecutive ticks the device faulted on (zero force throughout).
#[derive(Debug, Clone, PartialEq)]
pub struct FaultSpan {
    pub first_tick: u64,
    pub ticks: u64,
    /// Device time of the first tick, seconds.
    pub start_s: f64,
    /// Why, from the first tick of the run.
    pub cause: String,
}

/// Why a recorded tick faulted, in words.
fn fault_cause(d: &DeviceRecord) -> String {
    let name = |e: &DeviceErrorRecord| match e {
        DeviceErrorRecord::Disconnected => "device disconnected".to_owned(),
        DeviceErrorRecord::Timeout => "device not answering".to_owned(),
        DeviceErrorRecord::ForceDisabled => "force output disabled by the driver".to_owned(),
        DeviceErrorRecord::Driver { code } => format!("driver error {code:#x}"),
        DeviceErrorRecord::NeedsCalibration => "device needs calibration".to_owned(),
        DeviceErrorRecord::Overrun => "tick overran its servo period".to_owned(),
        DeviceErrorRecord::ForceLatched => {
            "force output latched off after repeated force trips".to_owned()
        }
        DeviceErrorRecord::Fatal => "servo tick failed".to_owned(),
        DeviceErrorRecord::NeedsCalibrationReset => {
            "device needs calibration at its reset position".to_owned()
        }
        DeviceErrorRecord::CalibrationUpdating => "device updating its calibration".to_owned(),
    };
    match (&d.device_error, &d.command_error, &d.sample) {
        (Some(e), _, _) => name(e),
        (None, Some(e), _) => format!("command refused: {}", name(e)),
        (None, None, Some(_)) => "sample refused (not finite, or outside the workspace)".into(),
        (None, None, None) => "no reading".into(),
    }
}

/// The runs of consecutive faulted ticks.
fn fault_spans(device: &[DeviceRecord]) -> Vec<FaultSpan> {
    let mut spans: Vec<FaultSpan> = Vec::new();
    let mut previous: Option<u64> = None;
    for d in device.iter().filter(|d| d.device_fault) {
        match spans.last_mut() {
            Some(span) if previous.is_some_and(|p| p + 1 == d.tick) => span.ticks += 1,
            _ => spans.push(FaultSpan {
                first_tick: d.tick,
                ticks: 1,
                start_s: d.time_ns as f64 * 1e-9,
                cause: fault_cause(d),
            }),
        }
        previous = Some(d.tick);
    }
    spans
}

/// At most this many fault spans are listed one by one.
const FAULT_SPANS_LISTED: usize = 10;
/// At most this many marks are listed one by one (the rest are counted).
const MARKS_LISTED: usize = 20;
/// A mark's note is printed up to this many characters (notes are at most 280).
const MARK_NOTE_PRINTED: usize = 80;

impl Info {
    pub fn of(r: &Recording) -> Info {
        let mut peak_force_n = 0.0;
        let mut peak_force_tick = None;
        let mut max_depth_m: f64 = 0.0;
        let mut flag_counts = [0u64; 32];
        let mut ticks_in_contact = 0;
        let mut device_fault_ticks = 0;
        let (mut ticks_lost, mut lost_runs) = (0, 0);
        let mut longest_lost_run: Option<(u64, u64)> = None;
        for d in &r.device {
            if d.lost_before > 0 {
                ticks_lost += d.lost_before;
                lost_runs += 1;
                if longest_lost_run.is_none_or(|(n, _)| d.lost_before > n) {
                    longest_lost_run = Some((d.lost_before, d.tick));
                }
            }
            let f = glam::DVec3::from_array(d.force_n).length();
            if f.is_finite() && (peak_force_tick.is_none() || f > peak_force_n) {
                peak_force_n = f;
                peak_force_tick = Some(d.tick);
            }
            if d.in_contact && d.depth_m.is_finite() {
                max_depth_m = max_depth_m.max(d.depth_m);
                ticks_in_contact += 1;
            }
            if d.device_fault {
                device_fault_ticks += 1;
            }
            for (bit, count) in flag_counts.iter_mut().enumerate() {
                if d.flags & (1 << bit) != 0 {
                    *count += 1;
                }
            }
        }
        let flags_seen = flag_counts
            .iter()
            .enumerate()
            .filter(|(_, n)| **n > 0)
            .map(|(bit, n)| {
                let name = ContactFlags::from_bits(1 << bit)
                    .and_then(|f| flag_names(f).next())
                    .unwrap_or("unknown_bit");
                (name, *n)
            })
            .collect();
        let tool = serde_json::to_string(&r.scene.message.tool).unwrap_or_default();
        Info {
            path: r.path.clone(),
            file_len: r.file_len,
            writer: r.build.writer.clone(),
            git_commit: r.build.git_commit.clone(),
            session_id: r.build.session_id.clone(),
            session_format_version: r.build.session_format_version,
            protocol_version: r.build.protocol_version,
            tool,
            duration_s: r.duration_ns() as f64 * 1e-9,
            ticks: r.device.len() as u64,
            ticks_missing: r.missing_ticks(),
            ticks_dropped_reported: r.last_stats.map(|s| s.ticks_dropped),
            ticks_lost,
            lost_runs,
            longest_lost_run,
            contact_frames: r.contacts.len() as u64,
            contact_frames_dropped_reported: r.last_stats.map(|s| s.contact_frames_dropped),
            ticks_in_contact,
            device: r.scene.message.device.name.clone(),
            device_fault_ticks,
            fault_spans: fault_spans(&r.device),
            peak_force_n,
            peak_force_tick,
            max_depth_m,
            flags_seen,
            ending: r.ending.clone(),
            damaged_stretches: r.lost.len(),
            recovery: r.recovery().to_string(),
            metrics: recording_metrics(r),
            recorded_metrics: None,
            marks: r.marks.clone(),
            start_time_ns: r.device.first().map_or(0, |d| d.time_ns),
            attempts: r.attempts().cloned().collect(),
            guidance: crate::guide::summary(r),
            alerts: r.alerts.clone(),
        }
        .with_recorded_metrics(r)
    }

    fn with_recorded_metrics(mut self, r: &Recording) -> Info {
        self.recorded_metrics = r.final_metrics().map(|recorded| {
            let computed = crate::stream::metrics_message(&self.metrics, true);
            let same = crate::check::same_metrics(recorded, &computed);
            (recorded.clone(), same)
        });
        self
    }
}

impl fmt::Display for Info {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let opt = |v: Option<u64>| v.map_or_else(|| "unknown".to_owned(), |n| n.to_string());
        writeln!(
            f,
            "file:              {} ({} bytes)",
            self.path.display(),
            self.file_len
        )?;
        writeln!(
            f,
            "written by:        {} (commit {}), session {}",
            self.writer,
            self.git_commit.as_deref().unwrap_or("unknown"),
            self.session_id
        )?;
        writeln!(
            f,
            "formats:           session log v{}, wire protocol v{}",
            self.session_format_version, self.protocol_version
        )?;
        writeln!(f, "tool:              {}", self.tool)?;
        writeln!(f, "duration:          {:.3} s", self.duration_s)?;
        writeln!(
            f,
            "ticks:             {} recorded, {} missing (recorder reported {} dropped)",
            self.ticks,
            self.ticks_missing,
            opt(self.ticks_dropped_reported)
        )?;
        match self.longest_lost_run {
            None => writeln!(f, "lost ticks:        none")?,
            Some((longest, tick)) => writeln!(
                f,
                "lost ticks:        {} in {} {} (deadlines with no tick; the device held its force), the longest {longest} before tick {tick}",
                self.ticks_lost,
                self.lost_runs,
                if self.lost_runs == 1 { "run" } else { "runs" },
            )?,
        }
        writeln!(
            f,
            "contact frames:    {} recorded (recorder reported {} dropped)",
            self.contact_frames,
            opt(self.contact_frames_dropped_reported)
        )?;
        writeln!(
            f,
            "in contact:        {} ticks, max depth {:.3} mm",
            self.ticks_in_contact,
            self.max_depth_m * 1e3
        )?;
        match self.peak_force_tick {
            Some(t) => writeln!(
                f,
                "peak force:        {:.4} N at tick {t}",
                self.peak_force_n
            )?,
            None => writeln!(f, "peak force:        none")?,
        }
        writeln!(f, "device:            {}", self.device)?;
        match self.fault_spans.iter().max_by_key(|s| s.ticks) {
            None => writeln!(f, "device faults:     none")?,
            Some(longest) => {
                let gaps = self.fault_spans.len();
                writeln!(
                    f,
                    "device faults:     {} ticks in {gaps} {} of zero force, the longest {} ticks at tick {}",
                    self.device_fault_ticks,
                    if gaps == 1 { "gap" } else { "gaps" },
                    longest.ticks,
                    longest.first_tick
                )?;
                for span in self.fault_spans.iter().take(FAULT_SPANS_LISTED) {
                    writeln!(
                        f,
                        "  gap at {:.3} s (tick {}): {} ticks, {}",
                        span.start_s, span.first_tick, span.ticks, span.cause
                    )?;
                }
                if self.fault_spans.len() > FAULT_SPANS_LISTED {
                    writeln!(
                        f,
                        "  … and {} more",
                        self.fault_spans.len() - FAULT_SPANS_LISTED
                    )?;
                }
            }
        }
        let mut flags = String::new();
        for (name, n) in &self.flags_seen {
            let _ = write!(flags, "{name} ({n} ticks) ");
        }
        writeln!(
            f,
            "flags seen:        {}",
            if flags.is_empty() {
                "none"
            } else {
                flags.trim_end()
            }
        )?;
        let m = &self.metrics;
        let raised = crate::stream::metrics_message(m, true).flags_raised;
        let mut flags_raised = String::new();
        for (name, n) in &raised {
            let _ = write!(
                flags_raised,
                "{}{name} ×{n}",
                if flags_raised.is_empty() { "" } else { ", " }
            );
        }
        writeln!(
            f,
            "trainee metrics:   peak {:.3} N at {:.3} s; {:.2} s above the safe {:.2} N; {:.2} s in contact over {:.1} mm; {} {}; mean squared jerk {:.3e} m²/s⁶; {} device fault ticks; flags raised: {}",
            m.peak_force_n,
            m.peak_force_time_s,
            m.time_above_safe_s,
            m.safe_force_n,
            m.time_in_contact_s,
            m.path_length_in_contact_m * 1e3,
            m.pushes,
            if m.pushes == 1 { "push" } else { "pushes" },
            m.mean_squared_jerk_m2_s6,
            m.device_fault_ticks,
            if flags_raised.is_empty() {
                "none"
            } else {
                &flags_raised
            }
        )?;
        match &self.recorded_metrics {
            Some((_, true)) => writeln!(
                f,
                "                   computed from the recorded ticks; the same as the live loop's, recorded at the end"
            )?,
            Some((recorded, false)) => writeln!(
                f,
                "                   computed from the {} recorded ticks; the live loop's, recorded at the end over {} ticks, differ: peak {:.3} N, {:.2} s in contact, {} pushes",
                self.metrics.ticks,
                recorded.ticks,
                recorded.peak_force_n,
                recorded.time_in_contact_s,
                recorded.pushes
            )?,
            None => writeln!(
                f,
                "                   computed from the recorded ticks (the file holds no final metrics: cut short, or recorded before they were kept)"
            )?,
        }
        self.fmt_marks(f)?;
        self.fmt_alerts(f)?;
        self.fmt_attempts(f)?;
        self.fmt_guidance(f)?;
        let status = match (&self.ending, self.damaged_stretches) {
            (Ending::Complete, 0) => "complete".to_owned(),
            (Ending::Complete, n) => format!("DAMAGED, recovered around {n} damaged stretches"),
            (Ending::Truncated { .. }, 0) => "TRUNCATED, recovered".to_owned(),
            (Ending::Truncated { .. }, n) => {
                format!("TRUNCATED and DAMAGED, recovered around {n} damaged stretches")
            }
        };
        writeln!(f, "status:            {status}")?;
        write!(f, "recovery:          {}", self.recovery)
    }
}

impl Info {
    /// The guidance lines of a guided session.
    fn fmt_guidance(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let Some(g) = &self.guidance else {
            return Ok(());
        };
        let gain = match &g.gain {
            softhaptic_proto::GuideGain::Fixed { gain } => format!("fixed at {gain}"),
            softhaptic_proto::GuideGain::AsNeeded { .. } => format!(
                "as needed, least {:.2}, last {:.2}",
                g.least_gain, g.last_gain
            ),
            softhaptic_proto::GuideGain::Schedule { gains } => format!(
                "by pass {}",
                gains
                    .iter()
                    .map(|g| format!("{g}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        };
        let source: String = g.source.chars().filter(|c| !c.is_control()).collect();
        writeln!(
            f,
            "guidance:          along {source}, gain {gain}; captured {:.2} s, {:.2} mm from the target on average",
            g.engaged_s,
            g.mean_tracking_m * 1e3
        )?;
        match &g.deviation {
            Some(d) => writeln!(
                f,
                "                   from the expert, aligned in time (DTW over {} pairs): path {:.2} mm on average, {:.2} mm at most; force {:.3} N on average",
                d.pairs,
                d.mean_path_m * 1e3,
                d.max_path_m * 1e3,
                d.mean_force_n
            )?,
            None => writeln!(
                f,
                "                   never captured: no deviation from the expert"
            )?,
        }
        if g.passes.len() > 1 {
            for p in &g.passes {
                let deviation = p.deviation.map_or_else(
                    || "no deviation".to_owned(),
                    |d| {
                        format!(
                            "path {:.2} mm, force {:.3} N",
                            d.mean_path_m * 1e3,
                            d.mean_force_n
                        )
                    },
                );
                writeln!(
                    f,
                    "  pass {} at gain {:.2}: captured {:.2} s{}; {deviation}",
                    p.pass + 1,
                    p.gain,
                    p.engaged_s,
                    if p.reached_end { ", to the end" } else { "" },
                )?;
            }
        }
        Ok(())
    }

    /// The exercises line: how many attempts, then each one's outcome and the metrics its pass
    /// marks hold (at most [`MARKS_LISTED`]).
    fn fmt_attempts(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.attempts.is_empty() {
            return writeln!(f, "exercises:         none");
        }
        let passed = self.attempts.iter().filter(|a| a.passed).count();
        writeln!(
            f,
            "exercises:         {} attempts, {passed} passed",
            self.attempts.len()
        )?;
        for a in self.attempts.iter().take(MARKS_LISTED) {
            let start_s = a.start_ns.saturating_sub(self.start_time_ns) as f64 * 1e-9;
            let took_s = a.end_ns.saturating_sub(a.start_ns) as f64 * 1e-9;
            let ended = match a.ended {
                softhaptic_proto::exercise::AttemptEnd::Completed => "completed",
                softhaptic_proto::exercise::AttemptEnd::TimeLimit => "time limit",
                softhaptic_proto::exercise::AttemptEnd::Stopped => "stopped",
            };
            let trainee: String = a.trainee.chars().filter(|c| !c.is_control()).collect();
            let exercise: String = a.exercise.chars().filter(|c| !c.is_control()).collect();
            write!(
                f,
                "  {trainee}, {exercise} #{} at {start_s:.3} s: {} ({ended} after {took_s:.3} s{})",
                a.attempt,
                if a.passed { "passed" } else { "not passed" },
                if a.score.safe {
                    ""
                } else {
                    ", above the safe force"
                }
            )?;
            for m in &a.marks {
                write!(
                    f,
                    "; {} {:.4} {}",
                    m.mark.metric,
                    m.value,
                    if m.met { "met" } else { "missed" }
                )?;
            }
            writeln!(f)?;
        }
        if self.attempts.len() > MARKS_LISTED {
            writeln!(f, "  … and {} more", self.attempts.len() - MARKS_LISTED)?;
        }
        Ok(())
    }

    /// The alerts line: how many, then each one's time, kind, detail and who acknowledged it
    /// (at most [`MARKS_LISTED`]).
    fn fmt_alerts(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.alerts.is_empty() {
            return writeln!(f, "alerts:            none");
        }
        let open = self
            .alerts
            .iter()
            .filter(|a| a.acknowledged.is_none())
            .count();
        writeln!(
            f,
            "alerts:            {} ({open} not acknowledged)",
            self.alerts.len()
        )?;
        for alert in self.alerts.iter().take(MARKS_LISTED) {
            let time_s = alert.time_ns.saturating_sub(self.start_time_ns) as f64 * 1e-9;
            let detail: String = alert
                .detail
                .chars()
                .map(|c| if c.is_control() { ' ' } else { c })
                .collect();
            let kind = serde_json::to_value(alert.kind)
                .ok()
                .and_then(|v| v.as_str().map(str::to_owned))
                .unwrap_or_default();
            let acknowledged = match &alert.acknowledged {
                Some(a) => {
                    let by: String =
                        a.by.chars()
                            .map(|c| if c.is_control() { ' ' } else { c })
                            .collect();
                    format!("acknowledged by {by}")
                }
                None => "not acknowledged".to_owned(),
            };
            writeln!(
                f,
                "  #{} at {time_s:.3} s, {kind}: {detail} ({acknowledged})",
                alert.id
            )?;
        }
        if self.alerts.len() > MARKS_LISTED {
            writeln!(f, "  … and {} more", self.alerts.len() - MARKS_LISTED)?;
        }
        Ok(())
    }

    /// The marks line: how many, then each one's time and note (at most [`MARKS_LISTED`], each
    /// note cut at [`MARK_NOTE_PRINTED`] characters, on one line whatever it holds).
    fn fmt_marks(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.marks.is_empty() {
            return writeln!(f, "marks:             none");
        }
        writeln!(f, "marks:             {}", self.marks.len())?;
        for mark in self.marks.iter().take(MARKS_LISTED) {
            let time_s = mark.time_ns.saturating_sub(self.start_time_ns) as f64 * 1e-9;
            // A note is the instructor's free text: control characters (a newline) would break
            // the report's one-line-per-item shape.
            let mut note: String = mark
                .note
                .chars()
                .map(|c| if c.is_control() { ' ' } else { c })
                .take(MARK_NOTE_PRINTED)
                .collect();
            if mark.note.chars().count() > MARK_NOTE_PRINTED {
                note.push('…');
            }
            let point = mark.point_m.map_or_else(String::new, |p| {
                format!(
                    " at ({:.1}, {:.1}, {:.1}) mm",
                    p[0] * 1e3,
                    p[1] * 1e3,
                    p[2] * 1e3
                )
            });
            writeln!(f, "  #{} at {time_s:.3} s{point}: {note}", mark.id)?;
        }
        if self.marks.len() > MARKS_LISTED {
            writeln!(f, "  … and {} more", self.marks.len() - MARKS_LISTED)?;
        }
        Ok(())
    }
}
