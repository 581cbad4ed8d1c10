//! [`export`]: a recording's channels as CSV, its trainee metrics, marks and exercise attempts
//! as JSON.

use std::io::Write as _;
use std::path::{Path, PathBuf};

use softhaptic_proto::ContactFlags;
use softhaptic_proto::record::{DeviceRecord, SampleRecord};
use softhaptic_proto::wire::{ContactFrame, ServerMessage, flag_names};

use super::recording_metrics;
use crate::SessionError;
use crate::reader::Recording;

/// What [`export`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct Exported {
    pub device: PathBuf,
    pub contact: PathBuf,
    /// The trainee's metrics as the final `metrics` message carries them.
    pub metrics: PathBuf,
    /// The instructors' marks as the `mark` messages carry them, a JSON list (empty when the
    /// session has none).
    pub marks: PathBuf,
    /// The results of the attempts at exercises, a JSON list (empty when none ran).
    pub attempts: PathBuf,
    /// The session's alerts, each as it last stood, a JSON list (empty when none was raised).
    pub alerts: PathBuf,
}

/// Writes `device.csv`, `contact.csv`, `metrics.json` (the trainee's metrics as the `metrics`
/// message carries them), `marks.json` (the instructors' marks), `attempts.json` (the results
/// of the attempts at exercises) and `alerts.json` (the alerts raised for the instructors, and
/// who acknowledged each) into `out_dir` (created).
pub fn export(r: &Recording, out_dir: &Path, replace: bool) -> Result<Exported, SessionError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |reason| SessionError::Io { path, reason }
    };
    std::fs::create_dir_all(out_dir).map_err(io(out_dir))?;
    let device_path = out_dir.join("device.csv");
    let contact_path = out_dir.join("contact.csv");
    let metrics_path = out_dir.join("metrics.json");
    let marks_path = out_dir.join("marks.json");
    let attempts_path = out_dir.join("attempts.json");
    let alerts_path = out_dir.join("alerts.json");
    // Checked before anything is written: an earlier export (another session's, say) is kept
    // whole unless it is to be replaced.
    if !replace {
        for path in [
            &device_path,
            &contact_path,
            &metrics_path,
            &marks_path,
            &attempts_path,
            &alerts_path,
        ] {
            if std::fs::symlink_metadata(path).is_ok() {
                return Err(SessionError::ExportExists { path: path.clone() });
            }
        }
    }

    write_file(
        &device_path,
        csv_table(DEVICE_COLUMNS, r.device.iter()).as_bytes(),
    )?;
    // The reader has checked every frame decodes as a contact message.
    let frames: Vec<(u64, ContactFrame)> = r
        .contacts
        .iter()
        .filter_map(|c| match ServerMessage::decode(&c.json) {
            Ok(ServerMessage::Contact(f)) => Some((c.time_ns, f)),
            _ => None,
        })
        .collect();
    write_file(
        &contact_path,
        csv_table(CONTACT_COLUMNS, frames.iter()).as_bytes(),
    )?;
    let metrics = crate::stream::metrics_message(&recording_metrics(r), true);
    write_json(&metrics_path, &metrics)?;
    write_json(&marks_path, &r.marks)?;
    let attempts: Vec<_> = r.attempts().collect();
    write_json(&attempts_path, &attempts)?;
    write_json(&alerts_path, &r.alerts)?;
    Ok(Exported {
        device: device_path,
        contact: contact_path,
        metrics: metrics_path,
        marks: marks_path,
        attempts: attempts_path,
        alerts: alerts_path,
    })
}

/// One CSV column: its header and how a row gives its field (never a comma: flags join with
/// `|`, an error's commas become `;`). Each table is described once, as a list of these, so
/// the header and the fields cannot drift apart.
struct Column<T> {
    name: &'static str,
    field: fn(&T) -> String,
}

const fn col<T>(name: &'static str, field: fn(&T) -> String) -> Column<T> {
    Column { name, field }
}

/// The header and a line per row.
fn csv_table<'a, T: 'a>(columns: &[Column<T>], rows: impl Iterator<Item = &'a T>) -> String {
    let mut out = String::new();
    let names: Vec<&str> = columns.iter().map(|c| c.name).collect();
    out.push_str(&names.join(","));
    out.push('\n');
    for row in rows {
        for (i, c) in columns.iter().enumerate() {
            if i > 0 {
                out.push(',');
            }
            out.push_str(&(c.field)(row));
        }
        out.push('\n');
    }
    out
}

/// A field of the device's sample, empty on a tick without one.
fn sample_field(d: &DeviceRecord, f: impl Fn(&SampleRecord) -> String) -> String {
    d.sample.as_ref().map(f).unwrap_or_default()
}

