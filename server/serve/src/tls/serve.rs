//! Serving a router on the viewer's port, plainly or over TLS; on the TLS port, a client's first
//! byte decides: a TLS handshake goes on to rustls, anything else gets a plain-text `400` saying
//! to use https. Either way a connection has a bounded time to speak, and the connections held
//! open are capped per client address and in all.

use std::collections::HashMap;
use std::future::Future;
use std::io;
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use axum::Router;
use axum_server::accept::{Accept, DefaultAcceptor};
use axum_server::tls_rustls::{RustlsAcceptor, RustlsConfig};
use rustls::ServerConfig;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio::task::JoinHandle;

use super::idle::{IdleStream, OnHttp2};
use super::{FIRST_REQUEST_TIMEOUT, HANDSHAKE_TIMEOUT, HEADER_READ_TIMEOUT, HTTP2_IDLE_TIMEOUT};
use crate::access::ConnectionLimits;

/// The first byte of every TLS connection: the record type of a handshake (RFC 8446 §5.1).
const TLS_HANDSHAKE_RECORD: u8 = 0x16;

/// What a client that spoke plain HTTP to the TLS port reads (in a `400 Bad Request`) before it
/// is closed: a browser shows it in place of a bare "connection reset".
const PLAIN_TEXT_REFUSAL: &str =
    "This softhaptic server speaks TLS only: open it with https:// (and its stream with wss://).\n";

/// Caps on the TCP connections a server holds open at once, counted from accept to close (a
/// WebSocket's connection included), so that clients that connect and never speak cannot take
/// every socket the process may open: per client address, and in all. Loopback is not capped
/// per address: a reverse proxy's connections all come from it.
/// With them, how long a connection may take to send its first request and each request's
/// headers, and how long an HTTP/2 connection may stay without traffic.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConnectionCaps {
    pub per_address: usize,
    pub total: usize,
    pub first_request_timeout: Duration,
    pub header_read_timeout: Duration,
    pub http2_idle_timeout: Duration,
}

/// Files the process keeps open besides its connections: the listening socket, the device, the
/// recording, NATS, the runtime's own, the viewer's files being served.
const FILES_BESIDE_CONNECTIONS: u64 = 256;

/// What to do about the open-file limit for `needed` files, given the limit's `soft` and
/// `hard` values: `Ok(Some(n))` raise the soft limit to `n`, `Ok(None)` nothing, `Err` the hard
/// limit is below what is needed (say so: connections past it would fail at accept, not be
/// refused by the caps).
pub fn open_file_limit_plan(needed: u64, soft: u64, hard: u64) -> Result<Option<u64>, u64> {
    if soft >= needed {
        Ok(None)
    } else if hard >= needed {
        // As far as allowed: nothing is gained by stopping at `needed`.
        Ok(Some(hard))
    } else {
        Err(hard)
    }
}

/// Raises the process's open-file limit (the usual soft limit, 1 024, is below the default
/// caps' 1 192 connections) to hold `caps.total` connections and the rest; warns when the hard
/// limit does not allow it.
pub fn ensure_open_file_limit(caps: &ConnectionCaps) {
    let needed = caps.total as u64 + FILES_BESIDE_CONNECTIONS;
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: `limit` is a valid rlimit for getrlimit to write.
    if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) } != 0 {
        tracing::warn!(error = %std::io::Error::last_os_error(), "could not read the open-file limit");
        return;
    }
    match open_file_limit_plan(needed, limit.rlim_cur, limit.rlim_max) {
        Ok(None) => {}
        Ok(Some(raised)) => {
            let new = libc::rlimit {
                rlim_cur: raised,
                rlim_max: limit.rlim_max,
            };
            // SAFETY: `new` is a valid rlimit, its soft value within the hard one.
            if unsafe { libc::setrlimit(libc::RLIMIT_NOFILE, &new) } == 0 {
                tracing::debug!(from = limit.rlim_cur, to = raised, "open-file limit raised");
            } else {
                tracing::warn!(error = %std::io::Error::last_os_error(), "could not raise the open-file limit");
            }
        }
        Err(hard) => tracing::warn!(
            hard,
            needed,
            "the open-file limit allows {hard} files, and the connection caps {}: connections \
             past it fail at accept instead of being refused; raise it (LimitNOFILE= in a \
             systemd unit, `ulimit -Hn`) or lower --max-viewers and --max-pending",
            caps.total
        ),
    }
}

