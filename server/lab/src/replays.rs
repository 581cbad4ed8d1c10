//! The archived recordings a lab hub has decoded for replays: loaded only when an instructor's
//! viewer opens a replay, kept in a cache bounded in bytes and expired once unused, and loaded
//! once however many viewers ask for one file at the same moment, while other files load beside
//! it.
//!
//! A replay open for viewers holds its recording (an `Arc`): it cannot be evicted, and counts
//! against the bound. A recording no replay holds stays for [`ReplayCacheLimits::idle_expiry`]
//! after its last use (a viewer that reloads its page finds it), and is the first evicted when
//! a new one needs room. When the open replays alone fill the bound, a new one is refused
//! ("try again later") rather than loaded beyond it: the hub's memory for replays is at most
//! the bound, plus the loads in flight ([`LOADS_AT_ONCE`], each a file and its decoding).

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::http::StatusCode;

use crate::session::reader::Recording;

/// Files fetched and decoded at once, all files together: each holds the file's bytes and what
/// it decodes to until it is done.
pub const LOADS_AT_ONCE: usize = 2;

/// How much the hub keeps of replays.
#[derive(Debug, Clone, Copy)]
pub struct ReplayCacheLimits {
    /// The memory of the recordings kept, open or not, bytes ([`replay_bytes`]).
    pub max_bytes: u64,
    /// How long a recording no replay holds is kept after its last use.
    pub idle_expiry: Duration,
}

impl Default for ReplayCacheLimits {
    /// 1 GiB (a class's instructors opening a few hour-long sessions at once), kept 10 minutes.
    fn default() -> Self {
        Self {
            max_bytes: 1 << 30,
            idle_expiry: Duration::from_secs(600),
        }
    }
}

/// What a replay of `recording` holds in memory, bytes: the recording, and its player's copy
/// of the frames and stats (counted as the recording again: a little more than it is).
pub fn replay_bytes(recording: &Recording) -> u64 {
    recording.memory_bytes().saturating_mul(2)
}

/// A refusal: the HTTP status and the detail for the hub's log (as the hub's own).
pub type Refusal = (StatusCode, String);

struct Cached {
    recording: Arc<Recording>,
    bytes: u64,
    last_used: Instant,
}

#[derive(Default)]
struct State {
    cached: HashMap<String, Cached>,
    /// One gate per file being loaded: the first to ask holds it and loads; the others wait on
    /// it and then find the file loaded.
    loading: HashMap<String, Arc<tokio::sync::Mutex<()>>>,
    /// Loads done (fetched and decoded), since the start.
    loads: u64,
}

impl State {
    fn used_bytes(&self) -> u64 {
        self.cached.values().map(|c| c.bytes).sum()
    }

    /// Drops what no replay holds and was last used longer ago than `expiry`.
    fn expire(&mut self, now: Instant, expiry: Duration) {
        self.cached.retain(|key, c| {
            let keep = Arc::strong_count(&c.recording) > 1
                || now.saturating_duration_since(c.last_used) < expiry;
            if !keep {
                tracing::info!(recording = %key, "an archived recording unused for a while is dropped");
            }
            keep
        });
    }

    /// Makes room for `bytes` within `max`: evicts what no replay holds, least recently used
    /// first. False when the open replays leave no room.
    fn make_room(&mut self, bytes: u64, max: u64) -> bool {
        while self.used_bytes().saturating_add(bytes) > max {
            let idle = self
                .cached
                .iter()
                .filter(|(_, c)| Arc::strong_count(&c.recording) == 1)
                .min_by_key(|(_, c)| c.last_used)
                .map(|(key, _)| key.clone());
            match idle {
                Some(key) => {
                    self.cached.remove(&key);
                    tracing::info!(recording = %key, "evicted from the replays' cache to make room");
                }
                None => return false,
            }
        }
        true
    }
}

/// The hub's decoded recordings (see the module's documentation).
pub struct ReplayCache {
    limits: ReplayCacheLimits,
    state: Mutex<State>,
    loads: tokio::sync::Semaphore,
}

