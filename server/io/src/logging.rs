//! The server's log: `RUST_LOG` chooses what is written (default `info`), to stderr, coloured only
//! for a person at a terminal; and whatever `RUST_LOG` says, the libraries' TRACE events that
//! print what a connection carries are never written, because those bytes hold secrets: a
//! viewer's first WebSocket message is its token (tungstenite logs each frame and message at
//! TRACE), and async-nats logs its CONNECT, with the NATS password or token, at TRACE.

use tracing::{Level, Metadata};
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::{EnvFilter, Layer};

/// Targets whose TRACE events print a connection's payload (see the module doc).
const PAYLOAD_TRACING_TARGETS: [&str; 3] = ["tungstenite", "tokio_tungstenite", "async_nats"];

/// Whether an event may print a secret and is therefore never written.
pub fn may_print_secrets(metadata: &Metadata<'_>) -> bool {
    may_print_secrets_at(metadata.target(), *metadata.level())
}

fn may_print_secrets_at(target: &str, level: Level) -> bool {
    level == Level::TRACE
        && PAYLOAD_TRACING_TARGETS.iter().any(|t| {
            target == *t
                || target
                    .strip_prefix(t)
                    .is_some_and(|rest| rest.starts_with("::"))
        })
}

/// Writes one line to stdout (a link, a fingerprint, the recording's path) for a person or a
/// supervisor to read. A server runs on when nobody reads its stdout any more (a closed pipe, a
/// supervisor gone), so a failed write is ignored, where `println!` would panic and stop the
/// loop and the recording with it.
pub fn print_line(line: std::fmt::Arguments<'_>) {
    use std::io::Write as _;
    let mut out = std::io::stdout().lock();
    let _ = out
        .write_fmt(line)
        .and_then(|()| out.write_all(b"\n"))
        .and_then(|()| out.flush());
}

/// An error and its causes on one line, `outer: cause: cause`, for the person who ran the
/// command. A cause whose text the line already ends with is not repeated: many of the project's
/// errors put their source's text in their own message (so that a log line read alone says
/// why) and also name it as the source, which `{:#}` would print twice.
pub fn error_text(error: &(dyn std::error::Error + 'static)) -> String {
    let mut text = error.to_string();
    let mut cause = error.source();
    while let Some(e) = cause {
        let next = e.to_string();
        if !next.is_empty() && !text.ends_with(&next) {
            text.push_str(": ");
            text.push_str(&next);
        }
        cause = e.source();
    }
    text
}

/// Installs the process's log. Call once, first.
pub fn init() {
    let env = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info"));
    let layer = tracing_subscriber::fmt::layer()
        .with_writer(std::io::stderr)
        // Colour codes only for a person at a terminal, not in a log file or a pipe.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_filter(env)
        .with_filter(tracing_subscriber::filter::filter_fn(|m| {
            !may_print_secrets(m)
        }));
    tracing_subscriber::registry().with(layer).init();
}

/// Prints a report on stdout. A reader that stops early (`softhaptic info FILE | head`) ends
/// the output, not the program with a panic, as with other command-line tools.
pub fn print_report(text: std::fmt::Arguments<'_>) -> anyhow::Result<()> {
    use anyhow::Context as _;
    use std::io::Write as _;
    let mut out = std::io::stdout().lock();
    match out.write_fmt(text).and_then(|()| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => other.context("could not write to stdout"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cause_already_in_the_message_is_not_printed_twice() {
        let fifo = std::io::Error::other("is a FIFO, not a regular file");
        let doubled = anyhow::Error::from(fifo)
            .context("could not read the token file /tmp/t: is a FIFO, not a regular file");
        assert_eq!(
            error_text(doubled.as_ref()),
            "could not read the token file /tmp/t: is a FIFO, not a regular file"
        );
        // A cause the message does not carry is still given, every level of it.
        let refused = std::io::Error::other("connection refused");
        let chain = anyhow::Error::from(refused)
            .context("NATS at 127.0.0.1:4222")
            .context("could not start the station");
        assert_eq!(
            error_text(chain.as_ref()),
            "could not start the station: NATS at 127.0.0.1:4222: connection refused"
        );
    }

    #[test]
    fn payload_traces_of_the_websocket_and_nats_libraries_are_never_written() {
        for target in [
            "tungstenite",
            "tungstenite::protocol",
            "tokio_tungstenite",
            "async_nats::connection",
        ] {
            assert!(may_print_secrets_at(target, Level::TRACE), "{target}");
            // Their other levels say what happened, not what was carried.
            assert!(!may_print_secrets_at(target, Level::DEBUG), "{target}");
        }
        for target in [
            "softhaptic_server::stream",
            "hyper",
            "tungstenite_x",
            "axum",
        ] {
            assert!(!may_print_secrets_at(target, Level::TRACE), "{target}");
        }
    }
}
