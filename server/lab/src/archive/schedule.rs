//! A station's archiving while it runs: the pass over its finished recordings at start, repeated
//! until nothing is left unarchived, and the session's own recording at stop.
//!
//! A pass that leaves a recording unarchived (NATS down, JetStream not ready, the bucket not
//! reachable) is not the last: the next one runs as soon as the archive's NATS client is
//! connected again after having been disconnected, and otherwise after a backoff that doubles
//! from [`RetryOptions::first_backoff`] up to [`RetryOptions::max_backoff`] (while the client is
//! disconnected, the backoff's pass waits for it to connect: a pass then would only time out).
//! Passes stop once one leaves nothing failed, or when the station stops
//! ([`StationArchive::finish`]): the pass in progress is dropped there (uploads resume, see
//! [`mod@super::upload`]) and the session's own recording goes first.

use std::path::{Path, PathBuf};
use std::time::Duration;

use tokio::sync::watch;
use tokio::task::JoinHandle;

use super::ArchiveReport;

/// When a station's archiving runs a pass again.
#[derive(Debug, Clone)]
pub struct RetryOptions {
    /// The wait after the first pass that left something unarchived; doubled after each
    /// further one, up to [`Self::max_backoff`].
    pub first_backoff: Duration,
    /// The longest wait between two passes while NATS stays connected.
    pub max_backoff: Duration,
    /// How often the NATS client's connection state is looked at while waiting.
    pub poll: Duration,
}

impl Default for RetryOptions {
    fn default() -> Self {
        Self {
            first_backoff: Duration::from_secs(1),
            max_backoff: Duration::from_secs(300),
            poll: Duration::from_millis(250),
        }
    }
}

/// Where a station's archiving is, for its log and its tests.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ArchiveProgress {
    /// Passes run to the end.
    pub passes: usize,
    /// The last of them.
    pub last: Option<ArchiveReport>,
    /// No pass will run again: the last left nothing failed.
    pub done: bool,
}

/// A station's archiving of its finished recordings, running in the background.
pub struct StationArchive {
    client: async_nats::Client,
    station: String,
    task: JoinHandle<()>,
    progress: watch::Receiver<ArchiveProgress>,
}

impl StationArchive {
    /// Starts archiving every finished recording of `dir` but `current` (the one being written)
    /// with `client`, as `station`; passes are repeated as [`RetryOptions`] says.
    pub fn start(
        client: async_nats::Client,
        station: String,
        dir: PathBuf,
        current: Option<PathBuf>,
        retry: RetryOptions,
    ) -> StationArchive {
        let (tx, progress) = watch::channel(ArchiveProgress::default());
        let task = tokio::spawn(passes(
            client.clone(),
            station.clone(),
            dir,
            current,
            retry,
            tx,
        ));
        StationArchive {
            client,
            station,
            task,
            progress,
        }
    }

    /// The passes so far.
    pub fn progress(&self) -> watch::Receiver<ArchiveProgress> {
        self.progress.clone()
    }

    /// Stops the passes (one in progress is dropped: what it stored is resumed next time) and
    /// archives `finished`, the session's own recording, within `within`: `Ok(true)` archived
    /// now, `Ok(false)` already there.
    pub async fn finish(mut self, finished: &Path, within: Duration) -> Result<bool, String> {
        self.task.abort();
        let _ = (&mut self.task).await;
        let attempt = async {
            // NATS may be back a moment after the port is: the store is asked again until the
            // deadline, not once.
            let store = loop {
                match super::store(&self.client, &self.station).await {
                    Ok(store) => break store,
                    Err(e) => {
                        tracing::debug!("the lab's archive is not reachable yet: {e}");
                        tokio::time::sleep(Duration::from_millis(500)).await;
                    }
                }
            };
            super::upload(&store, &self.station, finished).await
        };
        match tokio::time::timeout(within, attempt).await {
            Ok(result) => result,
            Err(_) => Err(format!(
                "not archived within {} s",
                within.as_secs_f64().round()
            )),
        }
    }
}

impl Drop for StationArchive {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Passes until one leaves nothing failed.
async fn passes(
    client: async_nats::Client,
    station: String,
    dir: PathBuf,
    current: Option<PathBuf>,
    retry: RetryOptions,
    progress: watch::Sender<ArchiveProgress>,
) {
    let mut backoff = retry.first_backoff;
    let mut passes = 0;
    loop {
        let report = super::upload_finished(&client, &station, &dir, current.as_deref()).await;
        passes += 1;
        let done = report.failed.is_empty() && report.sweep_failed.is_none();
        log_report(&report);
        progress.send_replace(ArchiveProgress {
            passes,
            last: Some(report),
            done,
        });
        if done {
            return;
        }
        backoff = if wait_for_next_pass(&client, backoff, retry.poll).await {
            // NATS is back: a pass that fails now (JetStream not ready yet) is tried again soon.
            retry.first_backoff
        } else {
            (backoff * 2).min(retry.max_backoff)
        };
    }
}

/// Returns when the next pass should run: at once when the client connects again after being
/// disconnected (`true`), or once `backoff` has passed and the client is connected (`false`).
async fn wait_for_next_pass(
    client: &async_nats::Client,
    backoff: Duration,
    poll: Duration,
) -> bool {
    let due = tokio::time::Instant::now() + backoff;
    let mut was_down = !crate::is_connected(client);
    loop {
        tokio::time::sleep(poll).await;
        let up = crate::is_connected(client);
        if up && (was_down || tokio::time::Instant::now() >= due) {
            return was_down;
        }
        was_down |= !up;
    }
}

/// A pass's report in the station's log.
pub fn log_report(report: &ArchiveReport) {
    let again = "tried again while the station runs (when NATS answers), or at its next start";
    for f in &report.uploaded {
        tracing::info!(file = %f, "recording archived in the lab (verified)");
    }
    for (f, why) in &report.failed {
        tracing::warn!(file = %f, "recording not archived ({why}): it is kept, and {again}");
    }
    if !report.already.is_empty() {
        tracing::info!(
            count = report.already.len(),
            "recordings already in the lab's archive"
        );
    }
    for (id, parts) in &report.orphans_removed {
        tracing::info!(
            chunk_id = %id,
            parts,
            "removed the parts of an upload that can never finish (no archived object uses them)"
        );
    }
    if let Some(why) = &report.sweep_failed {
        tracing::warn!("the archive's unused parts were not swept ({why}): {again}");
    }
}
