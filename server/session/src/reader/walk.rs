//! The walk over a recording's top-level records before the MCAP library sees them: every chunk
//! is checked (its sizes, its decompression, its checksum, the lengths of the records inside,
//! which must end exactly where the chunk does), every other record's fields must end exactly
//! where its length says; a damaged record is skipped and the walk resumes at the next chunk that
//! checks out; the records kept are then fed to the library as a whole file ([`Feed`]), read from
//! the [`Source`] as it asks for them.
//!
//! Long (920 lines, then 250 of tests) because every check of a record's layout, and the search
//! for where reading resumes, serve this one walk: read beside it, they show that nothing unchecked
//! reaches the library.

use super::LostSpan;

/// Largest uncompressed chunk accepted. The writer closes chunks at about 1 MiB; anything far
/// beyond is a damaged length field, which the MCAP library would try to allocate.
pub(super) const MAX_CHUNK_UNCOMPRESSED_BYTES: u64 = 64 << 20;

/// What a file's chunks may decompress to, in all, per byte of the file. A recording this build
/// writes decompresses to about 5 times its size (the test recordings: 4.8 to 5.8); a file whose
/// chunks claim far more is crafted to fill the reader's memory (a megabyte of whitespace
/// compresses to a few hundred bytes), and is refused before anything is decompressed.
pub(crate) const DECODED_BYTES_PER_FILE_BYTE: u64 = 64;
/// What any file may decompress to, however small: room for a scene whose meshes compress well.
pub(crate) const MIN_DECODED_BYTES: u64 = 32 << 20;

/// The most a file of `file_len` bytes may decompress to ([`DECODED_BYTES_PER_FILE_BYTE`],
/// [`MIN_DECODED_BYTES`]).
pub(crate) fn decoded_budget(file_len: u64) -> u64 {
    file_len
        .saturating_mul(DECODED_BYTES_PER_FILE_BYTE)
        .max(MIN_DECODED_BYTES)
}

/// The refusal of a file whose chunks claim more than [`decoded_budget`].
fn decodes_too_much(file_len: u64, claimed: u64, pos: u64) -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::InvalidData,
        format!(
            "its chunks decompress to more than the limit of {} bytes ({} bytes up to the chunk \
             at byte {pos}; the limit is {DECODED_BYTES_PER_FILE_BYTE} times the file's {file_len} \
             bytes, and at least {} MiB; a recording this build writes decompresses to about 5 \
             times its size): refused, as made to fill the reader's memory",
            decoded_budget(file_len),
            claimed,
            MIN_DECODED_BYTES >> 20
        ),
    )
}

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

/// Device times of the first and last message a chunk holds.
type Times = Option<(u64, u64)>;

/// When the records of `b` (opcode, u64 length, body) all fit exactly: the device times of the
/// first and last message among them, read from the messages themselves.
fn records_fit(b: &[u8]) -> Option<Times> {
    let mut pos = 0;
    let mut times: Times = None;
    while pos < b.len() {
        let len = read_u64(b, pos + 1)?;
        let end = usize::try_from(len)
            .ok()
            .and_then(|l| (pos + 9).checked_add(l))
            .filter(|&end| end <= b.len())?;
        if b[pos] == OP_MESSAGE {
            // channel id (u16), sequence (u32), log time (u64), publish time (u64), data.
            if len < 22 {
                return None;
            }
            let t = read_u64(b, pos + 9 + 6)?;
            times = Some(times.map_or((t, t), |(a, z)| (a.min(t), z.max(t))));
        }
        pos = end;
    }
    Some(times)
}

/// Bytes of a chunk body's fixed fields, up to and including its records' length, for the
/// compressions this build reads (none, or "zstd").
const CHUNK_FIXED_BYTES: usize = 32 + 4 + 8;

/// A chunk's fields before its records, read from the start of its body.
struct ChunkFields {
    uncompressed_size: u64,
    crc: u32,
    zstd: bool,
    records_start: usize,
}

/// The fields of a chunk whose body is `body_len` bytes long and starts with `head` (at least
/// [`CHUNK_FIXED_BYTES`] of it, or all of it when shorter), or why they cannot be those of a
/// chunk this build wrote: a compression it does not write, a size beyond reason, or records that
/// do not end exactly where the body does (a damaged length, of the chunk or of its records).
/// Cheap: it reads no records, so the search for a resumption point can reject most candidates
/// without reading their bodies.
fn chunk_fields(head: &[u8], body_len: u64) -> Result<ChunkFields, String> {
    let overrun = || "its fields overrun it".to_owned();
    let uncompressed_size = read_u64(head, 16).ok_or_else(overrun)?;
    let crc = read_u32(head, 24).ok_or_else(overrun)?;
    let name_len = read_u32(head, 28).ok_or_else(overrun)? as usize;
    if name_len != 0 && name_len != 4 {
        return Err(format!(
            "its compression name is {name_len} bytes long, not one this build reads"
        ));
    }
    let compression = head.get(32..32 + name_len).ok_or_else(overrun)?;
    let zstd = match compression {
        b"" => false,
        b"zstd" => true,
        other => {
            return Err(format!(
                "its compression {:?} is not one this build reads",
                String::from_utf8_lossy(other)
            ));
        }
    };
    let records_len = read_u64(head, 32 + name_len).ok_or_else(overrun)?;
    let records_start = 32 + name_len + 8;
    if uncompressed_size > MAX_CHUNK_UNCOMPRESSED_BYTES {
        return Err(format!("it claims {uncompressed_size} bytes uncompressed"));
    }
    if (records_start as u64).checked_add(records_len) != Some(body_len) {
        return Err(format!(
            "its records end at byte {} of its {body_len}-byte body",
            (records_start as u128) + u128::from(records_len)
        ));
    }
    let largest = if zstd {
        zstd::compress_bound(uncompressed_size as usize) as u64
    } else {
        uncompressed_size
    };
    if records_len > largest || (!zstd && records_len != uncompressed_size) {
        return Err(format!(
            "its {records_len} bytes of records cannot hold {uncompressed_size} bytes"
        ));
    }
    Ok(ChunkFields {
        uncompressed_size,
        crc,
        zstd,
        records_start,
    })
}

