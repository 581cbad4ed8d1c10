//! Measures a teaching lab on this machine's loopback: a real nats-server, stations and hubs as
//! separate `softhaptic` processes, and WebSocket viewers spread over the hubs, each watching one
//! station. Prints, per configuration: the frames per second each hub viewer received (min and
//! median), the frames they lost (gaps in `seq`), the latency the NATS hop adds (a viewer on the
//! station and one on a hub, both in this process, receiving the same frame: p50 and p99 of the
//! difference), the hubs' CPU per 100 viewers (from /proc), and a station's loop period error
//! while it publishes (from its `stats`).
//!
//! `cargo build --release -p softhaptic-server --bin softhaptic && cargo run --release -p
//! softhaptic-tests --bin lab-report -- [--stations 4] [--hubs 2] [--viewers 200] [--seconds 10]`
//! (SOFTHAPTIC_BIN names another build; needs nats-server, which `make test` installs).

use std::collections::HashMap;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use futures_util::StreamExt;
use softhaptic_proto::wire::ServerMessage;
use softhaptic_tests::nats::NatsServer;
use tokio_tungstenite::tungstenite::Message;

struct Options {
    stations: usize,
    hubs: usize,
    viewers: usize,
    seconds: f64,
}

/// The options, or `None` when the help was asked for (and printed).
fn parse() -> anyhow::Result<Option<Options>> {
    let mut o = Options {
        stations: 4,
        hubs: 2,
        viewers: 200,
        seconds: 10.0,
    };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--stations" => o.stations = value()?.parse()?,
            "--hubs" => o.hubs = value()?.parse()?,
            "--viewers" => o.viewers = value()?.parse()?,
            "--seconds" => o.seconds = value()?.parse()?,
            "-h" | "--help" => {
                println!(
                    "lab-report [--stations N (4)] [--hubs N (2)] [--viewers N (200)] [--seconds S (10)]"
                );
                return Ok(None);
            }
            other => bail!("unknown option {other:?} (see --help)"),
        }
    }
    if o.stations == 0 || o.hubs == 0 || !(1.0..=600.0).contains(&o.seconds) || o.viewers > 10_000 {
        bail!("--stations and --hubs ≥ 1, --viewers ≤ 10000, --seconds in [1, 600]");
    }
    Ok(Some(o))
}

/// A `softhaptic` process, killed when dropped; `addr` once it printed its URL.
struct Process {
    child: Child,
    addr: String,
}

impl Drop for Process {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn binary() -> PathBuf {
    std::env::var_os("SOFTHAPTIC_BIN").map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/release/softhaptic"),
        PathBuf::from,
    )
}

