//! The lab's archive upload against a real `nats-server` that is restarted part way: the upload
//! resumes with only the parts the store does not hold, is verified by the whole file's SHA-256,
//! and the hub lists and serves it byte for byte, beside an object an older station wrote with a
//! plain object-store `put`. The local file stays throughout.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use softhaptic_server::lab::archive::{self, UploadEvent, UploadOptions};
use softhaptic_server::lab::hub::RunningHub;
use softhaptic_tests::nats::{NatsServer, options as nats, start_hub};
use softhaptic_tests::scratch_dir;
use tokio::sync::mpsc;

/// Small parts, so that a recording of a few hundred kB is many of them.
const PART_BYTES: usize = 4096;
/// Parts the test lets through before it stops NATS.
const PAUSE_AFTER: usize = 20;
/// Every wait in this file: generous, for a loaded 2-core CI machine.
const DEADLINE: Duration = Duration::from_secs(120);

/// A copy of a recorded session in a fresh directory, and its number of parts.
fn recording(dir: &Path, name: &str) -> (PathBuf, usize) {
    let sessions = softhaptic_tests::repo_scenes().join("../tests/sessions");
    let path = dir.join(name);
    std::fs::copy(sessions.join("slide.mcap"), &path).unwrap();
    let bytes = std::fs::metadata(&path).unwrap().len() as usize;
    let total = bytes.div_ceil(PART_BYTES);
    assert!(total > 3 * PAUSE_AFTER, "{bytes} bytes: too few parts");
    (path, total)
}

async fn next_event(rx: &mut mpsc::Receiver<UploadEvent>) -> UploadEvent {
    tokio::time::timeout(DEADLINE, rx.recv())
        .await
        .expect("an upload event within the deadline")
        .expect("the upload reports until it is verified")
}

/// Lets the upload store its first [`PAUSE_AFTER`] parts and returns with it waiting for the
/// test to take the next event (it has stored at most two more parts by then).
async fn hold_after_some_parts(rx: &mut mpsc::Receiver<UploadEvent>, total: usize) {
    assert_eq!(
        next_event(rx).await,
        UploadEvent::Resuming { held: 0, total }
    );
    for index in 0..PAUSE_AFTER {
        assert_eq!(next_event(rx).await, UploadEvent::Stored { index, total });
    }
}

/// The parts an upload stored, from its events until it was verified; and the `held` of its first
/// `Resuming`.
async fn events_until_verified(
    rx: &mut mpsc::Receiver<UploadEvent>,
    total: usize,
) -> (Vec<usize>, Option<usize>) {
    let (mut stored, mut first_held) = (Vec::new(), None);
    loop {
        match next_event(rx).await {
            UploadEvent::Resuming { held, total: t } => {
                assert_eq!(t, total);
                first_held.get_or_insert(held);
            }
            UploadEvent::Stored { index, total: t } => {
                assert_eq!(t, total);
                stored.push(index);
            }
            UploadEvent::Verified { total: t, .. } => {
                assert_eq!(t, total);
                return (stored, first_held);
            }
        }
    }
}

