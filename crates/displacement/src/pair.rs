//! One reference/gradient pair: displacement, amplification ratio, displacement uncertainty.

use bostrack_core::{DotFit, DotFlags, Gaussian2D, GridIndex};
use bostrack_model::{ArVariant, amplification_ratio, bound_ratio};

/// Which position of a reference dot the displacement is measured from, and hence its
/// uncertainty `u_refpos` in `u_d² = u_refpos² + u_grad²`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum ReferencePosition {
    /// The fit in the single reference image: `u_refpos = u_ref`.
    #[default]
    SingleImage,
    /// The mean position over the K images of the no-flow stack:
    /// `u_refpos = u_ref / sqrt(K)` (docs/paper/NOTES.md §4).
    StackMean,
}

/// What to compute: each level includes the ones before it ("compute only what the requested
/// outputs need").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub enum Quantities {
    /// Displacement only.
    Displacement,
    /// Displacement and amplification ratio.
    AmplificationRatio,
    /// Displacement, amplification ratio, `u_ref`, `u_grad` and `u_d`.
    #[default]
    Uncertainty,
}

/// Which dot shapes enter the amplification ratio.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum ArShapes {
    /// The fitted parameters as they are (the formula of docs/paper/NOTES.md §2).
    #[default]
    Fitted,
    /// The fitted dots blurred by the unit pixel box: covariance `Σ + I/12` px², volume kept
    /// ([`pixel_blurred`]). For fits with the pixel-integrated model, whose fitted sigmas are
    /// those *before* the pixel integration, this is what the pixels carry: it brings AR to
    /// within 0.5 % of the exact ratio of the Cramér-Rao bounds down to σ = 1 px, where the
    /// plain formula is off by up to 7.5 % (3.3 % at σ = 1.5 px, 1.9 % at 2 px; see the
    /// crate's `ar_vs_crlb` example). Not for point-sampled fits, whose sigmas already include
    /// the pixel.
    PixelBlurred,
}

/// The dot as seen through the unit pixel box, approximated as a Gaussian: covariance
/// `[[σx², ρσxσy], [ρσxσy, σy²]] + I/12` (the variance of a uniform distribution over one
/// pixel), the same volume `2π I0 σx σy sqrt(1-ρ²)`, centre and background unchanged.
pub fn pixel_blurred(g: &Gaussian2D) -> Gaussian2D {
    let cxx = g.sigma_x * g.sigma_x + 1.0 / 12.0;
    let cyy = g.sigma_y * g.sigma_y + 1.0 / 12.0;
    let cxy = g.rho * g.sigma_x * g.sigma_y;
    let (sx, sy) = (cxx.sqrt(), cyy.sqrt());
    let rho = cxy / (sx * sy);
    let amplitude = g.volume() / (2.0 * std::f64::consts::PI * sx * sy * (1.0 - rho * rho).sqrt());
    Gaussian2D {
        sigma_x: sx,
        sigma_y: sy,
        rho,
        amplitude,
        ..*g
    }
}

/// Settings of [`pair_dot`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DisplacementConfig {
    /// Default [`Quantities::Uncertainty`].
    pub quantities: Quantities,
    /// Default [`ArVariant::Bounds`]: the ratio of the two fits' own bounds (`crlb_grad /
    /// crlb_ref`), right under shot noise too; it needs the records' bounds (NaN bounds give no
    /// AR). [`ArVariant::Notes`] is the closed form of docs/paper/NOTES.md §2 from the
    /// fitted shapes alone; [`ArVariant::Published`] only to reproduce published numbers.
    pub ar_variant: ArVariant,
    /// Default [`ArShapes::Fitted`].
    pub ar_shapes: ArShapes,
    /// Default [`ReferencePosition::SingleImage`].
    pub reference_position: ReferencePosition,
    /// A pair carrying any of these flags is not valid. Default
    /// [`DisplacementConfig::DEFAULT_INVALID_IF`].
    pub invalid_if: DotFlags,
}

impl DisplacementConfig {
    /// Flags that make a displacement unusable by default: no partner, failed fit, missing or
    /// merged dot, index disagreement, rejected by validation, a centre outside the region of
    /// interest (`outside_mask`), a fit not converged jointly with
    /// its neighbours (`unconverged`) or whose residual the noise model does not explain
    /// (`residual`): for those two the bound, and so `u_d`, does not describe the error.
    /// (Border, mask, saturation, faintness, defects, a shape at its bound and a neighbour
    /// outside the region of interest are warnings: the per-dot bound already accounts for
    /// them, or they are for the user to judge.) The table of every flag is in
    /// docs/CONVENTIONS.md.
    pub const DEFAULT_INVALID_IF: DotFlags = DotFlags::from_bits(
        DotFlags::UNMATCHED.bits()
            | DotFlags::FIT_FAILED.bits()
            | DotFlags::MISSING.bits()
            | DotFlags::MERGED.bits()
            | DotFlags::GRID_MISMATCH.bits()
            | DotFlags::OUTLIER.bits()
            | DotFlags::OUTSIDE_MASK.bits()
            | DotFlags::UNCONVERGED.bits()
            | DotFlags::RESIDUAL.bits(),
    );
}

