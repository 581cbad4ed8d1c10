//! Lock-free publication of fixed-size state between the loop and everyone else.
//!
//! The 1 kHz tick must never wait for a reader, and a reader must never see half of a tick's
//! state. [`SeqCell`] is a seqlock over plain `u64` words: the loop (or a device's reader
//! thread) writes, any thread reads. A state crosses it as words: [`Words`] writes its fields
//! in order into a fixed array and [`WordsReader`] reads them back in the same order, so each
//! type states its layout once, as a sequence, instead of as indices written twice.

use std::sync::atomic::{AtomicU64, Ordering, fence};

use glam::{DQuat, DVec3};

/// A seqlock over plain `u64` words: one writer, any number of readers, no `unsafe`.
///
/// The writer makes the sequence odd, stores the words, makes it even again; a reader retries
/// when it saw an odd sequence or a different one after reading. The writer never waits (it is
/// wait-free); a reader waits at most for the writer's few stores. Every word is an atomic, so a
/// torn read is detected, never undefined behaviour.
pub struct SeqCell<const N: usize> {
    seq: AtomicU64,
    words: [AtomicU64; N],
}

impl<const N: usize> SeqCell<N> {
    pub fn new(initial: [u64; N]) -> Self {
        Self {
            seq: AtomicU64::new(0),
            words: initial.map(AtomicU64::new),
        }
    }

    /// Publishes new words. One thread at a time may write a given cell (the loop's baton holder,
    /// whose hand-over orders the writes); two at once would not be unsafe but could let readers
    /// see a mix.
    pub fn write(&self, value: &[u64; N]) {
        let s = self.seq.load(Ordering::Relaxed);
        self.seq.store(s.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        for (w, v) in self.words.iter().zip(value) {
            w.store(*v, Ordering::Relaxed);
        }
        self.seq.store(s.wrapping_add(2), Ordering::Release);
    }

    /// One attempt at a consistent copy: `None` when the writer is mid-write (or wrote during the
    /// copy). Wait-free, for a reader that must never wait for its writer (the 1 kHz thread
    /// reading what a lower-priority thread publishes keeps its previous copy instead).
    pub fn try_read(&self) -> Option<[u64; N]> {
        let before = self.seq.load(Ordering::Acquire);
        if before & 1 == 1 {
            return None;
        }
        let out = std::array::from_fn(|i| self.words[i].load(Ordering::Relaxed));
        fence(Ordering::Acquire);
        (self.seq.load(Ordering::Relaxed) == before).then_some(out)
    }

    /// Reads a consistent copy of the last published words.
    pub fn read(&self) -> [u64; N] {
        let mut attempts = 0u32;
        loop {
            attempts = attempts.wrapping_add(1);
            if attempts.is_multiple_of(64) {
                // The writer was preempted mid-write (possible when it runs without SCHED_FIFO):
                // let it run instead of burning the reader's time slice.
                std::thread::yield_now();
            }
            let before = self.seq.load(Ordering::Acquire);
            if before & 1 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let out = std::array::from_fn(|i| self.words[i].load(Ordering::Relaxed));
            fence(Ordering::Acquire);
            if self.seq.load(Ordering::Relaxed) == before {
                return out;
            }
        }
    }
}

/// Writes values into `N` words in order (an `f64` by its bit pattern). Used on the 1 kHz
/// thread, so it never panics and never allocates: a write past the end is dropped, and
/// [`Words::finish`] checks in debug builds (every type's round-trip test runs them) that the
/// layout filled exactly `N` words.
pub struct Words<const N: usize> {
    words: [u64; N],
    at: usize,
}

impl<const N: usize> Default for Words<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> Words<N> {
    pub fn new() -> Self {
        Self {
            words: [0; N],
            at: 0,
        }
    }

    pub fn u64(&mut self, v: u64) -> &mut Self {
        if let Some(w) = self.words.get_mut(self.at) {
            *w = v;
        }
        self.at += 1;
        self
    }

    pub fn f64(&mut self, v: f64) -> &mut Self {
        self.u64(v.to_bits())
    }

    pub fn bool(&mut self, v: bool) -> &mut Self {
        self.u64(u64::from(v))
    }

    pub fn vec3(&mut self, v: DVec3) -> &mut Self {
        self.f64(v.x).f64(v.y).f64(v.z)
    }

