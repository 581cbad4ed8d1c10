//! The trainee's metrics end to end: a viewer gets them once a second; the loop's final metrics
//! are recorded, and are what the recording gives when computed again from its ticks (`info`,
//! `export`), what the replay check's world computes replaying them, and what a replay sends.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::time::{Duration, Instant};

use softhaptic_proto::wire::ServerMessage;
use softhaptic_server::access::AccessConfig;
use softhaptic_server::app::default_web_dir;
use softhaptic_server::scene::Scene;
use softhaptic_server::session::check::{CheckOverrides, check};
use softhaptic_server::session::reader::Recording;
use softhaptic_server::session::replay::{self, ReplayOptions};
use softhaptic_server::session::tools::{Info, export, recording_metrics};
use softhaptic_server::stream::{ViewerLimits, metrics_message};
use softhaptic_tests::{Viewer, scratch_dir, start_recorded, test_options};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn live_recorded_exported_and_replayed_metrics_are_the_same() {
    let scene = Scene::builtin_default().unwrap();
    let dir = scratch_dir("metrics");
    let session = start_recorded(scene, &dir, test_options()).await;
    let server = &session.server;

    // A viewer gets the metrics; once the simulated hand has pressed, they show it.
    let mut viewer = Viewer::connect(server.local_addr()).await;
    let deadline = Instant::now() + Duration::from_secs(60);
    let live = loop {
        assert!(Instant::now() < deadline, "no metrics with a press");
        if let Some(Ok(ServerMessage::Metrics(m))) = viewer.next(Duration::from_secs(10)).await
            && m.pushes >= 1
            && m.time_in_contact_s > 0.2
        {
            break m;
        }
    };
    assert!(!live.is_final);
    assert!(live.peak_force_n > 0.1 && live.ticks > 500, "{live:?}");
    assert_eq!(live.safe_force_n, 2.0);

    let (_, final_live, path, stats) = session.finish().await;
    let r = Recording::open(&path).unwrap();
    let recorded = recording_metrics(&r);

    // The recording keeps the 1 Hz messages viewers were sent and, last, the loop's final ones.
    assert!(r.metrics.iter().any(|m| !m.is_final), "{:?}", r.metrics);
    assert_eq!(r.metrics.iter().filter(|m| m.is_final).count(), 1);
    assert_eq!(r.final_metrics(), Some(&metrics_message(&final_live, true)));

    // The replaying world computes them from the recorded ticks as the live one did.
    let report = check(&r, CheckOverrides::default()).unwrap();
    assert!(report.passed(), "{report}");
    assert_eq!(report.metrics, recorded);
    // The live loop's, when the recording holds every tick it ran (a loaded machine may make the
    // recorder drop some; then the recording's are of the ticks it holds).
    if stats.ticks_dropped == 0 && r.missing_ticks() == 0 {
        assert_eq!(recorded, final_live);
        assert!(matches!(Info::of(&r).recorded_metrics, Some((_, true))));
        assert!(report.metrics_compared);
        assert!(
            report.to_string().contains("metrics are the ones recorded"),
            "{report}"
        );
        // `check` holds the replay's metrics against the recorded ones, to the bit.
        let mut tampered = r.clone();
        let last = tampered.metrics.len() - 1;
        tampered.metrics[last].path_length_in_contact_m += 1e-12;
        let report = check(&tampered, CheckOverrides::default()).unwrap();
        assert!(!report.passed());
        assert!(report.first_difference.is_none());
        assert!(report.to_string().contains("metrics differ"), "{report}");
        assert!(matches!(
            Info::of(&tampered).recorded_metrics,
            Some((_, false))
        ));
    } else {
        assert!(recorded.ticks < final_live.ticks);
    }
    assert!(final_live.ticks >= live.ticks);

    // `info` and `export` give the same.
    assert_eq!(Info::of(&r).metrics, recorded);
    let out = dir.join("export");
    let (_, _, json) = export(&r, &out, false).unwrap();
    // A second export into the same directory keeps the first, unless told to replace it.
    let e = export(&r, &out, false).unwrap_err().to_string();
    assert!(e.contains("device.csv") && e.contains("--replace"), "{e}");
    export(&r, &out, true).unwrap();
    let exported: softhaptic_proto::wire::MetricsMessage =
        serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap();
    assert_eq!(exported, metrics_message(&recorded, true));

    // The replay sends them on the recording's timeline: once a second, then the final ones.
    let replay = replay::start(
        r.clone(),
        ReplayOptions {
            addr: ([127, 0, 0, 1], 0).into(),
            web_dir: default_web_dir(),
            speed: 8.0,
            start_paused: false,
            viewer_limits: ViewerLimits::default(),
            access: AccessConfig::default(),
            tls: None,
        },
    )
    .await
    .unwrap();
    let mut watcher = Viewer::connect(replay.local_addr()).await;
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut seen = Vec::new();
    let replayed_final = loop {
        assert!(
            Instant::now() < deadline,
            "no final metrics in the replay: {seen:?}"
        );
        if let Some(Ok(ServerMessage::Metrics(m))) = watcher.next(Duration::from_secs(10)).await {
            if m.is_final {
                break m;
            }
            seen.push(m);
        }
    };
    assert_eq!(replayed_final, metrics_message(&recorded, true));
    // Non-decreasing as the replay plays on.
    assert!(
        seen.windows(2)
            .all(|w| w[0].ticks <= w[1].ticks && w[0].pushes <= w[1].pushes)
    );
    replay.shutdown().await;
    let _ = std::fs::remove_dir_all(&dir);
}