impl Default for DisplacementConfig {
    fn default() -> Self {
        DisplacementConfig {
            quantities: Quantities::default(),
            ar_variant: ArVariant::Bounds,
            ar_shapes: ArShapes::Fitted,
            reference_position: ReferencePosition::default(),
            invalid_if: Self::DEFAULT_INVALID_IF,
        }
    }
}

/// What the no-flow stack says about one reference dot (from `bostrack-uncertainty`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReferenceStats {
    /// K: stack images in which the dot was fitted.
    pub images: usize,
    /// Mean position over the stack (px); `None` when K = 0.
    pub mean: Option<[f64; 2]>,
    /// `[u_ref_x, u_ref_y]`: single-image position uncertainty (px); `None` when K was too
    /// small.
    pub u: Option<[f64; 2]>,
}

/// Everything known about one lattice site of a reference/gradient pair.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairInput<'a> {
    /// The reference fit; `None` if the site has no reference record.
    pub reference: Option<&'a DotFit>,
    /// The gradient fit; `None` if no gradient dot was matched.
    pub gradient: Option<&'a DotFit>,
    /// Stack statistics of the reference dot; `None` without a no-flow stack.
    pub stack: Option<ReferenceStats>,
    /// Flags from matching and validation (`GRID_MISMATCH`, `OUTLIER`).
    pub flags: DotFlags,
}

/// Where [`PairDot::reference_position`] came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ReferenceSource {
    /// The reference image's fit.
    Fit,
    /// The stack mean.
    StackMean,
}

/// Per-dot result; [`crate::to_row`] turns it into the CSV columns of [`crate::COLUMNS`].
///
/// Every `Option` is `None` exactly when the quantity was not requested or could not be
/// computed; nothing is a silent NaN.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairDot {
    /// Grid index of the reference record, else of the gradient record.
    pub index: GridIndex,
    pub reference: Option<DotFit>,
    pub gradient: Option<DotFit>,
    /// Reference position the displacement is measured from (px): the fit, or the stack mean
    /// with [`ReferencePosition::StackMean`] when the stack has it.
    pub reference_position: Option<[f64; 2]>,
    pub reference_source: Option<ReferenceSource>,
    /// `[dx, dy] = gradient - reference` (px, docs/CONVENTIONS.md); `None` unless both fits are
    /// present and usable.
    pub displacement: Option<[f64; 2]>,
    /// `[AR_x, AR_y]` (docs/paper/NOTES.md §2); `None` when not requested or not
    /// computable (non-positive amplitude, invalid shape).
    pub ar: Option<[f64; 2]>,
    /// `[u_ref_x, u_ref_y]`: single-image reference position uncertainty from the stack (px).
    pub u_ref: Option<[f64; 2]>,
    /// `u_grad = AR · u_ref` per axis (px).
    pub u_grad: Option<[f64; 2]>,
    /// `u_d = sqrt(u_refpos² + u_grad²)` per axis (px).
    pub u_d: Option<[f64; 2]>,
    /// Both fits present and usable, displacement finite, and none of the config's
    /// `invalid_if` flags set.
    pub valid: bool,
    /// Reference flags | gradient flags | input flags | `UNMATCHED` (a side missing) |
    /// `FIT_FAILED` (a present side not usable).
    pub flags: DotFlags,
}

pub(crate) fn usable(d: &DotFit) -> bool {
    d.status.is_ok() && d.params.x0.is_finite() && d.params.y0.is_finite()
}

fn finite2(v: [f64; 2]) -> Option<[f64; 2]> {
    (v[0].is_finite() && v[1].is_finite()).then_some(v)
}

