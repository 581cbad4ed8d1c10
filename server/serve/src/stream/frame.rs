//! A contact frame encoded once for every viewer, with each viewer's own `dropped` count
//! spliced into the shared text.

use axum::extract::ws::Utf8Bytes;
use softhaptic_proto::wire::{ContactFrame, ServerMessage};

/// A contact frame encoded once for every viewer.
///
/// Every viewer with no lost frames gets `with_no_drops` (shared bytes, no copy). A viewer that
/// lost frames needs its own `dropped` value, the frame's last field: it gets `prefix` (the JSON
/// up to and including `"dropped":`) followed by its count and `}`.
#[derive(Debug)]
pub struct EncodedFrame {
    pub seq: u64,
    with_no_drops: Utf8Bytes,
    prefix_len: usize,
}

/// The tail every encoded contact frame ends with when `dropped` is 0.
const NO_DROPS_TAIL: &str = "\"dropped\":0}";

impl EncodedFrame {
    /// Encodes `frame` (its `dropped` is ignored and written as 0).
    pub fn new(frame: &ContactFrame) -> Result<Self, serde_json::Error> {
        let frame = ContactFrame {
            dropped: 0,
            ..*frame
        };
        let text = ServerMessage::Contact(frame).encode()?;
        // `dropped` is the last field of `ContactFrame`, and serde writes fields in declaration
        // order, so the text always ends with the tail (checked by a test); if a future field
        // order broke that, fail loudly rather than send wrong counts.
        if !text.ends_with(NO_DROPS_TAIL) {
            return Err(serde::ser::Error::custom(
                "contact frame does not end with its dropped field",
            ));
        }
        let prefix_len = text.len() - 2;
        Ok(Self {
            seq: frame.seq,
            with_no_drops: Utf8Bytes::from(text),
            prefix_len,
        })
    }

    /// A frame received as text (a station's, relayed by a hub): it must be a contact message
    /// of the wire protocol whose `dropped` is 0, and it is encoded again from what was decoded,
    /// never passed on as it came: whitespace or unknown fields a station padded it with do not
    /// reach the hub's viewers (a real station's frame comes out byte for byte the same, as
    /// both sides encode it alike).
    pub fn from_text(text: String) -> Result<Self, String> {
        match ServerMessage::decode(&text) {
            Ok(ServerMessage::Contact(frame)) if frame.dropped == 0 => {
                Self::new(&frame).map_err(|e| e.to_string())
            }
            Ok(ServerMessage::Contact(_)) => Err("a contact frame whose dropped is not 0".into()),
            Ok(other) => Err(format!(
                "a {} message, not a contact frame",
                other.type_name()
            )),
            Err(e) => Err(e.to_string()),
        }
    }

    /// The text for a viewer that has lost `dropped` frames so far.
    pub fn text_for(&self, dropped: u64) -> Utf8Bytes {
        if dropped == 0 {
            return self.with_no_drops.clone();
        }
        let prefix = &self.with_no_drops.as_str()[..self.prefix_len];
        let mut text = String::with_capacity(self.prefix_len + 21);
        text.push_str(prefix);
        text.push_str(&dropped.to_string());
        text.push('}');
        Utf8Bytes::from(text)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use softhaptic_proto::{ContactFlags, ContactState};

    #[test]
    fn a_relayed_frame_is_encoded_again_padding_and_unknown_fields_dropped() {
        let state = ContactState {
            in_contact: true,
            depth_m: 0.003,
            ..ContactState::IDLE
        };
        let made = EncodedFrame::new(&ContactFrame::from_state(&state, 7, 0.02, 0)).unwrap();
        let sent = made.text_for(0).to_string();
        // A real station's frame: the same bytes.
        let relayed = EncodedFrame::from_text(sent.clone()).unwrap();
        assert_eq!(relayed.text_for(0).as_str(), sent);
        // Padded inside and given a field of its own: what viewers get is the frame alone.
        let padded = sent.replacen(
            '{',
            &format!("{{{}\"junk\":\"{}\",", " ".repeat(4096), "x".repeat(4096)),
            1,
        );
        assert!(padded.len() > 8000);
        let relayed = EncodedFrame::from_text(padded).unwrap();
        assert_eq!(relayed.text_for(0).as_str(), sent);
        // A frame claiming drops of its own is not one a station sends.
        let dropped = sent.replace("\"dropped\":0}", "\"dropped\":5}");
        assert!(EncodedFrame::from_text(dropped).is_err());
    }

    #[test]
    fn per_viewer_dropped_counts_are_spliced_into_the_shared_text() {
        let state = ContactState {
            in_contact: true,
            depth_m: 0.003,
            flags: ContactFlags::SATURATED,
            ..ContactState::IDLE
        };
        let encoded = EncodedFrame::new(&ContactFrame::from_state(&state, 42, 0.02, 0)).unwrap();
        for dropped in [0, 1, 17, u64::MAX] {
            let text = encoded.text_for(dropped);
            match ServerMessage::decode(&text).unwrap() {
                ServerMessage::Contact(f) => {
                    assert_eq!(f.dropped, dropped);
                    assert_eq!(f.seq, 42);
                    assert_eq!(f.flags, ContactFlags::SATURATED);
                }
                other => panic!("{other:?}"),
            }
        }
    }
}
