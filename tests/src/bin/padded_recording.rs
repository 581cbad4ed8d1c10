//! Writes a recording whose contact frames are padded with whitespace (valid in every respect,
//! checksums right; see `softhaptic_tests::crafted`), to measure what its readers take:
//! `padded-recording OUT.mcap [FRAMES [PADDING_KIB]]` (default 40 frames of 50 MiB: 51200 KiB), then
//! `/usr/bin/time -v softhaptic info OUT.mcap`.

use std::process::ExitCode;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(out) = args.first() else {
        eprintln!("usage: padded-recording OUT.mcap [FRAMES [PADDING_KIB]]");
        return ExitCode::from(2);
    };
    let number = |at: usize, default: usize| {
        args.get(at)
            .map_or(Ok(default), |a| a.parse::<usize>())
            .map_err(|e| format!("{:?}: {e}", args[at]))
    };
    let (frames, padding_kib) = match (number(1, 40), number(2, 50 << 10)) {
        (Ok(f), Ok(p)) => (f, p),
        (Err(e), _) | (_, Err(e)) => {
            eprintln!("padded-recording: not a number: {e}");
            return ExitCode::from(2);
        }
    };
    let bytes = softhaptic_tests::crafted::padded_recording(
        std::path::Path::new(out),
        frames,
        padding_kib << 10,
    );
    println!("{out}: {bytes} bytes, {frames} contact frames padded with {padding_kib} KiB each");
    ExitCode::SUCCESS
}
