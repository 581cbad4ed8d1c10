//! A hub's dashboard of every station (`/dashboard`, its WebSocket `/ws?dashboard`): the
//! stations' summaries, from their heartbeats, to every dashboard page about once a second, and
//! the instructors' actions from the page to a station.
//!
//! What a page is sent costs the hub the same whatever the stations do: one `dashboard`
//! message a second, encoded once for every page, made from the heartbeats the hub keeps
//! anyway (no frame of any station reaches a dashboard). An action is an instructor's only (an
//! observer's is answered `refused`), logged with who asked, sent to the station as a NATS
//! request on its `action` subject (the station carries it out and logs it too), and its answer
//! is sent back to the page that asked as `action_result`.

use std::sync::Arc;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use axum::body::Bytes;
use axum::extract::ws::{CloseFrame, Message, Utf8Bytes, WebSocket, close_code};
use softhaptic_proto::wire::{
    ActionResult, DashboardMessage, Hello, MarkRequest, Mode, PROTOCOL_VERSION, Refused, Role,
    ServerMessage, StationAction, StationActionRequest, message_type,
};
use tokio::sync::{broadcast, mpsc, watch};

use super::{ActionCall, Subjects};
use crate::access::MessageRate;
use crate::access::roles::{Action, may};
use crate::stream::{ViewerEnd, ViewerLimits};

/// How often the pages are sent the stations' tiles.
pub const DASHBOARD_PERIOD: Duration = Duration::from_secs(1);
/// How long a station has to answer an action.
const ACTION_TIMEOUT: Duration = Duration::from_secs(5);
/// Actions of one page waiting for their stations at once.
const ACTIONS_IN_FLIGHT: usize = 4;
/// The `refused` reason of a `station_action` from an observer.
pub const REFUSED_ACTION_OBSERVER: &str = Action::ActOnStation.observer_refusal();

/// What the hub's dashboard pages share: the latest `dashboard` message and its broadcast, and
/// what they cost.
pub struct DashboardHub {
    messages: broadcast::Sender<Utf8Bytes>,
    latest: Mutex<Option<Utf8Bytes>>,
    client: async_nats::Client,
    hello_instructor: Utf8Bytes,
    hello_observer: Utf8Bytes,
    pub counters: DashboardCounters,
}

/// What the dashboard costs, for the lab report.
#[derive(Default)]
pub struct DashboardCounters {
    /// Pages connected now.
    pub pages: AtomicU32,
    /// `dashboard` messages made (once a second while a page is open).
    pub messages_made: AtomicU64,
    /// Bytes of `dashboard` messages sent, all pages together.
    pub bytes_sent: AtomicU64,
    /// Actions passed on to stations, and refused to observers.
    pub actions: AtomicU64,
    pub refused: AtomicU64,
}

impl DashboardHub {
    pub fn new(client: async_nats::Client) -> Self {
        let hello = |role| {
            ServerMessage::Hello(Hello {
                protocol_version: PROTOCOL_VERSION,
                session_id: "dashboard".into(),
                role,
                mode: Mode::Live,
                server: crate::routes::SERVER_NAME.into(),
                force_feedback: false,
                accepts_marks: false,
            })
            .encode()
            .map(Utf8Bytes::from)
            .unwrap_or_default()
        };
        Self {
            messages: broadcast::channel(4).0,
            latest: Mutex::new(None),
            client,
            hello_instructor: hello(Role::Instructor),
            hello_observer: hello(Role::Observer),
            counters: DashboardCounters::default(),
        }
    }

    /// Whether any page is open (the hub makes no message for nobody).
    pub fn watched(&self) -> bool {
        self.messages.receiver_count() > 0
    }

