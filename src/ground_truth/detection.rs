//! Detection scores for people on the floor plane, as the DROW benchmark (Beyer, Hermans &
//! Leibe, RA-L 2017; Beyer et al., RA-L 2018) scores 2D range detectors: a detection is a
//! point with a confidence, and it is right when it lies within an association radius of a
//! true person (0.5 m and 0.3 m there: AP₀.₅ and AP₀.₃).
//!
//! Matching follows PASCAL VOC's rule: over all frames, detections are taken by falling
//! confidence, and each takes the nearest true person of its frame not yet taken, within the
//! radius; otherwise it is a false positive. The precision–recall curve has a point at each
//! distinct confidence (ties enter together, so the result does not depend on their order),
//! and the average precision is the area under its upper envelope (VOC 2010's all-point
//! interpolation). Precision and recall "at the operating point" count every detection the
//! detector gave.

use serde::Serialize;

/// A detection: its position, m, and its confidence.
pub type Detection = ([f64; 2], f64);

/// One frame: the true people and the detections, in one frame, m.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DetectionFrame {
    pub truth: Vec<[f64; 2]>,
    pub detections: Vec<Detection>,
}

/// A detector's scores at one radius.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct DetectionScore {
    /// True people summed over frames.
    pub truth: usize,
    pub detections: usize,
    pub true_positives: usize,
    /// Average precision; `None` without true people.
    pub ap: Option<f64>,
    /// With every detection counted; `None` without detections.
    pub precision: Option<f64>,
    /// With every detection counted; `None` without true people.
    pub recall: Option<f64>,
    /// The highest F1 along the curve.
    pub peak_f1: Option<f64>,
}

/// Scores detections against the truth within `radius` (see the module documentation).
pub fn score(frames: &[DetectionFrame], radius: f64) -> DetectionScore {
    let truth: usize = frames.iter().map(|f| f.truth.len()).sum();
    let mut order: Vec<(f64, usize, usize)> = frames
        .iter()
        .enumerate()
        .flat_map(|(k, f)| {
            f.detections
                .iter()
                .enumerate()
                .map(move |(i, d)| (d.1, k, i))
        })
        .collect();
    order.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut taken: Vec<Vec<bool>> = frames.iter().map(|f| vec![false; f.truth.len()]).collect();
    let mut tp = 0usize;
    // (recall, precision) after each group of equal confidence.
    let mut curve: Vec<(f64, f64)> = Vec::new();
    for (n, &(c, k, i)) in order.iter().enumerate() {
        let p = frames[k].detections[i].0;
        let nearest = frames[k]
            .truth
            .iter()
            .enumerate()
            .filter(|(j, _)| !taken[k][*j])
            .map(|(j, q)| (j, (p[0] - q[0]).hypot(p[1] - q[1])))
            .filter(|(_, d)| *d <= radius)
            .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        if let Some((j, _)) = nearest {
            taken[k][j] = true;
            tp += 1;
        }
        let group_ends = order.get(n + 1).is_none_or(|next| next.0 != c);
        if group_ends && truth > 0 {
            curve.push((tp as f64 / truth as f64, tp as f64 / (n + 1) as f64));
        }
    }
    // The envelope from the right, and the area under it.
    let mut ap = 0.0;
    let mut best = 0.0f64;
    let mut envelope = vec![0.0; curve.len()];
    for (e, &(_, p)) in envelope.iter_mut().zip(&curve).rev() {
        best = best.max(p);
        *e = best;
    }
    let mut last_recall = 0.0;
    for (&(r, _), &e) in curve.iter().zip(&envelope) {
        ap += (r - last_recall) * e;
        last_recall = r;
    }
    let peak_f1 = curve
        .iter()
        .map(|&(r, p)| {
            if r + p > 0.0 {
                2.0 * r * p / (r + p)
            } else {
                0.0
            }
        })
        .fold(None, |m: Option<f64>, f| Some(m.map_or(f, |m| m.max(f))));
    DetectionScore {
        truth,
        detections: order.len(),
        true_positives: tp,
        ap: (truth > 0).then_some(ap),
        precision: (!order.is_empty()).then(|| tp as f64 / order.len() as f64),
        recall: (truth > 0).then(|| tp as f64 / truth as f64),
        peak_f1: peak_f1.or((truth > 0).then_some(0.0)),
    }
}

/// Ranges from the frame's origin (the sensor) at which AP is reported against range, m.
pub const RANGE_BINS: [f64; 6] = [0.0, 2.0, 4.0, 6.0, 8.0, 10.0];

