//! The teaching lab with a real `nats-server`: two simulated stations publish, a hub lists them
//! and relays the one a viewer picks, frame for frame as the station's own viewers get it; NATS
//! refusing a station's credentials stops its start; a hub's viewer without a token is refused
//! as a station's is; NATS killed mid-session leaves the station and its viewers running, and
//! the relay comes back when NATS does.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use softhaptic_proto::wire::{ContactFrame, Role, ServerMessage};
use softhaptic_server::app::{self, RunningServer};
use softhaptic_server::lab::NatsOptions;
use softhaptic_server::lab::hub::{self};
use softhaptic_server::lab::station::StationOptions;
use softhaptic_server::scene::Scene;
use softhaptic_tests::nats::{NatsServer, start_hub as hub};
use softhaptic_tests::{Viewer, scratch_dir, test_options, wait_until};

const O: &str = softhaptic_tests::OBSERVER_TOKEN;

fn nats(url: String, credentials: Option<std::path::PathBuf>) -> NatsOptions {
    NatsOptions { url, credentials }
}

async fn station(
    name: &str,
    options: NatsOptions,
) -> Result<RunningServer, softhaptic_server::app::ServerError> {
    let mut o = test_options();
    o.lab = Some(StationOptions {
        nats: options,
        name: name.to_owned(),
    });
    app::start(Scene::builtin_default().unwrap(), o).await
}

