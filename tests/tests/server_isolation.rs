//! A slow or stalled viewer never delays the others or the haptic loop.
//!
//! The checks are on correctness, not timing: the other viewers keep receiving, every frame
//! produced either reaching them or counted as lost in what the server tells them, and the
//! force of every tick of a deterministic run (simulated device, fixed time step) is
//! bit-identical to a run with no viewer at all.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use futures_util::StreamExt;
use softhaptic_device::haptic_loop::TickRecord;
use softhaptic_proto::wire::ServerMessage;
use softhaptic_tests::{Viewer, start_default, test_options, wait_until};
use tokio_tungstenite::tungstenite::Message;

const WAIT: Duration = Duration::from_secs(10);
/// Ring large enough for the whole of one run, so no tick record is dropped before the end.
const RING: usize = 20_000;

/// Every tick record the ring holds, checked to be consecutive from tick 0.
fn drain(consumer: &mut rtrb::Consumer<TickRecord>) -> Vec<TickRecord> {
    let mut records = Vec::new();
    while let Ok(r) = consumer.pop() {
        records.push(r);
    }
    for (k, r) in records.iter().enumerate() {
        assert_eq!(r.contact.tick, k as u64, "tick records are consecutive");
    }
    records
}

/// What one viewer received while counting: how many contact frames, and the first and last
/// frame's `seq` and `dropped`.
#[derive(Debug, Default, Clone, Copy)]
struct Received {
    frames: u64,
    first: Option<(u64, u64)>,
    last: Option<(u64, u64)>,
}

impl Received {
    /// Every frame produced between the first and the last one it received reached it or is
    /// counted in what the server told it it lost: the stream never loses a frame silently.
    fn accounts_for_every_frame(&self) -> bool {
        match (self.first, self.last) {
            (Some((s0, d0)), Some((s1, d1))) => s1 - s0 + 1 == self.frames + (d1 - d0),
            _ => false,
        }
    }
}