impl ConnectionCaps {
    /// Room for the viewers `limits` admits, each with the few connections a browser opens for
    /// the page beside its WebSocket; [`FIRST_REQUEST_TIMEOUT`], [`HEADER_READ_TIMEOUT`] and
    /// [`HTTP2_IDLE_TIMEOUT`].
    pub fn for_limits(limits: &ConnectionLimits) -> ConnectionCaps {
        ConnectionCaps {
            per_address: 2 * limits.max_per_address as usize + 16,
            total: 2 * (limits.max_viewers as usize + limits.max_pending as usize) + 64,
            first_request_timeout: FIRST_REQUEST_TIMEOUT,
            header_read_timeout: HEADER_READ_TIMEOUT,
            http2_idle_timeout: HTTP2_IDLE_TIMEOUT,
        }
    }
}

/// Serves `app` on `listener` until `shutdown` turns true (or its sender is dropped), then stops
/// accepting and lets open requests finish. Without `tls` it is plain http and ws, HTTP/1.1 only
/// (cleartext HTTP/2, h2c, is refused: nothing needs it, and it would bring HTTP/2's costs to
/// a port without TLS); with it, https and wss on the same port (HTTP/1.1 and HTTP/2, WebSocket
/// upgrades over HTTP/1.1), a plain-text client refused as [`crate::tls`] says. Either way a
/// connection has `caps`' time to send its first request and each request's headers (an idle
/// keep-alive connection is closed after as long, an HTTP/2 one after `caps`'
/// `http2_idle_timeout` without traffic), and no more connections than `caps` are held open.
///
/// Requests carry [`axum::extract::ConnectInfo<SocketAddr>`] either way.
pub fn serve(
    listener: TcpListener,
    app: Router,
    tls: Option<Arc<ServerConfig>>,
    caps: ConnectionCaps,
    mut shutdown: watch::Receiver<bool>,
) -> JoinHandle<()> {
    let service = app.into_make_service_with_connect_info::<SocketAddr>();
    let handle = axum_server::Handle::new();
    let guard = ConnectionGuard::new(caps);
    let served: Pin<Box<dyn Future<Output = io::Result<()>> + Send>> = match tls {
        None => {
            let acceptor = guard.wrap(DefaultAcceptor::new(), OnHttp2::Refuse);
            Box::pin(server(listener, acceptor, &handle, caps).serve(service))
        }
        Some(config) => {
            let acceptor = guard.wrap(
                RustlsAcceptor::new(RustlsConfig::from_config(config))
                    .handshake_timeout(HANDSHAKE_TIMEOUT)
                    .acceptor(RefusePlainText),
                OnHttp2::CloseWhenIdle(caps.http2_idle_timeout),
            );
            Box::pin(server(listener, acceptor, &handle, caps).serve(service))
        }
    };
    tokio::spawn(async move {
        let mut served = served;
        let stop = async move {
            let _ = shutdown.wait_for(|stop| *stop).await;
        };
        let served = tokio::select! {
            served = &mut served => served,
            () = stop => {
                // No deadline, as with axum's own graceful shutdown: requests in flight finish
                // and idle connections close. An upgraded WebSocket is no longer the server's
                // connection; the router's viewer tasks close theirs on the same signal.
                handle.graceful_shutdown(None);
                served.await
            }
        };
        if let Err(e) = served {
            tracing::error!(error = %e, "HTTP server failed");
        }
    })
}

/// The server on `listener` with `acceptor`, both ways of serving alike: `caps`' timeouts,
/// shut down through `handle`, refusals logged.
fn server<Acc>(
    listener: TcpListener,
    acceptor: Acc,
    handle: &axum_server::Handle<SocketAddr>,
    caps: ConnectionCaps,
) -> axum_server::Server<SocketAddr, Acc> {
    let mut server = axum_server::Server::from_listener(listener)
        .acceptor(acceptor)
        .handle(handle.clone())
        .first_request_timeout(caps.first_request_timeout)
        .accept_error_handler(log_refused_connection);
    server
        .http_builder()
        .http1()
        .header_read_timeout(caps.header_read_timeout);
    server
}

/// Counts the open connections per client address and in all, refusing one over
/// [`ConnectionCaps`] at accept (it is closed at once).
#[derive(Debug, Clone)]
struct ConnectionGuard {
    caps: ConnectionCaps,
    open: Arc<Mutex<OpenConnections>>,
}

#[derive(Debug, Default)]
struct OpenConnections {
    total: usize,
    per_address: HashMap<IpAddr, usize>,
}

/// The error a connection over the caps ends with, told apart in the log.
#[derive(Debug, thiserror::Error)]
#[error("too many open connections ({what}): refused at accept")]
struct TooManyConnections {
    what: &'static str,
}

