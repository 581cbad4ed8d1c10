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
//!
//! `--dashboard-pages N` measures a hub's dashboard instead: `--stations` stations (two
//! `softhaptic` processes, the rest their heartbeats published again under other names, each
//! with two alerts in its summary: what a hub's dashboard reads of a station is its heartbeat
//! alone), one hub, and N dashboard pages (`/ws?dashboard`) connected for `--seconds`; printed:
//! the `dashboard` message's size, the bytes and messages each page received a second, and the
//! hub's CPU with no page open and with N, measured one after the other.

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
    dashboard_pages: usize,
}

/// The options, or `None` when the help was asked for (and printed).
fn parse() -> anyhow::Result<Option<Options>> {
    let mut o = Options {
        stations: 4,
        hubs: 2,
        viewers: 200,
        seconds: 10.0,
        dashboard_pages: 0,
    };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--stations" => o.stations = value()?.parse()?,
            "--hubs" => o.hubs = value()?.parse()?,
            "--viewers" => o.viewers = value()?.parse()?,
            "--seconds" => o.seconds = value()?.parse()?,
            "--dashboard-pages" => o.dashboard_pages = value()?.parse()?,
            "-h" | "--help" => {
                println!(
                    "lab-report [--stations N (4)] [--hubs N (2)] [--viewers N (200)] [--seconds S (10)]\n\
                     lab-report --dashboard-pages N [--stations N] [--seconds S]: a hub's dashboard with N pages"
                );
                return Ok(None);
            }
            other => bail!("unknown option {other:?} (see --help)"),
        }
    }
    if o.stations == 0 || o.hubs == 0 || !(1.0..=600.0).contains(&o.seconds) || o.viewers > 10_000 {
        bail!("--stations and --hubs ≥ 1, --viewers ≤ 10000, --seconds in [1, 600]");
    }
    if o.dashboard_pages > 1000 || o.stations > 512 {
        bail!("--dashboard-pages ≤ 1000, --stations ≤ 512 (a hub lists at most 512)");
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
    if o.dashboard_pages > 0 {
        return dashboard_report(&o).await;
    }
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

/// What one dashboard page received.
#[derive(Default)]
struct PageSeen {
    bytes: u64,
    messages: u64,
    last_message_bytes: usize,
    tiles: usize,
}

/// One dashboard page on `hub` until `until`, counting from `from_t`.
async fn dashboard_page(hub: String, from_t: Instant, until: Instant, seen: Arc<Mutex<PageSeen>>) {
    let Ok((mut socket, _)) =
        tokio_tungstenite::connect_async(format!("ws://{hub}/ws?dashboard")).await
    else {
        return;
    };
    while Instant::now() < until {
        let next = tokio::time::timeout(Duration::from_millis(200), socket.next()).await;
        let text = match next {
            Ok(Some(Ok(Message::Text(t)))) => t,
            Ok(Some(Ok(_))) | Err(_) => continue,
            _ => break,
        };
        if Instant::now() < from_t || !text.as_str().starts_with(r#"{"type":"dashboard""#) {
            continue;
        }
        let Ok(mut s) = seen.lock() else { break };
        s.bytes += text.len() as u64;
        s.messages += 1;
        s.last_message_bytes = text.len();
        if let Ok(ServerMessage::Dashboard(d)) = ServerMessage::decode(text.as_str()) {
            s.tiles = d.stations.len();
        }
    }
}

/// `--dashboard-pages`: the dashboard's cost on one hub (module docs).
async fn dashboard_report(o: &Options) -> anyhow::Result<()> {
    let nats = NatsServer::start("lab-report-dashboard");
    let url = nats.url();
    let running = o.stations.min(2);
    let mut stations = Vec::new();
    for i in 0..running {
        let name = format!("desk-{i}");
        stations.push(spawn(&[
            "--no-record",
            "--no-realtime",
            "--nats",
            &url,
            "--station",
            &name,
        ])?);
    }
    let hub = spawn(&["hub", "--nats", &url])?;
    // The other stations: the running ones' heartbeats again, under other names, with two
    // alerts each (one acknowledged), once a second.
    let client = async_nats::connect(url.as_str())
        .await
        .context("the report's own NATS connection")?;
    let mut heartbeats = client
        .subscribe(softhaptic_server::lab::STATUS_SUBJECTS)
        .await
        .context("subscribing to the heartbeats")?;
    let copies = o.stations - running;
    let relay = tokio::spawn(async move {
        while let Some(m) = heartbeats.next().await {
            let Ok(mut status) = serde_json::from_slice::<serde_json::Value>(&m.payload) else {
                continue;
            };
            let Some(from) = status["name"].as_str().map(str::to_owned) else {
                continue;
            };
            // Copies are made from the first running station only, so each copy comes once a
            // second as a real heartbeat does.
            if from != "desk-0" {
                continue;
            }
            if let Some(alerts) = status["summary"]["alerts"].as_array_mut() {
                alerts.push(serde_json::json!({"id": 1, "kind": "above_safe_force", "time_ns": 4_250_000_000u64, "unix_ms": 1_796_000_000_000u64, "detail": "2.63 N, above the safe 2.00 N", "acknowledged": {"by": "instructor at 10.0.0.7:53122 on a hub", "unix_ms": 1_796_000_004_000u64}}));
                alerts.push(serde_json::json!({"id": 2, "kind": "device_fault", "time_ns": 9_750_000_000u64, "unix_ms": 1_796_000_006_000u64, "detail": "device disconnected", "acknowledged": null}));
            }
            for i in 0..copies {
                let name = format!("copy-{i}");
                status["name"] = serde_json::Value::from(name.clone());
                let Ok(json) = serde_json::to_vec(&status) else {
                    continue;
                };
                let _ = client
                    .publish(format!("softhaptic.stations.{name}"), json.into())
                    .await;
            }
        }
    });
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let listed = reqwest_stations(&hub.addr).await.unwrap_or(0);
        if listed >= o.stations {
            break;
        }
        if Instant::now() > deadline {
            bail!("the hub lists {listed} of {} stations", o.stations);
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    eprintln!(
        "{} stations ({running} running), 1 hub, {} dashboard pages, {:.0} s without pages then {:.0} s with ...",
        o.stations, o.dashboard_pages, o.seconds, o.seconds
    );
    let measure = Duration::from_secs_f64(o.seconds);
    // The hub with no page open.
    let cpu_0 = cpu_s(hub.child.id());
    let t_0 = Instant::now();
    tokio::time::sleep(measure).await;
    let idle_cpu = (cpu_s(hub.child.id()) - cpu_0) / t_0.elapsed().as_secs_f64();
    // With the pages.
    let warmup = Duration::from_secs(3);
    let from_t = Instant::now() + warmup;
    let until = from_t + measure;
    let mut pages = Vec::new();
    let mut tasks = Vec::new();
    for _ in 0..o.dashboard_pages {
        let seen = Arc::new(Mutex::new(PageSeen::default()));
        tasks.push(tokio::spawn(dashboard_page(
            hub.addr.clone(),
            from_t,
            until,
            Arc::clone(&seen),
        )));
        pages.push(seen);
    }
    tokio::time::sleep_until(from_t.into()).await;
    let cpu_1 = cpu_s(hub.child.id());
    let t_1 = Instant::now();
    for t in tasks {
        let _ = t.await;
    }
    let measured_s = t_1.elapsed().as_secs_f64();
    let busy_cpu = (cpu_s(hub.child.id()) - cpu_1) / measured_s;
    relay.abort();

    let (mut rates, mut message_rates, mut size, mut tiles) = (Vec::new(), Vec::new(), 0, 0);
    for page in &pages {
        let Ok(p) = page.lock() else { continue };
        rates.push(p.bytes as f64 / measured_s);
        message_rates.push(p.messages as f64 / measured_s);
        size = size.max(p.last_message_bytes);
        tiles = tiles.max(p.tiles);
    }
    println!(
        "dashboard on loopback: {} stations ({running} running, {copies} from their heartbeats, 2 alerts each), 1 hub, {} pages, {:.1} s measured",
        o.stations, o.dashboard_pages, measured_s
    );
    println!(
        "  dashboard message         {size} bytes, {tiles} tiles ({:.0} bytes a tile)",
        size as f64 / tiles.max(1) as f64
    );
    println!(
        "  per page                  median {:.1} kB/s, {:.2} messages/s (min {:.1} kB/s)",
        percentile(rates.clone(), 0.5) / 1e3,
        percentile(message_rates, 0.5),
        percentile(rates.clone(), 0.0) / 1e3
    );
    println!(
        "  all pages                 {:.1} kB/s",
        rates.iter().sum::<f64>() / 1e3
    );
    println!(
        "  hub CPU                   {:.2} % of a core with no page, {:.2} % with {} pages ({:.3} % a page)",
        idle_cpu * 100.0,
        busy_cpu * 100.0,
        o.dashboard_pages,
        (busy_cpu - idle_cpu) * 100.0 / o.dashboard_pages as f64
    );
    drop(hub);
    drop(stations);
    Ok(())
}
