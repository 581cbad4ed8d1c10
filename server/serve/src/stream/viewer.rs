//! One viewer's connection task: its role first (an `auth` within the auth timeout when the
//! server has tokens), then `hello`, `scene`, the marks so far and every frame, stats and mark,
//! while it answers what the viewer sends; every send has a deadline, and every close reads
//! until the peer's close frame so that the peer learns its close code.
//!
//! At the server's shutdown a viewer first sends what is already queued for it on the stats
//! and marks channels (for [`SHUTDOWN_DRAIN`] at most): the session's final `metrics`, sent
//! just before the shutdown, are the last thing a viewer is told before the close.
//!
//! # Why one file
//! About 750 lines, all of them one connection's life in the order it happens (role, greeting,
//! stream, what the viewer sends, refusals, close) and how it ended ([`ViewerEnd`]). Every step shares the connection's
//! deadlines and its close rule; split into files, a reader checking that no path skips the
//! send deadline or the close handshake would have to follow the socket across them.

use std::fmt;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use axum::extract::ws::{CloseFrame, Message, Utf8Bytes, WebSocket, close_code};
use softhaptic_proto::wire::{
    Auth, ExerciseControl, MarkRequest, Refused, ReplayControl, Role, ServerMessage, message_type,
};
use tokio::sync::{broadcast, watch};

use super::{ControlRefusal, StreamCounters, StreamHub, ViewerLimits};
use crate::access::roles::{Action, may};
use crate::access::{
    Access, CLOSE_UNAUTHORIZED, Connection, LimitRefusal, MessageRate, REASON_BAD_TOKEN,
    REASON_NO_TOKEN, Tokens,
};

/// Counts a viewer for as long as its connection task lives.
struct ViewerGuard<'a>(&'a StreamCounters);

impl<'a> ViewerGuard<'a> {
    fn new(counters: &'a StreamCounters) -> Self {
        counters.viewers.fetch_add(1, Ordering::Relaxed);
        Self(counters)
    }
}

impl Drop for ViewerGuard<'_> {
    fn drop(&mut self) {
        self.0.viewers.fetch_sub(1, Ordering::Relaxed);
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ViewerEnd {
    Closed,
    /// The connection ended without WebSocket's closing handshake: a reset, an end of the
    /// stream without a close frame, or another failure of the link (a tab killed, a laptop
    /// closed, a network gone). Nothing is sent back: nobody is there to read it.
    Lost,
    /// A message that broke WebSocket's rules or the size limit, a binary message, or a text
    /// message that is not one of the wire's.
    Malformed,
    SendFailed,
    Shutdown,
    /// No `auth` with a token within the auth timeout, or a first message that was not one
    /// (4401).
    NoToken,
    /// A token that is neither role's (4401).
    BadToken,
    /// More messages than the connection's rate allows (1008).
    Flooded,
    /// Refused at the upgrade by a limit on connections (4429).
    Limit(LimitRefusal),
    /// Authenticated, but the stream it named cannot be served (a lab hub's station or
    /// recording that is not there): closed with this code and reason.
    Unavailable {
        code: u16,
        reason: &'static str,
    },
}

impl fmt::Display for ViewerEnd {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ViewerEnd::Closed => f.write_str("closed by the viewer"),
            ViewerEnd::Lost => f.write_str("connection lost (no close frame)"),
            ViewerEnd::Malformed => f.write_str("closed: malformed or oversized message"),
            ViewerEnd::SendFailed => {
                f.write_str("closed: the viewer stopped reading or the link failed")
            }
            ViewerEnd::Shutdown => f.write_str("closed: server shutting down (1001)"),
            ViewerEnd::NoToken => write!(f, "refused: {REASON_NO_TOKEN} ({CLOSE_UNAUTHORIZED})"),
            ViewerEnd::BadToken => write!(f, "refused: {REASON_BAD_TOKEN} ({CLOSE_UNAUTHORIZED})"),
            ViewerEnd::Flooded => write!(f, "closed: {REASON_FLOOD} (1008)"),
            ViewerEnd::Unavailable { code, reason } => write!(f, "refused: {reason} ({code})"),
            ViewerEnd::Limit(refusal) => {
                write!(
                    f,
                    "refused: {} ({})",
                    refusal.reason(),
                    crate::access::CLOSE_TOO_MANY
                )
            }
        }
    }
}