/// Why a chunk record's body cannot be trusted, if it cannot ([`chunk_fields`], then data that
/// does not decompress to its declared size and checksum, or inner records whose lengths do not
/// fit it exactly); when it can, the device times of its first and last message.
fn chunk_damage(body: &[u8]) -> Result<Times, String> {
    let fields = chunk_fields(body, body.len() as u64)?;
    let records = &body[fields.records_start..];
    let decompressed;
    let data = if fields.zstd {
        decompressed = zstd::bulk::decompress(records, fields.uncompressed_size as usize)
            .map_err(|e| format!("it does not decompress: {e}"))?;
        &decompressed[..]
    } else {
        records
    };
    if data.len() as u64 != fields.uncompressed_size {
        return Err(format!(
            "it decompresses to {} bytes instead of {}",
            data.len(),
            fields.uncompressed_size
        ));
    }
    if fields.crc != 0 && crc32fast::hash(data) != fields.crc {
        return Err("its checksum does not match".into());
    }
    records_fit(data).ok_or_else(|| "its records overrun it".into())
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

/// The name of a kind of record the data section holds, for messages.
fn record_kind(op: u8) -> Option<&'static str> {
    Some(match op {
        OP_HEADER => "header",
        OP_SCHEMA => "schema record",
        OP_CHANNEL => "channel record",
        OP_MESSAGE => "message record",
        OP_MESSAGE_INDEX => "message index",
        OP_ATTACHMENT => "attachment",
        OP_METADATA => "metadata record",
        OP_DATA_END => "data section's end record",
        _ => return None,
    })
}

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
/// How far the window reaches past its candidates: a record's header and a chunk's fixed fields,
/// so that a candidate is judged on them without another read.
const RESUME_OVERLAP_BYTES: usize = 64;

/// The candidate chunk bodies the walk reads in full while it looks for a resumption point, over
/// the whole file, at most: twice the file's length, and a mebibyte. A real chunk is read once
/// (the walk does not read it again), and a false candidate that passes the cheap checks of
/// [`chunk_fields`] is rare in a real file; a crafted one full of them is given up on instead
/// of read for hours.
fn resync_budget(file_len: u64) -> u64 {
    file_len.saturating_mul(2).saturating_add(1 << 20)
}