/// `device.csv`: one row per recorded tick.
const DEVICE_COLUMNS: &[Column<DeviceRecord>] = &[
    col("tick", |d| d.tick.to_string()),
    col("time_ns", |d| d.time_ns.to_string()),
    col("sample_ok", |d| d.sample.is_some().to_string()),
    col("tip_x_m", |d| {
        sample_field(d, |s| s.tip_position_m[0].to_string())
    }),
    col("tip_y_m", |d| {
        sample_field(d, |s| s.tip_position_m[1].to_string())
    }),
    col("tip_z_m", |d| {
        sample_field(d, |s| s.tip_position_m[2].to_string())
    }),
    col("tip_qx", |d| {
        sample_field(d, |s| s.tip_orientation[0].to_string())
    }),
    col("tip_qy", |d| {
        sample_field(d, |s| s.tip_orientation[1].to_string())
    }),
    col("tip_qz", |d| {
        sample_field(d, |s| s.tip_orientation[2].to_string())
    }),
    col("tip_qw", |d| {
        sample_field(d, |s| s.tip_orientation[3].to_string())
    }),
    col("vel_x_m_s", |d| {
        sample_field(d, |s| s.tip_velocity_m_s[0].to_string())
    }),
    col("vel_y_m_s", |d| {
        sample_field(d, |s| s.tip_velocity_m_s[1].to_string())
    }),
    col("vel_z_m_s", |d| {
        sample_field(d, |s| s.tip_velocity_m_s[2].to_string())
    }),
    col("buttons", |d| sample_field(d, |s| s.buttons.to_string())),
    col("device_fault", |d| d.device_fault.to_string()),
    col("device_error", |d| {
        d.device_error
            .map(|e| serde_json::to_string(&e).unwrap_or_default())
            .unwrap_or_default()
            .replace('"', "")
            .replace(',', ";")
    }),
    col("in_contact", |d| d.in_contact.to_string()),
    col("depth_m", |d| d.depth_m.to_string()),
    col("force_x_n", |d| d.force_n[0].to_string()),
    col("force_y_n", |d| d.force_n[1].to_string()),
    col("force_z_n", |d| d.force_n[2].to_string()),
    col("flags", |d| {
        flags_field(ContactFlags::from_bits_truncate(d.flags))
    }),
];

/// `contact.csv`: one row per 50 Hz frame, with the time it was logged.
const CONTACT_COLUMNS: &[Column<(u64, ContactFrame)>] = &[
    col("log_time_ns", |(t, _)| t.to_string()),
    col("seq", |(_, f)| f.seq.to_string()),
    col("tick", |(_, f)| f.tick.to_string()),
    col("time_ns", |(_, f)| f.time_ns.to_string()),
    col("tip_x_m", |(_, f)| f.tip_in_world.position_m.x.to_string()),
    col("tip_y_m", |(_, f)| f.tip_in_world.position_m.y.to_string()),
    col("tip_z_m", |(_, f)| f.tip_in_world.position_m.z.to_string()),
    col("in_contact", |(_, f)| f.in_contact.to_string()),
    col("depth_m", |(_, f)| f.depth_m.to_string()),
    col("normal_x", |(_, f)| f.normal.x.to_string()),
    col("normal_y", |(_, f)| f.normal.y.to_string()),
    col("normal_z", |(_, f)| f.normal.z.to_string()),
    col("contact_x_m", |(_, f)| f.contact_point_m.x.to_string()),
    col("contact_y_m", |(_, f)| f.contact_point_m.y.to_string()),
    col("contact_z_m", |(_, f)| f.contact_point_m.z.to_string()),
    col("contact_radius_m", |(_, f)| f.contact_radius_m.to_string()),
    col("deformed_radius_m", |(_, f)| {
        f.deformed_radius_m.to_string()
    }),
    col("force_x_n", |(_, f)| f.force_n.x.to_string()),
    col("force_y_n", |(_, f)| f.force_n.y.to_string()),
    col("force_z_n", |(_, f)| f.force_n.z.to_string()),
    col("flags", |(_, f)| flags_field(f.flags)),
    col("dropped", |(_, f)| f.dropped.to_string()),
];

/// Writes `value` as pretty JSON with a final newline.
fn write_json<T: serde::Serialize + ?Sized>(path: &Path, value: &T) -> Result<(), SessionError> {
    let json = serde_json::to_string_pretty(value).map_err(|e| SessionError::Io {
        path: path.to_path_buf(),
        reason: std::io::Error::other(e),
    })?;
    write_file(path, (json + "\n").as_bytes())
}

/// Flag names joined by `|` (no commas, so the field needs no quoting).
fn flags_field(flags: ContactFlags) -> String {
    flag_names(flags).collect::<Vec<_>>().join("|")
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<(), SessionError> {
    let mut f = std::fs::File::create(path).map_err(|reason| SessionError::Io {
        path: path.to_path_buf(),
        reason,
    })?;
    f.write_all(bytes)
        .and_then(|()| f.flush())
        .map_err(|reason| SessionError::Io {
            path: path.to_path_buf(),
            reason,
        })
}
