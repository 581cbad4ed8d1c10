//! The lab's archive when NATS is down, with a real `nats-server`: a station that starts with NATS
//! down archives its finished recordings once NATS is back, while it keeps running (not only at
//! its next start), and its own at stop; a hub asked for the archive's list with NATS down says
//! the archive did not answer (502), not that nothing is archived.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::path::Path;
use std::time::{Duration, Instant};

use softhaptic_server::lab::archive::{self, StationArchive};
use softhaptic_server::lab::hub::RunningHub;
use softhaptic_tests::nats::{NatsServer, options as nats, start_hub};
use softhaptic_tests::scratch_dir;

/// Every wait in this file: generous, for a loaded 2-core CI machine (a pass with NATS down
/// takes the JetStream requests' timeouts).
const DEADLINE: Duration = Duration::from_secs(180);

fn session(name: &str) -> std::path::PathBuf {
    softhaptic_tests::repo_scenes()
        .join("../tests/sessions")
        .join(name)
}

/// Waits until `$station/$file` is listed with `$path`'s digest, and reads the object back
/// through the object store's reader: the file's bytes. (A macro: this crate does not name
/// the NATS client's type.)
macro_rules! until_archived {
    ($client:expr, $station:expr, $file:expr, $path:expr) => {{
        use tokio::io::AsyncReadExt;
        let (client, station, file, path): (_, &str, &str, &Path) =
            ($client, $station, $file, $path);
        let digest = archive::digest_of(path).unwrap();
        let deadline = Instant::now() + DEADLINE;
        loop {
            let listed = archive::list(client, Some(station)).await;
            if let Some(entry) = listed
                .as_ref()
                .ok()
                .and_then(|l| l.iter().find(|a| a.file == file))
            {
                assert_eq!(
                    entry.digest.trim_end_matches('='),
                    digest.trim_end_matches('='),
                    "{entry:?}"
                );
                break;
            }
            assert!(
                Instant::now() < deadline,
                "{station}/{file} not archived within {DEADLINE:?}: {listed:?}"
            );
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
        let store = archive::store(client, station).await.unwrap();
        let mut object = store
            .objects()
            .get(archive::object_name(station, file))
            .await
            .unwrap();
        let mut bytes = Vec::new();
        object.read_to_end(&mut bytes).await.unwrap();
        assert!(
            bytes == std::fs::read(path).unwrap(),
            "the stored object is not the file"
        );
    }};
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_recording_left_unarchived_while_nats_was_down_is_archived_once_it_is_back() {
    let mut server = NatsServer::start("archive-retry");
    server.kill();
    let dir = scratch_dir("lab-archive-retry");
    let earlier = dir.join("earlier.mcap");
    std::fs::copy(session("slide.mcap"), &earlier).unwrap();
    let current = dir.join("current.mcap");

    // The station starts with NATS down: its client connects in the background.
    let client = softhaptic_server::lab::connect(
        &nats(server.url()),
        "retry test".into(),
        softhaptic_server::lab::Party::Station("desk-r"),
    )
    .await
    .unwrap();
    let archive = StationArchive::start(
        client.clone(),
        "desk-r".into(),
        dir.clone(),
        Some(current.clone()),
        Default::default(),
    );

    // Its first pass fails: the recording is reported, kept, and not archived.
    let mut progress = archive.progress();
    let first = tokio::time::timeout(DEADLINE, progress.wait_for(|p| p.passes >= 1))
        .await
        .expect("a first pass within the deadline")
        .unwrap()
        .clone();
    let report = first.last.unwrap();
    assert!(!first.done, "{report:?}");
    assert!(report.uploaded.is_empty(), "{report:?}");
    assert_eq!(report.failed.len(), 1, "{report:?}");
    assert!(report.failed[0].0.ends_with("earlier.mcap"), "{report:?}");
    assert!(earlier.is_file(), "the local file is kept");

    // NATS comes back while the station runs: the recording is archived and verified, with no
    // restart of the station.
    server.restart();
    until_archived!(&client, "desk-r", "earlier.mcap", &earlier);
    let done = tokio::time::timeout(DEADLINE, progress.wait_for(|p| p.done))
        .await
        .expect("the passes end once nothing failed")
        .unwrap()
        .clone();
    assert!(done.passes >= 2, "{done:?}");
    let last = done.last.unwrap();
    assert!(last.failed.is_empty(), "{last:?}");
    assert!(earlier.is_file(), "the local file is kept");

    // The station stops: its own recording is archived, verified, too.
    std::fs::copy(session("sphere-press.mcap"), &current).unwrap();
    assert_eq!(archive.finish(&current, DEADLINE).await, Ok(true));
    until_archived!(&client, "desk-r", "current.mcap", &current);
    let listed = archive::list(&client, Some("desk-r")).await.unwrap();
    let files: Vec<&str> = listed.iter().map(|a| a.file.as_str()).collect();
    assert_eq!(files, ["current.mcap", "earlier.mcap"]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_nats_down_the_hub_says_the_archive_did_not_answer_not_that_it_is_empty() {
    let mut server = NatsServer::start("archive-list-down");
    let hub = hub(server.url()).await;
    let path = "/api/archive?station=desk-l";

    // NATS up, nothing ever archived (no bucket): an empty list.
    let (status, body) = softhaptic_tests::http_get(hub.local_addr(), path).await;
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&body));
    let body: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(body, serde_json::json!({ "archive": [] }));

    // One recording archived.
    let client = softhaptic_server::lab::connect(
        &nats(server.url()),
        "list test".into(),
        softhaptic_server::lab::Party::Station("desk-l"),
    )
    .await
    .unwrap();
    let store = archive::store(&client, "desk-l").await.unwrap();
    assert_eq!(
        archive::upload(&store, "desk-l", &session("slide.mcap")).await,
        Ok(true)
    );
    let (status, _) = softhaptic_tests::http_get(hub.local_addr(), path).await;
    assert_eq!(status, 200);

    // NATS down: the archive did not answer (502, a short public reason), not "nothing" (once
    // the list the hub made just before, which it serves for 2 s to every page, is stale).
    server.kill();
    let deadline = Instant::now() + DEADLINE;
    let (status, body) = loop {
        let (status, body) = softhaptic_tests::http_get(hub.local_addr(), path).await;
        if status != 200 {
            break (status, body);
        }
        assert!(Instant::now() < deadline, "the list outlived NATS");
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    let text = String::from_utf8_lossy(&body).into_owned();
    assert_eq!(status, 502, "{text}");
    assert!(!text.contains("\"archive\""), "{text}");
    let body: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(
        body["error"], "the station or the archive did not answer",
        "{text}"
    );

    // NATS back: the list again, with the recording.
    server.restart();
    let deadline = Instant::now() + DEADLINE;
    loop {
        let (status, body) = softhaptic_tests::http_get(hub.local_addr(), path).await;
        if status == 200 {
            let body: serde_json::Value = serde_json::from_slice(&body).unwrap();
            let files: Vec<&str> = body["archive"]
                .as_array()
                .unwrap()
                .iter()
                .map(|a| a["file"].as_str().unwrap())
                .collect();
            assert_eq!(files, ["slide.mcap"]);
            break;
        }
        assert_eq!(status, 502);
        assert!(
            Instant::now() < deadline,
            "the list did not come back with NATS"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    // Read again from the store on reconnection (what changed meanwhile came with no feed to
    // the hub): the buckets listed once more, and the bucket followed by a new consumer.
    assert!(
        hub.archive_bucket_listings() >= 2,
        "{}",
        hub.archive_bucket_listings()
    );
    assert!(hub.archive_consumers() >= 2, "{}", hub.archive_consumers());
    hub.shutdown().await;
}

async fn hub(url: String) -> RunningHub {
    start_hub(nats(url), false).await
}