    /// Sends `message` to every page, encoded once, and keeps it for pages that connect later.
    pub fn publish(&self, message: DashboardMessage) {
        let Ok(text) = ServerMessage::Dashboard(Box::new(message)).encode() else {
            return;
        };
        let text = Utf8Bytes::from(text);
        self.counters.messages_made.fetch_add(1, Ordering::Relaxed);
        *self.latest.lock().unwrap_or_else(|p| p.into_inner()) = Some(text.clone());
        let _ = self.messages.send(text);
    }
}

/// Serves one dashboard page that has its `role`, until it leaves or the hub stops.
pub async fn serve_page(
    mut socket: WebSocket,
    dashboard: Arc<DashboardHub>,
    role: Role,
    mut rate: MessageRate,
    limits: ViewerLimits,
    mut shutdown: watch::Receiver<bool>,
    who: String,
) -> ViewerEnd {
    let timeout = limits.send_timeout;
    let mut messages = dashboard.messages.subscribe();
    dashboard.counters.pages.fetch_add(1, Ordering::Relaxed);
    let _page = PageGuard(&dashboard.counters.pages);
    let hello = match role {
        Role::Instructor => dashboard.hello_instructor.clone(),
        Role::Observer => dashboard.hello_observer.clone(),
    };
    let latest = dashboard
        .latest
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .clone();
    for text in std::iter::once(hello).chain(latest) {
        if !send(&mut socket, &dashboard, text, timeout).await {
            return ViewerEnd::SendFailed;
        }
    }
    let (results_tx, mut results) = mpsc::channel::<ActionResult>(ACTIONS_IN_FLIGHT);
    loop {
        tokio::select! {
            _ = shutdown.changed() => {
                close(&mut socket, close_code::AWAY, "server shutting down", timeout).await;
                return ViewerEnd::Shutdown;
            }
            text = messages.recv() => match text {
                Ok(text) => {
                    if !send(&mut socket, &dashboard, text, timeout).await {
                        return ViewerEnd::SendFailed;
                    }
                }
                // Behind: the next message says all a lost one did.
                Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(broadcast::error::RecvError::Closed) => return ViewerEnd::Shutdown,
            },
            Some(result) = results.recv() => {
                let Ok(text) = ServerMessage::ActionResult(result).encode() else { continue };
                if !send(&mut socket, &dashboard, Utf8Bytes::from(text), timeout).await {
                    return ViewerEnd::SendFailed;
                }
            }
            incoming = socket.recv() => {
                let text = match incoming {
                    None | Some(Ok(Message::Close(_))) => return ViewerEnd::Closed,
                    Some(Err(_)) => return ViewerEnd::Lost,
                    Some(Ok(Message::Text(text))) => text,
                    Some(Ok(Message::Binary(_))) => {
                        close(&mut socket, close_code::UNSUPPORTED, "binary messages are not accepted", timeout).await;
                        return ViewerEnd::Malformed;
                    }
                    Some(Ok(_)) => continue,
                };
                if !rate.allow(Instant::now()) {
                    close(&mut socket, close_code::POLICY, crate::stream::REASON_FLOOD, timeout).await;
                    return ViewerEnd::Flooded;
                }
                match message_type(&text).as_deref() {
                    // A token sent again, or by a page of a hub without tokens: nothing to do.
                    Ok("auth") => {}
                    Ok("station_action") => {
                        let Ok(request) = serde_json::from_str::<StationActionRequest>(&text) else {
                            close(&mut socket, close_code::INVALID, "invalid station_action message", timeout).await;
                            return ViewerEnd::Malformed;
                        };
                        if !may(role, Action::ActOnStation) {
                            dashboard.counters.refused.fetch_add(1, Ordering::Relaxed);
                            tracing::info!(client = %who, station = %request.station, action = request.action.name(), "station_action refused: {REFUSED_ACTION_OBSERVER}");
                            let refused = ServerMessage::Refused(Refused {
                                request: "station_action".into(),
                                reason: REFUSED_ACTION_OBSERVER.into(),
                            });
                            let Ok(text) = refused.encode() else { continue };
                            if !send(&mut socket, &dashboard, Utf8Bytes::from(text), timeout).await {
                                return ViewerEnd::SendFailed;
                            }
                            continue;
                        }
                        let answer = results_tx.clone();
                        match answer.try_reserve_owned() {
                            Ok(permit) => {
                                dashboard.counters.actions.fetch_add(1, Ordering::Relaxed);
                                tokio::spawn(act(Arc::clone(&dashboard), request, who.clone(), permit));
                            }
                            Err(_) => {
                                let busy = ActionResult {
                                    station: request.station.clone(),
                                    action: request.action.name().into(),
                                    done: false,
                                    reason: Some("this page has as many actions waiting as it may: try again when they are answered".into()),
                                };
                                let Ok(text) = ServerMessage::ActionResult(busy).encode() else { continue };
                                if !send(&mut socket, &dashboard, Utf8Bytes::from(text), timeout).await {
                                    return ViewerEnd::SendFailed;
                                }
                            }
                        }
                    }
                    // Another type: ignored, as a viewer ignores one it does not know.
                    Ok(_) => {}
                    Err(_) => {
                        close(&mut socket, close_code::INVALID, "malformed message", timeout).await;
                        return ViewerEnd::Malformed;
                    }
                }
            }
        }
    }
}

