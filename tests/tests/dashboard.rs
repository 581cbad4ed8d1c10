//! A hub's dashboard with a real `nats-server` and two simulated stations, over real
//! WebSockets: the page is sent every station's tile from the stations' heartbeats, the station
//! whose trainee presses above the safe force has that alert and the other none; an instructor
//! acknowledges it (the next tiles say who), marks the other station's session (the mark is
//! made on the station), and is told when a station is not there; an observer's action is
//! refused and changes nothing.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::time::{Duration, Instant};

use softhaptic_proto::wire::{
    ActionResult, AlertKind, DashboardMessage, Role, ServerMessage, StationAction,
    StationActionRequest,
};
use softhaptic_server::app::{self, RunningServer};
use softhaptic_server::lab::station::StationOptions;
use softhaptic_server::scene::Scene;
use softhaptic_tests::nats::{NatsServer, options, start_hub};
use softhaptic_tests::{Viewer, test_options, wait_until};

const I: &str = softhaptic_tests::INSTRUCTOR_TOKEN;
const O: &str = softhaptic_tests::OBSERVER_TOKEN;

/// A simulated station pressing the built-in liver, its safe force `safe_force_n`.
async fn station(name: &str, url: String, safe_force_n: f64) -> RunningServer {
    let mut o = test_options();
    o.lab = Some(StationOptions {
        nats: options(url),
        name: name.to_owned(),
    });
    let mut scene = Scene::builtin_default().unwrap();
    scene.safe_force_n = safe_force_n;
    app::start(scene, o).await.unwrap()
}

async fn page(addr: std::net::SocketAddr, token: &str) -> Viewer {
    let mut v = Viewer::connect_url(&format!("ws://{addr}/ws?dashboard")).await;
    v.authenticate(token).await;
    match v.expect_message(Duration::from_secs(10)).await {
        ServerMessage::Hello(h) => {
            assert_eq!(h.session_id, "dashboard");
            assert_eq!(
                h.role,
                if token == I {
                    Role::Instructor
                } else {
                    Role::Observer
                }
            );
        }
        other => panic!("expected hello, got {other:?}"),
    }
    v
}

/// The next `dashboard` message satisfying `wanted`, within 30 s.
async fn dashboard_until(
    v: &mut Viewer,
    what: &str,
    wanted: impl Fn(&DashboardMessage) -> bool,
) -> DashboardMessage {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        assert!(Instant::now() < deadline, "no dashboard with {what}");
        if let ServerMessage::Dashboard(d) = v.expect_message(Duration::from_secs(10)).await
            && wanted(&d)
        {
            return *d;
        }
    }
}

/// The next `action_result` (dashboards skipped).
async fn result(v: &mut Viewer) -> ActionResult {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        assert!(Instant::now() < deadline, "no action_result");
        if let ServerMessage::ActionResult(r) = v.expect_message(Duration::from_secs(10)).await {
            return r;
        }
    }
}