/// Starts `softhaptic ARGS --addr 127.0.0.1:0` and waits for the URL it prints.
fn spawn(args: &[&str]) -> anyhow::Result<Process> {
    use std::io::BufRead;
    let bin = binary();
    let mut child = Command::new(&bin)
        .args(args)
        .args(["--addr", "127.0.0.1:0"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .with_context(|| format!("{} (build it first: see --help)", bin.display()))?;
    let stdout = child.stdout.take().context("stdout")?;
    let mut lines = std::io::BufReader::new(stdout).lines();
    let addr = loop {
        let line = lines
            .next()
            .context("the server ended before printing its URL")??;
        if let Some(url) = line.split("viewer: http://").nth(1) {
            break url.trim_end_matches('/').to_owned();
        }
    };
    // Keep reading its stdout so it never blocks on a full pipe.
    std::thread::spawn(move || for _ in lines {});
    Ok(Process { child, addr })
}

/// User + system CPU seconds of a process so far.
fn cpu_s(pid: u32) -> f64 {
    let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
        return f64::NAN;
    };
    // The fields after the command's closing parenthesis; utime and stime are the 12th and 13th.
    let after = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks = |i: usize| {
        f.get(i)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(f64::NAN)
    };
    // /proc counts in USER_HZ, which Linux fixes at 100 for user space.
    (ticks(11) + ticks(12)) / 100.0
}

/// What one viewer saw: receive times (since `t0`) by frame seq, and its stats' period errors.
#[derive(Default)]
struct Seen {
    frames: HashMap<u64, f64>,
    period_error_p99_us: Vec<f64>,
    period_error_max_us: Vec<f64>,
}

/// Viewers per client address: below a server's per-address limit (50 by default).
const VIEWERS_PER_ADDRESS: usize = 40;

/// Watches `url` from the loopback address `from` until `until`.
async fn watch(
    url: String,
    from: std::net::Ipv4Addr,
    t0: Instant,
    until: Instant,
    seen: Arc<Mutex<Seen>>,
) {
    let Some(server) = url
        .strip_prefix("ws://")
        .and_then(|r| r.split('/').next())
        .and_then(|a| a.parse::<std::net::SocketAddr>().ok())
    else {
        return;
    };
    let Ok(tcp) = tokio::net::TcpSocket::new_v4() else {
        return;
    };
    if tcp.bind((from, 0).into()).is_err() {
        return;
    }
    let Ok(stream) = tcp.connect(server).await else {
        return;
    };
    let Ok((mut socket, _)) = tokio_tungstenite::client_async(&url, stream).await else {
        return;
    };
    while Instant::now() < until {
        let next = tokio::time::timeout(Duration::from_millis(200), socket.next()).await;
        let text = match next {
            Ok(Some(Ok(Message::Text(t)))) => t,
            Ok(Some(Ok(_))) | Err(_) => continue,
            _ => break,
        };
        let at = t0.elapsed().as_secs_f64();
        // Frames by their seq (cheaply: the field comes first after the type).
        let t = text.as_str();
        let seq = t
            .strip_prefix(r#"{"type":"contact","seq":"#)
            .and_then(|rest| rest.split(',').next())
            .and_then(|s| s.parse::<u64>().ok());
        let Ok(mut s) = seen.lock() else { break };
        if let Some(seq) = seq {
            s.frames.insert(seq, at);
        } else if t.starts_with(r#"{"type":"stats""#)
            && let Ok(ServerMessage::Stats(m)) = ServerMessage::decode(t)
        {
            s.period_error_p99_us.push(m.period_error_us.p99);
            s.period_error_max_us.push(m.period_error_us.max);
        }
    }
}

fn percentile(mut v: Vec<f64>, p: f64) -> f64 {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let Some(o) = parse()? else {
        return Ok(());
    };
    let nats = NatsServer::start("lab-report");
    let url = nats.url();
    let mut stations = Vec::new();
    for i in 0..o.stations {
        let name = format!("desk-{i}");
        stations.push((
            name.clone(),
            spawn(&[
                "--no-record",
                "--no-realtime",
                "--nats",
                &url,
                "--station",
                &name,
            ])?,
        ));
    }
    let mut hubs = Vec::new();
    for _ in 0..o.hubs {
        hubs.push(spawn(&["hub", "--nats", &url])?);
    }
    // Every hub lists every station before the viewers come.
    let deadline = Instant::now() + Duration::from_secs(60);
    for hub in &hubs {
        loop {
            let listed = reqwest_stations(&hub.addr).await.unwrap_or(0);
            if listed >= o.stations {
                break;
            }
            if Instant::now() > deadline {
                bail!("hub {} lists {listed} of {} stations", hub.addr, o.stations);
            }
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    }
    eprintln!(
        "{} stations, {} hubs, {} viewers on the hubs, {:.0} s ...",
        o.stations, o.hubs, o.viewers, o.seconds
    );

    let t0 = Instant::now();
    let warmup = Duration::from_secs(3);
    let until = t0 + warmup + Duration::from_secs_f64(o.seconds);
    let mut tasks = Vec::new();
    let mut hub_viewers = Vec::new();
    for v in 0..o.viewers {
        let hub = &hubs[v % o.hubs];
        let station = &stations[v % o.stations].0;
        let seen = Arc::new(Mutex::new(Seen::default()));
        let from = std::net::Ipv4Addr::new(127, 0, 1, 1 + (v / VIEWERS_PER_ADDRESS) as u8);
        tasks.push(tokio::spawn(watch(
            format!("ws://{}/ws?station={station}", hub.addr),
            from,
            t0,
            until,
            Arc::clone(&seen),
        )));
        hub_viewers.push((v % o.stations, seen));
    }
    // The reference: a viewer on station 0 itself, and one on station 0 through the first hub.
    let direct = Arc::new(Mutex::new(Seen::default()));
    tasks.push(tokio::spawn(watch(
        format!("ws://{}/ws", stations[0].1.addr),
        std::net::Ipv4Addr::LOCALHOST,
        t0,
        until,
        Arc::clone(&direct),
    )));
    tokio::time::sleep(warmup).await;
    let cpu_before: Vec<f64> = hubs.iter().map(|h| cpu_s(h.child.id())).collect();
    let measure_start = t0.elapsed().as_secs_f64();
    for t in tasks {
        let _ = t.await;
    }
    let measured_s = t0.elapsed().as_secs_f64() - measure_start;
    let cpu_after: Vec<f64> = hubs.iter().map(|h| cpu_s(h.child.id())).collect();

    // Per hub viewer: frames per second and frames lost within the measurement.
    let (mut rates, mut lost, mut latency_ms) = (Vec::new(), 0u64, Vec::new());
    let (direct, p99s, maxes) = direct
        .lock()
        .map(|d| {
            (
                d.frames.clone(),
                d.period_error_p99_us.clone(),
                d.period_error_max_us.clone(),
            )
        })
        .unwrap_or_default();
    for (station, seen) in &hub_viewers {
        let Ok(seen) = seen.lock() else { continue };
        let mut seqs: Vec<(u64, f64)> = seen
            .frames
            .iter()
            .filter(|(_, t)| **t >= measure_start)
            .map(|(s, t)| (*s, *t))
            .collect();
        seqs.sort_by_key(|x| x.0);
        rates.push(seqs.len() as f64 / measured_s);
        lost += seqs
            .windows(2)
            .map(|w| w[1].0.saturating_sub(w[0].0 + 1))
            .sum::<u64>();
        if *station == 0 {
            for (seq, t) in &seqs {
                if let Some(d) = direct.get(seq) {
                    latency_ms.push((t - d) * 1e3);
                }
            }
        }
    }
    let hub_cpu: f64 = cpu_before
        .iter()
        .zip(&cpu_after)
        .map(|(b, a)| a - b)
        .sum::<f64>()
        / measured_s;
    println!(
        "lab on loopback: {} stations, {} hubs, {} hub viewers, {:.1} s measured",
        o.stations, o.hubs, o.viewers, measured_s
    );
    println!(
        "  per hub viewer frames/s   min {:.1}  median {:.1}   (stations send 50)",
        percentile(rates.clone(), 0.0),
        percentile(rates, 0.5)
    );
    println!("  frames lost (seq gaps)    {lost} in all");
    println!(
        "  NATS hop latency          p50 {:.2} ms  p99 {:.2} ms  ({} frames compared)",
        percentile(latency_ms.clone(), 0.5),
        percentile(latency_ms.clone(), 0.99),
        latency_ms.len()
    );
    println!(
        "  hub CPU                   {:.1} % of a core in all, {:.2} % per 100 viewers",
        hub_cpu * 100.0,
        hub_cpu * 100.0 / (o.viewers as f64 / 100.0).max(0.01)
    );
    println!(
        "  station 0 loop period error  p99 {:.1} µs (median of its 1 s stats)  max {:.0} µs",
        percentile(p99s, 0.5),
        percentile(maxes, 1.0)
    );
    drop(hubs);
    drop(stations);
    Ok(())
}

/// How many stations a hub lists (a plain HTTP/1.1 GET on a fresh connection).
async fn reqwest_stations(addr: &str) -> Option<usize> {
    let addr: std::net::SocketAddr = addr.parse().ok()?;
    let (status, body) = softhaptic_tests::http_get(addr, "/api/stations").await;
    if status != 200 {
        return None;
    }
    let v: serde_json::Value = serde_json::from_slice(&body).ok()?;
    Some(
        v["stations"]
            .as_array()?
            .iter()
            .filter(|s| s["state"] != "offline")
            .count(),
    )
}