/// What the walk kept of a file: the byte ranges of the records to parse (in file order, but
/// for the summary's schema and channel records when the chunk defining them was lost), the
/// stretches skipped, and why the file ended early, if it did.
pub(super) struct Scanned {
    pub(super) keep: Vec<std::ops::Range<u64>>,
    pub(super) lost: Vec<LostSpan>,
    pub(super) tail: Option<String>,
    /// The first chunk was lost, and the channels were taken from the summary.
    pub(super) definitions_from_summary: bool,
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

/// The start of the chunk body `start..end` (its fixed fields, or all of it when shorter).
fn chunk_head_at<S: Source + ?Sized>(
    src: &S,
    start: u64,
    end: u64,
) -> std::io::Result<([u8; CHUNK_FIXED_BYTES], usize)> {
    let mut head = [0u8; CHUNK_FIXED_BYTES];
    let n = (end - start).min(CHUNK_FIXED_BYTES as u64) as usize;
    src.read_at(start, &mut head[..n])?;
    Ok((head, n))
}

/// Why the chunk whose body is `start..end` cannot be trusted (reading it into `scratch`), if
/// it cannot; when it can, the device times of its first and last message. Reads its fixed
/// fields first, and the rest only when they check out.
fn chunk_damage_at<S: Source + ?Sized>(
    src: &S,
    start: u64,
    end: u64,
    scratch: &mut Vec<u8>,
) -> std::io::Result<Result<Times, String>> {
    let len = end - start;
    if len > MAX_RECORD_BYTES {
        return Ok(Err(format!("it claims {len} bytes")));
    }
    let (head, n) = chunk_head_at(src, start, end)?;
    if let Err(why) = chunk_fields(&head[..n], len) {
        return Ok(Err(why));
    }
    scratch.clear();
    scratch.resize(len as usize, 0);
    src.read_at(start, scratch)?;
    Ok(chunk_damage(scratch))
}

/// The device times the chunk whose body starts at `start` says it holds (its header, which no
/// checksum covers), when they are there and in order.
fn chunk_times_at<S: Source + ?Sized>(src: &S, start: u64) -> Times {
    let mut times = [0u8; 16];
    if start.checked_add(16).is_none_or(|end| end > src.len()) {
        return None;
    }
    src.read_at(start, &mut times).ok()?;
    let (a, b) = (read_u64(&times, 0)?, read_u64(&times, 8)?);
    (a <= b).then_some((a, b))
}

/// Whether the body `start..end` of a record of kind `op` (not a chunk) is laid out as MCAP lays
/// it out: its fields, read from the lengths inside it, end exactly where its own length says
/// (a damaged length does not). A message's data has no length of its own: any length past its
/// fixed fields fits.
fn record_fits_at<S: Source + ?Sized>(
    src: &S,
    op: u8,
    start: u64,
    end: u64,
) -> std::io::Result<bool> {
    struct Cursor<'a, S: ?Sized> {
        src: &'a S,
        pos: u64,
        end: u64,
    }
    impl<S: Source + ?Sized> Cursor<'_, S> {
        /// Steps over `n` bytes, when they are there.
        fn skip(&mut self, n: u64) -> Option<()> {
            self.pos = self.pos.checked_add(n).filter(|&p| p <= self.end)?;
            Some(())
        }
        /// Reads an `N`-byte little-endian length, when it is there.
        fn len<const N: usize>(&mut self) -> std::io::Result<Option<u64>> {
            let at = self.pos;
            if self.skip(N as u64).is_none() {
                return Ok(None);
            }
            let mut b = [0u8; 8];
            self.src.read_at(at, &mut b[..N])?;
            Ok(Some(u64::from_le_bytes(b)))
        }
        /// Steps over a length-prefixed field (a string, a map, bytes).
        fn prefixed<const N: usize>(&mut self) -> std::io::Result<Option<()>> {
            Ok(match self.len::<N>()? {
                Some(n) => self.skip(n),
                None => None,
            })
        }
    }
    let mut c = Cursor {
        src,
        pos: start,
        end,
    };
    let fits = match op {
        // profile, library
        OP_HEADER => c.prefixed::<4>()?.and(c.prefixed::<4>()?),
        // id, name, encoding, data
        OP_SCHEMA => c
            .skip(2)
            .and(c.prefixed::<4>()?)
            .and(c.prefixed::<4>()?)
            .and(c.prefixed::<4>()?),
        // id, schema id, topic, message encoding, metadata
        OP_CHANNEL => c
            .skip(4)
            .and(c.prefixed::<4>()?)
            .and(c.prefixed::<4>()?)
            .and(c.prefixed::<4>()?),
        // channel id, sequence, log time, publish time, then data to the end
        OP_MESSAGE => c.skip(22).map(|()| c.pos = end),
        // channel id, (time, offset) pairs
        OP_MESSAGE_INDEX => match c.skip(2).and(c.len::<4>()?) {
            Some(n) if n % 16 == 0 => c.skip(n),
            _ => None,
        },
        // log time, create time, name, media type, data, crc
        OP_ATTACHMENT => c
            .skip(16)
            .and(c.prefixed::<4>()?)
            .and(c.prefixed::<4>()?)
            .and(c.prefixed::<8>()?)
            .and(c.skip(4)),
        // name, metadata
        OP_METADATA => c.prefixed::<4>()?.and(c.prefixed::<4>()?),
        OP_DATA_END => c.skip(4),
        _ => None,
    };
    Ok(fits.is_some() && c.pos == end)
}

/// The chunk inside the attachment whose body is `start..end`, as a range of the file, when
/// the attachment is the writer's copy of the first chunk
/// ([`softhaptic_proto::record::START_COPY_ATTACHMENT`]) and checks out: its name, then its
/// checksum, then the chunk its data holds, whole and intact ([`chunk_damage`]). Reads the name
/// first, and the rest only when it is that one.
fn start_copy_at<S: Source + ?Sized>(
    src: &S,
    start: u64,
    end: u64,
    scratch: &mut Vec<u8>,
) -> std::io::Result<Option<std::ops::Range<u64>>> {
    let name = softhaptic_proto::record::START_COPY_ATTACHMENT.as_bytes();
    // log time, create time, then the name's length and the name.
    let name_end = 16 + 4 + name.len() as u64;
    let len = end - start;
    if len < name_end || len > MAX_RECORD_BYTES {
        return Ok(None);
    }
    let mut head = vec![0u8; name_end as usize];
    src.read_at(start, &mut head)?;
    if read_u32(&head, 16) != Some(name.len() as u32) || &head[20..] != name {
        return Ok(None);
    }
    scratch.clear();
    scratch.resize(len as usize, 0);
    src.read_at(start, scratch)?;
    let body = &scratch[..];
    // media type, then the data's length, the data, and the checksum of everything before it.
    let Some(media_len) = read_u32(body, name_end as usize) else {
        return Ok(None);
    };
    let data_len_at = name_end as usize + 4 + media_len as usize;
    let Some(data_len) = read_u64(body, data_len_at) else {
        return Ok(None);
    };
    let data_start = data_len_at + 8;
    let Some(data_end) = usize::try_from(data_len)
        .ok()
        .and_then(|n| data_start.checked_add(n))
        .filter(|&e| e.checked_add(4) == Some(body.len()))
    else {
        return Ok(None);
    };
    let crc = read_u32(body, data_end).unwrap_or(0);
    if crc != 0 && crc32fast::hash(&body[..data_end]) != crc {
        return Ok(None);
    }
    let data = &body[data_start..data_end];
    let whole_chunk = data.first() == Some(&OP_CHUNK)
        && read_u64(data, 1).is_some_and(|n| n.checked_add(9) == Some(data.len() as u64))
        && chunk_damage(&data[9..]).is_ok();
    Ok(whole_chunk.then(|| start + data_start as u64..start + data_end as u64))
}

