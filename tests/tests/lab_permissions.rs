//! The lab's NATS permissions as `softhaptic nats-config` writes them
//! (`server/lab/src/permissions.rs`), on a real `nats-server` that runs that very
//! configuration: stations and a hub signed in with their own nkeys do all a lab does (a
//! station publishes, archives, answers the hub; the hub lists, relays, downloads); a station's
//! credentials that publish as another station, read another's frames or the hub's replies, or
//! touch another's archive bucket are refused by the server, and so is a hub that publishes a
//! frame or writes a bucket. And TLS to NATS: a station given the lab's CA connects to a
//! nats-server that requires TLS; credentials that would cross a network in plain text are
//! refused at start.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use softhaptic_server::lab::permissions::{HUB_SEED_FILE, station_seed_file, write_lab_config};
use softhaptic_server::lab::{NatsOptions, Party};
use softhaptic_tests::lab_ca::LabCa;
use softhaptic_tests::nats::{NatsServer, archive_sessions, start_hub, start_station};
use softhaptic_tests::{Viewer, http_request, scratch_dir, wait_until};
use tokio::sync::mpsc;

/// A guard against a hang, never a measured time.
const DEADLINE: Duration = Duration::from_secs(30);

/// A lab's sign-in for desk-1 and desk-2 written into a scratch directory, and a nats-server
/// running it (with `tls` when given: the server's certificate and key files).
struct Lab {
    server: NatsServer,
    dir: PathBuf,
}

impl Lab {
    fn start(name: &str, tls: Option<&TlsFiles>) -> Lab {
        let dir = scratch_dir(&format!("lab-permissions-{name}"));
        let written = write_lab_config(&dir, &["desk-1".to_owned(), "desk-2".to_owned()]).unwrap();
        // The file as nats-config wrote it (an `include` would be read relative to the
        // configuration's own directory, the NATS store here).
        let mut text = std::fs::read_to_string(&written.authorization).unwrap();
        if let Some(tls) = tls {
            text.push_str(&format!(
                "tls {{\n  cert_file: \"{}\"\n  key_file: \"{}\"\n}}\n",
                tls.cert.display(),
                tls.key.display()
            ));
        }
        Lab {
            server: NatsServer::start_with_config(name, text),
            dir,
        }
    }

    /// The options of `party`, signed in with its seed file.
    fn options(&self, party: Party<'_>) -> NatsOptions {
        let seed = match party {
            Party::Station(name) => station_seed_file(name),
            Party::Hub => HUB_SEED_FILE.to_owned(),
        };
        NatsOptions {
            credentials: Some(self.dir.join(seed)),
            ..NatsOptions::new(self.server.url())
        }
    }

    /// A bare client of `party` (its own inbox, as the lab's code connects) whose server errors
    /// come out of the returned channel as text.
    async fn client(&self, party: Party<'_>) -> (async_nats::Client, mpsc::Receiver<String>) {
        let seed_file = self.dir.join(match party {
            Party::Station(name) => station_seed_file(name),
            Party::Hub => HUB_SEED_FILE.to_owned(),
        });
        let text = std::fs::read_to_string(seed_file).unwrap();
        let seed = text
            .lines()
            .find(|l| l.starts_with("SU"))
            .unwrap()
            .to_owned();
        // Bounded: a test sees a few dozen events; any beyond are dropped, not queued.
        let (tx, rx) = mpsc::channel(1024);
        let client = async_nats::ConnectOptions::new()
            .nkey(seed)
            .custom_inbox_prefix(party.inbox_prefix())
            .event_callback(move |event| {
                let tx = tx.clone();
                async move {
                    let _ = tx.try_send(event.to_string());
                }
            })
            .connect(self.server.url())
            .await
            .unwrap();
        (client, rx)
    }
}

