//! The HTTP side the live server, the replay server and the lab's hub share: the routes of
//! proto/WIRE.md over a [`StreamHub`] (the viewer's files, the scene, the meshes, the WebSocket),
//! serving them over plain TCP or TLS within the connection caps, a viewer's WebSocket upgrade
//! behind the access rules, the server's name in `hello`, and how long a shutdown waits for the
//! viewers to close.
//!
//! Every route passes the access rules of [`crate::access`]: the Host rule on every request,
//! the security headers on every response, a bearer token on the session data (`/api/scene`,
//! `/meshes/*`) when the server has tokens, and at the WebSocket upgrade the Origin rule and the
//! connection limits.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::body::Bytes;
use axum::extract::connect_info::ConnectInfo;
use axum::extract::ws::WebSocketUpgrade;
use axum::extract::{Path as UrlPath, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use tokio::sync::watch;
use tokio::task::JoinHandle;

use crate::access::{self, Connection};
use crate::stream::{self, StreamHub, ViewerEnd};
use crate::viewer::Viewer;

/// How long a shutdown waits for the viewers' connections to close.
pub const VIEWERS_CLOSE_WAIT: Duration = Duration::from_secs(3);

/// The server's name in `hello`.
pub const SERVER_NAME: &str = concat!("softhaptic ", env!("CARGO_PKG_VERSION"));

/// HTTP state: the pre-encoded scene and meshes, and the stream hub.
#[derive(Clone)]
struct AppState {
    scene_json: Bytes,
    meshes: Arc<HashMap<String, Bytes>>,
    hub: Arc<StreamHub>,
}

/// Serves `app` on `listener` until `shutdown` turns true, then lets open requests finish; the
/// live server, the replay server and the hub all run their HTTP side this way, over TLS when
/// `tls` is given, holding at most `caps` connections open ([`crate::tls::serve`]). Each request
/// carries its client's address (`ConnectInfo<SocketAddr>`): the per-address limit and the audit
/// and refusal log lines use it.
pub fn serve_http(
    listener: tokio::net::TcpListener,
    app: Router,
    tls: Option<Arc<rustls::ServerConfig>>,
    caps: crate::tls::ConnectionCaps,
    shutdown: watch::Receiver<bool>,
) -> JoinHandle<()> {
    // Every connection the caps allow must fit under the open-file limit, or the ones past it
    // fail at accept instead of being refused.
    crate::tls::ensure_open_file_limit(&caps);
    crate::tls::serve(listener, app, tls, caps, shutdown)
}

/// The routes of proto/WIRE.md over a stream hub: the live server's (frames from the haptic loop)
/// and a recording's replay's.
pub fn viewer_router(
    viewer: &Viewer,
    scene_json: Bytes,
    meshes: impl Into<Arc<HashMap<String, Bytes>>>,
    hub: Arc<StreamHub>,
) -> Router {
    router(
        viewer,
        AppState {
            scene_json,
            meshes: meshes.into(),
            hub,
        },
    )
}

/// The routes of proto/WIRE.md, behind the access rules of the hub's [`Access`].
fn router(viewer: &Viewer, state: AppState) -> Router {
    let access = Arc::clone(&state.hub.access);
    // The session's data needs a token (when the server has tokens); the viewer's files do not.
    let session_data = Router::new()
        .route("/api/scene", get(api_scene))
        .route("/meshes/{file}", get(mesh))
        .route_layer(axum::middleware::from_fn_with_state(
            Arc::clone(&access),
            access::require_token,
        ));
    // The viewer's own files need no token.
    let routes = viewer
        .routes()
        .merge(session_data)
        .route("/ws", get(ws))
        .route("/api/stations", get(not_a_hub))
        .with_state(state)
        .layer(axum::middleware::from_fn_with_state(
            Arc::clone(&access),
            access::guard_host,
        ));
    // Outermost, so that refusals (421, 401, 403) carry the headers too.
    access::with_security_headers(routes, access.csp().clone(), access.config.strict_transport)
}

/// `/api/stations` of a station: it is not a lab hub (a lab's hub answers it with its stations).
async fn not_a_hub() -> Response {
    (
        [(header::CONTENT_TYPE, "application/json")],
        r#"{"hub":false,"stations":[]}"#,
    )
        .into_response()
}

async fn api_scene(State(state): State<AppState>) -> Response {
    (
        [(header::CONTENT_TYPE, "application/json")],
        state.scene_json.clone(),
    )
        .into_response()
}

async fn mesh(State(state): State<AppState>, UrlPath(file): UrlPath<String>) -> Response {
    let found = file
        .strip_suffix(".bin")
        .and_then(|name| state.meshes.get(name));
    match found {
        Some(bytes) => (
            [(header::CONTENT_TYPE, "application/octet-stream")],
            bytes.clone(),
        )
            .into_response(),
        None => (StatusCode::NOT_FOUND, format!("no render mesh {file:?}")).into_response(),
    }
}

/// The WebSocket upgrade: the Origin rule (403 before upgrading), the connection limits (4429
/// right after it, so a browser can tell the viewer why), then the viewer's stream; one audit
/// line when the connection ends.
async fn ws(
    State(state): State<AppState>,
    connect_info: Option<axum::Extension<ConnectInfo<SocketAddr>>>,
    headers: HeaderMap,
    upgrade: WebSocketUpgrade,
) -> Response {
    upgrade_viewer(
        state.hub,
        connect_info.map(|info| info.0.0),
        &headers,
        upgrade,
    )
}

/// A viewer's WebSocket on `hub`: the Origin rule, the connection limits, then the stream.
pub(crate) fn upgrade_viewer(
    hub: Arc<StreamHub>,
    peer: Option<SocketAddr>,
    headers: &HeaderMap,
    upgrade: WebSocketUpgrade,
) -> Response {
    let origin = match hub.access.check_origin(headers) {
        Ok(origin) => origin,
        Err(reason) => {
            if hub.access.log_refusal("403 (Origin)") {
                tracing::warn!(
                    client = %peer.map_or_else(|| "unknown".to_owned(), |p| p.to_string()),
                    "WebSocket upgrade refused (403): {reason}"
                );
            }
            return access::json_error(StatusCode::FORBIDDEN, "origin not allowed");
        }
    };
    let admission = hub.access.admit(peer.map(|p| p.ip()));
    let limits = hub.limits;
    limits.bound(upgrade).on_upgrade(move |socket| async move {
        match admission {
            Ok(admission) => {
                let mut connection = Connection::new(&hub.access, peer, origin, Some(admission));
                let end = stream::serve_viewer(socket, hub, &mut connection).await;
                connection.finish(&end);
            }
            Err(refusal) => {
                stream::refuse_connection(socket, &hub, refusal).await;
                Connection::new(&hub.access, peer, origin, None).finish(&ViewerEnd::Limit(refusal));
            }
        }
    })
}