/// Where [`resume_after`] found reading can resume.
enum Resume {
    /// At the record at this byte: a chunk that checks out in full (with the times of its
    /// messages), or the copy of the first chunk or the data section's end (`None`).
    At(u64, Option<Times>),
    /// Nowhere: no chunk after the damage checks out.
    Nowhere,
    /// The search read [`resync_budget`] bytes of candidates without finding one.
    GaveUp,
}

/// Where reading can resume after damage at `from`: the next chunk that checks out in full, the
/// copy of the first chunk ([`start_copy_at`]), or the data section's end record, whichever
/// comes first. Damage may have hit a length, so the
/// walk cannot step over it; a chunk is only trusted once its checksum matches. Reads the file
/// a window at a time and looks closer only where a byte could start such a record: a chunk
/// body is read only when its fixed fields check out ([`chunk_fields`]), and only while the
/// `budget` of bytes such reads may take lasts.
fn resume_after<S: Source + ?Sized>(
    src: &S,
    from: u64,
    scratch: &mut Vec<u8>,
    budget: &mut u64,
) -> std::io::Result<Resume> {
    let len = src.len();
    let mut window = vec![0u8; RESUME_WINDOW_BYTES + RESUME_OVERLAP_BYTES];
    let mut base = from;
    while base < len {
        // The window overlaps the next by a header and a chunk's fixed fields, so that a
        // candidate near the seam is seen whole.
        let n = ((len - base) as usize).min(window.len());
        src.read_at(base, &mut window[..n])?;
        let candidates = n.min(RESUME_WINDOW_BYTES);
        for i in 0..candidates {
            let op = window[i];
            if op != OP_CHUNK && op != OP_DATA_END && op != OP_ATTACHMENT {
                continue;
            }
            let pos = base + i as u64;
            let header: Option<[u8; 9]> = window.get(i..i + 9).and_then(|h| h.try_into().ok());
            let Some(header) = header else {
                continue;
            };
            match header_fits(len, pos, &header) {
                Some((OP_DATA_END, start, end)) if end - start == 4 => {
                    return Ok(Resume::At(pos, None));
                }
                Some((OP_ATTACHMENT, start, end)) => {
                    // Only the copy of the first chunk, whose name is read before its body.
                    let body_len = end - start;
                    if *budget < body_len {
                        return Ok(Resume::GaveUp);
                    }
                    if start_copy_at(src, start, end, scratch)?.is_some() {
                        return Ok(Resume::At(pos, None));
                    }
                }
                Some((OP_CHUNK, start, end)) => {
                    let body_len = end - start;
                    // The body lies within the file, so its fixed fields lie within the window.
                    let head_end = (i + 9 + CHUNK_FIXED_BYTES).min(i + 9 + body_len as usize);
                    let Some(head) = window.get(i + 9..head_end) else {
                        continue;
                    };
                    if chunk_fields(head, body_len).is_err() {
                        continue;
                    }
                    if *budget < body_len {
                        return Ok(Resume::GaveUp);
                    }
                    *budget -= body_len;
                    if let Ok(times) = chunk_damage_at(src, start, end, scratch)? {
                        return Ok(Resume::At(pos, Some(times)));
                    }
                }
                _ => {}
            }
        }
        base += candidates as u64;
    }
    Ok(Resume::Nowhere)
}

/// The device time a lost stretch covers, from the chunks kept on either side of it (`before`
/// ends, `after` starts; times read from their messages) and the times the lost stretch's first
/// chunk claims, if it starts with one (its header: no checksum covers it, so it is used only
/// where it agrees with the kept chunks around it).
fn lost_time(before: Option<u64>, after: Option<u64>, claimed: Times) -> Times {
    match (before, after, claimed) {
        (Some(a), Some(b), Some((c, _))) if a <= c && c <= b => Some((c, b)),
        (Some(a), Some(b), _) if a <= b => Some((a, b)),
        (None, Some(b), Some((c, _))) if c <= b => Some((c, b)),
        (Some(a), None, Some((_, d))) if a <= d => Some((a, d)),
        (None, None, claimed) => claimed,
        _ => None,
    }
}

