//! Measures the WebSocket stream of the real server and the haptic loop's timing under it:
//! frames per second received per viewer and bytes per contact frame with 1 and with 200 viewers
//! (one of which never reads), and the loop's period error with 0 and with 200 viewers.
//!
//! `cargo run --release -p softhaptic-tests --bin stream-report [-- --seconds 5] [--no-loop-standby]`
//! (`--no-loop-standby` runs the haptic loop without its standby thread, for comparison).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use futures_util::StreamExt;
use softhaptic_device::stats::LoopStats;
use softhaptic_tests::{Viewer, start_default, test_options};
use tokio_tungstenite::tungstenite::Message;

/// Frames and bytes one viewer received while measuring.
#[derive(Default)]
struct Received {
    frames: u64,
    bytes: u64,
}

async fn read(mut viewer: Viewer, measuring: Arc<AtomicBool>, stop: Arc<AtomicBool>) -> Received {
    let mut got = Received::default();
    while !stop.load(Ordering::Relaxed) {
        match tokio::time::timeout(Duration::from_millis(200), viewer.socket.next()).await {
            Ok(Some(Ok(Message::Text(text)))) => {
                if measuring.load(Ordering::Relaxed) && text.starts_with(r#"{"type":"contact""#) {
                    got.frames += 1;
                    got.bytes += text.len() as u64;
                }
            }
            Ok(Some(Ok(_))) | Err(_) => {}
            Ok(None) | Ok(Some(Err(_))) => break,
        }
    }
    got
}

struct Run {
    rates: Vec<f64>,
    bytes_per_frame: f64,
    stats: LoopStats,
}

/// Runs the default scene with `readers` reading viewers (plus one that never reads when
/// `stalled`), measures for `seconds` after a one-second settling time.
async fn run(readers: usize, stalled: bool, seconds: f64, standby: bool) -> Run {
    let mut options = test_options();
    options.realtime = true;
    options.loop_standby = standby;
    // Every viewer of this measurement comes from this machine's one address.
    options.access.limits.max_per_address = options.access.limits.max_viewers;
    let server = start_default(options).await;
    let addr = server.local_addr();
    let _stalled = if stalled {
        Some(Viewer::connect_with_small_buffer(addr, 4 * 1024).await)
    } else {
        None
    };
    let measuring = Arc::new(AtomicBool::new(false));
    let stop = Arc::new(AtomicBool::new(false));
    let mut tasks = Vec::new();
    for _ in 0..readers {
        let viewer = Viewer::connect(addr).await;
        tasks.push(tokio::spawn(read(
            viewer,
            Arc::clone(&measuring),
            Arc::clone(&stop),
        )));
    }
    tokio::time::sleep(Duration::from_secs(1)).await;
    measuring.store(true, Ordering::Relaxed);
    let started = Instant::now();
    tokio::time::sleep(Duration::from_secs_f64(seconds)).await;
    measuring.store(false, Ordering::Relaxed);
    let elapsed = started.elapsed().as_secs_f64();
    let stats = server.loop_stats();
    stop.store(true, Ordering::Relaxed);
    let (mut frames, mut bytes) = (0u64, 0u64);
    let mut rates = Vec::new();
    for t in tasks {
        let Ok(got) = t.await else { continue };
        rates.push(got.frames as f64 / elapsed);
        frames += got.frames;
        bytes += got.bytes;
    }
    rates.sort_by(f64::total_cmp);
    server.shutdown().await;
    Run {
        rates,
        bytes_per_frame: if frames > 0 {
            bytes as f64 / frames as f64
        } else {
            0.0
        },
        stats,
    }
}

fn print(label: &str, r: &Run) {
    let us = |ns: u64| ns as f64 * 1e-3;
    if r.rates.is_empty() {
        println!("{label}: no viewer");
    } else {
        println!(
            "{label}: frames/s per viewer min {:.1} median {:.1} max {:.1}; {:.0} bytes per contact frame",
            r.rates[0],
            r.rates[r.rates.len() / 2],
            r.rates[r.rates.len() - 1],
            r.bytes_per_frame
        );
    }
    println!(
        "{label}: loop {:.1} Hz, period error p50 {:.1} us, p99 {:.1} us, p99.9 {:.1} us, max {:.1} us, overruns {}, ticks by the standby {}, real-time {}",
        r.stats.loop_rate_hz,
        us(r.stats.period_error_p50_ns),
        us(r.stats.period_error_p99_ns),
        us(r.stats.period_error_p999_ns),
        us(r.stats.period_error_max_ns),
        r.stats.overruns,
        r.stats.standby_ticks,
        if r.stats.realtime_granted {
            "granted"
        } else {
            "not granted"
        },
    );
}

fn main() -> std::process::ExitCode {
    let seconds = std::env::args()
        .skip_while(|a| a != "--seconds")
        .nth(1)
        .and_then(|s| s.parse::<f64>().ok())
        .unwrap_or(5.0);
    let standby = !std::env::args().any(|a| a == "--no-loop-standby");
    let runtime = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
    {
        Ok(r) => r,
        Err(e) => {
            eprintln!("could not start the async runtime: {e}");
            return std::process::ExitCode::FAILURE;
        }
    };
    runtime.block_on(async {
        print("0 viewers", &run(0, false, seconds, standby).await);
        print("1 viewer", &run(1, false, seconds, standby).await);
        print(
            "200 viewers (199 reading, 1 never reading)",
            &run(199, true, seconds, standby).await,
        );
    });
    std::process::ExitCode::SUCCESS
}
