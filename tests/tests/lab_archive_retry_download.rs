//! A hub's download of an archived recording (`/stations/NAME/archive/FILE`), with a real
//! `nats-server`: the recording goes to the client as the store sends it, never whole in the
//! hub's memory, however many downloads run at once, and arrives byte for byte; one whose parts
//! are not the object's digest is never sent whole.
//!
//! The hub runs in this test's process, so the test counts the heap itself: a global allocator
//! that keeps the most bytes held at once since the test last reset it.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use softhaptic_server::lab::NatsOptions;
use softhaptic_server::lab::archive;
use softhaptic_tests::nats::NatsServer;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// The heap: bytes held now, and the most held since [`reset_peak`].
struct Counting;

static HELD: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

// SAFETY: every call is passed on to the system allocator unchanged; the counters are only
// arithmetic on the sizes asked for.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: the caller's promises about `layout` are the system allocator's.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let now = HELD.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `alloc` above with this `layout`.
        unsafe { System.dealloc(ptr, layout) };
        HELD.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: as for `alloc` and `dealloc`: the caller's promises are the system's.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            if new_size >= layout.size() {
                let grow = new_size - layout.size();
                let now = HELD.fetch_add(grow, Ordering::Relaxed) + grow;
                PEAK.fetch_max(now, Ordering::Relaxed);
            } else {
                HELD.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
            }
        }
        p
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Starts counting the peak from what is held now; returns that.
fn reset_peak() -> usize {
    let now = HELD.load(Ordering::Relaxed);
    PEAK.store(now, Ordering::Relaxed);
    now
}

/// The size of the archived object: a recording of tens of MB, as a long session makes.
const OBJECT_BYTES: usize = 24 << 20;
/// Downloads at once.
const DOWNLOADS: usize = 4;

