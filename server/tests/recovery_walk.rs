//! The recovery walk against damaged lengths: one bit flipped in a record's length field loses at
//! most the chunk that record is (none, for a record only needed for seeking), never the intact
//! chunks after it, and the loss is reported as device time.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use softhaptic_server::session::reader::{Ending, Recording};

fn slide() -> (PathBuf, Vec<u8>) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/sessions/slide.mcap");
    #[allow(clippy::disallowed_methods)] // test code: a recording of the source tree
    let bytes = std::fs::read(&path).unwrap();
    (path, bytes)
}

/// The data section's top-level records: opcode, record start, record end.
fn records(bytes: &[u8]) -> Vec<(u8, usize, usize)> {
    let mut out = Vec::new();
    let mut pos = 8;
    while pos + 9 <= bytes.len() {
        let op = bytes[pos];
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().unwrap()) as usize;
        out.push((op, pos, pos + 9 + len));
        if op == 0x0F {
            break;
        }
        pos += 9 + len;
    }
    out
}

/// The device times a chunk record's header claims.
fn chunk_times(bytes: &[u8], start: usize) -> (u64, u64) {
    let at = |i: usize| u64::from_le_bytes(bytes[i..i + 8].try_into().unwrap());
    (at(start + 9), at(start + 17))
}

/// `bytes` with bit `bit` of the length field of the record at `start` flipped.
fn flip_length_bit(bytes: &[u8], start: usize, bit: usize) -> Vec<u8> {
    let mut damaged = bytes.to_vec();
    damaged[start + 1 + bit / 8] ^= 1 << (bit % 8);
    damaged
}

/// Reads `damaged` and checks that every tick of `full` outside `lost` (a device-time range,
/// inclusive) was recovered, and nothing else; returns the recording.
fn read_losing_at_most(
    full: &Recording,
    path: &Path,
    damaged: &[u8],
    lost: Option<(u64, u64)>,
) -> Recording {
    let r = Recording::from_bytes(path, damaged).unwrap();
    let have: BTreeSet<u64> = r.device.iter().map(|d| d.tick).collect();
    let all: BTreeSet<u64> = full.device.iter().map(|d| d.tick).collect();
    assert!(have.is_subset(&all), "{}", r.recovery());
    let missing: Vec<u64> = full
        .device
        .iter()
        .filter(|d| !have.contains(&d.tick))
        .filter(|d| lost.is_none_or(|(a, b)| d.time_ns < a || d.time_ns > b))
        .map(|d| d.time_ns)
        .collect();
    assert!(
        missing.is_empty(),
        "{} intact ticks lost, device time {:.3} s to {:.3} s: {}",
        missing.len(),
        missing[0] as f64 * 1e-9,
        missing[missing.len() - 1] as f64 * 1e-9,
        r.recovery()
    );
    r
}

/// The audit's case: bit 17 of the first data chunk's length makes the chunk claim 128 KiB more
/// than it holds, still within the file. The chunk's own records check out, but they end before
/// its claimed end; it must not be kept over the chunks it would cover.
#[test]
fn a_stretched_chunk_length_loses_that_chunk_and_no_chunk_after_it() {
    let (path, bytes) = slide();
    let data_chunks: Vec<_> = records(&bytes)
        .into_iter()
        .filter(|r| r.0 == 0x06)
        .skip(1)
        .collect();
    let (_, start, _) = data_chunks[0];
    let damaged = flip_length_bit(&bytes, start, 17);
    let claimed = chunk_times(&bytes, start);
    let full = Recording::from_bytes(&path, &bytes).unwrap();
    let r = read_losing_at_most(&full, &path, &damaged, Some(claimed));
    assert_eq!(r.ending, Ending::Complete, "{}", r.recovery());
    assert_eq!(r.lost.len(), 1, "{}", r.recovery());
    assert_eq!(r.lost[0].first_byte, start as u64);
    // The loss is told as the device time between the chunks kept on either side.
    let (a, b) = r.lost[0].time_ns.expect("the lost time is known");
    assert!(a <= claimed.0 && claimed.1 <= b, "{:?} {claimed:?}", (a, b));
    let next_kept = chunk_times(&bytes, data_chunks[1].1).0;
    assert!(b <= next_kept, "{b} {next_kept}");
    let text = r.recovery().to_string();
    assert!(
        text.contains("device time 0.000 s to 1.000 s") && text.contains("its records end"),
        "{text}"
    );
}

/// The audit's second case: a message index (needed only for seeking) whose length claims 128 KiB
/// more than it holds. Stepping over it on its length would land inside a later chunk.
#[test]
fn a_stretched_message_index_length_loses_no_tick() {
    let (path, bytes) = slide();
    let full = Recording::from_bytes(&path, &bytes).unwrap();
    let all = records(&bytes);
    let first_data_chunk = all.iter().filter(|r| r.0 == 0x06).nth(1).unwrap().1;
    // The first index after it: the index of the first data chunk.
    let (_, start, _) = *all
        .iter()
        .find(|r| r.0 == 0x07 && r.1 > first_data_chunk)
        .unwrap();
    let damaged = flip_length_bit(&bytes, start, 17);
    let r = read_losing_at_most(&full, &path, &damaged, None);
    assert_eq!(r.ending, Ending::Complete, "{}", r.recovery());
    assert_eq!(r.device, full.device, "{}", r.recovery());
    assert_eq!(r.contacts, full.contacts);
    assert_eq!(r.lost.len(), 1, "{}", r.recovery());
    assert!(
        r.recovery().to_string().contains("message index"),
        "{}",
        r.recovery()
    );
}

