//! The WebSocket stream of the real server: greeting, 50 Hz contact frames showing the
//! simulated press, stats, and how incoming messages are handled.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::time::{Duration, Instant};

use softhaptic_proto::wire::{Mode, PROTOCOL_VERSION, Role, ServerMessage};
use softhaptic_proto::{CalibrationSource, ContactFlags};
use softhaptic_tests::{Viewer, start_default, test_options};

const WAIT: Duration = Duration::from_secs(5);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn viewer_gets_hello_scene_then_contact_frames_showing_the_press() {
    let server = start_default(test_options()).await;
    let mut viewer = Viewer::connect(server.local_addr()).await;

    let ServerMessage::Hello(hello) = viewer.expect_message(WAIT).await else {
        panic!("first message is hello")
    };
    assert_eq!(hello.protocol_version, PROTOCOL_VERSION);
    // A loopback server without tokens: every viewer is an instructor.
    assert_eq!(hello.role, Role::Instructor);
    assert_eq!(hello.mode, Mode::Live);
    assert!(hello.server.starts_with("softhaptic "));
    assert!(!hello.session_id.is_empty());

    let ServerMessage::Scene(scene) = viewer.expect_message(WAIT).await else {
        panic!("second message is scene")
    };
    assert_eq!(scene.model.name, "hertz");
    assert_eq!(scene.calibration.source(), CalibrationSource::FemNeoHookean);
    assert_eq!(scene.render_meshes.len(), 1);
    assert_eq!(scene.render_meshes[0].url, "/meshes/liver.bin");
    assert_eq!(scene.device.name, "simulated PHANTOM Desktop");

    // The demonstration approaches for 0.5 s and presses for 0.5 s: among the frames of its
    // first pass the tip is in contact, pressed, and pushed back along the normal. Frames are
    // read until the press is past its deepest (device time, however slowly a loaded machine
    // runs the loop), with a generous deadline; the frame rate itself is checked on virtual
    // time below.
    let started = Instant::now();
    let mut frames: Vec<softhaptic_proto::wire::ContactFrame> = Vec::new();
    let mut stats = 0;
    while frames.last().is_none_or(|f| f.time_ns < 2_500_000_000) {
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "the press did not come"
        );
        match viewer.expect_message(WAIT).await {
            ServerMessage::Contact(f) => frames.push(f),
            ServerMessage::Stats(s) => {
                assert!(s.viewers >= 1);
                stats += 1;
            }
            // Once a second beside the stats.
            ServerMessage::Metrics(m) => assert!(m.ticks > 0),
            other => panic!("unexpected {other:?}"),
        }
    }
    assert!(
        stats >= 1,
        "at least one stats message over 2.5 s of the session"
    );
    for pair in frames.windows(2) {
        assert_eq!(
            pair[1].seq,
            pair[0].seq + 1,
            "no frame lost by a fast viewer"
        );
        assert!(pair[1].tick >= pair[0].tick);
        assert!(pair[1].time_ns >= pair[0].time_ns);
        assert_eq!(pair[1].dropped, 0);
    }
    let pressed = frames
        .iter()
        .filter(|f| f.in_contact && f.depth_m > 0.5e-3)
        .max_by(|a, b| a.depth_m.total_cmp(&b.depth_m))
        .expect("the press is visible in the frames");
    let push = pressed.force_n.dot(pressed.normal);
    assert!(push > 0.05, "force along the normal {push} N");
    assert!(pressed.force_n.length() <= scene.device.peak_force_n + 1e-9);
    assert!(pressed.contact_radius_m > 0.0);
    // R_d comes from the scene's calibration table at the frame's depth.
    let expected = scene.calibration.deformed_radius_m(pressed.depth_m);
    assert!((pressed.deformed_radius_m - expected).abs() < 1e-12);
    assert!(pressed.deformed_radius_m > pressed.contact_radius_m);
    assert!(!pressed.flags.contains(ContactFlags::DEVICE_FAULT));
    assert!(
        frames
            .iter()
            .any(|f| !f.in_contact && f.deformed_radius_m == 0.0)
    );

    server.shutdown().await;
}

