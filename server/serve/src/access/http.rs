//! The HTTP side of the access rules: the Host guard every request passes ([`guard_host`]), the
//! bearer token of the session-data routes ([`require_token`]) and the JSON error they answer
//! with.

use std::net::SocketAddr;
use std::sync::Arc;

use axum::extract::connect_info::ConnectInfo;
use axum::extract::{Request, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use softhaptic_proto::wire::Role;

use super::origin::request_host;
use super::roles::{Action, may};
use super::{Access, REASON_BAD_TOKEN, REASON_NO_TOKEN};

/// The client's address of a request, when the server was started with connection info.
pub fn peer_of(request: &Request) -> Option<SocketAddr> {
    request
        .extensions()
        .get::<ConnectInfo<SocketAddr>>()
        .map(|c| c.0)
}

/// Middleware: a request whose `Host` is not one of the server's names is refused with 421
/// Misdirected Request (DNS rebinding: a page of another site that resolved its own name to
/// this address).
pub async fn guard_host(
    State(access): State<Arc<Access>>,
    request: Request,
    next: Next,
) -> Response {
    let host = request_host(request.headers())
        .or_else(|| request.uri().authority().map(|a| a.to_string()));
    match host {
        Some(host) if access.host_allowed(&host) => next.run(request).await,
        host => {
            if access.log_refusal("421 (Host not this server's)") {
                tracing::warn!(
                    client = %peer_of(&request).map_or_else(|| "unknown".to_owned(), |p| p.to_string()),
                    host = ?host.as_deref().unwrap_or("none"),
                    path = %request.uri().path(),
                    "request refused (421): the Host is not a name of this server; give it with --host-name if it is"
                );
            }
            json_error(
                StatusCode::MISDIRECTED_REQUEST,
                "this server is not reached by that host name",
            )
        }
    }
}

/// Middleware of the session-data routes: with tokens, `Authorization: Bearer <token>` of
/// either role, else 401 with `WWW-Authenticate: Bearer` (a wrong token answered after the wait
/// [`Access::token_failed`] says). The request goes on carrying its [`Role`] (an extension:
/// `Extension<Role>` in a handler), an instructor's on a server without tokens; a route that not
/// every role may use checks it with [`refusal`]. Every answer, given or refused, says
/// `Cache-Control: no-store`: session data is nobody's to keep (a shared browser's cache, a
/// proxy's).
pub async fn require_token(
    State(access): State<Arc<Access>>,
    request: Request,
    next: Next,
) -> Response {
    let mut response = check_token(&access, request, next).await;
    response
        .headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    response
}

async fn check_token(access: &Access, mut request: Request, next: Next) -> Response {
    let Some(tokens) = access.tokens() else {
        request.extensions_mut().insert(Role::Instructor);
        return next.run(request).await;
    };
    let presented = request
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| {
            let (scheme, token) = v.trim().split_once(' ')?;
            scheme.eq_ignore_ascii_case("bearer").then(|| token.trim())
        });
    let (reason, challenge) = match presented.map(|t| tokens.role_of(t)) {
        Some(Some(role)) => {
            request.extensions_mut().insert(role);
            return next.run(request).await;
        }
        Some(None) => (REASON_BAD_TOKEN, "Bearer error=\"invalid_token\""),
        None => (REASON_NO_TOKEN, "Bearer"),
    };
    let client = peer_of(&request);
    if access.log_refusal("401 (token)") {
        tracing::warn!(
            client = %client.map_or_else(|| "unknown".to_owned(), |p| p.to_string()),
            path = %request.uri().path(),
            "request refused (401): {reason}"
        );
    }
    if reason == REASON_BAD_TOKEN {
        tokio::time::sleep(access.token_failed(client.map(|c| c.ip()))).await;
    }
    let mut response = json_error(StatusCode::UNAUTHORIZED, reason);
    response.headers_mut().insert(
        header::WWW_AUTHENTICATE,
        HeaderValue::from_static(challenge),
    );
    response
}

/// `None` when `role` may do `action` ([`super::roles::may`]); else the 403 to answer, with the
/// role's refusal, logged with the client and what was asked (`what`).
pub fn refusal(
    role: Role,
    action: Action,
    client: Option<SocketAddr>,
    what: &str,
) -> Option<Response> {
    if may(role, action) {
        return None;
    }
    let reason = action.observer_refusal();
    tracing::warn!(
        client = %client.map_or_else(|| "unknown".to_owned(), |p| p.to_string()),
        role = role.as_str(),
        %what,
        "request refused (403): {reason}"
    );
    Some(json_error(StatusCode::FORBIDDEN, reason))
}

/// A JSON error response: `{"error": "<reason>"}`.
pub fn json_error(status: StatusCode, reason: &str) -> Response {
    let body = serde_json::json!({ "error": reason }).to_string();
    (status, [(header::CONTENT_TYPE, "application/json")], body).into_response()
}
