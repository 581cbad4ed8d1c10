//! How far a trainee's attempt was from an expert's: the two trajectories aligned in time by
//! dynamic time warping, then compared point by point.
//!
//! A trainee who moves at another pace than the expert is not "off" for it: comparing the two
//! by clock time would count every lag as distance. Dynamic time warping pairs each of the
//! trainee's samples with the expert's point it corresponds to (monotonically, each sequence
//! walked from its start to its end, repeats allowed), choosing the pairing whose summed
//! distance is least. Over that pairing: the mean and largest distance between the tips, and the
//! mean difference of the forces' sizes.
//!
//! The pairing is searched within a band around the diagonal (a quarter of the expert's points
//! either side, at least [`MIN_BAND`]), so the cost is O(n · band) and the memory O(m): two rows
//! of the table, each cell carrying the sums of its best pairing so that no path is kept for a
//! backtrack.

use glam::DVec3;

/// Smallest half-width of the band, points.
pub const MIN_BAND: usize = 20;

/// One trajectory sample: the tip's position and the size of the force on it.
pub type Sample = (DVec3, f64);

/// The trainee's deviation from the expert over the aligned pairs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Deviation {
    /// Mean distance between paired tips, m.
    pub mean_path_m: f64,
    /// Largest distance between paired tips, m.
    pub max_path_m: f64,
    /// Mean |trainee's |F| − expert's |F||, N.
    pub mean_force_n: f64,
    /// Pairs on the alignment.
    pub pairs: usize,
}

#[derive(Debug, Clone, Copy)]
struct Cell {
    cost: f64,
    force_sum: f64,
    max: f64,
    pairs: usize,
}

const EMPTY: Cell = Cell {
    cost: f64::INFINITY,
    force_sum: 0.0,
    max: 0.0,
    pairs: 0,
};

/// The alignment of `trainee` onto `expert` and the deviation over it; `None` when either is
/// empty or a sample is not finite.
pub fn deviation(trainee: &[Sample], expert: &[Sample]) -> Option<Deviation> {
    let (n, m) = (trainee.len(), expert.len());
    if n == 0 || m == 0 {
        return None;
    }
    let finite = |s: &Sample| s.0.is_finite() && s.1.is_finite();
    if !trainee.iter().all(finite) || !expert.iter().all(finite) {
        return None;
    }
    let band = (m / 4).max(MIN_BAND);
    // The band's centre for trainee sample i: the same fraction of the expert's points, so
    // sequences of different lengths meet at both ends.
    let window = |i: usize| {
        let centre = if n > 1 { i * (m - 1) / (n - 1) } else { 0 };
        (centre.saturating_sub(band), (centre + band).min(m - 1))
    };
    let mut previous = vec![EMPTY; m];
    let mut current = vec![EMPTY; m];
    for (i, &(p, f)) in trainee.iter().enumerate() {
        let (lo, hi) = window(i);
        current.fill(EMPTY);
        for j in lo..=hi {
            let (q, g) = expert[j];
            let d = p.distance(q);
            let best = if i == 0 && j == 0 {
                Some(Cell {
                    cost: 0.0,
                    force_sum: 0.0,
                    max: 0.0,
                    pairs: 0,
                })
            } else {
                let mut candidates = [EMPTY; 3];
                if i > 0 {
                    candidates[0] = previous[j];
                    if j > 0 {
                        candidates[1] = previous[j - 1];
                    }
                }
                if j > 0 {
                    candidates[2] = current[j - 1];
                }
                candidates
                    .into_iter()
                    .filter(|c| c.cost.is_finite())
                    .min_by(|a, b| a.cost.total_cmp(&b.cost))
            };
            if let Some(b) = best {
                current[j] = Cell {
                    cost: b.cost + d,
                    force_sum: b.force_sum + (f - g).abs(),
                    max: b.max.max(d),
                    pairs: b.pairs + 1,
                };
            }
        }
        std::mem::swap(&mut previous, &mut current);
    }
    let end = previous[m - 1];
    (end.cost.is_finite() && end.pairs > 0).then(|| Deviation {
        mean_path_m: end.cost / end.pairs as f64,
        max_path_m: end.max,
        mean_force_n: end.force_sum / end.pairs as f64,
        pairs: end.pairs,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    /// A 100 mm straight path along x, 1 mm apart, with a force rising from 0 to 1 N.
    fn expert() -> Vec<Sample> {
        (0..=100)
            .map(|i| (DVec3::new(0.001 * i as f64, 0.0, 0.0), 0.01 * i as f64))
            .collect()
    }

    #[test]
    fn the_same_path_at_another_pace_deviates_by_nothing() {
        // The trainee goes slowly at first, then fast: 300 samples along the same path, its
        // force following the expert's at each place.
        let trainee: Vec<Sample> = (0..300)
            .map(|k| {
                let u = (k as f64 / 299.0).powi(2);
                (DVec3::new(0.1 * u, 0.0, 0.0), u)
            })
            .collect();
        let d = deviation(&trainee, &expert()).unwrap();
        // Each trainee sample lies within half a millimetre of an expert point.
        assert!(d.mean_path_m < 0.0005, "{d:?}");
        assert!(d.mean_force_n < 0.005, "{d:?}");
    }

    #[test]
    fn a_path_beside_the_experts_deviates_by_its_offset_and_a_harder_press_by_its_force() {
        let trainee: Vec<Sample> = (0..=200)
            .map(|k| {
                let x = 0.0005 * k as f64;
                (DVec3::new(x, 0.003, 0.0), 0.5 + 10.0 * x)
            })
            .collect();
        let d = deviation(&trainee, &expert()).unwrap();
        assert!((d.mean_path_m - 0.003).abs() < 2e-4, "{d:?}");
        assert!(d.max_path_m >= 0.003 - 1e-12);
        assert!((d.mean_force_n - 0.5).abs() < 0.01, "{d:?}");
        // Clock-time comparison would have paired the trainee's first half with the whole path.
        assert!(d.pairs >= 201);
    }

    #[test]
    fn empty_or_broken_input_has_no_deviation() {
        assert!(deviation(&[], &expert()).is_none());
        assert!(deviation(&expert(), &[]).is_none());
        let mut broken = expert();
        broken[3].0.x = f64::NAN;
        assert!(deviation(&broken, &expert()).is_none());
        // One sample each: their distance.
        let d = deviation(&[(DVec3::Y, 1.0)], &[(DVec3::ZERO, 0.0)]).unwrap();
        assert_eq!((d.mean_path_m, d.mean_force_n, d.pairs), (1.0, 1.0, 1));
    }
}
