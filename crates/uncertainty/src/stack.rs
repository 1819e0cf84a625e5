//! Per-dot scatter over a no-flow stack, after removing each image's common-mode shift.

use crate::error::StackError;
use bostrack_core::{DotFit, GridIndex, median};
use std::collections::HashMap;

/// What to do with the shift that all dots of one image share (camera or target motion between
/// the images of the stack).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CommonMode {
    /// Keep it: the scatter then includes the motion.
    Keep,
    /// Remove it: alternate `m_i = mean_k(x_ik - s_k)` (per-dot mean over the stack) and
    /// `s_k = median_i(x_ik - m_i)` (robust shift of image k over its dots), `passes` times,
    /// starting from `s = 0`, then fix the gauge so that the shifts average to zero over the
    /// images (the corrected positions are then in the frame of the average image). One pass
    /// is exact for a complete stack; the second corrects the means of dots missing in some
    /// images.
    Remove { passes: usize },
}

impl Default for CommonMode {
    fn default() -> Self {
        CommonMode::Remove { passes: 2 }
    }
}

/// Settings of [`stack_scatter`] and [`reference_stack`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StackConfig {
    /// Default: [`CommonMode::Remove`] with 2 passes.
    pub common_mode: CommonMode,
    /// Fewest images a dot must be fitted in to get an uncertainty, default 3 (at least 2).
    pub min_images: usize,
}

impl Default for StackConfig {
    fn default() -> Self {
        StackConfig {
            common_mode: CommonMode::default(),
            min_images: 3,
        }
    }
}

/// Whether a dot got an uncertainty.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum StackStatus {
    /// Fitted in at least `min_images` images: `u` and the relative standard error are set.
    Ok,
    /// Fitted in fewer than `min_images` images: no `u` (the mean is still given when K >= 1).
    TooFewImages,
}

/// Statistics of one dot over the stack.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DotScatter {
    /// K: images in which the dot was fitted (status ok, finite position).
    pub images: usize,
    /// Mean position over those images after common-mode removal (px); `None` when K = 0.
    pub mean: Option<[f64; 2]>,
    /// `[u_ref_x, u_ref_y]`: sample standard deviation (divisor K - 1) of the corrected
    /// positions (px): the single-image reference position uncertainty. `None` when
    /// K < `min_images`.
    pub u: Option<[f64; 2]>,
    /// Relative standard error of `u`, `1/sqrt(2(K - 1))` (the large-K form for normal data,
    /// docs/paper/NOTES.md §4; 24 % at K = 10). `None` with `u`.
    pub relative_standard_error: Option<f64>,
    pub status: StackStatus,
}

/// Result of [`stack_scatter`].
#[derive(Clone, Debug, PartialEq)]
pub struct Scatter {
    /// One per dot, in input order.
    pub dots: Vec<DotScatter>,
    /// Common-mode shift removed from each image (px); zeros with [`CommonMode::Keep`].
    pub shifts: Vec<[f64; 2]>,
}

/// `[x, y]` samples of dot `i` in image `k`: `samples[k][i]`, `None` where the dot was not
/// fitted. Every image must list the same number of dots.
///
/// Common-mode removal per [`CommonMode`], then per dot the mean, the sample standard
/// deviation in x and y (divisor K - 1) and its relative standard error. A sample with a
/// non-finite coordinate counts as absent.
pub fn stack_scatter(
    samples: &[Vec<Option<[f64; 2]>>],
    cfg: &StackConfig,
) -> Result<Scatter, StackError> {
    if cfg.min_images < 2 {
        return Err(StackError::Config(format!(
            "min_images must be at least 2 for a standard deviation, got {}",
            cfg.min_images
        )));
    }
    if let CommonMode::Remove { passes: 0 } = cfg.common_mode {
        return Err(StackError::Config(
            "common-mode removal needs at least 1 pass (or CommonMode::Keep)".into(),
        ));
    }
    let n = samples.first().map_or(0, Vec::len);
    for (k, s) in samples.iter().enumerate() {
        if s.len() != n {
            return Err(StackError::Shape {
                image: k,
                len: s.len(),
                expected: n,
            });
        }
    }
    let get = |k: usize, i: usize| -> Option<[f64; 2]> {
        samples[k][i].filter(|p| p[0].is_finite() && p[1].is_finite())
    };
    let n_img = samples.len();
    let count: Vec<usize> = (0..n)
        .map(|i| (0..n_img).filter(|&k| get(k, i).is_some()).count())
        .collect();

    let mut shifts = vec![[0.0; 2]; n_img];
    if let CommonMode::Remove { passes } = cfg.common_mode {
        let mut rx = Vec::with_capacity(n);
        let mut ry = Vec::with_capacity(n);
        let mut has = vec![false; n_img];
        for _ in 0..passes {
            let means = corrected_means(samples.len(), n, &get, &shifts);
            for (k, s) in shifts.iter_mut().enumerate() {
                rx.clear();
                ry.clear();
                for i in 0..n {
                    // a dot seen once has residual 0 by construction: it carries no information
                    if count[i] < 2 {
                        continue;
                    }
                    if let (Some(p), Some(m)) = (get(k, i), means[i]) {
                        rx.push(p[0] - m[0]);
                        ry.push(p[1] - m[1]);
                    }
                }
                if !rx.is_empty() {
                    // s_k = median_i(x_ik - m_i); m_i holds the current shifts removed, so the
                    // residual is the full shift of image k
                    *s = [median(&mut rx), median(&mut ry)];
                    has[k] = true;
                }
            }
            // gauge: the estimated shifts average to zero (images without an estimate keep 0)
            let (sx, sy, c) = shifts
                .iter()
                .zip(&has)
                .filter(|(_, h)| **h)
                .fold((0.0, 0.0, 0usize), |(a, b, c), (s, _)| {
                    (a + s[0], b + s[1], c + 1)
                });
            if c > 0 {
                let (gx, gy) = (sx / c as f64, sy / c as f64);
                for (s, _) in shifts.iter_mut().zip(&has).filter(|(_, h)| **h) {
                    s[0] -= gx;
                    s[1] -= gy;
                }
            }
        }
    }

    let means = corrected_means(n_img, n, &get, &shifts);
    let mut dots = Vec::with_capacity(n);
    for i in 0..n {
        let k_i = count[i];
        let (u, rse, status) = if k_i >= cfg.min_images {
            let m = means[i].expect("K >= 2");
            let (mut vx, mut vy) = (0.0, 0.0);
            for k in 0..n_img {
                if let Some(p) = get(k, i) {
                    let (dx, dy) = (p[0] - shifts[k][0] - m[0], p[1] - shifts[k][1] - m[1]);
                    vx += dx * dx;
                    vy += dy * dy;
                }
            }
            let dof = (k_i - 1) as f64;
            (
                Some([(vx / dof).sqrt(), (vy / dof).sqrt()]),
                Some(1.0 / (2.0 * dof).sqrt()),
                StackStatus::Ok,
            )
        } else {
            (None, None, StackStatus::TooFewImages)
        };
        dots.push(DotScatter {
            images: k_i,
            mean: means[i],
            u,
            relative_standard_error: rse,
            status,
        });
    }
    Ok(Scatter { dots, shifts })
}