fn action(station: &str, action: StationAction) -> String {
    serde_json::to_string(&StationActionRequest {
        station: station.into(),
        action,
    })
    .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_dashboard_shows_every_station_raises_alerts_and_takes_an_instructors_actions() {
    let nats = NatsServer::start("dashboard");
    // desk-hard's trainee presses above its safe force (0.05 N); desk-calm's never reaches 50 N.
    let hard = station("desk-hard", nats.url(), 0.05).await;
    let calm = station("desk-calm", nats.url(), 50.0).await;
    let hub = start_hub(options(nats.url()), true).await;
    wait_until("both stations listed", || hub.stations().len() == 2).await;

    let mut teacher = page(hub.local_addr(), I).await;
    let mut watcher = page(hub.local_addr(), O).await;
    let alert_of = |d: &DashboardMessage, name: &str| {
        d.stations
            .iter()
            .find(|s| s.name == name)
            .and_then(|s| s.summary.as_ref())
            .and_then(|s| {
                s.alerts
                    .iter()
                    .find(|a| a.kind == AlertKind::AboveSafeForce)
                    .cloned()
            })
    };
    let d = dashboard_until(&mut teacher, "desk-hard's alert", |d| {
        alert_of(d, "desk-hard").is_some()
    })
    .await;
    assert_eq!(
        d.stations
            .iter()
            .map(|s| s.name.as_str())
            .collect::<Vec<_>>(),
        ["desk-calm", "desk-hard"]
    );
    let alert = alert_of(&d, "desk-hard").unwrap();
    assert!(alert.acknowledged.is_none());
    assert!(
        alert.detail.contains("above the safe 0.05 N"),
        "{}",
        alert.detail
    );
    let hard_tile = d.stations.iter().find(|s| s.name == "desk-hard").unwrap();
    let summary = hard_tile.summary.as_ref().unwrap();
    assert!(summary.force_n.iter().any(|&f| f > 0.05), "{summary:?}");
    assert_eq!(summary.safe_force_n, 0.05);
    assert!(alert_of(&d, "desk-calm").is_none());
    // The observer is sent the same tiles.
    dashboard_until(&mut watcher, "desk-hard's alert", |d| {
        alert_of(d, "desk-hard").is_some()
    })
    .await;

    // An observer's action is refused, and the alert stays open.
    watcher
        .send_text(&action(
            "desk-hard",
            StationAction::Acknowledge { alert: alert.id },
        ))
        .await;
    loop {
        match watcher.expect_message(Duration::from_secs(10)).await {
            ServerMessage::Refused(r) => {
                assert_eq!(r.request, "station_action");
                assert_eq!(r.reason, "only an instructor acts on a station");
                break;
            }
            ServerMessage::Dashboard(_) => {}
            other => panic!("expected refused, got {other:?}"),
        }
    }
    assert!(hard.hub().summary.all_alerts()[0].acknowledged.is_none());

    // The instructor acknowledges it: the station takes it, and the tiles say who.
    teacher
        .send_text(&action(
            "desk-hard",
            StationAction::Acknowledge { alert: alert.id },
        ))
        .await;
    let r = result(&mut teacher).await;
    assert!(r.done, "{r:?}");
    assert_eq!(
        (r.station.as_str(), r.action.as_str()),
        ("desk-hard", "acknowledge")
    );
    let d = dashboard_until(&mut teacher, "the alert acknowledged", |d| {
        alert_of(d, "desk-hard").is_some_and(|a| a.acknowledged.is_some())
    })
    .await;
    let by = alert_of(&d, "desk-hard").unwrap().acknowledged.unwrap().by;
    assert!(by.starts_with("instructor at 127.0.0.1:"), "{by}");
    // Twice is refused by the station.
    teacher
        .send_text(&action(
            "desk-hard",
            StationAction::Acknowledge { alert: alert.id },
        ))
        .await;
    let r = result(&mut teacher).await;
    assert!(!r.done && r.reason.unwrap().contains("already acknowledged"));

    // A mark on the other station's session, made by the station itself.
    teacher
        .send_text(&action(
            "desk-calm",
            StationAction::Mark {
                note: "watch the wrist".into(),
            },
        ))
        .await;
    let r = result(&mut teacher).await;
    assert!(r.done, "{r:?}");
    let marks = calm.hub().made_marks();
    assert_eq!(marks.len(), 1);
    assert!(marks[0].as_str().contains("watch the wrist"));
    // An exercise control where none run, a re-arm of a simulated device, a station that is
    // not there: each answered, none carried out.
    for (station, a, reason) in [
        (
            "desk-calm",
            StationAction::Exercise {
                control: softhaptic_proto::wire::ExerciseAction::Repeat,
            },
            "no exercises run here",
        ),
        ("desk-calm", StationAction::RearmDevice, "no haptic device"),
        ("desk-gone", StationAction::RearmDevice, "did not answer"),
    ] {
        teacher.send_text(&action(station, a)).await;
        let r = result(&mut teacher).await;
        assert!(!r.done, "{r:?}");
        assert!(r.reason.as_ref().unwrap().contains(reason), "{r:?}");
        assert_eq!(r.station, station);
    }

    let counters = hub.dashboard_counters();
    assert_eq!(counters.pages.load(std::sync::atomic::Ordering::Relaxed), 2);
    assert!(
        counters
            .bytes_sent
            .load(std::sync::atomic::Ordering::Relaxed)
            > 0
    );
    hub.shutdown().await;
    hard.shutdown().await;
    calm.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_sessions_alerts_and_their_acknowledgements_are_in_its_recording() {
    use softhaptic_server::session::reader::Recording;
    use softhaptic_server::session::tools::{Info, export};

    let dir = softhaptic_tests::scratch_dir("dashboard-alerts");
    let mut scene = Scene::builtin_default().unwrap();
    scene.safe_force_n = 0.05;
    let live = softhaptic_tests::start_recorded(scene, &dir, test_options()).await;
    let summary = std::sync::Arc::clone(&live.server.hub().summary);
    wait_until("an alert raised", || !summary.all_alerts().is_empty()).await;
    summary
        .acknowledge(1, "instructor at 127.0.0.1:9 on a hub")
        .unwrap();
    let (_, _, path, _) = live.finish().await;

    // The recording holds the session's alerts as they last stood (the hand may have pressed
    // again meanwhile: a new press above the safe force is a new alert).
    let recording = Recording::open(&path).unwrap();
    assert_eq!(recording.alerts, summary.all_alerts());
    let alert = &recording.alerts[0];
    assert_eq!(alert.kind, AlertKind::AboveSafeForce);
    assert_eq!(
        alert.acknowledged.as_ref().unwrap().by,
        "instructor at 127.0.0.1:9 on a hub"
    );
    let info = Info::of(&recording).to_string();
    assert!(
        info.contains(&format!(
            "alerts:            {} ({} not acknowledged)",
            recording.alerts.len(),
            recording.alerts.len() - 1
        )),
        "{info}"
    );
    assert!(info.contains("above_safe_force"), "{info}");
    let out = dir.join("export");
    let exported = export(&recording, &out, false).unwrap();
    let written: Vec<softhaptic_proto::wire::Alert> =
        serde_json::from_slice(&std::fs::read(exported.alerts).unwrap()).unwrap();
    assert_eq!(&written, &recording.alerts);
    let _ = std::fs::remove_dir_all(&dir);
}