/// Walks the file's top-level records: keeps the header, the schemas, channels and messages
/// outside chunks, and every chunk that checks out ([`chunk_damage`]); steps over the records
/// needed only for seeking once their fields fit their length ([`record_fits_at`]); skips a
/// damaged chunk or record and resumes at the next good chunk ([`resume_after`]), searching from
/// the end of the last record that checked out in full (a record stepped over on its length
/// alone may have had that length damaged); stops at the data section's end (the summary and
/// index after it are only for seeking). Holds one record at a time.
pub(super) fn scan<S: Source + ?Sized>(src: &S) -> std::io::Result<Scanned> {
    let len = src.len();
    let mut keep: Vec<std::ops::Range<u64>> = Vec::new();
    // The chunks kept: where they start, and the device times of their messages.
    let mut chunks: Vec<(u64, Times)> = Vec::new();
    // Each lost stretch, and the times its first chunk claims, if it starts with one.
    let mut lost: Vec<(LostSpan, Times)> = Vec::new();
    let mut tail = None;
    let mut scratch = Vec::new();
    let mut budget = resync_budget(len);
    // What the chunks checked so far decompress to (a chunk given up on later still counts:
    // the limit is on the work, and a real file is far below it).
    let mut decoded: u64 = 0;
    let mut pos = mcap::MAGIC.len() as u64;
    // The end of the last record that checked out in full: the records after it, up to `pos`,
    // were stepped over on their length alone.
    let mut trusted_end = pos;
    // The chunk the search for a resumption point found and checked, not to read it again.
    let mut checked: Option<(u64, Times)> = None;
    // The copy of the first chunk, once seen: read only if the first chunk is lost.
    let mut start_copy: Option<std::ops::Range<u64>> = None;
    loop {
        if pos >= len {
            tail = Some("the file ends without its data section's end and footer".to_owned());
            break;
        }
        // What is wrong with the record at `pos`, and the times it claims (a chunk's header).
        // (Whether its length reaches past the file's end: a file cut short, or damage.)
        let (reason, claimed, past_end): (String, Times, bool) = match record_at(src, pos)? {
            None => {
                let mut opcode = [0u8; 1];
                src.read_at(pos, &mut opcode)?;
                let claimed = if opcode[0] == OP_CHUNK {
                    chunk_times_at(src, pos + 9)
                } else {
                    None
                };
                (
                    format!("the record at byte {pos} claims a length past the file's end"),
                    claimed,
                    true,
                )
            }
            Some((OP_CHUNK, start, end)) => {
                // Held against the limit before anything is decompressed: the header says.
                let (head, n) = chunk_head_at(src, start, end)?;
                if let Ok(fields) = chunk_fields(&head[..n], end - start) {
                    decoded = decoded.saturating_add(fields.uncompressed_size);
                    if decoded > decoded_budget(len) {
                        return Err(decodes_too_much(len, decoded, pos));
                    }
                }
                let check = match checked.take() {
                    Some((at, times)) if at == pos => Ok(times),
                    _ => chunk_damage_at(src, start, end, &mut scratch)?,
                };
                match check {
                    Ok(times) => {
                        keep.push(pos..end);
                        chunks.push((pos, times));
                        pos = end;
                        trusted_end = end;
                        continue;
                    }
                    Err(why) => (
                        format!("the chunk at byte {pos} is damaged: {why}"),
                        chunk_times_at(src, start),
                        false,
                    ),
                }
            }
            Some((op @ (OP_HEADER | OP_SCHEMA | OP_CHANNEL | OP_MESSAGE), start, end))
                if end - start <= MAX_RECORD_BYTES && record_fits_at(src, op, start, end)? =>
            {
                keep.push(pos..end);
                // A message's length cannot be checked against its fields.
                if op != OP_MESSAGE && trusted_end == pos {
                    trusted_end = end;
                }
                pos = end;
                continue;
            }
            // Needed only for seeking, or not written by this project.
            Some((op @ (OP_MESSAGE_INDEX | OP_ATTACHMENT | OP_METADATA), start, end))
                if record_fits_at(src, op, start, end)? =>
            {
                if op == OP_ATTACHMENT && start_copy.is_none() {
                    start_copy = start_copy_at(src, start, end, &mut scratch)?;
                }
                if trusted_end == pos {
                    trusted_end = end;
                }
                pos = end;
                continue;
            }
            Some((OP_DATA_END, start, end)) if end - start == 4 => {
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
            Some((op, start, end)) => (
                match record_kind(op) {
                    Some(kind) => format!(
                        "the {kind} at byte {pos} is damaged: its fields do not fit its length \
                         of {} bytes",
                        end - start
                    ),
                    // A record of a kind the data section does not hold (a damaged opcode).
                    None => format!("a record of kind {op:#04x} at byte {pos} (damaged)"),
                },
                None,
                false,
            ),
        };
        // Damage at `pos`. Records stepped over on their length alone since the last one that
        // checked out may have led here by a damaged length: the search starts where they do,
        // and they are given up with the damage.
        let (lost_from, search_from, reason) = if trusted_end < pos {
            let reason =
                format!("{reason}, where the length of the record at byte {trusted_end} leads");
            (trusted_end, trusted_end, reason)
        } else {
            (pos, pos + 1, reason)
        };
        keep.retain(|r| r.start < lost_from);
        chunks.retain(|&(at, _)| at < lost_from);
        let found = resume_after(src, search_from, &mut scratch, &mut budget)?;
        let next = match found {
            Resume::At(next, times) => {
                checked = times.map(|t| (next, t));
                Some(next)
            }
            Resume::Nowhere | Resume::GaveUp => None,
        };
        if matches!(found, Resume::Nowhere) && past_end {
            // The chunk being written when the file was cut (a crash): nothing good follows it.
            tail = Some(format!(
                "the record at byte {pos} runs past the end of the file"
            ));
            break;
        }
        let end = next.unwrap_or(len);
        lost.push((
            LostSpan {
                first_byte: lost_from,
                bytes: end - lost_from,
                time_ns: None,
                reason,
            },
            claimed,
        ));
        match found {
            Resume::At(next, _) => {
                pos = next;
                trusted_end = next;
            }
            Resume::Nowhere => {
                tail = Some("damage reaches the end of the data".to_owned());
                break;
            }
            Resume::GaveUp => {
                tail = Some(format!(
                    "the search for intact data after the damage at byte {pos} was given up \
                     after reading {} bytes of candidates (the rest of the file is not read)",
                    resync_budget(len)
                ));
                break;
            }
        }
    }
    // The time each lost stretch covers, from the kept chunks around it.
    let mut lost = lost
        .into_iter()
        .map(|(mut span, claimed)| {
            let before = chunks
                .iter()
                .filter(|&&(at, _)| at < span.first_byte)
                .filter_map(|&(_, t)| t)
                .map(|(_, z)| z)
                .next_back();
            let after = chunks
                .iter()
                .filter(|&&(at, _)| at >= span.first_byte + span.bytes)
                .find_map(|&(_, t)| t)
                .map(|(a, _)| a);
            span.time_ns = lost_time(before, after, claimed);
            span
        })
        .collect::<Vec<LostSpan>>();
    // The first chunk, which defines the channels and holds the build and scene, lost: its copy
    // takes its place; without one (a recording made before the copy existed, or the copy
    // damaged too), the summary's copies of the schema and channel records define the channels
    // for the chunks kept after it, and the refusal can say what was intact.
    let first_chunk_lost = lost
        .first()
        .is_some_and(|l| chunks.first().is_none_or(|&(at, _)| l.first_byte < at));
    let mut definitions_from_summary = false;
    if first_chunk_lost {
        let at = keep
            .iter()
            .take_while(|r| r.start < lost[0].first_byte)
            .count();
        if let Some(copy) = start_copy {
            keep.insert(at, copy);
            lost[0]
                .reason
                .push_str("; the session's build and scene were read from their copy after it");
        } else {
            let definitions = summary_definitions(src)?;
            if !definitions.is_empty() {
                definitions_from_summary = true;
                keep.splice(at..at, definitions);
            }
        }
    }
    Ok(Scanned {
        keep,
        lost,
        tail,
        definitions_from_summary,
    })
}

/// Largest summary section read for its schema and channel records (the writer's is a few KiB).
const MAX_SUMMARY_BYTES: u64 = 16 << 20;

/// The schema and channel records of the file's summary section (the writer repeats there every
/// schema and channel it defined), when the file ends with an intact footer that points at a
/// summary whose checksum matches (or has none) and whose records fit their lengths.
fn summary_definitions<S: Source + ?Sized>(src: &S) -> std::io::Result<Vec<std::ops::Range<u64>>> {
    let len = src.len();
    let magic_len = mcap::MAGIC.len() as u64;
    let Some(footer_at) = len.checked_sub(magic_len + 29) else {
        return Ok(Vec::new());
    };
    let mut end_magic = [0u8; 8];
    src.read_at(len - magic_len, &mut end_magic)?;
    if end_magic[..] != mcap::MAGIC[..]
        || record_at(src, footer_at)? != Some((OP_FOOTER, footer_at + 9, footer_at + 29))
    {
        return Ok(Vec::new());
    }
    let mut footer = [0u8; 20];
    src.read_at(footer_at + 9, &mut footer)?;
    let (Some(summary_start), Some(offsets_start), Some(crc)) = (
        read_u64(&footer, 0),
        read_u64(&footer, 8),
        read_u32(&footer, 16),
    ) else {
        return Ok(Vec::new());
    };
    let summary_end = if offsets_start == 0 {
        footer_at
    } else {
        offsets_start
    };
    let checked_len = (footer_at + 9 + 16).checked_sub(summary_start);
    if summary_start < mcap::MAGIC.len() as u64
        || summary_start >= summary_end
        || summary_end > footer_at
        || checked_len.is_none_or(|n| n > MAX_SUMMARY_BYTES)
    {
        return Ok(Vec::new());
    }
    if crc != 0 {
        // The checksum covers the summary, its offsets and the footer up to the checksum.
        let mut summary = vec![0u8; checked_len.unwrap_or(0) as usize];
        src.read_at(summary_start, &mut summary)?;
        if crc32fast::hash(&summary) != crc {
            return Ok(Vec::new());
        }
    }
    let mut definitions = Vec::new();
    let mut pos = summary_start;
    while pos < summary_end {
        let Some((op, start, end)) = record_at(src, pos)? else {
            break;
        };
        if end > summary_end {
            break;
        }
        // The other records there (statistics, indexes) are stepped over.
        if op == OP_SCHEMA || op == OP_CHANNEL {
            if !record_fits_at(src, op, start, end)? {
                break;
            }
            definitions.push(pos..end);
        }
        pos = end;
    }
    Ok(definitions)
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

#[cfg(test)]
mod tests {
    use super::{Scanned, Source, scan};
    use std::cell::Cell;

    /// Bytes in memory that count how many of them are read.
    struct Counting<'a> {
        bytes: &'a [u8],
        read: Cell<u64>,
    }

    impl Source for Counting<'_> {
        fn len(&self) -> u64 {
            self.bytes.len() as u64
        }
        fn read_at(&self, pos: u64, buf: &mut [u8]) -> std::io::Result<()> {
            self.read.set(self.read.get() + buf.len() as u64);
            Source::read_at(self.bytes, pos, buf)
        }
    }

    /// Scans `bytes`; returns what the walk kept and how many bytes it read.
    fn scan_counting(bytes: &[u8]) -> (Scanned, u64) {
        let src = Counting {
            bytes,
            read: Cell::new(0),
        };
        let scanned = scan(&src).unwrap();
        (scanned, src.read.get())
    }

    /// Appends a record: its opcode, its length, its body.
    fn record(out: &mut Vec<u8>, op: u8, body: &[u8]) {
        out.push(op);
        out.extend_from_slice(&(body.len() as u64).to_le_bytes());
        out.extend_from_slice(body);
    }

    /// The body of a message record on channel 1.
    fn message(time_ns: u64) -> Vec<u8> {
        let mut body = Vec::new();
        body.extend_from_slice(&1u16.to_le_bytes());
        body.extend_from_slice(&0u32.to_le_bytes());
        body.extend_from_slice(&time_ns.to_le_bytes());
        body.extend_from_slice(&time_ns.to_le_bytes());
        body.extend_from_slice(b"{}");
        body
    }

    /// The body of an uncompressed chunk holding one message at `time_ns`, with its checksum.
    fn chunk(time_ns: u64) -> Vec<u8> {
        let mut records = Vec::new();
        record(&mut records, 0x05, &message(time_ns));
        let mut body = Vec::new();
        body.extend_from_slice(&time_ns.to_le_bytes());
        body.extend_from_slice(&time_ns.to_le_bytes());
        body.extend_from_slice(&(records.len() as u64).to_le_bytes());
        body.extend_from_slice(&crc32fast::hash(&records).to_le_bytes());
        body.extend_from_slice(&0u32.to_le_bytes());
        body.extend_from_slice(&(records.len() as u64).to_le_bytes());
        body.extend_from_slice(&records);
        body
    }

    /// The magic and a header record.
    fn start() -> Vec<u8> {
        let mut out = mcap::MAGIC.to_vec();
        let mut header = Vec::new();
        for s in ["test", "walk"] {
            header.extend_from_slice(&(s.len() as u32).to_le_bytes());
            header.extend_from_slice(s.as_bytes());
        }
        record(&mut out, 0x01, &header);
        out
    }

    /// Appends the data section's end, a footer and the magic.
    fn close(out: &mut Vec<u8>) {
        record(out, 0x0F, &[0; 4]);
        record(out, 0x02, &[0; 20]);
        out.extend_from_slice(mcap::MAGIC);
    }

    /// Fake chunk headers after a damaged opcode, each claiming a body of `claimed` bytes that
    /// lies within the file, with the fields `fields` gives it (from its body length); then a
    /// good chunk. Returns the file and where the good chunk starts.
    fn fakes(count: usize, claimed: u64, fields: impl Fn(u64) -> Vec<u8>) -> (Vec<u8>, usize) {
        let mut out = start();
        record(&mut out, 0x42, &[]);
        for _ in 0..count {
            out.push(0x06);
            out.extend_from_slice(&claimed.to_le_bytes());
            out.extend_from_slice(&fields(claimed));
        }
        out.resize(out.len() + claimed as usize, 0);
        let good = out.len();
        record(&mut out, 0x06, &chunk(7));
        close(&mut out);
        (out, good)
    }

    /// A chunk's fixed fields: times, uncompressed size, checksum, compression, records' length.
    fn fixed_fields(uncompressed: u64, compression: &str, records_len: u64) -> Vec<u8> {
        let mut f = vec![0u8; 16];
        f.extend_from_slice(&uncompressed.to_le_bytes());
        f.extend_from_slice(&1u32.to_le_bytes());
        f.extend_from_slice(&(compression.len() as u32).to_le_bytes());
        f.extend_from_slice(compression.as_bytes());
        f.extend_from_slice(&records_len.to_le_bytes());
        f
    }

    /// The audit's crafted file, scaled down: a damaged opcode, then a thousand fake chunk
    /// headers each claiming a 1 MiB body within the file whose fields cannot be a chunk's (100
    /// MB uncompressed; a compression this build does not write; records that do not end where
    /// the body does). The search rejects each on its fixed fields, without reading its body
    /// (before, it read a gigabyte), and finds the good chunk after them.
    #[test]
    fn resync_rejects_fake_chunks_on_their_fixed_fields_without_reading_them() {
        let claimed = 1u64 << 20;
        let kinds: [fn(u64) -> Vec<u8>; 3] = [
            |len| fixed_fields(100_000_000, "zstd", len - 44),
            |len| fixed_fields(1 << 20, "lz4\0", len - 44),
            |len| fixed_fields(1 << 20, "zstd", len - 45),
        ];
        for fields in kinds {
            let (bytes, good) = fakes(1000, claimed, fields);
            let (scanned, read) = scan_counting(&bytes);
            assert!(
                read < 3 * bytes.len() as u64,
                "read {read} bytes of a {}-byte file",
                bytes.len()
            );
            assert!(
                scanned.keep.iter().any(|r| r.start == good as u64),
                "{:?} {:?}",
                scanned.keep,
                scanned.tail
            );
            assert_eq!(scanned.lost.len(), 1);
            assert_eq!(scanned.tail, None);
        }
    }

    /// Fake chunk headers whose fixed fields check out (their data does not decompress): each
    /// must be read to be refused, and the search gives up once it has read twice the file's
    /// length and a mebibyte in candidates, instead of reading a gigabyte (hours on a large
    /// crafted file).
    #[test]
    fn resync_gives_up_after_a_bounded_read_of_fake_chunks() {
        let claimed = 1u64 << 20;
        let (bytes, _) = fakes(1000, claimed, |len| fixed_fields(1 << 20, "zstd", len - 44));
        let (scanned, read) = scan_counting(&bytes);
        let len = bytes.len() as u64;
        assert!(
            read <= 3 * len + (2 << 20),
            "read {read} bytes of a {len}-byte file"
        );
        let tail = scanned.tail.unwrap_or_default();
        assert!(tail.contains("given up"), "{tail}");
        // What was not read is told as lost, to the end of the file.
        let last = scanned.lost.last().unwrap();
        assert_eq!(last.first_byte + last.bytes, len);
    }

    /// A message record outside chunks (the walk steps over it on its length alone) whose length
    /// was damaged to land inside a later chunk: the walk finds damage where it lands, gives up
    /// the message, and resumes its search where the message started, so that the chunks the
    /// damaged length covered are kept.
    #[test]
    fn damage_after_a_jump_resumes_from_the_last_record_that_checked_out() {
        let mut bytes = start();
        record(&mut bytes, 0x06, &chunk(1));
        let message_at = bytes.len();
        record(&mut bytes, 0x05, &message(2));
        let second = bytes.len();
        record(&mut bytes, 0x06, &chunk(3));
        let third = bytes.len();
        record(&mut bytes, 0x06, &chunk(4));
        let third_end = bytes.len();
        close(&mut bytes);
        // The message now claims to end 3 bytes into the third chunk's body (its start time).
        let stretched = (third + 9 + 3 - (message_at + 9)) as u64;
        bytes[message_at + 1..message_at + 9].copy_from_slice(&stretched.to_le_bytes());

        let (scanned, _) = scan_counting(&bytes);
        assert!(
            scanned.keep.contains(&(second as u64..third as u64)),
            "{:?}",
            scanned.keep
        );
        assert!(
            scanned.keep.contains(&(third as u64..third_end as u64)),
            "{:?}",
            scanned.keep
        );
        assert!(
            scanned.keep.iter().all(|r| r.start != message_at as u64),
            "the damaged message is not kept: {:?}",
            scanned.keep
        );
        assert_eq!(scanned.lost.len(), 1);
        assert_eq!(scanned.lost[0].first_byte, message_at as u64);
        assert_eq!(scanned.lost[0].bytes, (second - message_at) as u64);
        let reason = &scanned.lost[0].reason;
        assert!(
            reason.contains(&format!(
                "the length of the record at byte {message_at} leads"
            )),
            "{reason}"
        );
        // The lost stretch lies between the chunks of 1 ns and 3 ns.
        assert_eq!(scanned.lost[0].time_ns, Some((1, 3)));
    }

    /// A chunk whose length was stretched over the next chunk: its own records check out, but
    /// they end before its claimed end, so it is damaged and the next chunk is kept.
    #[test]
    fn a_chunk_whose_records_end_before_its_body_is_damaged() {
        let mut bytes = start();
        let first = bytes.len();
        record(&mut bytes, 0x06, &chunk(1));
        let second = bytes.len();
        record(&mut bytes, 0x06, &chunk(2));
        let second_end = bytes.len();
        close(&mut bytes);
        let stretched = (second_end - first - 9) as u64;
        bytes[first + 1..first + 9].copy_from_slice(&stretched.to_le_bytes());

        let (scanned, _) = scan_counting(&bytes);
        assert_eq!(
            scanned.keep.last(),
            Some(&(second as u64..second_end as u64)),
            "{:?}",
            scanned.keep
        );
        assert_eq!(scanned.lost.len(), 1);
        assert_eq!(scanned.lost[0].first_byte, first as u64);
        assert!(
            scanned.lost[0].reason.contains("its records end"),
            "{}",
            scanned.lost[0].reason
        );
        assert_eq!(scanned.lost[0].time_ns, Some((1, 2)));
    }
}