    /// x, y, z, w.
    pub fn quat(&mut self, q: DQuat) -> &mut Self {
        self.f64(q.x).f64(q.y).f64(q.z).f64(q.w)
    }

    pub fn u64s(&mut self, values: &[u64]) -> &mut Self {
        for &v in values {
            self.u64(v);
        }
        self
    }

    /// The words written.
    pub fn finish(&self) -> [u64; N] {
        debug_assert_eq!(self.at, N, "a layout of {} words written into {N}", self.at);
        self.words
    }
}

/// Reads back, in the same order, what [`Words`] wrote. A read past the end gives 0.
pub struct WordsReader<'a, const N: usize> {
    words: &'a [u64; N],
    at: usize,
}

impl<'a, const N: usize> WordsReader<'a, N> {
    pub fn new(words: &'a [u64; N]) -> Self {
        Self { words, at: 0 }
    }

    pub fn u64(&mut self) -> u64 {
        let v = self.words.get(self.at).copied().unwrap_or(0);
        self.at += 1;
        v
    }

    pub fn f64(&mut self) -> f64 {
        f64::from_bits(self.u64())
    }

    pub fn bool(&mut self) -> bool {
        self.u64() != 0
    }

    pub fn vec3(&mut self) -> DVec3 {
        let (x, y, z) = (self.f64(), self.f64(), self.f64());
        DVec3::new(x, y, z)
    }

    /// x, y, z, w.
    pub fn quat(&mut self) -> DQuat {
        let (x, y, z, w) = (self.f64(), self.f64(), self.f64(), self.f64());
        DQuat::from_xyzw(x, y, z, w)
    }

    pub fn u64s<const M: usize>(&mut self) -> [u64; M] {
        std::array::from_fn(|_| self.u64())
    }

    /// Checks in debug builds that the layout read was the one written, all `N` words.
    pub fn finish(&self) {
        debug_assert_eq!(self.at, N, "a layout of {} words read from {N}", self.at);
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn values_come_back_in_the_order_written() {
        let q = DQuat::from_rotation_y(0.3);
        let mut w = Words::<11>::new();
        w.u64(7)
            .f64(-0.5)
            .bool(true)
            .vec3(DVec3::new(1.0, 2.0, 3.0))
            .quat(q)
            .u64s(&[9]);
        let words = w.finish();
        let mut r = WordsReader::new(&words);
        assert_eq!(r.u64(), 7);
        assert_eq!(r.f64(), -0.5);
        assert!(r.bool());
        assert_eq!(r.vec3(), DVec3::new(1.0, 2.0, 3.0));
        assert_eq!(r.quat(), q);
        assert_eq!(r.u64s::<1>(), [9]);
        r.finish();
    }

    #[test]
    #[cfg(debug_assertions)]
    #[should_panic(expected = "a layout of 2 words written into 3")]
    fn a_layout_shorter_than_its_words_is_caught() {
        let mut w = Words::<3>::new();
        w.u64(1).u64(2);
        let _ = w.finish();
    }

    #[test]
    fn a_write_past_the_end_is_dropped_not_a_panic_in_release() {
        let mut w = Words::<1>::new();
        w.u64(1).u64(2);
        assert_eq!(w.words, [1]);
        let words = [5u64];
        let mut r = WordsReader::new(&words);
        assert_eq!((r.u64(), r.u64()), (5, 0));
    }

    #[test]
    fn seqlock_readers_never_see_a_torn_value() {
        let cell = std::sync::Arc::new(SeqCell::<8>::new([0; 8]));
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let readers: Vec<_> = (0..2)
            .map(|_| {
                let (cell, stop) = (std::sync::Arc::clone(&cell), std::sync::Arc::clone(&stop));
                std::thread::spawn(move || {
                    let mut reads = 0u64;
                    while !stop.load(Ordering::Relaxed) {
                        let w = cell.read();
                        assert!(w.iter().all(|&x| x == w[0]), "torn read {w:?}");
                        reads += 1;
                    }
                    reads
                })
            })
            .collect();
        for i in 1..=200_000u64 {
            cell.write(&[i; 8]);
        }
        stop.store(true, Ordering::Relaxed);
        for r in readers {
            assert!(r.join().unwrap() > 0);
        }
        assert_eq!(cell.read(), [200_000; 8]);
    }
}