/// `GET path` on `addr`, read to its end a piece at a time (the test holds no copy of the body,
/// so that the heap it counts is the hub's): status, `Content-Length`, the body's size and
/// SHA-256.
async fn download(addr: std::net::SocketAddr, path: &str) -> (u16, Option<usize>, usize, Vec<u8>) {
    use sha2::Digest;
    let mut socket = tokio::net::TcpStream::connect(addr).await.unwrap();
    socket
        .write_all(
            format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n").as_bytes(),
        )
        .await
        .unwrap();
    let mut head = Vec::new();
    let mut body = (0usize, sha2::Sha256::new());
    let mut piece = vec![0u8; 64 << 10];
    let mut in_body = false;
    loop {
        let read = tokio::time::timeout(Duration::from_secs(120), socket.read(&mut piece))
            .await
            .expect("the download within the deadline");
        // The end, or the hub cutting the connection (a body it could not send whole).
        let n = read.unwrap_or(0);
        if n == 0 {
            break;
        }
        if in_body {
            body.0 += n;
            body.1.update(&piece[..n]);
            continue;
        }
        head.extend_from_slice(&piece[..n]);
        if let Some(end) = head.windows(4).position(|w| w == b"\r\n\r\n") {
            body.0 += head.len() - end - 4;
            body.1.update(&head[end + 4..]);
            head.truncate(end);
            in_body = true;
        }
    }
    let head = String::from_utf8_lossy(&head).into_owned();
    let status = head.split(' ').nth(1).unwrap().parse().unwrap();
    let length = head.lines().find_map(|l| {
        let (name, value) = l.split_once(':')?;
        name.eq_ignore_ascii_case("content-length")
            .then(|| value.trim().parse().unwrap())
    });
    (status, length, body.0, body.1.finalize().to_vec())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn archived_downloads_are_streamed_not_held_whole_in_the_hubs_memory() {
    let server = NatsServer::start("archive-download");
    let nats = NatsOptions::new(server.url());
    // An archived recording's bytes (any bytes: a download does not read them).
    let object: Vec<u8> = (0..OBJECT_BYTES)
        .map(|i| (i as u32).wrapping_mul(2_654_435_761).to_be_bytes()[0])
        .collect();
    {
        let client = softhaptic_server::lab::connect(
            &nats,
            "download test".into(),
            softhaptic_server::lab::Party::Station("desk-d"),
        )
        .await
        .unwrap();
        let store = archive::store(&client, "desk-d").await.unwrap();
        store
            .objects()
            .put("desk-d/long.mcap", &mut object.as_slice())
            .await
            .unwrap();
    }
    let hub = softhaptic_tests::nats::start_hub(nats, false).await;
    let addr = hub.local_addr();

    // Several downloads at once, each read to its end and compared.
    let want = {
        use sha2::Digest;
        sha2::Sha256::digest(&object).to_vec()
    };
    let before = reset_peak();
    let downloads: Vec<_> = (0..DOWNLOADS)
        .map(|_| tokio::spawn(download(addr, "/stations/desk-d/archive/long.mcap")))
        .collect();
    for d in downloads {
        let (status, length, bytes, digest) = d.await.unwrap();
        assert_eq!(status, 200);
        assert_eq!(length, Some(OBJECT_BYTES));
        assert_eq!(bytes, OBJECT_BYTES);
        assert!(digest == want, "the download is not the recording");
    }
    let peak = PEAK.load(Ordering::Relaxed).saturating_sub(before);
    eprintln!(
        "heap peak during {DOWNLOADS} downloads of {} MB: {:.1} MB above the start",
        OBJECT_BYTES >> 20,
        peak as f64 / f64::from(1 << 20)
    );
    // A hub that holds a download whole holds the recording's size at least, once per
    // download; one that streams holds what is in flight.
    assert!(
        peak < OBJECT_BYTES,
        "the heap grew by {peak} bytes for {DOWNLOADS} downloads of {OBJECT_BYTES} bytes"
    );
    hub.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_download_whose_parts_do_not_have_the_objects_digest_never_ends_whole() {
    use base64::Engine;
    let server = NatsServer::start("archive-download-digest");
    let nats = NatsOptions::new(server.url());
    let client = softhaptic_server::lab::connect(
        &nats,
        "digest test".into(),
        softhaptic_server::lab::Party::Station("desk-d"),
    )
    .await
    .unwrap();
    let store = archive::store(&client, "desk-d").await.unwrap();
    // Two objects of the same size (several parts each), different bytes.
    let size = 5 * (128 << 10) + 17;
    let good: Vec<u8> = (0..size).map(|i| (i % 251) as u8).collect();
    let other: Vec<u8> = (0..size).map(|i| (i % 241) as u8).collect();
    store
        .objects()
        .put("desk-d/good.mcap", &mut good.as_slice())
        .await
        .unwrap();
    store
        .objects()
        .put("desk-d/other.mcap", &mut other.as_slice())
        .await
        .unwrap();
    let other_parts = store
        .objects()
        .info("desk-d/other.mcap")
        .await
        .unwrap()
        .nuid;
    // good.mcap's meta, now naming other.mcap's parts: same size and part count, not its
    // digest (as a store damaged, or written by something else, could hold).
    let info = store.objects().info("desk-d/good.mcap").await.unwrap();
    let mut meta = serde_json::to_value(&info).unwrap();
    meta["nuid"] = serde_json::Value::String(other_parts.clone());
    let subject = format!(
        "$O.{}.M.{}",
        archive::bucket("desk-d"),
        base64::engine::general_purpose::URL_SAFE.encode("desk-d/good.mcap")
    );
    client
        .publish(subject, serde_json::to_vec(&meta).unwrap().into())
        .await
        .unwrap();
    client.flush().await.unwrap();
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    while store.objects().info("desk-d/good.mcap").await.unwrap().nuid != other_parts {
        assert!(
            std::time::Instant::now() < deadline,
            "the meta not replaced"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }

    let hub = softhaptic_tests::nats::start_hub(nats, false).await;
    // The intact object downloads whole.
    let (status, length, bytes, digest) =
        download(hub.local_addr(), "/stations/desk-d/archive/other.mcap").await;
    assert_eq!((status, length, bytes), (200, Some(size), size));
    assert!(
        digest == <sha2::Sha256 as sha2::Digest>::digest(&other).to_vec(),
        "the download is not the recording"
    );
    // The damaged one: never the whole body its length promised (the check comes before the
    // last part goes).
    let (status, length, bytes, _) =
        download(hub.local_addr(), "/stations/desk-d/archive/good.mcap").await;
    if status == 200 {
        assert_eq!(length, Some(size));
        assert!(
            bytes < size,
            "a body that is not the recording went out whole"
        );
    } else {
        assert_eq!(status, 404);
    }
    hub.shutdown().await;
}