/// Reads `viewer` until `stop`, counting contact frames received while `counting` is set.
async fn count_frames(
    mut viewer: Viewer,
    counting: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
) -> Received {
    let mut got = Received::default();
    while !stop.load(Ordering::Relaxed) {
        let next = tokio::time::timeout(Duration::from_millis(200), viewer.socket.next()).await;
        match next {
            Ok(Some(Ok(Message::Text(text)))) => {
                if !counting.load(Ordering::Relaxed) {
                    continue;
                }
                if let Ok(ServerMessage::Contact(f)) = ServerMessage::decode(&text) {
                    got.frames += 1;
                    got.first.get_or_insert((f.seq, f.dropped));
                    got.last = Some((f.seq, f.dropped));
                }
            }
            Ok(Some(Ok(_))) | Err(_) => {}
            Ok(None) | Ok(Some(Err(_))) => break,
        }
    }
    got
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_hundred_viewers_and_a_stalled_one_leave_rates_and_forces_unchanged() {
    // Run with viewers: 199 that read, one that never reads, over small socket buffers so the
    // stalled one blocks its connection within a second.
    let (producer, mut with_viewers_ring) = rtrb::RingBuffer::new(RING);
    let mut options = test_options();
    options.tick_sink = Some(producer);
    options.send_buffer_bytes = Some(8 * 1024);
    // The stalled viewer's connection is cut once a send has waited this long.
    options.viewer_limits.send_timeout = Duration::from_secs(1);
    // All 200 viewers come from this machine's one address.
    options.access.limits.max_per_address = 200;
    let server = start_default(options).await;
    let addr = server.local_addr();

    let stalled = Viewer::connect_with_small_buffer(addr, 4 * 1024).await;
    let counting = Arc::new(AtomicBool::new(false));
    let stop = Arc::new(AtomicBool::new(false));
    let mut readers = Vec::new();
    for _ in 0..199 {
        let mut viewer = Viewer::connect(addr).await;
        assert!(matches!(
            viewer.expect_message(WAIT).await,
            ServerMessage::Hello(_)
        ));
        assert!(matches!(
            viewer.expect_message(WAIT).await,
            ServerMessage::Scene(_)
        ));
        readers.push(tokio::spawn(count_frames(
            viewer,
            Arc::clone(&counting),
            Arc::clone(&stop),
        )));
    }
    // Every viewer is connected, except the stalled one if its send timeout already expired.
    let counters = server.counters();
    assert_eq!(
        counters.viewers.load(Ordering::Relaxed)
            + counters.stalled_closes.load(Ordering::Relaxed) as u32,
        200,
        "every viewer connected"
    );

    // Counted over 100 frames of the server's production, however long a loaded machine takes
    // to make them.
    let sent = || server.counters().frames_sent.load(Ordering::Relaxed);
    counting.store(true, Ordering::Relaxed);
    let produced_from = sent();
    let give_up = Instant::now() + Duration::from_secs(60);
    while sent() < produced_from + 100 {
        assert!(
            Instant::now() < give_up,
            "the server stopped producing frames"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    counting.store(false, Ordering::Relaxed);
    let produced = sent() - produced_from;
    stop.store(true, Ordering::Relaxed);
    let mut received = Vec::new();
    for r in readers {
        received.push(r.await.unwrap());
    }
    // Frames each reading viewer got, as a share of those produced while counting.
    let mut shares: Vec<f64> = received
        .iter()
        .map(|r| r.frames as f64 / produced as f64)
        .collect();
    shares.sort_by(f64::total_cmp);
    let stalled_lost = server.counters().dropped_frames.load(Ordering::Relaxed);
    // Its socket buffers fill within a second, its next send waits out the timeout, and the
    // server closes it; the others were served meanwhile (the rates above).
    let cut_by = Instant::now() + Duration::from_secs(10);
    while server.counters().stalled_closes.load(Ordering::Relaxed) == 0 && Instant::now() < cut_by {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let stalled_closes = server.counters().stalled_closes.load(Ordering::Relaxed);
    let with_viewers_stats = server.loop_stats();
    drop(stalled);
    server.shutdown().await;
    let with_viewers = drain(&mut with_viewers_ring);
    eprintln!(
        "200 viewers: share of the {produced} frames produced received, min {:.2} median {:.2} max {:.2}; frames lost (all viewers) {stalled_lost}; stalled viewers cut {stalled_closes}; loop period error p50 {} ns p99 {} ns p999 {} ns max {} ns",
        shares[0],
        shares[shares.len() / 2],
        shares[shares.len() - 1],
        with_viewers_stats.period_error_p50_ns,
        with_viewers_stats.period_error_p99_ns,
        with_viewers_stats.period_error_p999_ns,
        with_viewers_stats.period_error_max_ns,
    );
    // The stalled viewer held none of the others: each kept receiving the newest frames, and
    // every frame it did not get is one the server told it it lost.
    for (k, r) in received.iter().enumerate() {
        assert!(r.frames > 0, "reader {k} received nothing while counting");
        assert!(r.accounts_for_every_frame(), "reader {k}: {r:?}");
    }
    assert_eq!(
        stalled_closes, 1,
        "exactly the stalled viewer was cut for not reading"
    );

    // The same demonstration with no viewer: the loop must have computed exactly the same force
    // at every tick.
    let (producer, mut alone_ring) = rtrb::RingBuffer::new(RING);
    let mut options = test_options();
    options.tick_sink = Some(producer);
    let server = start_default(options).await;
    while alone_ring.slots() < RING - with_viewers.len() {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let alone_stats = server.shutdown().await;
    let alone = drain(&mut alone_ring);
    eprintln!(
        "0 viewers: loop period error p50 {} ns p99 {} ns p999 {} ns max {} ns",
        alone_stats.period_error_p50_ns,
        alone_stats.period_error_p99_ns,
        alone_stats.period_error_p999_ns,
        alone_stats.period_error_max_ns,
    );
    assert!(alone.len() >= with_viewers.len());
    let bits = |r: &TickRecord| r.contact.force_n.to_array().map(f64::to_bits);
    for (a, b) in with_viewers.iter().zip(&alone) {
        assert_eq!(
            bits(a),
            bits(b),
            "force differs at tick {}: {:?} vs {:?}",
            a.contact.tick,
            a.contact.force_n,
            b.contact.force_n
        );
    }
    assert!(
        with_viewers
            .iter()
            .any(|r| r.contact.force_n.length() > 0.1),
        "the compared run includes the press"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_viewer_that_stalls_skips_ahead_and_is_told_how_many_frames_it_lost() {
    let mut options = test_options();
    options.send_buffer_bytes = Some(8 * 1024);
    let server = start_default(options).await;
    let mut slow = Viewer::connect_with_small_buffer(server.local_addr(), 4 * 1024).await;
    let mut fast = Viewer::connect(server.local_addr()).await;
    for v in [&mut slow, &mut fast] {
        assert!(matches!(
            v.expect_message(WAIT).await,
            ServerMessage::Hello(_)
        ));
        assert!(matches!(
            v.expect_message(WAIT).await,
            ServerMessage::Scene(_)
        ));
    }
    // The fast viewer keeps reading while the slow one stalls for 2 s.
    let stop = Arc::new(AtomicBool::new(false));
    let fast_task = tokio::spawn(count_frames(
        fast,
        Arc::new(AtomicBool::new(true)),
        Arc::clone(&stop),
    ));
    // The slow viewer reads nothing while the server produces 60 frames: more than its backlog
    // and both socket buffers hold (a frame is about 600 bytes), so it must have lapped. Counted
    // in frames, not seconds: a slow machine waits longer, not less.
    let sent = || server.counters().frames_sent.load(Ordering::Relaxed);
    let stalled_at = sent();
    wait_until("60 frames produced during the stall", || {
        sent() >= stalled_at + 60
    })
    .await;
    // Then it reads: first what the socket buffers held, then the newest frames, until it has
    // been told of the loss and seen some frames after that.
    let mut frames = Vec::new();
    let mut after_loss = 0;
    while after_loss < 25 {
        if let ServerMessage::Contact(f) = slow.expect_message(WAIT).await {
            if f.dropped > 0 {
                after_loss += 1;
            }
            frames.push(f);
        }
    }
    stop.store(true, Ordering::Relaxed);
    let fast = fast_task.await.unwrap();
    let gaps: u64 = frames.windows(2).map(|w| w[1].seq - w[0].seq - 1).sum();
    let first = frames.first().expect("frames after the stall");
    let last = frames.last().expect("frames after the stall");
    assert!(last.dropped > 0, "the stalled viewer lost frames");
    assert_eq!(
        last.dropped - first.dropped,
        gaps,
        "every frame missing from the sequence is counted in dropped"
    );
    assert!(frames.windows(2).all(|w| w[1].seq > w[0].seq));
    // The fast viewer kept receiving while the other stalled, every frame accounted for.
    assert!(
        fast.frames > 0 && fast.accounts_for_every_frame(),
        "{fast:?}"
    );
    server.shutdown().await;
}
