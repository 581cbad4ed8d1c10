//! Where a palpation scene's inclusions are, on their way to the viewers allowed to see them.
//!
//! Two latest-value channels: `hidden`, the answer while an attempt runs, read only by the
//! tasks of viewers who may see it ([`crate::access::roles::Action::SeeInclusions`], on a
//! station with tokens), and `public`, the answer once a palpation attempt has ended, read by
//! every viewer. An observer's task never holds a receiver of `hidden`, so nothing it is sent
//! can carry the positions before the end. A `watch` channel keeps the latest value, so a
//! viewer that connects later gets where things stand, and a slow one skips to the newest.

use axum::extract::ws::Utf8Bytes;
use tokio::sync::watch;

/// The inclusions' two channels of one stream (both empty where the scene has none).
pub struct InclusionsFeed {
    hidden: watch::Sender<Option<Utf8Bytes>>,
    public: watch::Sender<Option<Utf8Bytes>>,
}

impl Default for InclusionsFeed {
    fn default() -> Self {
        Self::none()
    }
}

impl InclusionsFeed {
    /// The feed of a stream whose scene has no inclusions: nothing is ever sent.
    pub fn none() -> Self {
        Self {
            hidden: watch::channel(None).0,
            public: watch::channel(None).0,
        }
    }

    /// An attempt (or a session without exercises) starts: `text`, an encoded `inclusions`
    /// message with `revealed: false`, goes to the viewers who may see the answer, and the
    /// previous attempt's public answer is withdrawn from viewers that connect from now on.
    pub fn show_instructors(&self, text: Utf8Bytes) {
        self.public.send_replace(None);
        self.hidden.send_replace(Some(text));
    }

    /// A palpation attempt has ended: `text` (`revealed: true`) goes to every viewer.
    pub fn reveal(&self, text: Utf8Bytes) {
        self.public.send_replace(Some(text));
    }

    /// Sets both channels to another server's (a lab hub mirrors a station's), each only when it
    /// changed, so that viewers are told nothing twice.
    pub fn mirror(&self, hidden: Option<Utf8Bytes>, public: Option<Utf8Bytes>) {
        // The public answer first, as `show_instructors` does: a new attempt withdraws it
        // before its own hidden answer is told.
        self.public
            .send_if_modified(|p| replace_if_changed(p, public));
        self.hidden
            .send_if_modified(|h| replace_if_changed(h, hidden));
    }

    /// A receiver of the answer while an attempt runs; only for a viewer who may see it.
    pub fn hidden(&self) -> watch::Receiver<Option<Utf8Bytes>> {
        self.hidden.subscribe()
    }

    /// A receiver of the answer once an attempt has ended, for every viewer.
    pub fn public(&self) -> watch::Receiver<Option<Utf8Bytes>> {
        self.public.subscribe()
    }
}

fn replace_if_changed(slot: &mut Option<Utf8Bytes>, value: Option<Utf8Bytes>) -> bool {
    if *slot == value {
        return false;
    }
    *slot = value;
    true
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn a_new_attempt_withdraws_the_previous_answer_from_later_viewers() {
        let feed = InclusionsFeed::none();
        assert!(feed.hidden().borrow().is_none() && feed.public().borrow().is_none());
        feed.show_instructors(Utf8Bytes::from_static("a1"));
        assert!(feed.public().borrow().is_none());
        feed.reveal(Utf8Bytes::from_static("a1 revealed"));
        assert_eq!(feed.public().borrow().as_deref(), Some("a1 revealed"));
        feed.show_instructors(Utf8Bytes::from_static("a2"));
        assert!(feed.public().borrow().is_none());
        assert_eq!(feed.hidden().borrow().as_deref(), Some("a2"));
    }
}