fn lock(m: &Mutex<State>) -> std::sync::MutexGuard<'_, State> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl ReplayCache {
    pub fn new(limits: ReplayCacheLimits) -> Self {
        Self {
            limits,
            state: Mutex::new(State::default()),
            loads: tokio::sync::Semaphore::new(LOADS_AT_ONCE),
        }
    }

    pub fn limits(&self) -> ReplayCacheLimits {
        self.limits
    }

    /// The recording `key`, from the cache or loaded by `load` (which fetches and decodes it);
    /// callers asking for the same key at once share one load. Refused with 429 (too many) when
    /// the replays open now leave no room for it.
    pub async fn get_or_load<F, Fut>(&self, key: &str, load: F) -> Result<Arc<Recording>, Refusal>
    where
        F: FnOnce() -> Fut,
        Fut: Future<Output = Result<Recording, Refusal>>,
    {
        let gate = {
            let mut state = lock(&self.state);
            state.expire(Instant::now(), self.limits.idle_expiry);
            if let Some(found) = self.hit(&mut state, key) {
                return Ok(found);
            }
            Arc::clone(state.loading.entry(key.to_owned()).or_default())
        };
        let _turn = gate.lock().await;
        if let Some(found) = self.hit(&mut lock(&self.state), key) {
            return Ok(found);
        }
        let loaded = {
            let _permit = self
                .loads
                .acquire()
                .await
                .map_err(|e| (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
            load().await
        };
        let mut state = lock(&self.state);
        if state
            .loading
            .get(key)
            .is_some_and(|g| Arc::ptr_eq(g, &gate))
        {
            state.loading.remove(key);
        }
        let recording = loaded?;
        state.loads += 1;
        let bytes = replay_bytes(&recording);
        if !state.make_room(bytes, self.limits.max_bytes) {
            return Err((
                StatusCode::TOO_MANY_REQUESTS,
                format!(
                    "{key}: its replay takes {bytes} bytes, and the replays open now hold {} of \
                     the {} the hub keeps",
                    state.used_bytes(),
                    self.limits.max_bytes
                ),
            ));
        }
        let recording = Arc::new(recording);
        state.cached.insert(
            key.to_owned(),
            Cached {
                recording: Arc::clone(&recording),
                bytes,
                last_used: Instant::now(),
            },
        );
        Ok(recording)
    }

    fn hit(&self, state: &mut State, key: &str) -> Option<Arc<Recording>> {
        let cached = state.cached.get_mut(key)?;
        cached.last_used = Instant::now();
        Some(Arc::clone(&cached.recording))
    }

    /// A replay of `key` closed: its recording's expiry counts from now.
    pub fn touch(&self, key: &str) {
        if let Some(c) = lock(&self.state).cached.get_mut(key) {
            c.last_used = Instant::now();
        }
    }

    /// Drops what has expired (the hub calls it periodically; every load does too).
    pub fn expire(&self) {
        lock(&self.state).expire(Instant::now(), self.limits.idle_expiry);
    }

    /// The recordings held now, by key, and the bytes each is counted for.
    pub fn cached(&self) -> Vec<(String, u64)> {
        let mut out: Vec<(String, u64)> = lock(&self.state)
            .cached
            .iter()
            .map(|(k, c)| (k.clone(), c.bytes))
            .collect();
        out.sort();
        out
    }

    /// How many loads (fetch and decode) were done since the start.
    pub fn loads(&self) -> u64 {
        lock(&self.state).loads
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    fn recording() -> Recording {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../tests/sessions/sphere-press.mcap");
        Recording::open(&path).unwrap()
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn one_load_per_file_however_many_ask_at_once() {
        let cache = Arc::new(ReplayCache::new(ReplayCacheLimits::default()));
        let started = Arc::new(std::sync::atomic::AtomicU32::new(0));
        let mut tasks = Vec::new();
        for _ in 0..8 {
            let (cache, started) = (Arc::clone(&cache), Arc::clone(&started));
            tasks.push(tokio::spawn(async move {
                cache
                    .get_or_load("st/a.mcap", || async move {
                        started.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                        // Long enough that every other task asks while this one loads.
                        tokio::task::yield_now().await;
                        Ok(recording())
                    })
                    .await
                    .unwrap()
            }));
        }
        let mut got = Vec::new();
        for t in tasks {
            got.push(t.await.unwrap());
        }
        assert_eq!(started.load(std::sync::atomic::Ordering::SeqCst), 1);
        assert_eq!(cache.loads(), 1);
        assert!(got.iter().all(|r| Arc::ptr_eq(r, &got[0])));
    }

    #[tokio::test]
    async fn open_replays_are_never_evicted_and_idle_ones_make_room_then_expire() {
        let one = replay_bytes(&recording());
        let cache = ReplayCache::new(ReplayCacheLimits {
            max_bytes: one + one / 2,
            idle_expiry: Duration::from_secs(3600),
        });
        let load = || async { Ok(recording()) };
        let a = cache.get_or_load("a", load).await.unwrap();
        // `a` is held (open): no room for `b`.
        let (status, detail) = cache.get_or_load("b", load).await.unwrap_err();
        assert_eq!(status, StatusCode::TOO_MANY_REQUESTS, "{detail}");
        assert_eq!(cache.cached(), [("a".to_owned(), one)]);
        // Closed: `a` makes room for `b`.
        drop(a);
        let _b = cache.get_or_load("b", load).await.unwrap();
        assert_eq!(cache.cached(), [("b".to_owned(), one)]);
        assert_eq!(cache.loads(), 3);

        // Expiry: what no replay holds goes once unused for the expiry.
        let quick = ReplayCache::new(ReplayCacheLimits {
            max_bytes: 1 << 30,
            idle_expiry: Duration::ZERO,
        });
        let held = quick.get_or_load("held", load).await.unwrap();
        drop(quick.get_or_load("idle", load).await.unwrap());
        quick.expire();
        assert_eq!(quick.cached(), [("held".to_owned(), one)]);
        drop(held);
        quick.expire();
        assert!(quick.cached().is_empty());
    }
}
