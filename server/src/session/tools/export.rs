//! [`export`]: a recording's channels as CSV, its trainee metrics and marks as JSON.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use softhaptic_proto::ContactFlags;
use softhaptic_proto::wire::{ServerMessage, flag_names};

use super::recording_metrics;
use crate::session::SessionError;
use crate::session::reader::Recording;

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
}

/// Writes `device.csv`, `contact.csv`, `metrics.json` (the trainee's metrics as the `metrics`
/// message carries them) and `marks.json` (the instructors' marks) into `out_dir` (created).
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
    // Checked before anything is written: an earlier export (another session's, say) is kept
    // whole unless it is to be replaced.
    if !replace {
        for path in [&device_path, &contact_path, &metrics_path, &marks_path] {
            if std::fs::symlink_metadata(path).is_ok() {
                return Err(SessionError::ExportExists { path: path.clone() });
            }
        }
    }

    let mut out = String::with_capacity(r.device.len() * 200);
    out.push_str(
        "tick,time_ns,sample_ok,tip_x_m,tip_y_m,tip_z_m,tip_qx,tip_qy,tip_qz,tip_qw,\
         vel_x_m_s,vel_y_m_s,vel_z_m_s,buttons,device_fault,device_error,in_contact,depth_m,\
         force_x_n,force_y_n,force_z_n,flags\n",
    );
    for d in &r.device {
        let _ = write!(out, "{},{},", d.tick, d.time_ns);
        match &d.sample {
            Some(s) => {
                let _ = write!(out, "true,");
                for v in s
                    .tip_position_m
                    .iter()
                    .chain(&s.tip_orientation)
                    .chain(&s.tip_velocity_m_s)
                {
                    let _ = write!(out, "{v},");
                }
                let _ = write!(out, "{},", s.buttons);
            }
            None => out.push_str("false,,,,,,,,,,,,"),
        }
        let error = d
            .device_error
            .map(|e| serde_json::to_string(&e).unwrap_or_default())
            .unwrap_or_default()
            .replace('"', "")
            .replace(',', ";");
        let _ = write!(
            out,
            "{},{error},{},{},{},{},{},",
            d.device_fault, d.in_contact, d.depth_m, d.force_n[0], d.force_n[1], d.force_n[2]
        );
        out.push_str(&flags_field(ContactFlags::from_bits_truncate(d.flags)));
        out.push('\n');
    }
    write_file(&device_path, out.as_bytes())?;

    let mut out = String::with_capacity(r.contacts.len() * 200);
    out.push_str(
        "log_time_ns,seq,tick,time_ns,tip_x_m,tip_y_m,tip_z_m,in_contact,depth_m,\
         normal_x,normal_y,normal_z,contact_x_m,contact_y_m,contact_z_m,contact_radius_m,\
         deformed_radius_m,force_x_n,force_y_n,force_z_n,flags,dropped\n",
    );
    for c in &r.contacts {
        // The reader has checked every frame decodes as a contact message.
        let Ok(ServerMessage::Contact(f)) = ServerMessage::decode(&c.json) else {
            continue;
        };
        let p = f.tip_in_world.position_m;
        let _ = write!(
            out,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},",
            c.time_ns,
            f.seq,
            f.tick,
            f.time_ns,
            p.x,
            p.y,
            p.z,
            f.in_contact,
            f.depth_m,
            f.normal.x,
            f.normal.y,
            f.normal.z,
            f.contact_point_m.x,
            f.contact_point_m.y,
            f.contact_point_m.z,
            f.contact_radius_m,
            f.deformed_radius_m,
            f.force_n.x,
            f.force_n.y,
            f.force_n.z,
        );
        out.push_str(&flags_field(f.flags));
        let _ = writeln!(out, ",{}", f.dropped);
    }
    write_file(&contact_path, out.as_bytes())?;
    let metrics = crate::stream::metrics_message(&recording_metrics(r), true);
    write_json(&metrics_path, &metrics)?;
    write_json(&marks_path, &r.marks)?;
    Ok(Exported {
        device: device_path,
        contact: contact_path,
        metrics: metrics_path,
        marks: marks_path,
    })
}

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