impl ConnectionGuard {
    fn new(caps: ConnectionCaps) -> Self {
        ConnectionGuard {
            caps,
            open: Arc::new(Mutex::new(OpenConnections::default())),
        }
    }

    fn wrap<A>(&self, inner: A, http2: OnHttp2) -> Guarded<A> {
        Guarded {
            guard: self.clone(),
            inner,
            http2,
        }
    }

    /// A slot for a connection from `ip`, or why there is none.
    fn admit(&self, ip: IpAddr) -> Result<Slot, TooManyConnections> {
        let mut open = self.open.lock().unwrap_or_else(PoisonError::into_inner);
        if open.total >= self.caps.total {
            return Err(TooManyConnections { what: "in all" });
        }
        // IPv6 by its /64: one host has a whole /64 to connect from.
        let ip = crate::access::client_key(ip);
        let capped = !ip.is_loopback();
        let from_ip = open.per_address.get(&ip).copied().unwrap_or(0);
        if capped && from_ip >= self.caps.per_address {
            return Err(TooManyConnections {
                what: "from this address",
            });
        }
        open.total += 1;
        open.per_address.insert(ip, from_ip + 1);
        Ok(Slot {
            guard: self.clone(),
            ip,
        })
    }
}

/// One admitted connection's place in the count, given back when the connection closes.
#[derive(Debug)]
struct Slot {
    guard: ConnectionGuard,
    ip: IpAddr,
}

impl Drop for Slot {
    fn drop(&mut self) {
        let mut open = self
            .guard
            .open
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        open.total = open.total.saturating_sub(1);
        if let Some(n) = open.per_address.get_mut(&self.ip) {
            *n = n.saturating_sub(1);
            if *n == 0 {
                open.per_address.remove(&self.ip);
            }
        }
    }
}

/// An acceptor in front of `inner` that admits a connection only within the caps, keeps its
/// slot for as long as the connection lives, and treats its HTTP/2 as `http2` says
/// ([`IdleStream`]).
#[derive(Debug, Clone)]
struct Guarded<A> {
    guard: ConnectionGuard,
    inner: A,
    http2: OnHttp2,
}

impl<A, S> Accept<TcpStream, S> for Guarded<A>
where
    A: Accept<TcpStream, S> + Clone + Send + Sync + 'static,
    A::Future: Send,
    A::Stream: AsyncRead + AsyncWrite + Unpin + Send,
    A::Service: Send,
    S: Send + 'static,
{
    type Stream = IdleStream<A::Stream, Slot>;
    type Service = A::Service;
    type Future = Pin<Box<dyn Future<Output = io::Result<(Self::Stream, A::Service)>> + Send>>;

    fn accept(&self, stream: TcpStream, service: S) -> Self::Future {
        let admitted = stream
            .peer_addr()
            .map_err(|e| io::Error::new(e.kind(), e))
            .and_then(|peer| self.guard.admit(peer.ip()).map_err(io::Error::other));
        let inner = self.inner.clone();
        let http2 = self.http2;
        Box::pin(async move {
            // Over the caps, the stream is dropped here: closed before anything is read.
            let slot = admitted?;
            let (stream, service) = inner.accept(stream, service).await?;
            Ok((IdleStream::new(stream, http2, slot), service))
        })
    }
}

/// The inner acceptor of the TLS acceptor: lets a connection through to the TLS handshake only
/// when its first byte starts one, and otherwise answers a short plain-text 400 and closes.
#[derive(Debug, Clone, Copy)]
struct RefusePlainText;

/// The error a plain-text client's connection ends with, told apart in the log.
#[derive(Debug, thiserror::Error)]
#[error("a plain-text client on the TLS port (http:// or ws:// instead of https:// or wss://)")]
struct PlainTextRefused;

impl<S: Send + 'static> Accept<TcpStream, S> for RefusePlainText {
    type Stream = TcpStream;
    type Service = S;
    type Future = Pin<Box<dyn Future<Output = io::Result<(TcpStream, S)>> + Send>>;

    fn accept(&self, stream: TcpStream, service: S) -> Self::Future {
        Box::pin(async move {
            let mut first = [0_u8; 1];
            let peeked = tokio::time::timeout(HANDSHAKE_TIMEOUT, stream.peek(&mut first))
                .await
                .map_err(|_| {
                    io::Error::new(io::ErrorKind::TimedOut, "no TLS handshake began in time")
                })??;
            if peeked == 0 {
                return Err(io::Error::new(
                    io::ErrorKind::UnexpectedEof,
                    "closed before the TLS handshake",
                ));
            }
            if first[0] != TLS_HANDSHAKE_RECORD {
                refuse_plain_text(stream).await;
                return Err(io::Error::new(io::ErrorKind::InvalidData, PlainTextRefused));
            }
            Ok((stream, service))
        })
    }
}

