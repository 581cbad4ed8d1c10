//! An idle timeout for HTTP/2 connections, which hyper does not have, and the refusal of
//! cleartext HTTP/2 (h2c).
//!
//! HTTP/1.1's idle keep-alive connection is closed by hyper's header-read timeout, but an HTTP/2
//! connection waits for its next stream for ever: a client (or a thousand) that opens one and
//! goes quiet holds a socket and a place in the connection caps until the server stops. This
//! layer sits on the decrypted stream, recognises HTTP/2 by the connection preface its client
//! must send first (RFC 9113 §3.4; so ALPN's `h2` and prior knowledge inside TLS alike), and
//! from then on ends the connection when no byte has moved either way for the timeout. Bytes
//! are the measure, not streams: a download in progress writes, a viewer's page that is open
//! asks; a response its client does not read for the whole timeout is as stalled as a silent
//! client. The server sends no pings of its own, which would count as traffic. HTTP/1 streams
//! (and the WebSockets upgraded from them, quiet for minutes in a paused replay) pass untouched.
//!
//! Without TLS the same recognition refuses HTTP/2 outright: hyper's connection builder serves
//! prior-knowledge HTTP/2 whenever it serves upgrades, whatever version it is limited to, and
//! nothing needs h2c (browsers speak HTTP/2 only over TLS).

use std::io;
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::time::{Instant, Sleep};

/// A bound on a deadline's distance, so that `Instant` arithmetic cannot overflow.
const ONE_DAY: Duration = Duration::from_secs(24 * 3600);

/// What every HTTP/2 client sends first (RFC 9113 §3.4).
pub(super) const HTTP2_PREFACE: &[u8] = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n";

/// What becomes of a connection that turns out to be HTTP/2.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum OnHttp2 {
    /// Ended at once, with an error (cleartext: h2c is not served).
    Refuse,
    /// Ended after this long without a byte either way.
    CloseWhenIdle(Duration),
}

/// The error an h2c connection ends with.
#[derive(Debug, thiserror::Error)]
#[error("cleartext HTTP/2 (h2c) is not served: HTTP/1.1, or HTTP/2 over TLS")]
pub(super) struct H2cRefused;

/// Whether a connection is HTTP/2, from its first bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Protocol {
    /// The first bytes matched this much of the preface so far.
    Unknown {
        matched: usize,
    },
    Http2,
    /// Anything else: left to hyper's own timeouts.
    Other,
}

/// A connection's stream that, once it is known to be HTTP/2, fails ([`OnHttp2::Refuse`]) or
/// ends (end of file) after `idle` without a byte read or written. `held` lives as long as the
/// connection (its slot in the connection caps).
#[derive(Debug)]
pub(super) struct IdleStream<T, H> {
    stream: T,
    _held: H,
    protocol: Protocol,
    refuse: bool,
    idle: Duration,
    deadline: Pin<Box<Sleep>>,
}

impl<T, H> IdleStream<T, H> {
    pub(super) fn new(stream: T, http2: OnHttp2, held: H) -> Self {
        let (refuse, idle) = match http2 {
            // The deadline is never watched then.
            OnHttp2::Refuse => (true, Duration::MAX),
            OnHttp2::CloseWhenIdle(idle) => (false, idle),
        };
        IdleStream {
            stream,
            _held: held,
            protocol: Protocol::Unknown { matched: 0 },
            refuse,
            idle,
            deadline: Box::pin(tokio::time::sleep_until(Instant::now() + idle.min(ONE_DAY))),
        }
    }

    /// Bytes moved: the idle time starts again.
    fn active(&mut self) {
        if self.protocol == Protocol::Http2 {
            self.deadline
                .as_mut()
                .reset(Instant::now() + self.idle.min(ONE_DAY));
        }
    }

    /// Follows the preface through the first bytes read.
    fn sniff(&mut self, read: &[u8]) {
        let Protocol::Unknown { matched } = self.protocol else {
            return;
        };
        let wanted = &HTTP2_PREFACE[matched..];
        let n = read.len().min(wanted.len());
        self.protocol = if read[..n] != wanted[..n] {
            Protocol::Other
        } else if matched + n == HTTP2_PREFACE.len() {
            Protocol::Http2
        } else {
            Protocol::Unknown {
                matched: matched + n,
            }
        };
    }
}

impl<T: AsyncRead + Unpin, H: Unpin> AsyncRead for IdleStream<T, H> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let before = buf.filled().len();
        match Pin::new(&mut self.stream).poll_read(cx, buf) {
            Poll::Ready(Ok(())) => {
                let this = &mut *self;
                let read = &buf.filled()[before..];
                if !read.is_empty() {
                    this.sniff(read);
                    if this.refuse && this.protocol == Protocol::Http2 {
                        return Poll::Ready(Err(io::Error::new(
                            io::ErrorKind::InvalidData,
                            H2cRefused,
                        )));
                    }
                    this.active();
                }
                Poll::Ready(Ok(()))
            }
            Poll::Ready(Err(e)) => Poll::Ready(Err(e)),
            Poll::Pending => {
                // hyper keeps a read pending on an HTTP/2 connection for as long as it lives,
                // so this is where the deadline is watched (and its waker registered).
                if self.protocol == Protocol::Http2
                    && !self.refuse
                    && self.deadline.as_mut().poll(cx).is_ready()
                {
                    tracing::debug!("HTTP/2 connection idle: closed");
                    // End of file: hyper closes the connection as if the client had.
                    return Poll::Ready(Ok(()));
                }
                Poll::Pending
            }
        }
    }
}

impl<T: AsyncWrite + Unpin, H: Unpin> AsyncWrite for IdleStream<T, H> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let written = Pin::new(&mut self.stream).poll_write(cx, buf);
        if matches!(written, Poll::Ready(Ok(n)) if n > 0) {
            self.active();
        }
        written
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let written = Pin::new(&mut self.stream).poll_write_vectored(cx, bufs);
        if matches!(written, Poll::Ready(Ok(n)) if n > 0) {
            self.active();
        }
        written
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[tokio::test]
    async fn the_preface_is_followed_across_reads_and_anything_else_is_left_alone() {
        let mut h2 = IdleStream::new((), OnHttp2::Refuse, ());
        h2.sniff(&HTTP2_PREFACE[..5]);
        assert_eq!(h2.protocol, Protocol::Unknown { matched: 5 });
        h2.sniff(&[&HTTP2_PREFACE[5..], b"\0\0\0\x04"].concat());
        assert_eq!(h2.protocol, Protocol::Http2);
        let mut http1 = IdleStream::new((), OnHttp2::Refuse, ());
        http1.sniff(b"GET / HTTP/1.1\r\n");
        assert_eq!(http1.protocol, Protocol::Other);
        // A request that starts like the preface but is not it.
        let mut pri = IdleStream::new((), OnHttp2::Refuse, ());
        pri.sniff(b"PRI * HTTP/1.1\r\n");
        assert_eq!(pri.protocol, Protocol::Other);
    }
}
