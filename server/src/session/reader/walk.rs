//! The walk over a recording's top-level records before the MCAP library sees them: every chunk
//! is checked (its sizes, its decompression, its checksum, the lengths of the records inside),
//! a damaged one is skipped and the walk resumes at the next chunk that checks out; the records
//! kept are then fed to the library as a whole file ([`Feed`]), read from the [`Source`] as it
//! asks for them.

use super::LostSpan;

/// Largest uncompressed chunk accepted. The writer closes chunks at about 1 MiB; anything far
/// beyond is a damaged length field, which the MCAP library would try to allocate.
const MAX_CHUNK_UNCOMPRESSED_BYTES: u64 = 64 << 20;

/// MCAP opcode of a chunk record.
const OP_CHUNK: u8 = 0x06;

/// Little-endian reads that fail instead of panicking on short input.
fn read_u32(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(
        b.get(at..at.checked_add(4)?)?.try_into().ok()?,
    ))
}

fn read_u64(b: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(
        b.get(at..at.checked_add(8)?)?.try_into().ok()?,
    ))
}

/// The records of `b` (opcode, u64 length, body) all fit exactly.
fn records_fit(b: &[u8]) -> bool {
    let mut pos = 0;
    while pos < b.len() {
        let Some(len) = read_u64(b, pos + 1) else {
            return false;
        };
        match usize::try_from(len)
            .ok()
            .and_then(|l| (pos + 9).checked_add(l))
        {
            Some(end) if end <= b.len() => pos = end,
            _ => return false,
        }
    }
    true
}

/// Why a chunk record's body cannot be trusted, if it cannot: a size beyond reason, a compression
/// this build does not write, data that does not decompress to its declared size and checksum,
/// or inner records whose lengths overrun the chunk.
fn chunk_damage(body: &[u8]) -> Option<String> {
    let fields = || {
        let uncompressed_size = read_u64(body, 16)?;
        let crc = read_u32(body, 24)?;
        let name_len = read_u32(body, 28)? as usize;
        let name_end = 32usize.checked_add(name_len)?;
        let compression = body.get(32..name_end)?;
        let records_len = usize::try_from(read_u64(body, name_end)?).ok()?;
        let records_start = name_end + 8;
        let records = body.get(records_start..records_start.checked_add(records_len)?)?;
        Some((uncompressed_size, crc, compression, records))
    };
    let Some((uncompressed_size, crc, compression, records)) = fields() else {
        return Some("its fields overrun it".into());
    };
    if uncompressed_size > MAX_CHUNK_UNCOMPRESSED_BYTES {
        return Some(format!("it claims {uncompressed_size} bytes uncompressed"));
    }
    let data = match compression {
        b"" => records.to_vec(),
        b"zstd" => match zstd::bulk::decompress(records, uncompressed_size as usize) {
            Ok(d) => d,
            Err(e) => return Some(format!("it does not decompress: {e}")),
        },
        other => {
            return Some(format!(
                "its compression {:?} is not one this build reads",
                String::from_utf8_lossy(other)
            ));
        }
    };
    if data.len() as u64 != uncompressed_size {
        return Some(format!(
            "it decompresses to {} bytes instead of {uncompressed_size}",
            data.len()
        ));
    }
    if crc != 0 && crc32fast::hash(&data) != crc {
        return Some("its checksum does not match".into());
    }
    if !records_fit(&data) {
        return Some("its records overrun it".into());
    }
    None
}

/// MCAP opcodes the walk tells apart.
const OP_HEADER: u8 = 0x01;
const OP_FOOTER: u8 = 0x02;
const OP_SCHEMA: u8 = 0x03;
const OP_CHANNEL: u8 = 0x04;
const OP_MESSAGE: u8 = 0x05;
const OP_MESSAGE_INDEX: u8 = 0x07;
const OP_ATTACHMENT: u8 = 0x09;
const OP_METADATA: u8 = 0x0C;
const OP_DATA_END: u8 = 0x0F;