/// Displacement, amplification ratio and displacement uncertainty of one pair
/// (docs/CONVENTIONS.md, docs/paper/NOTES.md §2 and §4):
///
/// - `d = x_grad - x_ref`, with `x_ref` the reference fit or the stack mean
///   ([`ReferencePosition`]; the fit where the stack has no mean for the dot);
/// - AR per axis: with [`ArVariant::Bounds`] (the default), `crlb_grad / crlb_ref` of the two
///   records (`bostrack_model::bound_ratio`); with the other variants,
///   `amplification_ratio(reference, gradient, cfg.ar_variant)` from the fitted amplitudes,
///   sigmas and ρ of the same dot in both images (optionally blurred by the pixel first,
///   [`ArShapes`]);
/// - `u_grad = AR · u_ref`, `u_refpos = u_ref` (single image) or `u_ref / sqrt(K)` (stack
///   mean position), `u_d = sqrt(u_refpos² + u_grad²)`.
///
/// Without stack statistics `u_ref`, `u_grad` and `u_d` are `None`; the per-dot CRLB of both
/// fits stays in the records. `None` only for an input with neither record.
pub fn pair_dot(input: &PairInput<'_>, cfg: &DisplacementConfig) -> Option<PairDot> {
    let index = input.reference.or(input.gradient)?.index;
    Some(pair_dot_at(input, index, cfg))
}

/// [`pair_dot`] for the dot at grid `index` (for an input with a record, that record's index
/// gives `pair_dot`'s result; an input with neither record is an unmatched dot without
/// quantities). For a caller that always has a record, such as the reference's, and collects
/// the results by position.
pub fn pair_dot_at(input: &PairInput<'_>, index: GridIndex, cfg: &DisplacementConfig) -> PairDot {
    let (r, g) = (input.reference, input.gradient);
    let mut flags = input.flags;
    for d in [r, g].into_iter().flatten() {
        flags |= d.flags;
        if !d.status.is_ok() {
            flags |= DotFlags::FIT_FAILED;
        }
    }
    if r.is_none() || g.is_none() {
        flags |= DotFlags::UNMATCHED;
    }

    // reference position
    let stack_mean = (cfg.reference_position == ReferencePosition::StackMean)
        .then(|| input.stack.and_then(|s| s.mean))
        .flatten()
        .and_then(finite2);
    let (reference_position, reference_source) = match (stack_mean, r) {
        (Some(m), Some(_)) => (Some(m), Some(ReferenceSource::StackMean)),
        (_, Some(d)) if usable(d) => (Some([d.params.x0, d.params.y0]), Some(ReferenceSource::Fit)),
        _ => (None, None),
    };

    let both = match (r, g) {
        (Some(r), Some(g)) if usable(r) && usable(g) => Some((r, g)),
        _ => None,
    };
    let displacement = both.and_then(|(_, g)| {
        let p = reference_position?;
        finite2([g.params.x0 - p[0], g.params.y0 - p[1]])
    });

    let ar = (cfg.quantities >= Quantities::AmplificationRatio)
        .then(|| {
            both.map(|(r, g)| match (cfg.ar_variant, cfg.ar_shapes) {
                (ArVariant::Bounds, _) => bound_ratio([r.crlb_x, r.crlb_y], [g.crlb_x, g.crlb_y]),
                (_, ArShapes::Fitted) => amplification_ratio(&r.params, &g.params, cfg.ar_variant),
                (_, ArShapes::PixelBlurred) => amplification_ratio(
                    &pixel_blurred(&r.params),
                    &pixel_blurred(&g.params),
                    cfg.ar_variant,
                ),
            })
        })
        .flatten()
        .and_then(finite2);

    let (mut u_ref, mut u_grad, mut u_d) = (None, None, None);
    if cfg.quantities >= Quantities::Uncertainty
        && let Some(s) = input.stack
        && let Some(u) = s.u.and_then(finite2)
    {
        u_ref = Some(u);
        if let Some(a) = ar {
            let ug = [a[0] * u[0], a[1] * u[1]];
            u_grad = Some(ug);
            let scale = match reference_source {
                Some(ReferenceSource::StackMean) if s.images > 0 => 1.0 / (s.images as f64).sqrt(),
                _ => 1.0,
            };
            u_d = finite2([(u[0] * scale).hypot(ug[0]), (u[1] * scale).hypot(ug[1])]);
        }
    }

    let valid = displacement.is_some() && !flags.intersects(cfg.invalid_if);
    PairDot {
        index,
        reference: r.copied(),
        gradient: g.copied(),
        reference_position,
        reference_source,
        displacement,
        ar,
        u_ref,
        u_grad,
        u_d,
        valid,
        flags,
    }
}

/// [`pair_dot`] over many pairs (inputs with neither record are skipped).
pub fn pair_dots<'a>(
    inputs: impl IntoIterator<Item = PairInput<'a>>,
    cfg: &DisplacementConfig,
) -> Vec<PairDot> {
    // (room for every input at once: a `filter_map` collect would grow the records by copies)
    let inputs = inputs.into_iter();
    let mut out = Vec::with_capacity(inputs.size_hint().0);
    out.extend(inputs.filter_map(|p| pair_dot(&p, cfg)));
    out
}
