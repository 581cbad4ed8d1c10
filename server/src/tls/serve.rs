//! Serving a router on the viewer's port, plainly or over TLS; on the TLS port, a client's first
//! byte decides: a TLS handshake goes on to rustls, anything else gets a plain-text `400` saying
//! to use https, and either has a bounded time to speak.

use std::future::Future;
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum_server::accept::Accept;
use axum_server::tls_rustls::{RustlsAcceptor, RustlsConfig};
use rustls::ServerConfig;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio::task::JoinHandle;

use super::{FIRST_REQUEST_TIMEOUT, HANDSHAKE_TIMEOUT};

/// The first byte of every TLS connection: the record type of a handshake (RFC 8446 §5.1).
const TLS_HANDSHAKE_RECORD: u8 = 0x16;

/// What a client that spoke plain HTTP to the TLS port reads (in a `400 Bad Request`) before it
/// is closed: a browser shows it in place of a bare "connection reset".
const PLAIN_TEXT_REFUSAL: &str =
    "This softhaptic server speaks TLS only: open it with https:// (and its stream with wss://).\n";

/// Serves `app` on `listener` until `shutdown` turns true (or its sender is dropped), then stops
/// accepting and lets open requests finish. Without `tls` it is plain http and ws, as
/// `axum::serve` serves; with it, https and wss on the same port (HTTP/1.1 and HTTP/2, WebSocket upgrades
/// over HTTP/1.1), a plain-text client refused as [`crate::tls`] says.
///
/// Requests carry [`axum::extract::ConnectInfo<SocketAddr>`] either way.
pub fn serve(
    listener: TcpListener,
    app: Router,
    tls: Option<Arc<ServerConfig>>,
    mut shutdown: watch::Receiver<bool>,
) -> JoinHandle<()> {
    let service = app.into_make_service_with_connect_info::<SocketAddr>();
    let Some(config) = tls else {
        return tokio::spawn(async move {
            let served = axum::serve(listener, service)
                .with_graceful_shutdown(async move {
                    let _ = shutdown.wait_for(|stop| *stop).await;
                })
                .await;
            if let Err(e) = served {
                tracing::error!(error = %e, "HTTP server failed");
            }
        });
    };
    let handle = axum_server::Handle::new();
    let acceptor = RustlsAcceptor::new(RustlsConfig::from_config(config))
        .handshake_timeout(HANDSHAKE_TIMEOUT)
        .acceptor(RefusePlainText);
    let server = axum_server::Server::from_listener(listener)
        .acceptor(acceptor)
        .handle(handle.clone())
        .first_request_timeout(FIRST_REQUEST_TIMEOUT)
        .accept_error_handler(log_refused_connection);
    tokio::spawn(async move {
        let served = server.serve(service);
        tokio::pin!(served);
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
            tracing::error!(error = %e, "HTTPS server failed");
        }
    })
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

/// One log line per connection that did not become a TLS connection; never an error, because a
/// client (or a port scanner) causes it, not the server.
fn log_refused_connection(client: Option<&SocketAddr>, error: &io::Error) {
    let Some(client) = client else {
        // The listener itself failed (out of file descriptors, say); axum-server backs off and
        // keeps accepting.
        tracing::warn!(error = %error, "could not accept a connection");
        return;
    };
    let inner = error.get_ref();
    if inner.is_some_and(|e| e.is::<PlainTextRefused>()) {
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