/// AP against range: for each bin of [`RANGE_BINS`], the frames cut to the true people and the
/// detections whose range from the origin falls in it, scored within `radius`.
pub fn by_range(frames: &[DetectionFrame], radius: f64) -> Vec<(f64, f64, DetectionScore)> {
    let range = |p: &[f64; 2]| p[0].hypot(p[1]);
    RANGE_BINS
        .windows(2)
        .map(|w| {
            let inside = |p: &[f64; 2]| (w[0]..w[1]).contains(&range(p));
            let cut: Vec<DetectionFrame> = frames
                .iter()
                .map(|f| DetectionFrame {
                    truth: f.truth.iter().copied().filter(|p| inside(p)).collect(),
                    detections: f
                        .detections
                        .iter()
                        .copied()
                        .filter(|d| inside(&d.0))
                        .collect(),
                })
                .collect();
            (w[0], w[1], score(&cut, radius))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(truth: &[[f64; 2]], dets: &[([f64; 2], f64)]) -> DetectionFrame {
        DetectionFrame {
            truth: truth.to_vec(),
            detections: dets.to_vec(),
        }
    }

    #[test]
    fn a_hand_computed_curve() {
        // Two frames, three people. By falling confidence:
        //   0.9 frame 0, 0.1 m from a → TP   (P 1/1, R 1/3)
        //   0.8 frame 1, 0.6 m from c → FP   (P 1/2, R 1/3)
        //   0.7 frame 0, 0.2 m from b → TP   (P 2/3, R 2/3)
        //   0.6 frame 0, 0.05 m from a, already taken → FP (P 2/4, R 2/3)
        // Envelope: 1 at R 1/3, 2/3 at R 2/3; AP = 1/3·1 + 1/3·2/3 = 5/9.
        let frames = [
            frame(
                &[[1.0, 0.0], [3.0, 0.0]],
                &[([1.1, 0.0], 0.9), ([3.0, 0.2], 0.7), ([1.0, 0.05], 0.6)],
            ),
            frame(&[[2.0, 2.0]], &[([2.0, 2.6], 0.8)]),
        ];
        let s = score(&frames, 0.5);
        assert_eq!((s.truth, s.detections, s.true_positives), (3, 4, 2));
        assert!((s.ap.unwrap() - 5.0 / 9.0).abs() < 1e-12, "{s:?}");
        assert_eq!(s.precision, Some(0.5));
        assert!((s.recall.unwrap() - 2.0 / 3.0).abs() < 1e-12);
        // Peak F1 at (R 2/3, P 2/3).
        assert!((s.peak_f1.unwrap() - 2.0 / 3.0).abs() < 1e-12);
        // At 0.3 m the 0.6 m detection still misses and the others still hit: the same.
        assert_eq!(score(&frames, 0.3).ap, s.ap);
        // At 0.15 m the 0.2 m detection misses too: only the first hits, AP = 1/3.
        assert!((score(&frames, 0.15).ap.unwrap() - 1.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn ties_enter_together_whatever_their_order() {
        // Two detections of equal confidence, one right, one wrong: one curve point, P ½ at
        // R 1, in either order.
        let a = [frame(
            &[[0.0, 0.0]],
            &[([0.0, 0.1], 0.5), ([5.0, 5.0], 0.5)],
        )];
        let b = [frame(
            &[[0.0, 0.0]],
            &[([5.0, 5.0], 0.5), ([0.0, 0.1], 0.5)],
        )];
        assert_eq!(score(&a, 0.5).ap, Some(0.5));
        assert_eq!(score(&b, 0.5).ap, Some(0.5));
    }

    #[test]
    fn nobody_to_find_and_nothing_found() {
        let s = score(&[frame(&[], &[([1.0, 1.0], 0.9)])], 0.5);
        assert_eq!((s.ap, s.recall, s.precision), (None, None, Some(0.0)));
        let s = score(&[frame(&[[1.0, 1.0]], &[])], 0.5);
        assert_eq!((s.ap, s.recall, s.precision), (Some(0.0), Some(0.0), None));
    }

    #[test]
    fn range_bins_split_people_and_detections() {
        let frames = [frame(
            &[[1.0, 0.0], [5.0, 0.0]],
            &[([1.0, 0.1], 0.9), ([5.3, 0.0], 0.8)],
        )];
        let bins = by_range(&frames, 0.5);
        assert_eq!(bins.len(), 5);
        assert_eq!(bins[0].2.ap, Some(1.0));
        assert_eq!(bins[1].2.ap, None);
        assert_eq!(bins[2].2.ap, Some(1.0));
        // A detection and its person on either side of a bin's edge miss each other.
        let edge = [frame(&[[3.9, 0.0]], &[([4.1, 0.0], 0.9)])];
        let bins = by_range(&edge, 0.5);
        assert_eq!((bins[1].2.ap, bins[2].2.ap), (Some(0.0), None));
    }
}
