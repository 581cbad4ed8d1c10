//! The trainee's metrics end to end: a viewer gets them once a second; the loop's final metrics
//! are what the recording gives when computed again from its ticks (`info`, `export`), and what
//! the replay check's world computes replaying them.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::time::{Duration, Instant};

use softhaptic_proto::wire::ServerMessage;
use softhaptic_server::app;
use softhaptic_server::scene::Scene;
use softhaptic_server::session::check::{CheckOverrides, check};
use softhaptic_server::session::cli::{LiveRecording, RecordArgs};
use softhaptic_server::session::reader::Recording;
use softhaptic_server::session::tools::{Info, export, recording_metrics};
use softhaptic_server::stream::metrics_message;
use softhaptic_tests::{Viewer, scratch_dir, test_options};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn live_recorded_exported_and_replayed_metrics_are_the_same() {
    let scene = Scene::builtin_default().unwrap();
    let dir = scratch_dir("metrics");
    let args = RecordArgs {
        no_record: false,
        record_dir: dir.clone(),
    };
    let mut recording = LiveRecording::start(&args, &scene, None).unwrap().unwrap();
    let mut options = test_options();
    options.tick_sink = recording.take_tick_sink();
    options.session_id = Some(recording.session_id().to_owned());
    let server = app::start(scene, options).await.unwrap();
    recording.attach(&server);

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

    let (_, final_live) = server.shutdown_with_metrics().await;
    let (path, stats) = recording.finish().unwrap();
    let r = Recording::open(&path).unwrap();
    let recorded = recording_metrics(&r);

    // The replaying world computes them from the recorded ticks as the live one did.
    let report = check(&r, CheckOverrides::default()).unwrap();
    assert!(report.passed(), "{report}");
    assert_eq!(report.metrics, recorded);
    // The live loop's, when the recording holds every tick it ran (a loaded machine may make the
    // recorder drop some; then the recording's are of the ticks it holds).
    if stats.ticks_dropped == 0 && r.missing_ticks() == 0 {
        assert_eq!(recorded, final_live);
    } else {
        assert!(recorded.ticks < final_live.ticks);
    }
    assert!(final_live.ticks >= live.ticks);

    // `info` and `export` give the same.
    assert_eq!(Info::of(&r).metrics, recorded);
    let out = dir.join("export");
    let (_, _, json) = export(&r, &out).unwrap();
    let exported: softhaptic_proto::wire::MetricsMessage =
        serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap();
    assert_eq!(exported, metrics_message(&recorded, true));
    let _ = std::fs::remove_dir_all(&dir);
}