/// Random access to a recording's bytes: the file itself (read a record at a time, never whole)
/// or bytes already in memory.
pub(crate) trait Source {
    fn len(&self) -> u64;
    /// Fills `buf` from `pos`; the range lies within [`Source::len`].
    fn read_at(&self, pos: u64, buf: &mut [u8]) -> std::io::Result<()>;
}

impl Source for [u8] {
    fn len(&self) -> u64 {
        <[u8]>::len(self) as u64
    }
    fn read_at(&self, pos: u64, buf: &mut [u8]) -> std::io::Result<()> {
        let start = usize::try_from(pos).map_err(std::io::Error::other)?;
        let src = start
            .checked_add(buf.len())
            .and_then(|end| self.get(start..end))
            .ok_or_else(|| std::io::Error::from(std::io::ErrorKind::UnexpectedEof))?;
        buf.copy_from_slice(src);
        Ok(())
    }
}

/// A recording file, of the length it had when it was opened (a live recording read while it
/// is written is read as far as it went then).
pub(super) struct FileSource {
    pub(super) file: std::fs::File,
    pub(super) len: u64,
}

impl Source for FileSource {
    fn len(&self) -> u64 {
        self.len
    }
    fn read_at(&self, pos: u64, buf: &mut [u8]) -> std::io::Result<()> {
        use std::os::unix::fs::FileExt;
        self.file.read_exact_at(buf, pos)
    }
}

/// Largest top-level record read: a chunk the writer closes at about 1 MiB (compressed, less),
/// or the scene record with its meshes. A length beyond it is damage, never allocated.
pub(super) const MAX_RECORD_BYTES: u64 = 256 << 20;
/// The window the search for a resumption point reads at a time.
const RESUME_WINDOW_BYTES: usize = 64 << 10;

/// What the walk kept of a file: the byte ranges of the records to parse (in file order), the
/// stretches skipped, and why the file ended early, if it did.
pub(super) struct Scanned {
    pub(super) keep: Vec<std::ops::Range<u64>>,
    pub(super) lost: Vec<LostSpan>,
    pub(super) tail: Option<String>,
}

/// The record at `pos`: its opcode and body range, when its header is there and its body ends
/// within the file.
fn record_at<S: Source + ?Sized>(src: &S, pos: u64) -> std::io::Result<Option<(u8, u64, u64)>> {
    let mut header = [0u8; 9];
    if pos.checked_add(9).is_none_or(|end| end > src.len()) {
        return Ok(None);
    }
    src.read_at(pos, &mut header)?;
    Ok(header_fits(src.len(), pos, &header))
}

/// The record whose 9-byte header (opcode, u64 length) is `header`, at `pos` of a file `len`
/// bytes long: its opcode and body range, when its body ends within the file.
fn header_fits(len: u64, pos: u64, header: &[u8; 9]) -> Option<(u8, u64, u64)> {
    let body_len = read_u64(header, 1)?;
    let body_start = pos + 9;
    let body_end = body_start.checked_add(body_len)?;
    (body_end <= len).then_some((header[0], body_start, body_end))
}

/// Why the chunk whose body is `start..end` cannot be trusted (reading it into `scratch`), if
/// it cannot.
fn chunk_damage_at<S: Source + ?Sized>(
    src: &S,
    start: u64,
    end: u64,
    scratch: &mut Vec<u8>,
) -> std::io::Result<Option<String>> {
    let len = end - start;
    if len > MAX_RECORD_BYTES {
        return Ok(Some(format!("it claims {len} bytes")));
    }
    scratch.clear();
    scratch.resize(len as usize, 0);
    src.read_at(start, scratch)?;
    Ok(chunk_damage(scratch))
}

/// The device times the chunk whose body starts at `start` says it holds.
fn chunk_times_at<S: Source + ?Sized>(src: &S, start: u64) -> Option<(u64, u64)> {
    let mut times = [0u8; 16];
    src.read_at(start, &mut times).ok()?;
    Some((read_u64(&times, 0)?, read_u64(&times, 8)?))
}