/// Passes an instructor's action to its station and its answer to the page.
async fn act(
    dashboard: Arc<DashboardHub>,
    request: StationActionRequest,
    who: String,
    permit: mpsc::OwnedPermit<ActionResult>,
) {
    let StationActionRequest { station, action } = request;
    let name = action.name();
    let refuse = |reason: String| ActionResult {
        station: station.clone(),
        action: name.into(),
        done: false,
        reason: Some(reason),
    };
    let result = if let Err(reason) = super::check_station_name(&station) {
        refuse(reason)
    } else if let StationAction::Mark { note } = &action
        && let Some(problem) = (MarkRequest {
            note: note.clone(),
            point_m: None,
        })
        .problem()
    {
        refuse(problem.to_owned())
    } else {
        let by = format!("instructor at {who} on a hub");
        tracing::info!(client = %who, station = %station, action = ?action, "an instructor's action from the dashboard, sent to the station");
        let call = serde_json::to_vec(&ActionCall { action, by }).unwrap_or_default();
        let reply = tokio::time::timeout(
            ACTION_TIMEOUT,
            dashboard
                .client
                .request(Subjects::of(&station).action, Bytes::from(call)),
        )
        .await;
        match reply {
            Ok(Ok(reply)) => match serde_json::from_slice::<ActionResult>(&reply.payload) {
                Ok(answer) => ActionResult {
                    station: station.clone(),
                    action: name.into(),
                    ..answer
                },
                Err(_) => refuse("the station's answer could not be read".into()),
            },
            Ok(Err(e)) => {
                tracing::info!(station = %station, "an action's station did not answer: {e}");
                refuse("the station did not answer: is it running and in the lab?".into())
            }
            Err(_) => refuse("the station did not answer within 5 s".into()),
        }
    };
    permit.send(result);
}

struct PageGuard<'a>(&'a AtomicU32);

impl Drop for PageGuard<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::Relaxed);
    }
}

async fn send(
    socket: &mut WebSocket,
    dashboard: &DashboardHub,
    text: Utf8Bytes,
    timeout: Duration,
) -> bool {
    let bytes = text.len() as u64;
    let sent = matches!(
        tokio::time::timeout(timeout, socket.send(Message::Text(text))).await,
        Ok(Ok(()))
    );
    if sent {
        dashboard
            .counters
            .bytes_sent
            .fetch_add(bytes, Ordering::Relaxed);
    }
    sent
}

async fn close(socket: &mut WebSocket, code: u16, reason: &'static str, timeout: Duration) {
    let frame = CloseFrame {
        code,
        reason: Utf8Bytes::from_static(reason),
    };
    let _ = tokio::time::timeout(timeout, socket.send(Message::Close(Some(frame)))).await;
}
