//! A recording is read as a stream: what stays in memory while `Recording::open` reads a file is
//! what it decoded and one record at a time, never the file. Measured with a global allocator
//! that tracks the live heap's peak (one per test binary, so this binary holds only this test).

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use softhaptic_server::session::reader::Recording;

struct PeakTracking;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

fn grew(bytes: usize) {
    let live = LIVE.fetch_add(bytes, Ordering::Relaxed) + bytes;
    PEAK.fetch_max(live, Ordering::Relaxed);
}

// SAFETY: forwards every call unchanged to the system allocator, only counting live bytes.
unsafe impl GlobalAlloc for PeakTracking {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        grew(layout.size());
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        grew(new_size);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: PeakTracking = PeakTracking;

/// Where the first chunk record of an MCAP file ends (its top-level records walked from the
/// magic: opcode, u64 length, body).
fn end_of_first_chunk(bytes: &[u8]) -> usize {
    let mut pos = 8;
    loop {
        let op = bytes[pos];
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().unwrap()) as usize;
        pos += 9 + len;
        if op == 0x06 {
            return pos;
        }
    }
}

#[test]
fn a_recording_with_64_mib_of_damage_is_read_in_a_few_mib() {
    let sessions = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/sessions");
    #[allow(clippy::disallowed_methods)] // test code: a recording of the source tree
    let original = std::fs::read(sessions.join("slide.mcap")).unwrap();
    let whole = Recording::from_bytes(Path::new("slide.mcap"), &original).unwrap();

    // 64 MiB of zeros after the first chunk: damage the reader must walk past to the next chunk.
    const DAMAGE: usize = 64 << 20;
    let at = end_of_first_chunk(&original);
    let dir = std::env::temp_dir().join(format!("softhaptic-stream-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("damaged.mcap");
    {
        // The zeros are a hole (a seek past the end), so the file takes no disk space for them
        // on filesystems with sparse files, yet reads back as 64 MiB of zeros.
        use std::io::{Seek, SeekFrom, Write};
        let mut f = std::fs::File::create(&path).unwrap();
        f.write_all(&original[..at]).unwrap();
        f.seek(SeekFrom::Current(DAMAGE as i64)).unwrap();
        f.write_all(&original[at..]).unwrap();
    }

    let before = LIVE.load(Ordering::Relaxed);
    PEAK.store(before, Ordering::Relaxed);
    let read = Recording::open(&path).unwrap();
    let peak = PEAK.load(Ordering::Relaxed) - before;
    let _ = std::fs::remove_dir_all(&dir);

    // Every tick is there: the zeros held no data, and the records on both sides are intact.
    assert_eq!(read.device, whole.device);
    assert_eq!(read.contacts.len(), whole.contacts.len());
    assert_eq!(read.lost.len(), 1, "{:?}", read.lost);
    // The zeros, and the first chunk's message indexes after them (only for seeking).
    let lost = read.lost[0].bytes;
    assert!(
        (DAMAGE as u64..DAMAGE as u64 + 4096).contains(&lost),
        "{lost}"
    );
    // The decoded records of this 4-second recording take a few MiB; reading the file whole (let
    // alone copying it) would take 64 MiB more.
    assert!(
        peak < 16 << 20,
        "reading took {} MiB of heap at its peak",
        peak >> 20
    );
}