/// The close reason of a connection that sent more messages than its rate allows.
pub const REASON_FLOOD: &str = "too many messages";
/// The `refused` reason of a `replay_control` from an observer.
pub const REFUSED_OBSERVER: &str = Action::ControlReplay.observer_refusal();
/// The `refused` reason of an `add_mark` from an observer.
pub const REFUSED_MARK_OBSERVER: &str = Action::Mark.observer_refusal();
/// The `refused` reason of an `add_mark` sent to a replay.
pub const REFUSED_MARK_REPLAY: &str = "a replay's marks are the recording's: mark a live session";
/// The `refused` reason of an `add_mark` sent to a stream that takes none (a lab hub's relay of
/// a station: it can neither stamp a mark with the station's time nor record it).
pub const REFUSED_MARK_HUB: &str =
    "marks are not taken through the lab hub: mark the session on its station's own page";
/// The `refused` reason of an `add_mark` once the session has all the marks it keeps.
pub const REFUSED_MARKS_FULL: &str = "this session has all the marks it can keep (1000)";
/// The `refused` reason of an `exercise_control` from an observer.
pub const REFUSED_EXERCISE_OBSERVER: &str = Action::ControlExercise.observer_refusal();
/// The `refused` reason of an `exercise_control` where no exercises run (a session started
/// without `--exercises`, a replay, a lab hub's relay).
pub const REFUSED_EXERCISE_NONE: &str =
    "no exercises run here: a station runs them when started with --exercises";
/// The `refused` reason of an `exercise_control` sent faster than the station takes them.
pub const REFUSED_EXERCISE_BUSY: &str = "the station is still taking the previous control";
/// The `refused` reason of a `rearm_device` from an observer.
pub const REFUSED_REARM_OBSERVER: &str = Action::RearmDevice.observer_refusal();
/// The `refused` reason of a `rearm_device` where there is no device to re-arm (a replay, a lab
/// hub's relay, a device whose force output cannot latch off).
pub const REFUSED_REARM_NONE: &str =
    "there is no haptic device here whose force output can be re-armed";
/// The `refused` reason of a `replay_control` sent to a live session.
pub const REFUSED_LIVE: &str = "this is a live session: there is no replay to control";

/// Serves one viewer: its role (see [`crate::stream`]), `hello` and `scene`, then every contact
/// frame and stats message, until the viewer leaves, misbehaves, stops reading, or the server
/// shuts down. `connection` learns the role, for the audit line its owner logs.
pub async fn serve_viewer(
    mut socket: WebSocket,
    hub: Arc<StreamHub>,
    connection: &mut Connection,
) -> ViewerEnd {
    let mut rate = MessageRate::new(&hub.access.config.limits, Instant::now());
    let client = connection.peer.map(|p| p.ip());
    let role = match role_of(&mut socket, &hub.gate(), &mut rate, client).await {
        Ok(role) => role,
        Err(end) => return end,
    };
    serve_role(socket, hub, connection, role, rate).await
}

/// What a connection needs before it has a stream: the access rules, its limits, the server's
/// shutdown, and the counters its refusals go to.
struct Gate<'a> {
    access: &'a Access,
    limits: ViewerLimits,
    shutdown: &'a watch::Receiver<bool>,
    counters: &'a StreamCounters,
}

impl StreamHub {
    fn gate(&self) -> Gate<'_> {
        Gate {
            access: &self.access,
            limits: self.limits,
            shutdown: &self.shutdown,
            counters: &self.counters,
        }
    }
}

