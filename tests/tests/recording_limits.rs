//! Recordings made to fill their reader's memory (`softhaptic_tests::crafted`: valid in every
//! respect, contact frames padded with whitespace) are refused by every reader, naming the limit,
//! by the library's reader (`softhaptic info`, `check`, `export` and `replay` on such a file, and
//! their peak memory, are in `recording_memory.rs`); what it keeps of a padded frame is the frame.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use softhaptic_server::session::reader::Recording;
use softhaptic_tests::crafted::padded_recording;
use softhaptic_tests::scratch_dir;
use std::path::Path;

#[test]
fn a_frame_padded_past_its_channels_limit_is_refused_naming_it() {
    let dir = scratch_dir("limits-frame");
    let path = dir.join("padded.mcap");
    padded_recording(&path, 3, 1 << 20);
    let e = Recording::open(&path).unwrap_err().to_string();
    for says in [
        path.display().to_string(),
        "on /contact".to_owned(),
        "at most 65536 bytes".to_owned(),
    ] {
        assert!(e.contains(&says), "{e}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_file_that_decodes_to_far_more_than_its_size_is_refused_naming_the_limit() {
    let dir = scratch_dir("limits-total");
    let path = dir.join("padded.mcap");
    // Each frame under its channel's limit, 40 MiB of them from a file of a few hundred KiB.
    let bytes = padded_recording(&path, 700, 60 << 10);
    assert!(bytes < 1 << 20, "{bytes}");
    let e = Recording::open(&path).unwrap_err().to_string();
    for says in [
        path.display().to_string(),
        format!("more than the limit of {} bytes", 32 << 20),
        format!("64 times the file's {bytes} bytes"),
    ] {
        assert!(e.contains(&says), "{e}");
    }
    // From memory, as a lab hub reads an archived file: the same refusal.
    let e = Recording::from_bytes(&path, &std::fs::read(&path).unwrap())
        .unwrap_err()
        .to_string();
    assert!(e.contains("more than the limit of"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_padded_frame_within_the_limits_is_kept_without_its_padding() {
    let dir = scratch_dir("limits-compact");
    let path = dir.join("padded.mcap");
    padded_recording(&path, 20, 32 << 10);
    let padded = Recording::open(&path).unwrap();
    let original =
        Recording::open(&Path::new(env!("CARGO_MANIFEST_DIR")).join("sessions/slide.mcap"))
            .unwrap();
    assert_eq!(padded.contacts.len(), 20);
    for (kept, sent) in padded.contacts.iter().zip(&original.contacts) {
        assert_eq!(kept.json, sent.json);
        assert_eq!(kept.json.capacity(), kept.json.len());
    }
    let _ = std::fs::remove_dir_all(&dir);
}