/// Contact frames by seq (their `dropped` set to 0: each viewer has its own count) until
/// `count` have come.
async fn frames(viewer: &mut Viewer, count: usize) -> BTreeMap<u64, ContactFrame> {
    let mut out = BTreeMap::new();
    let deadline = Instant::now() + Duration::from_secs(60);
    while out.len() < count {
        assert!(Instant::now() < deadline, "only {} frames", out.len());
        if let Some(Ok(ServerMessage::Contact(c))) = viewer.next(Duration::from_secs(10)).await {
            out.insert(c.seq, ContactFrame { dropped: 0, ..c });
        }
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hub_lists_two_stations_and_relays_the_one_picked_frame_for_frame() {
    let server = NatsServer::start("two-stations");
    let a = station("desk-a", nats(server.url(), None)).await.unwrap();
    let b = station("desk-b", nats(server.url(), None)).await.unwrap();
    let hub = hub(nats(server.url(), None), false).await;
    wait_until("both stations listed", || {
        let s = hub.stations();
        s.len() == 2 && s.iter().all(|s| s.state != "offline")
    })
    .await;
    let listed = hub.stations();
    assert_eq!(listed[0].name, "desk-a");
    assert_eq!(listed[1].name, "desk-b");
    assert!(listed[0].scene.contains("liver"), "{:?}", listed[0]);

    // The hub's answer to the page, over HTTP.
    let (status, body) = softhaptic_tests::http_get(hub.local_addr(), "/api/stations").await;
    assert_eq!(status, 200);
    let list: hub::StationList = serde_json::from_slice(&body).unwrap();
    assert!(list.hub && list.stations.len() == 2);

    // A viewer on the station and one on the hub, for station b.
    let mut direct = Viewer::connect(b.local_addr()).await;
    let mut relayed =
        Viewer::connect_url(&format!("ws://{}/ws?station=desk-b", hub.local_addr())).await;
    let hello = match relayed.expect_message(Duration::from_secs(10)).await {
        ServerMessage::Hello(h) => h,
        other => panic!("expected hello, got {other:?}"),
    };
    // The station's own session, as its own viewers are told it.
    match ServerMessage::decode(b.hub().hello(Role::Instructor).as_str()).unwrap() {
        ServerMessage::Hello(own) => assert_eq!(hello.session_id, own.session_id),
        other => panic!("{other:?}"),
    }
    match relayed.expect_message(Duration::from_secs(10)).await {
        ServerMessage::Scene(s) => {
            assert_eq!(s.render_meshes[0].url, "/stations/desk-b/meshes/liver.bin");
            assert_eq!(s.tool, b.scene_message().tool);
        }
        other => panic!("expected scene, got {other:?}"),
    }
    let from_station = frames(&mut direct, 150).await;
    let from_hub = frames(&mut relayed, 150).await;
    // Every frame both saw is the same frame; the hub's are consecutive (none lost on the way).
    let common: Vec<u64> = from_hub
        .keys()
        .filter(|seq| from_station.contains_key(seq))
        .copied()
        .collect();
    assert!(common.len() >= 50, "{} frames in common", common.len());
    for seq in &common {
        assert_eq!(from_hub[seq], from_station[seq], "frame {seq}");
    }
    let seqs: Vec<u64> = from_hub.keys().copied().collect();
    let gaps = seqs.windows(2).filter(|w| w[1] != w[0] + 1).count();
    assert!(gaps <= 2, "{gaps} gaps in {seqs:?}");

    // The mesh through the hub is the station's.
    let (status, relayed_mesh) =
        softhaptic_tests::http_get(hub.local_addr(), "/stations/desk-b/meshes/liver.bin").await;
    assert_eq!(status, 200);
    let (_, own_mesh) = softhaptic_tests::http_get(b.local_addr(), "/meshes/liver.bin").await;
    assert!(relayed_mesh.len() > 1 << 20, "{}", relayed_mesh.len());
    assert!(relayed_mesh == own_mesh);

    // A station that is not there.
    let (status, _) =
        softhaptic_tests::http_get(hub.local_addr(), "/api/scene?station=desk-z").await;
    assert_eq!(status, 404);

    hub.shutdown().await;
    a.shutdown().await;
    b.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nats_refusing_the_credentials_stops_a_station_and_a_hub_wants_its_token() {
    let server = NatsServer::start_with_user("auth", "desk", "s3cret-pass");
    let e = station("desk-a", nats(server.url(), None))
        .await
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("refused this station"), "{e}");
    assert!(e.contains("--nats-credentials"), "{e}");

    let dir = scratch_dir("lab-credentials");
    let wrong = dir.join("wrong.toml");
    std::fs::write(&wrong, "user = \"desk\"\npassword = \"not-it\"\n").unwrap();
    let e = station("desk-a", nats(server.url(), Some(wrong)))
        .await
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("refused"), "{e}");
    assert!(!e.contains("not-it"), "the password is not shown: {e}");

    let right = dir.join("right.toml");
    std::fs::write(&right, "user = \"desk\"\npassword = \"s3cret-pass\"\n").unwrap();
    let a = station("desk-a", nats(server.url(), Some(right.clone())))
        .await
        .unwrap();
    let hub = hub(nats(server.url(), Some(right)), true).await;
    wait_until("the station listed", || hub.stations().len() == 1).await;

    // Without a token, the hub refuses the stream and the list as a station would.
    let mut viewer =
        Viewer::connect_url(&format!("ws://{}/ws?station=desk-a", hub.local_addr())).await;
    let (close, _) = viewer.until_closed(Duration::from_secs(30)).await;
    assert_eq!(close.map(|c| c.0), Some(4401));
    let (status, _) = softhaptic_tests::http_get(hub.local_addr(), "/api/stations").await;
    assert_eq!(status, 401);
    // With one, it streams.
    let mut viewer =
        Viewer::connect_url(&format!("ws://{}/ws?station=desk-a", hub.local_addr())).await;
    viewer.authenticate(O).await;
    match viewer.expect_message(Duration::from_secs(10)).await {
        ServerMessage::Hello(h) => assert_eq!(h.role, Role::Observer),
        other => panic!("expected hello, got {other:?}"),
    }
    hub.shutdown().await;
    a.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_nats_gone_the_station_serves_its_viewers_and_the_relay_resumes_when_it_is_back() {
    let mut server = NatsServer::start("outage");
    let a = station("desk-a", nats(server.url(), None)).await.unwrap();
    let hub = hub(nats(server.url(), None), false).await;
    wait_until("the station listed", || hub.stations().len() == 1).await;
    let mut relayed =
        Viewer::connect_url(&format!("ws://{}/ws?station=desk-a", hub.local_addr())).await;
    let before = frames(&mut relayed, 20).await;
    let mut direct = Viewer::connect(a.local_addr()).await;

    server.kill();
    // The station's own viewer carries on: frames keep coming, consecutive.
    let during = frames(&mut direct, 100).await;
    let seqs: Vec<u64> = during.keys().copied().collect();
    assert!(
        seqs.windows(2).filter(|w| w[1] != w[0] + 1).count() <= 2,
        "{seqs:?}"
    );
    wait_until("the hub to show the station offline", || {
        hub.stations().first().is_some_and(|s| s.state == "offline")
    })
    .await;

    server.restart();
    wait_until("the station back on the hub", || {
        hub.stations().first().is_some_and(|s| s.state != "offline")
    })
    .await;
    // The relay carries on after the gap: later frames, with the frames not published counted.
    let last_before = *before.keys().last().unwrap();
    let deadline = Instant::now() + Duration::from_secs(60);
    let resumed = loop {
        assert!(Instant::now() < deadline, "the relay did not resume");
        if let Some(Ok(ServerMessage::Contact(c))) = relayed.next(Duration::from_secs(30)).await
            && c.seq > last_before + 50
        {
            break c;
        }
    };
    assert!(resumed.seq > *seqs.last().unwrap());
    assert!(
        hub.stations()[0].unpublished_frames > 0,
        "{:?}",
        hub.stations()
    );
    hub.shutdown().await;
    a.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hubs_are_interchangeable_a_viewer_of_a_stopped_hub_carries_on_at_another() {
    let server = NatsServer::start("two-hubs");
    let a = station("desk-a", nats(server.url(), None)).await.unwrap();
    let first = hub(nats(server.url(), None), false).await;
    let second = hub(nats(server.url(), None), false).await;
    wait_until("both hubs list the station", || {
        first.stations().len() == 1 && second.stations().len() == 1
    })
    .await;
    let mut viewer =
        Viewer::connect_url(&format!("ws://{}/ws?station=desk-a", first.local_addr())).await;
    let session = match viewer.expect_message(Duration::from_secs(10)).await {
        ServerMessage::Hello(h) => h.session_id,
        other => panic!("expected hello, got {other:?}"),
    };
    let seen = frames(&mut viewer, 10).await;
    let last = *seen.keys().last().unwrap();

    // The first hub goes away; its viewer is closed, and reconnects to the other (what a load
    // balancer in front of both does): the same session, carrying on where it was.
    first.shutdown().await;
    let (close, _) = viewer.until_closed(Duration::from_secs(30)).await;
    assert!(
        close.as_ref().is_none_or(|c| c.0 == 1001 || c.0 == 1000),
        "{close:?}"
    );
    let mut viewer =
        Viewer::connect_url(&format!("ws://{}/ws?station=desk-a", second.local_addr())).await;
    match viewer.expect_message(Duration::from_secs(10)).await {
        ServerMessage::Hello(h) => assert_eq!(h.session_id, session),
        other => panic!("expected hello, got {other:?}"),
    }
    let after = frames(&mut viewer, 10).await;
    assert!(*after.keys().next().unwrap() > last);
    second.shutdown().await;
    a.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn recordings_are_archived_verified_retried_and_replayed_from_the_hub() {
    use softhaptic_server::lab::archive;
    let mut server = NatsServer::start("archive");
    let dir = scratch_dir("lab-archive");
    let sessions = softhaptic_tests::repo_scenes().join("../tests/sessions");
    for f in ["slide.mcap", "sphere-press.mcap"] {
        std::fs::copy(sessions.join(f), dir.join(f)).unwrap();
    }
    let client = softhaptic_server::lab::connect(
        &nats(server.url(), None),
        "archive test".into(),
        "station",
    )
    .await
    .unwrap();

    // NATS gone: nothing archived, both files reported and kept.
    server.kill();
    let report = tokio::time::timeout(
        Duration::from_secs(120),
        archive::upload_finished(&client, "desk-a", &dir, None),
    )
    .await
    .unwrap();
    assert!(report.uploaded.is_empty(), "{report:?}");
    assert_eq!(report.failed.len(), 2, "{report:?}");
    assert!(dir.join("slide.mcap").is_file() && dir.join("sphere-press.mcap").is_file());

    // Back: the next pass archives them (the one being written is left for later), verified.
    server.restart();
    wait_until("the client back", || {
        softhaptic_server::lab::is_connected(&client)
    })
    .await;
    let report = archive::upload_finished(
        &client,
        "desk-a",
        &dir,
        Some(&dir.join("sphere-press.mcap")),
    )
    .await;
    assert!(report.failed.is_empty(), "{report:?}");
    assert_eq!(report.uploaded.len(), 1, "{report:?}");
    let report = archive::upload_finished(&client, "desk-a", &dir, None).await;
    assert_eq!(
        (report.uploaded.len(), report.already.len()),
        (1, 1),
        "{report:?}"
    );
    assert!(dir.join("slide.mcap").is_file(), "the local file is kept");

    // The hub lists them with the file's digest, serves the file, and replays it.
    let hub = hub(nats(server.url(), None), false).await;
    let (status, body) =
        softhaptic_tests::http_get(hub.local_addr(), "/api/archive?station=desk-a").await;
    assert_eq!(status, 200);
    let listed: serde_json::Value = serde_json::from_slice(&body).unwrap();
    let listed = listed["archive"].as_array().unwrap();
    assert_eq!(listed.len(), 2, "{listed:?}");
    assert_eq!(listed[0]["file"], "slide.mcap");
    assert_eq!(
        listed[0]["digest"].as_str().unwrap().trim_end_matches('='),
        archive::digest_of(&dir.join("slide.mcap"))
            .unwrap()
            .trim_end_matches('=')
    );
    let (status, bytes) =
        softhaptic_tests::http_get(hub.local_addr(), "/stations/desk-a/archive/slide.mcap").await;
    assert_eq!(status, 200);
    assert!(bytes == std::fs::read(dir.join("slide.mcap")).unwrap());

    let mut viewer = Viewer::connect_url(&format!(
        "ws://{}/ws?station=desk-a&archive=slide.mcap",
        hub.local_addr()
    ))
    .await;
    match viewer.expect_message(Duration::from_secs(10)).await {
        ServerMessage::Hello(h) => assert_eq!(h.mode, softhaptic_proto::wire::Mode::Replay),
        other => panic!("expected hello, got {other:?}"),
    }
    match viewer.expect_message(Duration::from_secs(10)).await {
        ServerMessage::Scene(s) => assert_eq!(
            s.render_meshes[0].url,
            "/stations/desk-a/archive/slide.mcap/meshes/liver.bin"
        ),
        other => panic!("expected scene, got {other:?}"),
    }
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        use futures_util::StreamExt;
        assert!(Instant::now() < deadline, "no replay status");
        let next = tokio::time::timeout(Duration::from_secs(5), viewer.socket.next()).await;
        if let Ok(Some(Ok(tokio_tungstenite::tungstenite::Message::Text(t)))) = next
            && t.starts_with(r#"{"type":"replay""#)
        {
            let r: softhaptic_proto::wire::ReplayStatus = serde_json::from_str(&t).unwrap();
            assert_eq!(r.file, "slide.mcap");
            assert!(r.paused);
            break;
        }
    }
    let (status, mesh) = softhaptic_tests::http_get(
        hub.local_addr(),
        "/stations/desk-a/archive/slide.mcap/meshes/liver.bin",
    )
    .await;
    assert_eq!(status, 200);
    assert!(mesh.len() > 1 << 20);
    hub.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_station_and_a_hub_sign_in_with_a_user_nkey_and_another_key_is_refused() {
    let key = nkeys::KeyPair::new_user();
    let server = NatsServer::start_with_nkey("nkey", &key.public_key());
    let dir = scratch_dir("lab-nkey");
    // As `nk -gen user` writes it: the seed on a line of its own.
    let seed_file = dir.join("desk.nk");
    std::fs::write(&seed_file, format!("{}\n", key.seed().unwrap())).unwrap();
    let stranger = nkeys::KeyPair::new_user().seed().unwrap();
    let wrong = dir.join("stranger.nk");
    std::fs::write(&wrong, format!("{stranger}\n")).unwrap();

    let e = station("desk-n", nats(server.url(), Some(wrong)))
        .await
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("refused this station"), "{e}");
    assert!(!e.contains(&stranger[2..12]), "the seed is not shown: {e}");

    let a = station("desk-n", nats(server.url(), Some(seed_file.clone())))
        .await
        .unwrap();
    let hub = hub(nats(server.url(), Some(seed_file)), false).await;
    wait_until("the station listed", || hub.stations().len() == 1).await;
    let mut viewer =
        Viewer::connect_url(&format!("ws://{}/ws?station=desk-n", hub.local_addr())).await;
    assert_eq!(frames(&mut viewer, 10).await.len(), 10);
    hub.shutdown().await;
    a.shutdown().await;
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_station_signs_in_with_a_creds_file_to_a_nats_in_operator_mode() {
    let (server, creds) = NatsServer::start_with_operator("operator");
    let dir = scratch_dir("lab-creds");
    let creds_file = dir.join("desk.creds");
    std::fs::write(&creds_file, &creds).unwrap();
    // Without it, refused.
    let e = station("desk-c", nats(server.url(), None))
        .await
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("refused this station"), "{e}");

    let a = station("desk-c", nats(server.url(), Some(creds_file.clone())))
        .await
        .unwrap();
    let hub = hub(nats(server.url(), Some(creds_file)), false).await;
    wait_until("the station listed", || hub.stations().len() == 1).await;
    let mut viewer =
        Viewer::connect_url(&format!("ws://{}/ws?station=desk-c", hub.local_addr())).await;
    assert_eq!(frames(&mut viewer, 10).await.len(), 10);
    hub.shutdown().await;
    a.shutdown().await;
    let _ = std::fs::remove_dir_all(&dir);
}