impl Access {
    /// Serves a viewer whose stream is found only once the viewer has its role: the lab hub's,
    /// which looks up the station or the recording a viewer names for a viewer with a valid
    /// token only (a client without one learns nothing of what exists, and makes the hub fetch
    /// nothing). With tokens the `auth` comes first, as for [`serve_viewer`], and its refusals
    /// count in `counters`; then `find` gives the stream for the viewer's role, or the close code and reason of a
    /// stream that cannot be served (closed with them), and the viewer is served as
    /// [`serve_viewer`] serves one.
    pub async fn serve_viewer_found_after_auth<F, Fut>(
        &self,
        mut socket: WebSocket,
        limits: ViewerLimits,
        shutdown: &watch::Receiver<bool>,
        counters: &StreamCounters,
        connection: &mut Connection,
        find: F,
    ) -> ViewerEnd
    where
        F: FnOnce(Role) -> Fut,
        Fut: Future<Output = Result<Arc<StreamHub>, (u16, &'static str)>>,
    {
        let (role, rate) = match self
            .role_and_rate(&mut socket, limits, shutdown, counters, connection)
            .await
        {
            Ok(found) => found,
            Err(end) => return end,
        };
        match find(role).await {
            Ok(hub) => serve_role(socket, hub, connection, role, rate).await,
            Err((code, reason)) => {
                connection.authenticated(role);
                close(&mut socket, code, reason, limits.send_timeout).await;
                ViewerEnd::Unavailable { code, reason }
            }
        }
    }

    /// Serves a connection that is not a viewer of a stream (a lab hub's dashboard page) behind
    /// the same token exchange as a viewer: with tokens the `auth` comes first and its refusals
    /// count in `counters`; then `serve` has the socket, the role and the connection's message
    /// rate.
    pub async fn serve_after_auth<F, Fut>(
        &self,
        mut socket: WebSocket,
        limits: ViewerLimits,
        shutdown: &watch::Receiver<bool>,
        counters: &StreamCounters,
        connection: &mut Connection,
        serve: F,
    ) -> ViewerEnd
    where
        F: FnOnce(WebSocket, Role, MessageRate) -> Fut,
        Fut: Future<Output = ViewerEnd>,
    {
        let (role, rate) = match self
            .role_and_rate(&mut socket, limits, shutdown, counters, connection)
            .await
        {
            Ok(found) => found,
            Err(end) => return end,
        };
        connection.authenticated(role);
        serve(socket, role, rate).await
    }

    /// The role of a connection that has no stream yet (after the `auth` exchange when there are
    /// tokens) and its message rate, which the exchange has already drawn on.
    async fn role_and_rate(
        &self,
        socket: &mut WebSocket,
        limits: ViewerLimits,
        shutdown: &watch::Receiver<bool>,
        counters: &StreamCounters,
        connection: &Connection,
    ) -> Result<(Role, MessageRate), ViewerEnd> {
        let gate = Gate {
            access: self,
            limits,
            shutdown,
            counters,
        };
        let mut rate = MessageRate::new(&self.config.limits, Instant::now());
        let client = connection.peer.map(|p| p.ip());
        let role = role_of(socket, &gate, &mut rate, client).await?;
        Ok((role, rate))
    }

    /// Closes a connection refused by a limit on connections before it has a stream, with 4429
    /// and the limit's reason, counted in `counters`.
    pub async fn refuse_viewer(
        &self,
        mut socket: WebSocket,
        refusal: LimitRefusal,
        limits: ViewerLimits,
        counters: &StreamCounters,
    ) {
        counters.limit_refusals.fetch_add(1, Ordering::Relaxed);
        close(
            &mut socket,
            crate::access::CLOSE_TOO_MANY,
            refusal.reason(),
            limits.send_timeout,
        )
        .await;
    }
}

/// The connection's role: an instructor without tokens, else the role of the token its `auth`
/// presents (a wrong one from `client` answered after the wait [`Access::token_failed`] says).
async fn role_of(
    socket: &mut WebSocket,
    gate: &Gate<'_>,
    rate: &mut MessageRate,
    client: Option<std::net::IpAddr>,
) -> Result<Role, ViewerEnd> {
    match gate.access.tokens() {
        None => Ok(Role::Instructor),
        Some(tokens) => authenticate(socket, gate, tokens, rate, client).await,
    }
}

/// Serves a connection that has its `role`: `hello`, `scene`, then the stream.
async fn serve_role(
    mut socket: WebSocket,
    hub: Arc<StreamHub>,
    connection: &mut Connection,
    role: Role,
    mut rate: MessageRate,
) -> ViewerEnd {
    let timeout = hub.limits.send_timeout;
    connection.authenticated(role);
    let _guard = ViewerGuard::new(&hub.counters);
    // Subscribe before sending the greeting, so no frame produced meanwhile is missed.
    let mut frames = hub.frames.subscribe();
    let mut stats = hub.stats.subscribe();
    let mut marks = hub.marks.subscribe();
    let mut exercise = hub.exercise.messages.subscribe();
    let mut shutdown = hub.shutdown.clone();
    // The inclusions' positions before an attempt's end: only to a role that may see them, and
    // never without tokens, where everyone is an instructor and the trainee's screen is one of
    // them. An observer's task holds no receiver of them at all.
    let sees_answer = may(role, Action::SeeInclusions) && hub.access.tokens().is_some();
    let mut hidden_inclusions = sees_answer.then(|| hub.inclusions.hidden());
    let mut public_inclusions = hub.inclusions.public();

    for greeting in [hub.hello(role), &hub.scene] {
        if !send(
            &mut socket,
            Message::Text(greeting.clone()),
            timeout,
            &hub.counters,
        )
        .await
        {
            return ViewerEnd::SendFailed;
        }
    }
    // The marks made before this viewer came (a mark made meanwhile is also queued: sent twice,
    // which its id makes harmless).
    for mark in hub.made_marks() {
        if !send(&mut socket, Message::Text(mark), timeout, &hub.counters).await {
            return ViewerEnd::SendFailed;
        }
    }
    // Where the station's exercise stands (a newer message already queued is sent after it).
    if let Some(latest) = hub.exercise.latest()
        && !send(&mut socket, Message::Text(latest), timeout, &hub.counters).await
    {
        return ViewerEnd::SendFailed;
    }
    // Where the inclusions are, if this viewer may be told now.
    let mut now = Vec::new();
    if let Some(hidden) = hidden_inclusions.as_mut() {
        now.extend(hidden.borrow_and_update().clone());
    }
    now.extend(public_inclusions.borrow_and_update().clone());
    // Whether this viewer, told no positions before the end, holds a revealed answer: when the
    // answer is withdrawn (a replay sought back before the end, a new attempt) it is told so.
    let mut told_answer = hidden_inclusions.is_none() && !now.is_empty();
    for text in now {
        if !send(&mut socket, Message::Text(text), timeout, &hub.counters).await {
            return ViewerEnd::SendFailed;
        }
    }
    // A replay's current frame, unless a newer one is already queued for this viewer.
    if frames.is_empty()
        && let Some(held) = hub.held_frame()
        && !send(
            &mut socket,
            Message::Text(held.text_for(0)),
            timeout,
            &hub.counters,
        )
        .await
    {
        return ViewerEnd::SendFailed;
    }

    let mut dropped: u64 = 0;
    loop {
        if *shutdown.borrow() {
            drain_queued(
                &mut socket,
                [&mut marks, &mut exercise, &mut stats],
                &hub.counters,
                timeout,
            )
            .await;
            close(
                &mut socket,
                close_code::AWAY,
                "server shutting down",
                timeout,
            )
            .await;
            return ViewerEnd::Shutdown;
        }
        tokio::select! {
            changed = shutdown.changed() => {
                // An error means the server was dropped without an orderly shutdown: leave too.
                if changed.is_err() {
                    drain_queued(&mut socket, [&mut marks, &mut exercise, &mut stats], &hub.counters, timeout).await;
                    close(&mut socket, close_code::AWAY, "server shutting down", timeout).await;
                    return ViewerEnd::Shutdown;
                }
            }
            incoming = socket.recv() => {
                if let Some(end) =
                    handle_incoming(&mut socket, &hub, connection, role, &mut rate, incoming).await
                {
                    return end;
                }
            }
            frame = frames.recv() => {
                let frame = match frame {
                    Ok(frame) => frame,
                    Err(broadcast::error::RecvError::Lagged(lost)) => {
                        // Fell FRAME_BACKLOG behind: skip to the newest frame.
                        let mut lost = lost;
                        let mut newest = None;
                        loop {
                            match frames.try_recv() {
                                Ok(f) => {
                                    if newest.replace(f).is_some() {
                                        lost += 1;
                                    }
                                }
                                Err(broadcast::error::TryRecvError::Lagged(n)) => lost += n,
                                Err(_) => break,
                            }
                        }
                        dropped += lost;
                        hub.counters.dropped_frames.fetch_add(lost, Ordering::Relaxed);
                        match newest {
                            Some(f) => f,
                            None => continue,
                        }
                    }
                    Err(broadcast::error::RecvError::Closed) => return ViewerEnd::Shutdown,
                };
                if !send(&mut socket, Message::Text(frame.text_for(dropped)), timeout, &hub.counters).await {
                    return ViewerEnd::SendFailed;
                }
            },
            text = stats.recv() => {
                if let Ok(text) = text
                    && !send(&mut socket, Message::Text(text), timeout, &hub.counters).await
                {
                    return ViewerEnd::SendFailed;
                }
            },
            mark = marks.recv() => {
                if let Ok(text) = mark
                    && !send(&mut socket, Message::Text(text), timeout, &hub.counters).await
                {
                    return ViewerEnd::SendFailed;
                }
            },
            text = exercise.recv() => {
                if let Ok(text) = text
                    && !send(&mut socket, Message::Text(text), timeout, &hub.counters).await
                {
                    return ViewerEnd::SendFailed;
                }
            },
            text = changed_text(hidden_inclusions.as_mut()) => {
                if let Some(text) = text
                    && !send(&mut socket, Message::Text(text), timeout, &hub.counters).await
                {
                    return ViewerEnd::SendFailed;
                }
            },
            text = changed_text(Some(&mut public_inclusions)) => {
                let text = match text {
                    Some(text) => {
                        told_answer = hidden_inclusions.is_none();
                        text
                    }
                    // An instructor told the answer before the end is told again with the
                    // attempt's hidden message; anyone else, once told, is told it is withdrawn.
                    None if std::mem::take(&mut told_answer) => withdrawn_inclusions(),
                    None => continue,
                };
                if !send(&mut socket, Message::Text(text), timeout, &hub.counters).await {
                    return ViewerEnd::SendFailed;
                }
            },
        }
    }
}

/// The `inclusions` message that withdraws a revealed answer: no positions, not revealed, no
/// attempt (proto/WIRE.md, `inclusions`).
fn withdrawn_inclusions() -> Utf8Bytes {
    Utf8Bytes::from_static(
        r#"{"type":"inclusions","revealed":false,"exercise_index":null,"attempt":null,"inclusions":[]}"#,
    )
}

/// The next value `receiver` holds once it changes (`None` when it was cleared); never ready
/// without a receiver, or once its sender is gone.
async fn changed_text(
    receiver: Option<&mut watch::Receiver<Option<Utf8Bytes>>>,
) -> Option<Utf8Bytes> {
    let Some(r) = receiver else {
        return std::future::pending().await;
    };
    if r.changed().await.is_err() {
        return std::future::pending().await;
    }
    r.borrow_and_update().clone()
}

/// Longest a closing viewer spends sending what was queued for it before the shutdown.
const SHUTDOWN_DRAIN: Duration = Duration::from_secs(1);

/// Sends the marks, exercise messages, stats and metrics already queued for this viewer (the session's final
/// `metrics` among them), in the order each channel received them, for at most
/// [`SHUTDOWN_DRAIN`]: the shutdown flag and the last messages arrive together, and the
/// viewer's `select!` may see the flag first. A viewer that stopped reading costs the drain's
/// bound, no more; one that lagged gets the newest (the channels keep those).
async fn drain_queued(
    socket: &mut WebSocket,
    channels: [&mut broadcast::Receiver<Utf8Bytes>; 3],
    counters: &StreamCounters,
    timeout: Duration,
) {
    let drain = async {
        for channel in channels {
            loop {
                let text = match channel.try_recv() {
                    Ok(text) => text,
                    Err(broadcast::error::TryRecvError::Lagged(_)) => continue,
                    Err(_) => break,
                };
                if !send(socket, Message::Text(text), timeout, counters).await {
                    return;
                }
            }
        }
    };
    let _ = tokio::time::timeout(SHUTDOWN_DRAIN, drain).await;
}

/// Waits for the connection's `auth` (nothing is sent before it): the role of its token, or
/// the connection closed with 4401 (no valid `auth` first, or none within the auth timeout).
async fn authenticate(
    socket: &mut WebSocket,
    gate: &Gate<'_>,
    tokens: &Tokens,
    rate: &mut MessageRate,
    client: Option<std::net::IpAddr>,
) -> Result<Role, ViewerEnd> {
    let timeout = gate.limits.send_timeout;
    let deadline = tokio::time::Instant::now() + gate.access.config.limits.auth_timeout;
    let mut shutdown = gate.shutdown.clone();
    loop {
        if *shutdown.borrow() {
            close(socket, close_code::AWAY, "server shutting down", timeout).await;
            return Err(ViewerEnd::Shutdown);
        }
        let incoming = tokio::select! {
            _ = shutdown.changed() => continue,
            incoming = tokio::time::timeout_at(deadline, socket.recv()) => incoming,
        };
        let message = match incoming {
            Err(_) => {
                gate.counters
                    .unauthorized_closes
                    .fetch_add(1, Ordering::Relaxed);
                close(socket, CLOSE_UNAUTHORIZED, REASON_NO_TOKEN, timeout).await;
                return Err(ViewerEnd::NoToken);
            }
            Ok(None | Some(Ok(Message::Close(_)))) => return Err(ViewerEnd::Closed),
            Ok(Some(Err(e))) => {
                tracing::debug!(error = %e, "viewer connection failed before presenting a token");
                return Err(receive_failed(socket, gate, &e).await);
            }
            Ok(Some(Ok(message))) => message,
        };
        if !rate.allow(Instant::now()) {
            return Err(flooded(socket, gate).await);
        }
        match message {
            Message::Ping(_) | Message::Pong(_) => continue,
            Message::Binary(_) => {
                return Err(malformed(socket, gate, close_code::UNSUPPORTED, BINARY_REFUSED).await);
            }
            Message::Close(_) => return Err(ViewerEnd::Closed),
            Message::Text(text) => {
                // Anything but an `auth` with a string token is no token presented.
                let role = serde_json::from_str::<Auth>(&text)
                    .ok()
                    .map(|auth| tokens.role_of(&auth.token));
                let (reason, end) = match role {
                    Some(Some(role)) => return Ok(role),
                    Some(None) => (REASON_BAD_TOKEN, ViewerEnd::BadToken),
                    None => (REASON_NO_TOKEN, ViewerEnd::NoToken),
                };
                if end == ViewerEnd::BadToken {
                    // Slowed, but never past the server's shutdown.
                    let wait = tokio::time::sleep(gate.access.token_failed(client));
                    tokio::select! {
                        () = wait => {}
                        _ = shutdown.changed() => {}
                    }
                }
                gate.counters
                    .unauthorized_closes
                    .fetch_add(1, Ordering::Relaxed);
                close(socket, CLOSE_UNAUTHORIZED, reason, timeout).await;
                return Err(end);
            }
        }
    }
}

/// Close reason of a connection that sent a binary message.
const BINARY_REFUSED: &str = "binary messages are not accepted";
/// Close reason of a connection whose message broke the WebSocket protocol or its size limit.
const INVALID_REFUSED: &str = "invalid or oversized message";

/// Closes a connection that sent what the protocol does not accept (a binary message, a message
/// that breaks WebSocket's rules or the size limit), with `code` and `reason`.
async fn malformed(
    socket: &mut WebSocket,
    gate: &Gate<'_>,
    code: u16,
    reason: &'static str,
) -> ViewerEnd {
    gate.counters
        .malformed_closes
        .fetch_add(1, Ordering::Relaxed);
    close(socket, code, reason, gate.limits.send_timeout).await;
    ViewerEnd::Malformed
}

/// Ends a connection whose receive failed: a link that went away is [`ViewerEnd::Lost`] (and
/// nothing is sent to it); a protocol violation or an oversized message is closed as malformed
/// (1009).
async fn receive_failed(socket: &mut WebSocket, gate: &Gate<'_>, error: &axum::Error) -> ViewerEnd {
    if is_connection_lost(error) {
        return ViewerEnd::Lost;
    }
    malformed(socket, gate, close_code::SIZE, INVALID_REFUSED).await
}

/// Whether a receive error is the link going away (a reset, an end of the stream without a close
/// frame, any I/O error) rather than the peer breaking WebSocket's rules or the size limit.
///
/// The error inside is tungstenite's, which this crate does not depend on by name (axum wraps
/// it): its variants without a source are told apart by their `Debug` form, which the unit test
/// below pins to the tungstenite this is built with.
fn is_connection_lost(error: &axum::Error) -> bool {
    use std::error::Error as _;
    let Some(inner) = error.source() else {
        return false;
    };
    if matches!(
        format!("{inner:?}").as_str(),
        "ConnectionClosed" | "AlreadyClosed" | "Protocol(ResetWithoutClosingHandshake)"
    ) {
        return true;
    }
    let mut cause = Some(inner);
    while let Some(e) = cause {
        if e.is::<std::io::Error>() {
            return true;
        }
        cause = e.source();
    }
    false
}

/// Closes a connection that sent more than its rate allows.
async fn flooded(socket: &mut WebSocket, gate: &Gate<'_>) -> ViewerEnd {
    gate.counters.flood_closes.fetch_add(1, Ordering::Relaxed);
    close(
        socket,
        close_code::POLICY,
        REASON_FLOOD,
        gate.limits.send_timeout,
    )
    .await;
    ViewerEnd::Flooded
}

/// Handles one incoming message of a connection that has its `role`; `Some` when the
/// connection ends.
async fn handle_incoming(
    socket: &mut WebSocket,
    hub: &StreamHub,
    connection: &Connection,
    role: Role,
    rate: &mut MessageRate,
    incoming: Option<Result<Message, axum::Error>>,
) -> Option<ViewerEnd> {
    let timeout = hub.limits.send_timeout;
    let message = match incoming {
        None | Some(Ok(Message::Close(_))) => return Some(ViewerEnd::Closed),
        Some(Err(e)) => {
            tracing::debug!(error = %e, "viewer connection failed");
            return Some(receive_failed(socket, &hub.gate(), &e).await);
        }
        Some(Ok(message)) => message,
    };
    if !rate.allow(Instant::now()) {
        return Some(flooded(socket, &hub.gate()).await);
    }
    let text = match message {
        Message::Text(text) => text,
        Message::Binary(_) => {
            return Some(
                malformed(socket, &hub.gate(), close_code::UNSUPPORTED, BINARY_REFUSED).await,
            );
        }
        // Pings are answered by the WebSocket layer.
        Message::Ping(_) | Message::Pong(_) | Message::Close(_) => return None,
    };
    match message_type(&text) {
        Ok(kind) if kind == "replay_control" => {
            let tx = match &hub.replay_control {
                None => return refuse(socket, hub, connection, &kind, REFUSED_LIVE).await,
                Some(_) if !may(role, Action::ControlReplay) => {
                    return refuse(socket, hub, connection, &kind, REFUSED_OBSERVER).await;
                }
                Some(tx) => tx,
            };
            let control = serde_json::from_str::<ReplayControl>(&text)
                .map_err(|e| e.to_string())
                .and_then(|c| c.validate().map(|()| c).map_err(|e| e.to_string()));
            match control {
                // A full queue means controls arrive faster than they matter.
                Ok(c) => {
                    let _ = tx.try_send(c);
                }
                Err(reason) => {
                    tracing::debug!(reason, "invalid replay_control message");
                    hub.counters
                        .malformed_closes
                        .fetch_add(1, Ordering::Relaxed);
                    close(
                        socket,
                        close_code::INVALID,
                        "invalid replay_control message",
                        timeout,
                    )
                    .await;
                    return Some(ViewerEnd::Malformed);
                }
            }
        }
        Ok(kind) if kind == "add_mark" => {
            if hub.replay_control.is_some() {
                return refuse(socket, hub, connection, &kind, REFUSED_MARK_REPLAY).await;
            }
            if !hub.accepts_marks {
                return refuse(socket, hub, connection, &kind, REFUSED_MARK_HUB).await;
            }
            if !may(role, Action::Mark) {
                return refuse(socket, hub, connection, &kind, REFUSED_MARK_OBSERVER).await;
            }
            let request = serde_json::from_str::<MarkRequest>(&text).map_err(|e| e.to_string());
            match request.and_then(|r| r.problem().map_or(Ok(r), Err)) {
                Ok(r) => match hub.add_mark(r) {
                    Ok(m) => tracing::info!(id = m.id, time_ns = m.time_ns, "instructor mark"),
                    Err(super::AddMarkError::Full) => {
                        return refuse(socket, hub, connection, &kind, REFUSED_MARKS_FULL).await;
                    }
                    Err(e) => tracing::error!(error = %e, "could not make a mark"),
                },
                Err(reason) => return refuse(socket, hub, connection, &kind, &reason).await,
            }
        }
        Ok(kind) if kind == "rearm_device" => {
            if !may(role, Action::RearmDevice) {
                return refuse(socket, hub, connection, &kind, REFUSED_REARM_OBSERVER).await;
            }
            if !hub.rearm_device() {
                return refuse(socket, hub, connection, &kind, REFUSED_REARM_NONE).await;
            }
            // The audit line: who re-armed the force output of a device that tripped.
            tracing::warn!(
                client = %connection.peer.map_or_else(|| "unknown".to_owned(), |p| p.to_string()),
                role = role.as_str(),
                "an instructor re-armed the haptic device's force output"
            );
        }
        Ok(kind) if kind == "exercise_control" => {
            if !hub.exercise.takes_controls() {
                return refuse(socket, hub, connection, &kind, REFUSED_EXERCISE_NONE).await;
            }
            if !may(role, Action::ControlExercise) {
                return refuse(socket, hub, connection, &kind, REFUSED_EXERCISE_OBSERVER).await;
            }
            let control = match serde_json::from_str::<ExerciseControl>(&text) {
                Ok(c) => c,
                Err(e) => return refuse(socket, hub, connection, &kind, &e.to_string()).await,
            };
            match hub.exercise.control(control.action) {
                // The audit line: who moved the trainee's exercises on, and how.
                Ok(()) => tracing::warn!(
                    client = %connection.peer.map_or_else(|| "unknown".to_owned(), |p| p.to_string()),
                    role = role.as_str(),
                    action = control.action.as_str(),
                    "an instructor moved the station's exercises on"
                ),
                Err(ControlRefusal::NoExercises) => {
                    return refuse(socket, hub, connection, &kind, REFUSED_EXERCISE_NONE).await;
                }
                Err(ControlRefusal::Busy) => {
                    return refuse(socket, hub, connection, &kind, REFUSED_EXERCISE_BUSY).await;
                }
            }
        }
        // The connection has its role already (or the server has no tokens): a later `auth`
        // changes nothing and is ignored.
        Ok(kind) if kind == "auth" => {}
        Ok(kind) => {
            let n = hub
                .counters
                .unknown_messages
                .fetch_add(1, Ordering::Relaxed);
            if n == 0 {
                tracing::warn!(kind, "ignoring a viewer message of unknown type");
            } else {
                tracing::debug!(kind, "ignoring a viewer message of unknown type");
            }
        }
        Err(e) => {
            tracing::debug!(error = %e, "malformed viewer message");
            hub.counters
                .malformed_closes
                .fetch_add(1, Ordering::Relaxed);
            close(socket, close_code::INVALID, "malformed message", timeout).await;
            return Some(ViewerEnd::Malformed);
        }
    }
    None
}

/// Answers a request the connection may not make with `refused`, logs it, and keeps the
/// connection open (`Some` only when the reply cannot be sent).
async fn refuse(
    socket: &mut WebSocket,
    hub: &StreamHub,
    connection: &Connection,
    request: &str,
    reason: &str,
) -> Option<ViewerEnd> {
    hub.counters
        .refused_requests
        .fetch_add(1, Ordering::Relaxed);
    tracing::info!(
        client = %connection.peer.map_or_else(|| "unknown".to_owned(), |p| p.to_string()),
        role = connection.role.map_or("none", Role::as_str),
        request,
        "request refused: {reason}"
    );
    let reply = ServerMessage::Refused(Refused {
        request: request.to_owned(),
        reason: reason.to_owned(),
    });
    match reply.encode() {
        Ok(text) => {
            let message = Message::Text(Utf8Bytes::from(text));
            if !send(socket, message, hub.limits.send_timeout, &hub.counters).await {
                return Some(ViewerEnd::SendFailed);
            }
        }
        Err(e) => tracing::error!(error = %e, "could not encode a refused message"),
    }
    None
}

/// Closes a connection refused by a limit on connections, with 4429 and the limit's reason.
pub async fn refuse_connection(socket: WebSocket, hub: &StreamHub, refusal: LimitRefusal) {
    hub.access
        .refuse_viewer(socket, refusal, hub.limits, &hub.counters)
        .await;
}

/// Sends with a deadline; false when the connection is unusable. A send that times out is
/// counted in `stalled_closes`.
async fn send(
    socket: &mut WebSocket,
    message: Message,
    timeout: Duration,
    counters: &StreamCounters,
) -> bool {
    match tokio::time::timeout(timeout, socket.send(message)).await {
        Ok(Ok(())) => true,
        Ok(Err(_)) => false,
        Err(_) => {
            counters.stalled_closes.fetch_add(1, Ordering::Relaxed);
            tracing::debug!("closing a viewer that stopped reading");
            false
        }
    }
}

/// How long a closing connection's remaining messages are read and discarded, waiting for the
/// peer's close frame.
const CLOSE_DRAIN: Duration = Duration::from_secs(1);

/// Sends a close frame, then reads (and discards) what the peer still sends until its own close
/// frame, for at most [`CLOSE_DRAIN`]. Dropping a socket with unread data makes the kernel
/// reset the connection, and a reset can reach the peer before it has read our close frame:
/// a flooding client would then never learn its close code.
async fn close(socket: &mut WebSocket, code: u16, reason: &'static str, timeout: Duration) {
    let frame = CloseFrame {
        code,
        reason: Utf8Bytes::from_static(reason),
    };
    // The peer may already be gone; nothing more to do either way.
    if !matches!(
        tokio::time::timeout(timeout, socket.send(Message::Close(Some(frame)))).await,
        Ok(Ok(()))
    ) {
        return;
    }
    let _ = tokio::time::timeout(CLOSE_DRAIN, async {
        while let Some(Ok(message)) = socket.recv().await {
            if matches!(message, Message::Close(_)) {
                break;
            }
        }
    })
    .await;
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::is_connection_lost;
    use tungstenite::error::{CapacityError, Error, ProtocolError};

    fn lost(e: Error) -> bool {
        is_connection_lost(&axum::Error::new(e))
    }

    #[test]
    fn a_link_that_went_away_is_lost_and_a_broken_rule_is_not() {
        assert!(lost(Error::Protocol(
            ProtocolError::ResetWithoutClosingHandshake
        )));
        assert!(lost(Error::ConnectionClosed));
        assert!(lost(Error::AlreadyClosed));
        for kind in [
            std::io::ErrorKind::ConnectionReset,
            std::io::ErrorKind::BrokenPipe,
            std::io::ErrorKind::UnexpectedEof,
        ] {
            assert!(lost(Error::Io(std::io::Error::from(kind))), "{kind:?}");
        }
        assert!(!lost(Error::Capacity(CapacityError::MessageTooLong {
            size: 1 << 20,
            max_size: 1 << 16,
        })));
        assert!(!lost(Error::Protocol(
            ProtocolError::UnmaskedFrameFromClient
        )));
        assert!(!lost(Error::Protocol(ProtocolError::InvalidOpcode(3))));
        assert!(!lost(Error::Utf8("not UTF-8".into())));
    }
}