/// `attempt`'s first success, tried again until the deadline (NATS just restarted: JetStream
/// may answer a moment after the port does).
async fn until_ok<T, F: std::future::Future<Output = Result<T, String>>>(
    what: &str,
    mut attempt: impl FnMut() -> F,
) -> T {
    let deadline = Instant::now() + DEADLINE;
    loop {
        match attempt().await {
            Ok(t) => return t,
            Err(e) => assert!(Instant::now() < deadline, "{what}: {e}"),
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_upload_cut_by_a_nats_restart_resends_only_the_missing_parts_and_the_hub_reads_it_back()
{
    let mut server = NatsServer::start("archive-resume");
    let dir = scratch_dir("lab-archive-resume");
    let (path, total) = recording(&dir, "slide.mcap");
    let local = std::fs::read(&path).unwrap();
    let client = softhaptic_server::lab::connect(
        &nats(server.url()),
        "resume test".into(),
        softhaptic_server::lab::Party::Station("desk-a"),
    )
    .await
    .unwrap();
    let store = archive::store(&client, "desk-a").await.unwrap();

    // The first attempt stores some parts, then NATS stops under it; it gives up at once.
    let (tx, mut rx) = mpsc::channel(1);
    let options = UploadOptions {
        part_bytes: PART_BYTES,
        resume_within: Duration::ZERO,
        progress: Some(tx),
    };
    let first = {
        let (store, path) = (store.clone(), path.clone());
        tokio::spawn(async move { archive::upload_with(&store, "desk-a", &path, &options).await })
    };
    hold_after_some_parts(&mut rx, total).await;
    let listed = archive::list(&client, Some("desk-a")).await.unwrap();
    assert!(
        listed.is_empty(),
        "an unverified upload is listed: {listed:?}"
    );
    server.kill();
    drop(rx);
    let failed = tokio::time::timeout(DEADLINE, first)
        .await
        .unwrap()
        .unwrap()
        .unwrap_err();
    assert!(
        failed.contains(&format!("of {total} parts stored")),
        "{failed}"
    );
    assert!(
        std::fs::read(&path).unwrap() == local,
        "the local file is kept as it was"
    );

    // NATS back with the same store: the next attempt asks what is there and sends the rest.
    server.restart();
    let store = until_ok("the object store", || archive::store(&client, "desk-a")).await;
    let (tx, mut rx) = mpsc::channel(1);
    let options = UploadOptions {
        part_bytes: PART_BYTES,
        progress: Some(tx),
        ..Default::default()
    };
    let second = {
        let (store, path) = (store.clone(), path.clone());
        tokio::spawn(async move { archive::upload_with(&store, "desk-a", &path, &options).await })
    };
    let (stored, held) = events_until_verified(&mut rx, total).await;
    assert_eq!(
        tokio::time::timeout(DEADLINE, second)
            .await
            .unwrap()
            .unwrap(),
        Ok(true)
    );
    let held = held.unwrap();
    // What the first attempt stored: the parts the test saw, at most the two it stored while the
    // test held it, and the one it had sent when NATS went (stored when the client reconnects).
    assert!(
        (PAUSE_AFTER..=PAUSE_AFTER + 3).contains(&held),
        "the store held {held} parts"
    );
    let distinct: BTreeSet<usize> = stored.iter().copied().collect();
    assert_eq!(
        distinct.len(),
        stored.len(),
        "a part was sent twice: {stored:?}"
    );
    assert_eq!(
        distinct,
        (held..total).collect(),
        "not exactly the missing parts"
    );
    assert!(stored.len() < total);
    eprintln!(
        "{total} parts of {PART_BYTES} bytes; {held} stored before NATS stopped; {} sent after it came back",
        stored.len()
    );

    // The store's digest is the file's; hubs list it and serve it byte for byte.
    let digest = archive::digest_of(&path).unwrap();
    let listed = archive::list(&client, Some("desk-a")).await.unwrap();
    assert_eq!(listed.len(), 1, "{listed:?}");
    assert_eq!(listed[0].digest, digest);
    assert_eq!(listed[0].bytes, local.len() as u64);
    assert!(
        std::fs::read(&path).unwrap() == local,
        "the local file is kept"
    );
    assert_eq!(
        archive::upload_with(&store, "desk-a", &path, &UploadOptions::default()).await,
        Ok(false),
        "archived once"
    );

    // An object an older station wrote with the object store's own `put` reads the same way.
    let legacy = softhaptic_tests::repo_scenes().join("../tests/sessions/sphere-press.mcap");
    let mut reader = tokio::fs::File::open(&legacy).await.unwrap();
    store
        .objects()
        .put("desk-a/older.mcap", &mut reader)
        .await
        .unwrap();

    let hub = hub(server.url()).await;
    let (status, body) =
        softhaptic_tests::http_get(hub.local_addr(), "/api/archive?station=desk-a").await;
    assert_eq!(status, 200);
    let body: serde_json::Value = serde_json::from_slice(&body).unwrap();
    let files: Vec<&str> = body["archive"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["file"].as_str().unwrap())
        .collect();
    assert_eq!(files, ["older.mcap", "slide.mcap"]);
    for (file, want) in [
        ("slide.mcap", local.clone()),
        ("older.mcap", std::fs::read(&legacy).unwrap()),
    ] {
        let (status, bytes) = softhaptic_tests::http_get(
            hub.local_addr(),
            &format!("/stations/desk-a/archive/{file}"),
        )
        .await;
        assert_eq!(status, 200, "{file}");
        assert!(bytes == want, "{file}: {} bytes served", bytes.len());
    }
    hub.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_nats_restart_during_an_upload_is_resumed_in_the_same_call_without_resending_a_part() {
    let mut server = NatsServer::start("archive-resume-same-call");
    let dir = scratch_dir("lab-archive-resume-same-call");
    let (path, total) = recording(&dir, "slide.mcap");
    let client = softhaptic_server::lab::connect(
        &nats(server.url()),
        "resume test".into(),
        softhaptic_server::lab::Party::Station("desk-a"),
    )
    .await
    .unwrap();
    let store = archive::store(&client, "desk-b").await.unwrap();
    let (tx, mut rx) = mpsc::channel(1);
    let options = UploadOptions {
        part_bytes: PART_BYTES,
        resume_within: DEADLINE,
        progress: Some(tx),
    };
    let upload = {
        let (store, path) = (store.clone(), path.clone());
        tokio::spawn(async move { archive::upload_with(&store, "desk-b", &path, &options).await })
    };
    hold_after_some_parts(&mut rx, total).await;
    server.kill();
    server.restart();
    // Either the client's reconnection carried the next part through, or the upload asked the
    // store what it holds: in both cases no part goes twice and the whole file is verified.
    let (stored, _) = events_until_verified(&mut rx, total).await;
    assert_eq!(
        tokio::time::timeout(DEADLINE, upload)
            .await
            .unwrap()
            .unwrap(),
        Ok(true)
    );
    let mut all: Vec<usize> = (0..PAUSE_AFTER).chain(stored).collect();
    let sent = all.len();
    all.sort_unstable();
    all.dedup();
    assert_eq!(all.len(), sent, "a part was sent twice");
    assert!(all.iter().all(|&i| i < total));
    let listed = archive::list(&client, Some("desk-b")).await.unwrap();
    assert_eq!(listed.len(), 1, "{listed:?}");
    assert_eq!(listed[0].digest, archive::digest_of(&path).unwrap());
    assert!(path.is_file(), "the local file is kept");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_parts_of_an_upload_that_can_never_finish_are_swept_once_old_and_nothing_else_is() {
    let server = NatsServer::start("archive-orphans");
    let dir = scratch_dir("lab-archive-orphans");
    let client = softhaptic_server::lab::connect(
        &nats(server.url()),
        "orphan test".into(),
        softhaptic_server::lab::Party::Station("desk-a"),
    )
    .await
    .unwrap();
    let store = archive::store(&client, "desk-a").await.unwrap();
    let small = UploadOptions {
        part_bytes: PART_BYTES,
        ..UploadOptions::default()
    };
    // One recording archived whole.
    let (kept, kept_parts) = recording(&dir, "slide.mcap");
    assert_eq!(
        archive::upload_with(&store, "desk-a", &kept, &small).await,
        Ok(true)
    );
    // Another cut short after some parts, then changed on disk before any pass resumed it: its
    // parts are under an id no upload of the file as it is now will ever use.
    let (cut, cut_parts) = recording(&dir, "cut.mcap");
    let (tx, mut rx) = mpsc::channel(1);
    let upload = {
        let (store, cut) = (store.clone(), cut.clone());
        let options = UploadOptions {
            progress: Some(tx),
            ..small.clone()
        };
        tokio::spawn(async move { archive::upload_with(&store, "desk-a", &cut, &options).await })
    };
    hold_after_some_parts(&mut rx, cut_parts).await;
    upload.abort();
    let _ = upload.await;
    drop(rx);
    let mut bytes = std::fs::read(&cut).unwrap();
    bytes.push(0);
    std::fs::write(&cut, &bytes).unwrap();

    let before = archive::stored_parts(&store).await.unwrap();
    assert_eq!(before.len(), 2, "{before:?}");
    assert!(before.iter().any(|(_, n)| *n == kept_parts), "{before:?}");
    let orphan = before
        .iter()
        .find(|(_, n)| *n != kept_parts)
        .cloned()
        .unwrap();
    assert!(orphan.1 >= PAUSE_AFTER, "{orphan:?}");

    // Young parts are kept: the upload could still be going.
    assert_eq!(
        archive::sweep_orphan_parts(&store, Duration::from_secs(3600)).await,
        Ok(vec![])
    );
    assert_eq!(archive::stored_parts(&store).await.unwrap(), before);
    // Once old enough, the unused ones go, and only they.
    let removed = archive::sweep_orphan_parts(&store, Duration::ZERO)
        .await
        .unwrap();
    assert_eq!(removed, vec![orphan]);
    let after = archive::stored_parts(&store).await.unwrap();
    assert_eq!(after.len(), 1);
    assert_eq!(after[0].1, kept_parts);
    // The archived recording reads back whole.
    let fetched = archive::fetch(&client, "desk-a", "slide.mcap", u64::MAX)
        .await
        .unwrap();
    assert!(fetched == std::fs::read(&kept).unwrap());
    // And the changed file archives from its first part under its own id.
    assert_eq!(
        archive::upload_with(&store, "desk-a", &cut, &small).await,
        Ok(true)
    );
    assert_eq!(
        archive::sweep_orphan_parts(&store, Duration::ZERO).await,
        Ok(vec![])
    );
}

async fn hub(url: String) -> RunningHub {
    start_hub(nats(url), false).await
}