/// The frame task sends one contact frame every 20 ms: counted on tokio's virtual clock, so a
/// loaded machine cannot make it look slower or faster.
#[tokio::test(start_paused = true)]
async fn frames_are_produced_at_50_hz_of_the_server_s_clock() {
    use std::sync::atomic::Ordering;
    let server = start_default(test_options()).await;
    let sent = || server.counters().frames_sent.load(Ordering::Relaxed);
    // Let the first tick of the frame interval pass, then count over one virtual second.
    tokio::time::sleep(Duration::from_millis(30)).await;
    let (before, counted_from) = (sent(), tokio::time::Instant::now());
    tokio::time::sleep(Duration::from_secs(1)).await;
    let produced = sent() - before;
    assert_eq!(counted_from.elapsed(), Duration::from_secs(1));
    assert!(
        (49..=51).contains(&produced),
        "{produced} frames in one second of the server's clock"
    );
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_message_closes_only_that_viewer_and_unknown_types_are_ignored() {
    let server = start_default(test_options()).await;
    let addr = server.local_addr();
    let mut bad = Viewer::connect(addr).await;
    let mut odd = Viewer::connect(addr).await;
    let mut good = Viewer::connect(addr).await;
    for v in [&mut bad, &mut odd, &mut good] {
        assert!(matches!(
            v.expect_message(WAIT).await,
            ServerMessage::Hello(_)
        ));
        assert!(matches!(
            v.expect_message(WAIT).await,
            ServerMessage::Scene(_)
        ));
    }

    odd.send_text(r#"{"type":"from_the_future","x":1}"#).await;
    bad.send_text("this is not json").await;

    // The malformed sender is closed: its stream ends within a few frames.
    let mut closed = false;
    for _ in 0..100 {
        match bad.next(WAIT).await {
            None => {
                closed = true;
                break;
            }
            Some(_) => continue,
        }
    }
    assert!(closed, "the malformed sender's connection was closed");

    // The others keep receiving consecutive frames.
    for v in [&mut odd, &mut good] {
        let mut last_seq = None;
        let mut contacts = 0;
        while contacts < 25 {
            if let ServerMessage::Contact(f) = v.expect_message(WAIT).await {
                if let Some(prev) = last_seq {
                    assert_eq!(f.seq, prev + 1);
                }
                last_seq = Some(f.seq);
                contacts += 1;
            }
        }
    }
    let counters = server.counters();
    assert_eq!(
        counters
            .unknown_messages
            .load(std::sync::atomic::Ordering::Relaxed),
        1
    );
    assert_eq!(
        counters
            .malformed_closes
            .load(std::sync::atomic::Ordering::Relaxed),
        1
    );

    // An oversized message closes its sender too.
    let mut huge = Viewer::connect(addr).await;
    huge.send_text(&format!(
        r#"{{"type":"x","pad":"{}"}}"#,
        "a".repeat(200_000)
    ))
    .await;
    let mut closed = false;
    for _ in 0..100 {
        if huge.next(WAIT).await.is_none() {
            closed = true;
            break;
        }
    }
    assert!(closed, "the oversized sender's connection was closed");
    assert!(matches!(
        good.expect_message(WAIT).await,
        ServerMessage::Contact(_) | ServerMessage::Stats(_)
    ));

    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_closes_viewers_and_stops_the_loop() {
    let server = start_default(test_options()).await;
    let mut viewer = Viewer::connect(server.local_addr()).await;
    assert!(matches!(
        viewer.expect_message(WAIT).await,
        ServerMessage::Hello(_)
    ));
    softhaptic_tests::wait_until("200 ticks of the loop", || server.loop_stats().ticks >= 200)
        .await;
    let stats = server.shutdown().await;
    assert!(stats.ticks >= 200, "the loop ran: {} ticks", stats.ticks);
    // The viewer's stream ends (close frame) instead of hanging.
    let mut ended = false;
    for _ in 0..100 {
        if viewer.next(WAIT).await.is_none() {
            ended = true;
            break;
        }
    }
    assert!(ended);
}