/// Every bit of the length of every chunk after the first (which defines the session) and of
/// the message indexes of the first data chunk: each flip loses at most the ticks of the chunk
/// it hit.
#[test]
fn any_flipped_length_bit_loses_at_most_its_own_chunk() {
    let (path, bytes) = slide();
    let full = Recording::from_bytes(&path, &bytes).unwrap();
    let all = records(&bytes);
    let data_chunks: Vec<usize> = all.iter().filter(|r| r.0 == 0x06).map(|r| r.1).collect();
    let (first, second) = (data_chunks[1], data_chunks[2]);
    // Bits 0 to 18 reach every length within this file (367 788 bytes); 40 and 63, far past it.
    assert!(bytes.len() < 1 << 19);
    let bits: Vec<usize> = (0..19).chain([40, 63]).collect();
    let hit = all
        .iter()
        .filter(|r| r.0 == 0x06 && r.1 >= first || r.0 == 0x07 && (first..second).contains(&r.1));
    for &(op, start, _) in hit {
        let lost = match op {
            0x06 => Some(chunk_times(&bytes, start)),
            0x07 => None,
            _ => continue,
        };
        for &bit in &bits {
            let damaged = flip_length_bit(&bytes, start, bit);
            let r = read_losing_at_most(&full, &path, &damaged, lost);
            assert!(!r.lost.is_empty(), "bit {bit} at {start}: {}", r.recovery());
            if op == 0x06 {
                assert!(
                    r.lost.iter().all(|l| l.time_ns.is_some()),
                    "bit {bit} at {start}: {}",
                    r.recovery()
                );
            }
        }
    }
}

/// A bit flipped in the first chunk, which holds the build and scene records: the writer's copy
/// of that chunk, right after it, takes its place, and every tick is read; the account names
/// the damaged chunk and the copy.
#[test]
fn a_damaged_first_chunk_is_replaced_by_its_copy_and_nothing_is_lost() {
    let (path, bytes) = slide();
    let full = Recording::from_bytes(&path, &bytes).unwrap();
    let (_, start, end) = *records(&bytes).iter().find(|r| r.0 == 0x06).unwrap();
    // The copy is the attachment after the first chunk's message indexes.
    assert!(
        records(&bytes)
            .iter()
            .skip_while(|r| r.1 < end)
            .take_while(|r| r.0 != 0x06)
            .any(|r| r.0 == 0x09),
        "no attachment between the first chunk and the second"
    );
    for at in [(start + 9 + 44 + end) / 2, end - 3, start + 30] {
        let mut damaged = bytes.clone();
        damaged[at] ^= 0x02;
        let r = Recording::from_bytes(&path, &damaged).unwrap();
        assert_eq!(r.device, full.device, "byte {at}: {}", r.recovery());
        assert_eq!(r.scene.scene_toml, full.scene.scene_toml);
        assert_eq!(r.lost.len(), 1, "byte {at}: {}", r.recovery());
        assert_eq!(r.lost[0].first_byte, start as u64);
        assert!(
            r.lost[0].reason.contains("read from their copy"),
            "{}",
            r.lost[0]
        );
    }
    // A file cut short as well (a crash): no summary to define the channels, and the copy
    // alone makes the chunks kept readable.
    let third_chunk_end = records(&bytes)
        .iter()
        .filter(|r| r.0 == 0x06)
        .nth(2)
        .unwrap()
        .2;
    let mut cut = bytes[..third_chunk_end].to_vec();
    cut[(start + 9 + 44 + end) / 2] ^= 0x02;
    let r = Recording::from_bytes(&path, &cut).unwrap();
    let kept: Vec<_> = full
        .device
        .iter()
        .take_while(|d| d.time_ns <= r.device.last().unwrap().time_ns)
        .cloned()
        .collect();
    assert!(r.device.len() > 1_000, "{}", r.recovery());
    assert_eq!(r.device, kept, "{}", r.recovery());
}

/// The first chunk and its copy both damaged (or a recording made before the copy existed): the
/// recording cannot be read, but the refusal says the file is damaged (not that it ends early),
/// and that the ticks after the damage are intact: the channels they are on are read from the
/// file's summary.
#[test]
fn a_damaged_first_chunk_and_copy_are_refused_as_damage_naming_the_intact_ticks() {
    let (path, bytes) = slide();
    let full = Recording::from_bytes(&path, &bytes).unwrap();
    let all = records(&bytes);
    let (_, start, end) = *all.iter().find(|r| r.0 == 0x06).unwrap();
    let (_, copy_start, copy_end) = *all.iter().find(|r| r.0 == 0x09).unwrap();
    let mut damaged = bytes.clone();
    damaged[(start + 9 + 44 + end) / 2] ^= 0x02;
    damaged[(copy_start + copy_end) / 2] ^= 0x02;
    let e = Recording::from_bytes(&path, &damaged)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("damaged")
            && !e.contains("the file ends")
            && e.contains(&format!("the {} ticks after it", full.device.len()))
            && e.contains("summary")
            && e.contains("the first chunk and its copy"),
        "{e}"
    );
}
