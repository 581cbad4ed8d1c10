//! Recordings made to hurt their reader, written by the project's own session writer so that
//! every checksum is right and only their content is hostile: contact frames padded with
//! whitespace (still valid JSON, and still a contact message of the wire) compress to almost
//! nothing and decode to whatever size the padding is.

use std::path::Path;

use softhaptic_server::session::reader::Recording;
use softhaptic_server::session::writer::SessionWriter;

/// Writes to `out` a complete recording with the build, the scene and the first second of ticks
/// of `tests/sessions/slide.mcap`, then `frames` of its contact frames each followed by
/// `padding_bytes` of spaces. Returns the file's size.
pub fn padded_recording(out: &Path, frames: usize, padding_bytes: usize) -> u64 {
    let source = Path::new(env!("CARGO_MANIFEST_DIR")).join("sessions/slide.mcap");
    let r = Recording::open(&source).unwrap_or_else(|e| panic!("{e}"));
    let _ = std::fs::remove_file(out);
    let mut w = SessionWriter::create(out, &r.build, &r.scene).unwrap_or_else(|e| panic!("{e}"));
    for d in r.device.iter().take(1000) {
        w.write_device(d).unwrap_or_else(|e| panic!("{e}"));
    }
    let padding = " ".repeat(padding_bytes);
    let mut text = String::with_capacity(padding_bytes + 1024);
    for c in r.contacts.iter().cycle().take(frames) {
        text.clear();
        text.push_str(&c.json);
        text.push_str(&padding);
        w.write_contact(c.time_ns, &text)
            .unwrap_or_else(|e| panic!("{e}"));
    }
    w.finish().unwrap_or_else(|e| panic!("{e}"));
    std::fs::metadata(out)
        .unwrap_or_else(|e| panic!("{e}"))
        .len()
}