impl Drop for Lab {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// Waits for the server's refusal of `what` (`publish` or `subscription`) on `subject`.
async fn refused(events: &mut mpsc::Receiver<String>, what: &str, subject: &str) {
    let wanted = format!("permissions violation for {what} to \"{subject}\"").to_lowercase();
    let until = Instant::now() + DEADLINE;
    let mut seen = Vec::new();
    loop {
        let left = until.saturating_duration_since(Instant::now());
        match tokio::time::timeout(left, events.recv()).await {
            Ok(Some(event)) if event.to_lowercase().contains(&wanted) => return,
            Ok(Some(event)) => seen.push(event),
            _ => panic!("no refusal of the {what} to {subject}; the server said {seen:?}"),
        }
    }
}

/// Archives `tests/sessions/slide.mcap` as `station`'s, signed in as `station`.
async fn archive_slide(lab: &Lab, station: &str) {
    archive_sessions(
        lab.options(Party::Station(station)),
        station,
        &[("slide.mcap", "slide.mcap")],
    )
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_station_and_a_hub_do_all_a_lab_does_with_their_own_permissions() {
    let lab = Lab::start("permitted", None);
    let station = start_station("desk-1", lab.options(Party::Station("desk-1")))
        .await
        .unwrap();
    archive_slide(&lab, "desk-1").await;
    let hub = start_hub(lab.options(Party::Hub), false).await;
    wait_until("desk-1 listed by the hub", || {
        hub.stations().iter().any(|s| s.name == "desk-1")
    })
    .await;
    // Relayed: the hub asked desk-1 for its scene (desk-1 answered its inbox) and subscribed
    // to its frames.
    let mut viewer =
        Viewer::connect_url(&format!("ws://{}/ws?station=desk-1", hub.local_addr())).await;
    let until = Instant::now() + DEADLINE;
    loop {
        if let Some(Ok(softhaptic_proto::wire::ServerMessage::Contact(_))) =
            viewer.next(Duration::from_secs(5)).await
        {
            break;
        }
        assert!(Instant::now() < until, "no frame relayed from desk-1");
    }
    // The archive, listed from desk-1's bucket and downloaded whole.
    let listing = http_request(hub.local_addr(), "/api/archive", &[]).await;
    assert_eq!(listing.status, 200);
    let text = String::from_utf8_lossy(&listing.body).into_owned();
    assert!(text.contains("\"station\":\"desk-1\""), "{text}");
    assert!(text.contains("\"file\":\"slide.mcap\""), "{text}");
    let download = http_request(hub.local_addr(), "/stations/desk-1/archive/slide.mcap", &[]).await;
    assert_eq!(download.status, 200);
    let recorded = Path::new(env!("CARGO_MANIFEST_DIR")).join("sessions/slide.mcap");
    assert_eq!(download.body, std::fs::read(recorded).unwrap());
    hub.shutdown().await;
    station.shutdown().await;
}

/// The files `/api/archive` lists now, as `STATION/FILE`; `None` unless answered 200.
async fn listed(hub: std::net::SocketAddr) -> Option<Vec<String>> {
    let answer = http_request(hub, "/api/archive", &[]).await;
    if answer.status != 200 {
        return None;
    }
    let body: serde_json::Value = serde_json::from_slice(&answer.body).unwrap();
    Some(
        body["archive"]
            .as_array()
            .unwrap()
            .iter()
            .map(|a| {
                format!(
                    "{}/{}",
                    a["station"].as_str().unwrap(),
                    a["file"].as_str().unwrap()
                )
            })
            .collect(),
    )
}

/// Asks `/api/archive` until it lists `want` (a guard against a hang, never a measured time).
async fn until_listed(hub: std::net::SocketAddr, want: &[&str]) {
    let until = Instant::now() + DEADLINE;
    loop {
        let now = listed(hub).await;
        if now.as_deref().is_some_and(|l| l == want) {
            return;
        }
        assert!(Instant::now() < until, "listed {now:?}, not {want:?}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// JetStream's count of the account's API requests and consumers, as the server answers
/// `$JS.API.INFO` (read as JSON: async-nats's own type wants fields Debian's 2.9 server lacks).
async fn jetstream_use(client: &async_nats::Client) -> (u64, u64) {
    let answer = client.request("$JS.API.INFO", "".into()).await.unwrap();
    let info: serde_json::Value = serde_json::from_slice(&answer.payload).unwrap();
    let count = |v: &serde_json::Value| v.as_u64().unwrap_or_else(|| panic!("{info}"));
    (count(&info["api"]["total"]), count(&info["consumers"]))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_hub_lists_the_archive_from_the_stores_change_feed_not_per_page() {
    let lab = Lab::start("listing", None);
    archive_slide(&lab, "desk-1").await;
    let hub = start_hub(lab.options(Party::Hub), false).await;
    let addr = hub.local_addr();
    until_listed(addr, &["desk-1/slide.mcap"]).await;
    // desk-1's bucket read once: one listing of the buckets, one consumer.
    assert_eq!(
        (hub.archive_bucket_listings(), hub.archive_consumers()),
        (1, 1)
    );

    // Archived after the hub started, into a bucket it reads, and into a new station's bucket:
    // both listed from the change feed and the advisory, the buckets never listed again.
    archive_sessions(
        lab.options(Party::Station("desk-1")),
        "desk-1",
        &[("press.mcap", "sphere-press.mcap")],
    )
    .await;
    until_listed(addr, &["desk-1/press.mcap", "desk-1/slide.mcap"]).await;
    archive_slide(&lab, "desk-2").await;
    until_listed(
        addr,
        &[
            "desk-1/press.mcap",
            "desk-1/slide.mcap",
            "desk-2/slide.mcap",
        ],
    )
    .await;
    assert_eq!(
        (hub.archive_bucket_listings(), hub.archive_consumers()),
        (1, 2)
    );

    // Deleted (by its own station): gone from the listing.
    let (desk1, _events) = lab.client(Party::Station("desk-1")).await;
    let js = async_nats::jetstream::new(desk1);
    let store = js
        .get_object_store(softhaptic_server::lab::archive::bucket("desk-1"))
        .await
        .unwrap();
    store.delete("desk-1/slide.mcap").await.unwrap();
    until_listed(addr, &["desk-1/press.mcap", "desk-2/slide.mcap"]).await;

    // A class asking: no JetStream request at all, no consumer made. JetStream's own counts,
    // around the pages' requests and around nothing (its account request counts itself).
    let (hub_client, _events) = lab.client(Party::Hub).await;
    let (r0, _) = jetstream_use(&hub_client).await;
    let (r1, consumers_before) = jetstream_use(&hub_client).await;
    let answers =
        futures_util::future::join_all((0..200).map(|_| http_request(addr, "/api/archive", &[])))
            .await;
    assert!(
        answers
            .iter()
            .all(|a| a.status == 200 && a.body == answers[0].body)
    );
    let (r2, consumers_after) = jetstream_use(&hub_client).await;
    assert_eq!(r2 - r1, r1 - r0, "JetStream requests made for 200 listings");
    assert!(
        consumers_after <= consumers_before,
        "{consumers_before} → {consumers_after}"
    );
    assert_eq!(
        (hub.archive_bucket_listings(), hub.archive_consumers()),
        (1, 2)
    );
    hub.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_station_cannot_speak_for_another_nor_read_or_touch_its_data_and_a_hub_only_reads() {
    let lab = Lab::start("refused", None);
    archive_slide(&lab, "desk-1").await;
    let desk1_bucket = softhaptic_server::lab::archive::bucket("desk-1");
    let desk1_stream = softhaptic_server::lab::archive::bucket_stream("desk-1");

    let (desk2, mut desk2_events) = lab.client(Party::Station("desk-2")).await;
    for subject in [
        "softhaptic.station.desk-1.contact".to_owned(),
        "softhaptic.stations.desk-1".to_owned(),
        format!("$O.{desk1_bucket}.C.forged"),
        format!("$JS.API.STREAM.PURGE.{desk1_stream}"),
        format!("$JS.API.STREAM.MSG.GET.{desk1_stream}"),
        format!("$JS.API.CONSUMER.CREATE.{desk1_stream}"),
    ] {
        desk2.publish(subject.clone(), "{}".into()).await.unwrap();
        desk2.flush().await.unwrap();
        refused(&mut desk2_events, "publish", &subject).await;
    }
    for subject in [
        "softhaptic.station.desk-1.contact",
        "softhaptic.station.desk-1.session",
        "_INBOX.hub.>",
        "_INBOX.station.desk-1.>",
        "_INBOX.>",
    ] {
        let _subscription = desk2.subscribe(subject).await.unwrap();
        desk2.flush().await.unwrap();
        refused(&mut desk2_events, "subscription", subject).await;
    }

    let (hub, mut hub_events) = lab.client(Party::Hub).await;
    for subject in [
        "softhaptic.station.desk-1.contact".to_owned(),
        "softhaptic.station.desk-1.stats".to_owned(),
        "softhaptic.stations.desk-1".to_owned(),
        format!("$O.{desk1_bucket}.M.forged"),
        format!("$JS.API.STREAM.PURGE.{desk1_stream}"),
        format!("$JS.API.STREAM.DELETE.{desk1_stream}"),
    ] {
        hub.publish(subject.clone(), "{}".into()).await.unwrap();
        hub.flush().await.unwrap();
        refused(&mut hub_events, "publish", &subject).await;
    }

    // What is allowed goes through: desk-1's frame reaches the hub's subscription.
    let mut frames = hub
        .subscribe("softhaptic.station.desk-1.contact")
        .await
        .unwrap();
    hub.flush().await.unwrap();
    let (desk1, _) = lab.client(Party::Station("desk-1")).await;
    let until = Instant::now() + DEADLINE;
    let got = loop {
        desk1
            .publish("softhaptic.station.desk-1.contact", "frame".into())
            .await
            .unwrap();
        desk1.flush().await.unwrap();
        use futures_util::StreamExt;
        if let Ok(Some(m)) = tokio::time::timeout(Duration::from_millis(500), frames.next()).await {
            break m;
        }
        assert!(
            Instant::now() < until,
            "desk-1's frame never reached the hub"
        );
    };
    assert_eq!(&got.payload[..], b"frame");
    // And desk-1's recording is still its own, whole: listed with its digest by the hub.
    let listed = softhaptic_server::lab::archive::list(&hub, None)
        .await
        .unwrap();
    assert_eq!(listed.len(), 1, "{listed:?}");
    assert_eq!(listed[0].station, "desk-1");
}

/// The lab's CA and a server certificate it signed for 127.0.0.1, as PEM files.
struct TlsFiles {
    ca: PathBuf,
    cert: PathBuf,
    key: PathBuf,
}

fn tls_files(dir: &Path) -> TlsFiles {
    let ca = LabCa::new(&["127.0.0.1", "localhost"]);
    std::fs::create_dir_all(dir).unwrap();
    let files = TlsFiles {
        ca: dir.join("lab-ca.pem"),
        cert: dir.join("nats-cert.pem"),
        key: dir.join("nats-key.pem"),
    };
    std::fs::write(&files.ca, &ca.ca_pem).unwrap();
    std::fs::write(&files.cert, &ca.server_pem).unwrap();
    std::fs::write(&files.key, &ca.server_key_pem).unwrap();
    files
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_station_reaches_a_nats_that_requires_tls_with_the_labs_ca_and_not_without() {
    let certificates = scratch_dir("lab-permissions-tls-files");
    let tls = tls_files(&certificates);
    let lab = Lab::start("tls", Some(&tls));
    let with_ca = NatsOptions {
        tls_ca: Some(tls.ca.clone()),
        ..lab.options(Party::Station("desk-1"))
    };
    let station = start_station("desk-1", with_ca).await.unwrap();
    let hub = start_hub(
        NatsOptions {
            tls_ca: Some(tls.ca.clone()),
            ..lab.options(Party::Hub)
        },
        false,
    )
    .await;
    wait_until("desk-1 listed over TLS", || {
        hub.stations().iter().any(|s| s.name == "desk-1")
    })
    .await;
    hub.shutdown().await;
    station.shutdown().await;

    // Without the CA the server's certificate is trusted by nothing: refused, not retried.
    let without = softhaptic_server::lab::connect(
        &lab.options(Party::Station("desk-2")),
        "no CA".into(),
        Party::Station("desk-2"),
    )
    .await;
    let e = without
        .expect_err("connected to a TLS NATS without its CA")
        .to_string();
    assert!(e.contains("--nats-ca"), "{e}");
    // A file that is no certificate is named.
    let e = softhaptic_server::lab::connect(
        &NatsOptions {
            tls_ca: Some(tls.key.clone()),
            ..lab.options(Party::Station("desk-2"))
        },
        "bad CA".into(),
        Party::Station("desk-2"),
    )
    .await
    .err()
    .unwrap()
    .to_string();
    assert!(e.contains("--nats-ca") && e.contains("nats-key.pem"), "{e}");
    assert!(!e.contains("PRIVATE KEY"), "{e}");
    let _ = std::fs::remove_dir_all(&certificates);
}

#[test]
fn credentials_that_would_cross_a_network_in_plain_text_are_refused() {
    let with_credentials = |url: &str, ca: Option<&str>| NatsOptions {
        url: url.to_owned(),
        credentials: Some(PathBuf::from("/etc/softhaptic/station-desk-1.nk")),
        tls_ca: ca.map(PathBuf::from),
    };
    for plain in [
        "nats://lab-server:4222",
        "nats://127.0.0.1:4222,nats://10.0.0.6:4222",
        "192.0.2.7:4222",
    ] {
        let e = with_credentials(plain, None)
            .check_transport()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--nats-ca") && e.contains("tls://") && e.contains(plain),
            "{e}"
        );
    }
    for fine in [
        with_credentials("nats://127.0.0.1:4222", None),
        with_credentials("nats://localhost:4222", None),
        with_credentials("nats://[::1]:4222", None),
        with_credentials("tls://lab-server:4222", None),
        with_credentials("nats://lab-server:4222", Some("/etc/softhaptic/lab-ca.pem")),
        NatsOptions::new("nats://lab-server:4222"),
    ] {
        fine.check_transport().unwrap();
    }
}