/// Per-dot mean of `x_ik - s_k` over the images where the dot is present.
fn corrected_means(
    n_img: usize,
    n: usize,
    get: &dyn Fn(usize, usize) -> Option<[f64; 2]>,
    shifts: &[[f64; 2]],
) -> Vec<Option<[f64; 2]>> {
    (0..n)
        .map(|i| {
            let (mut sx, mut sy, mut c) = (0.0, 0.0, 0usize);
            for k in 0..n_img {
                if let Some(p) = get(k, i) {
                    sx += p[0] - shifts[k][0];
                    sy += p[1] - shifts[k][1];
                    c += 1;
                }
            }
            (c > 0).then(|| [sx / c as f64, sy / c as f64])
        })
        .collect()
}

/// One reference dot's stack statistics: [`DotScatter`] with its grid index.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StackDot {
    pub index: GridIndex,
    pub scatter: DotScatter,
}

/// Result of [`reference_stack`].
#[derive(Clone, Debug, PartialEq)]
pub struct ReferenceStack {
    /// One per reference record, in the order of the reference slice.
    pub dots: Vec<StackDot>,
    /// Common-mode shift removed from each stack image (px).
    pub shifts: Vec<[f64; 2]>,
    /// Per stack image: records whose grid index is not among the reference records (or
    /// repeats one already seen in that image); they are left out.
    pub unknown: Vec<usize>,
}

impl ReferenceStack {
    /// Statistics by grid index (a map built on each call; keep it if you ask often).
    pub fn by_index(&self) -> HashMap<GridIndex, DotScatter> {
        self.dots.iter().map(|d| (d.index, d.scatter)).collect()
    }
}

/// Reference position uncertainty from the fits of a no-flow stack: each stack image's fits are
/// matched to the reference records by grid index (detection keeps the reference indices,
/// docs/CONVENTIONS.md; use the kd-tree matcher of the match stage first where it did not);
/// records with a usable fit (status ok, finite position) are the samples; then
/// [`stack_scatter`]. Include the reference image's own fits in `stack` if it belongs to the
/// stack. A grid index repeated in the reference keeps its first record (the later ones get
/// K = 0).
pub fn reference_stack<S: AsRef<[DotFit]>>(
    reference: &[DotFit],
    stack: &[S],
    cfg: &StackConfig,
) -> Result<ReferenceStack, StackError> {
    let mut slot: HashMap<GridIndex, usize> = HashMap::with_capacity(reference.len());
    for (i, d) in reference.iter().enumerate() {
        slot.entry(d.index).or_insert(i);
    }
    let mut unknown = Vec::with_capacity(stack.len());
    let samples: Vec<Vec<Option<[f64; 2]>>> = stack
        .iter()
        .map(|img| {
            let mut row = vec![None; reference.len()];
            let mut seen = vec![false; reference.len()];
            let mut unk = 0;
            for d in img.as_ref() {
                match slot.get(&d.index) {
                    Some(&i) if !seen[i] => {
                        seen[i] = true;
                        if d.status.is_ok() {
                            row[i] = Some([d.params.x0, d.params.y0]);
                        }
                    }
                    _ => unk += 1,
                }
            }
            unknown.push(unk);
            row
        })
        .collect();
    let sc = stack_scatter(&samples, cfg)?;
    // `stack_scatter` returns no dots for an empty stack: every reference dot then has K = 0
    let empty = DotScatter {
        images: 0,
        mean: None,
        u: None,
        relative_standard_error: None,
        status: StackStatus::TooFewImages,
    };
    let dots = reference
        .iter()
        .enumerate()
        .map(|(i, d)| StackDot {
            index: d.index,
            scatter: sc.dots.get(i).copied().unwrap_or(empty),
        })
        .collect();
    Ok(ReferenceStack {
        dots,
        shifts: sc.shifts,
        unknown,
    })
}