/// Where reading can resume after damage at `from`: the next chunk that checks out in full, or
/// the data section's end record, whichever comes first. Damage may have hit a length, so the
/// walk cannot step over it; a chunk is only trusted once its checksum matches. Reads the file
/// a window at a time and looks closer only where a byte could start such a record.
fn resume_after<S: Source + ?Sized>(
    src: &S,
    from: u64,
    scratch: &mut Vec<u8>,
) -> std::io::Result<Option<u64>> {
    let len = src.len();
    let mut window = vec![0u8; RESUME_WINDOW_BYTES + 8];
    let mut base = from;
    while base < len {
        // The window overlaps the next by a header's length, so a header across the seam is seen.
        let n = ((len - base) as usize).min(window.len());
        src.read_at(base, &mut window[..n])?;
        let candidates = n.min(RESUME_WINDOW_BYTES);
        for i in 0..candidates {
            let op = window[i];
            if op != OP_CHUNK && op != OP_DATA_END {
                continue;
            }
            let pos = base + i as u64;
            let header: Option<[u8; 9]> = window.get(i..i + 9).and_then(|h| h.try_into().ok());
            let Some(header) = header else {
                continue;
            };
            match header_fits(len, pos, &header) {
                Some((OP_DATA_END, start, end)) if end - start == 4 => return Ok(Some(pos)),
                Some((OP_CHUNK, start, end))
                    if chunk_damage_at(src, start, end, scratch)?.is_none() =>
                {
                    return Ok(Some(pos));
                }
                _ => {}
            }
        }
        base += candidates as u64;
    }
    Ok(None)
}

/// Walks the file's top-level records: keeps the header, the schemas, channels and messages
/// outside chunks, and every chunk that checks out ([`chunk_damage`]); skips a damaged chunk or
/// record and resumes at the next good chunk ([`resume_after`]); stops at the data section's end
/// (the summary and index after it are only for seeking). Holds one record at a time.
pub(super) fn scan<S: Source + ?Sized>(src: &S) -> std::io::Result<Scanned> {
    let len = src.len();
    let mut keep = Vec::new();
    let mut lost = Vec::new();
    let mut tail = None;
    let mut scratch = Vec::new();
    let mut pos = mcap::MAGIC.len() as u64;
    let skip = |lost: &mut Vec<LostSpan>,
                scratch: &mut Vec<u8>,
                pos: u64,
                time_ns,
                reason: String|
     -> std::io::Result<Option<u64>> {
        let next = resume_after(src, pos + 1, scratch)?;
        let end = next.unwrap_or(len);
        lost.push(LostSpan {
            first_byte: pos,
            bytes: end - pos,
            time_ns,
            reason,
        });
        Ok(next)
    };
    loop {
        if pos >= len {
            tail = Some("the file ends without its data section's end and footer".to_owned());
            break;
        }
        let Some((op, start, end)) = record_at(src, pos)? else {
            // The chunk being written when the file was cut (a crash), or a damaged length:
            // a good chunk further on tells the two apart.
            match resume_after(src, pos + 1, &mut scratch)? {
                Some(next) => {
                    lost.push(LostSpan {
                        first_byte: pos,
                        bytes: next - pos,
                        time_ns: None,
                        reason: format!(
                            "the record at byte {pos} claims a length past the file's end"
                        ),
                    });
                    pos = next;
                    continue;
                }
                None => {
                    tail = Some(format!(
                        "the record at byte {pos} runs past the end of the file"
                    ));
                    break;
                }
            }
        };
        match op {
            OP_CHUNK => match chunk_damage_at(src, start, end, &mut scratch)? {
                None => {
                    keep.push(pos..end);
                    pos = end;
                }
                Some(why) => {
                    let times = chunk_times_at(src, start);
                    let reason = format!("the chunk at byte {pos} is damaged: {why}");
                    match skip(&mut lost, &mut scratch, pos, times, reason)? {
                        Some(next) => pos = next,
                        None => {
                            tail = Some("damage reaches the end of the data".to_owned());
                            break;
                        }
                    }
                }
            },
            OP_HEADER | OP_SCHEMA | OP_CHANNEL | OP_MESSAGE if end - start <= MAX_RECORD_BYTES => {
                keep.push(pos..end);
                pos = end;
            }
            // Needed only for seeking, or not written by this project.
            OP_MESSAGE_INDEX | OP_ATTACHMENT | OP_METADATA => pos = end,
            OP_DATA_END if end - start == 4 => {
                // The writer closes a file with its summary, a footer and the magic; the data is
                // whole either way, but a file without them was not closed.
                let magic_len = mcap::MAGIC.len() as u64;
                let mut end_magic = [0u8; 8];
                let ends_with_magic = len >= end + magic_len
                    && src.read_at(len - magic_len, &mut end_magic).is_ok()
                    && end_magic[..] == mcap::MAGIC[..];
                let footer_at = len.checked_sub(magic_len + 29);
                let closed = ends_with_magic
                    && match footer_at {
                        Some(at) if at >= end => {
                            record_at(src, at)? == Some((OP_FOOTER, at + 9, at + 29))
                        }
                        _ => false,
                    };
                if !closed {
                    tail = Some(
                        "the file's footer is missing or damaged (the data before it is whole)"
                            .to_owned(),
                    );
                }
                break;
            }
            // A record of a kind the data section does not hold (a damaged opcode), or one far
            // larger than any the writer makes (a damaged length).
            other => {
                let reason = format!("a record of kind {other:#04x} at byte {pos} (damaged)");
                match skip(&mut lost, &mut scratch, pos, None, reason)? {
                    Some(next) => pos = next,
                    None => {
                        tail = Some("damage reaches the end of the data".to_owned());
                        break;
                    }
                }
            }
        }
    }
    Ok(Scanned { keep, lost, tail })
}