/// Tells a plain-text client to use https and closes its connection, in at most about 2.5 s.
async fn refuse_plain_text(mut stream: TcpStream) {
    // Read the request first: closing a socket with unread data sends a reset, and a reset can
    // make the client discard our answer before showing it.
    let mut buffer = [0_u8; 4096];
    let _ = tokio::time::timeout(Duration::from_millis(500), stream.read(&mut buffer)).await;
    let _ = tokio::time::timeout(Duration::from_secs(1), async {
        let response = format!(
            "HTTP/1.1 400 Bad Request\r\nContent-Type: text/plain; charset=utf-8\r\n\
             Content-Length: {}\r\nConnection: close\r\n\r\n{PLAIN_TEXT_REFUSAL}",
            PLAIN_TEXT_REFUSAL.len()
        );
        stream.write_all(response.as_bytes()).await?;
        stream.shutdown().await
    })
    .await;
    // Then wait (briefly) for the client to close its side, for the same reason.
    let _ = tokio::time::timeout(Duration::from_secs(1), async {
        while let Ok(n) = stream.read(&mut buffer).await {
            if n == 0 {
                break;
            }
        }
    })
    .await;
}

/// One log line per connection refused at accept or that did not become a TLS connection; never
/// an error, because a client (or a port scanner) causes it, not the server.
fn log_refused_connection(client: Option<&SocketAddr>, error: &io::Error) {
    let Some(client) = client else {
        // The listener itself failed (out of file descriptors, say); axum-server backs off and
        // keeps accepting.
        tracing::warn!(error = %error, "could not accept a connection");
        return;
    };
    let inner = error.get_ref();
    if let Some(e) = inner.and_then(|e| e.downcast_ref::<TooManyConnections>()) {
        // Debug only: a flood of them is what the cap is for, and must not flood the log too.
        tracing::debug!(%client, error = %e, "connection refused");
    } else if inner.is_some_and(|e| e.is::<PlainTextRefused>()) {
        tracing::info!(
            %client,
            "refused a plain-text request on the TLS port: told the client to use https:// and wss://"
        );
    } else if let Some(rustls::Error::AlertReceived(alert)) =
        inner.and_then(|e| e.downcast_ref::<rustls::Error>())
    {
        // The usual cause is a browser or viewer that does not trust the certificate yet; worth
        // seeing when a lab machine cannot connect.
        tracing::info!(
            %client,
            alert = ?alert,
            "a client ended the TLS handshake (does it trust this server's certificate?)"
        );
    } else {
        tracing::debug!(%client, error = %error, "TLS handshake failed");
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use std::time::Instant;

    #[test]
    fn the_open_file_limit_is_raised_to_hold_the_default_caps_or_the_shortfall_said() {
        let caps = ConnectionCaps::for_limits(&ConnectionLimits::default());
        let needed = caps.total as u64 + FILES_BESIDE_CONNECTIONS;
        // The usual soft limit is below the default caps.
        assert!(needed > 1024, "{needed}");
        assert_eq!(
            open_file_limit_plan(needed, 1024, 524_288),
            Ok(Some(524_288))
        );
        assert_eq!(open_file_limit_plan(needed, 65_536, 524_288), Ok(None));
        assert_eq!(open_file_limit_plan(needed, 1024, 1024), Err(1024));
        // And in this process, with the test machine's hard limit: raised as far as needed.
        ensure_open_file_limit(&caps);
        let mut limit = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        // SAFETY: `limit` is a valid rlimit for getrlimit to write.
        assert_eq!(
            unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) },
            0
        );
        assert!(
            limit.rlim_cur >= needed.min(limit.rlim_max),
            "{}",
            limit.rlim_cur
        );
    }

    /// Serves a one-route app plainly on a loopback port with `caps`.
    async fn serve_ok(caps: ConnectionCaps) -> (SocketAddr, watch::Sender<bool>, JoinHandle<()>) {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let app = Router::new().route("/", axum::routing::get(|| async { "ok" }));
        let (stop, stopped) = watch::channel(false);
        let task = serve(listener, app, None, caps, stopped);
        (addr, stop, task)
    }

    /// Reads until the server closes the connection (true) or `deadline` passes (false).
    async fn closed_by_server(stream: &mut TcpStream, deadline: Duration) -> bool {
        let until = Instant::now() + deadline;
        let mut buffer = [0_u8; 1024];
        loop {
            let left = until.saturating_duration_since(Instant::now());
            match tokio::time::timeout(left, stream.read(&mut buffer)).await {
                Ok(Ok(0)) | Ok(Err(_)) => return true,
                Ok(Ok(_)) => {}
                Err(_) => return false,
            }
        }
    }

    fn small(total: usize) -> ConnectionCaps {
        ConnectionCaps {
            per_address: 1,
            total,
            first_request_timeout: Duration::from_millis(300),
            header_read_timeout: Duration::from_millis(300),
            http2_idle_timeout: Duration::from_millis(300),
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn silent_slow_and_idle_connections_are_closed_by_the_server() {
        let (addr, stop, task) = serve_ok(small(64)).await;
        // Silent from the start.
        let mut silent = TcpStream::connect(addr).await.unwrap();
        // Half a request's headers, then nothing.
        let mut slow = TcpStream::connect(addr).await.unwrap();
        slow.write_all(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")
            .await
            .unwrap();
        // A whole request, answered, then the keep-alive connection left idle.
        let mut idle = TcpStream::connect(addr).await.unwrap();
        idle.write_all(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            .await
            .unwrap();
        let mut answer = [0_u8; 256];
        let n = idle.read(&mut answer).await.unwrap();
        assert!(
            answer[..n].starts_with(b"HTTP/1.1 200"),
            "{:?}",
            &answer[..n]
        );
        // A generous deadline against the 0.3 s the server allows: this is not a timing test.
        for (what, stream) in [
            ("silent", &mut silent),
            ("slow", &mut slow),
            ("idle", &mut idle),
        ] {
            assert!(
                closed_by_server(stream, Duration::from_secs(20)).await,
                "the {what} connection is still open"
            );
        }
        stop.send(true).unwrap();
        task.await.unwrap();
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn connections_over_the_cap_are_closed_at_once_and_admitted_again_when_others_close() {
        let caps = ConnectionCaps {
            first_request_timeout: Duration::from_secs(600),
            header_read_timeout: Duration::from_secs(600),
            ..small(4)
        };
        let (addr, stop, task) = serve_ok(caps).await;
        let mut held = Vec::new();
        for _ in 0..4 {
            held.push(TcpStream::connect(addr).await.unwrap());
        }
        // The fifth is closed without an answer (the server may still be accepting the first
        // four: retried until it is refused, within a generous deadline).
        let until = Instant::now() + Duration::from_secs(20);
        loop {
            let mut extra = TcpStream::connect(addr).await.unwrap();
            let _ = extra
                .write_all(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
                .await;
            let mut answer = [0_u8; 64];
            match tokio::time::timeout(Duration::from_secs(2), extra.read(&mut answer)).await {
                Ok(Ok(0)) | Ok(Err(_)) => break,
                _ => assert!(Instant::now() < until, "the fifth connection was served"),
            }
        }
        // Loopback is not capped per address (the cap of one would have refused the second).
        held.clear();
        let until = Instant::now() + Duration::from_secs(20);
        loop {
            let mut again = TcpStream::connect(addr).await.unwrap();
            again
                .write_all(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
                .await
                .unwrap();
            let mut answer = Vec::new();
            let _ =
                tokio::time::timeout(Duration::from_secs(2), again.read_to_end(&mut answer)).await;
            if answer.starts_with(b"HTTP/1.1 200") {
                break;
            }
            assert!(
                Instant::now() < until,
                "no connection admitted after the others closed"
            );
        }
        stop.send(true).unwrap();
        task.await.unwrap();
    }

    #[test]
    fn the_per_address_cap_counts_each_client_and_spares_loopback() {
        let guard = ConnectionGuard::new(ConnectionCaps {
            per_address: 2,
            total: 5,
            ..small(5)
        });
        let lab: IpAddr = "192.0.2.7".parse().unwrap();
        let other: IpAddr = "192.0.2.8".parse().unwrap();
        let a = guard.admit(lab).unwrap();
        let _b = guard.admit(lab).unwrap();
        assert!(guard.admit(lab).is_err(), "a third from one address");
        // The IPv4-mapped spelling of the same address is the same client.
        assert!(guard.admit("::ffff:192.0.2.7".parse().unwrap()).is_err());
        let _c = guard.admit(other).unwrap();
        let _d = guard.admit(IpAddr::from([127, 0, 0, 1])).unwrap();
        let _e = guard.admit(IpAddr::from([127, 0, 0, 1])).unwrap();
        assert!(guard.admit(other).is_err(), "over the total");
        drop(a);
        guard.admit(lab).unwrap();
    }
}