/// The bytes the MCAP library reads: the magic, the kept records read from the source as it
/// asks for them, and a closing data end (checksum 0: not computed), a footer pointing at no
/// summary and the magic, so that it reads them as a whole file.
pub(super) struct Feed<'a, S: ?Sized> {
    src: &'a S,
    parts: Vec<FeedPart>,
    part: usize,
    offset: u64,
}

enum FeedPart {
    Bytes(Vec<u8>),
    Range(std::ops::Range<u64>),
}

impl<'a, S: Source + ?Sized> Feed<'a, S> {
    pub(super) fn new(src: &'a S, keep: &[std::ops::Range<u64>]) -> Self {
        let mut closing = Vec::new();
        let mut record = |op: u8, body: &[u8]| {
            closing.push(op);
            closing.extend_from_slice(&(body.len() as u64).to_le_bytes());
            closing.extend_from_slice(body);
        };
        record(OP_DATA_END, &[0; 4]);
        record(OP_FOOTER, &[0; 20]);
        closing.extend_from_slice(mcap::MAGIC);
        let mut parts = vec![FeedPart::Bytes(mcap::MAGIC.to_vec())];
        parts.extend(keep.iter().cloned().map(FeedPart::Range));
        parts.push(FeedPart::Bytes(closing));
        Self {
            src,
            parts,
            part: 0,
            offset: 0,
        }
    }

    /// Fills as much of `buf` as the next part allows; 0 at the end.
    pub(super) fn fill(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        while let Some(part) = self.parts.get(self.part) {
            let part_len = match part {
                FeedPart::Bytes(b) => b.len() as u64,
                FeedPart::Range(r) => r.end - r.start,
            };
            if self.offset >= part_len {
                self.part += 1;
                self.offset = 0;
                continue;
            }
            let n = ((part_len - self.offset) as usize).min(buf.len());
            match part {
                FeedPart::Bytes(b) => {
                    let at = self.offset as usize;
                    buf[..n].copy_from_slice(&b[at..at + n]);
                }
                FeedPart::Range(r) => self.src.read_at(r.start + self.offset, &mut buf[..n])?,
            }
            self.offset += n as u64;
            return Ok(n);
        }
        Ok(0)
    }
}
