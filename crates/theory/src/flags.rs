bostrack_core::bit_flags! {
    /// Conditions under which a [`crate::Prediction`] is computed but the model's assumptions are
    /// strained, as bit flags serialised `a|b|c` (empty string for none), like
    /// `bostrack_core::DotFlags`.
    pub struct TheoryFlags {
    /// The bracket of Eq. 24 (geometric cone angle minus the mean-deflection term) went
    /// negative and was clamped to zero (NOTES.md §4): the predicted blur is then zero, which
    /// the ray tracer shows to be wrong (the blur does not depend on first derivatives).
    CONE_CLAMPED = 0, "cone_clamped";
    /// The gradient term of Eq. 24 changed the cone angle by more than 25 %: the prediction
    /// depends strongly on that heuristic term.
    CONE_CORRECTED = 1, "cone_corrected";
    /// The geometric cone angle exceeds 0.035 rad (2°), beyond the small-angle assumption of
    /// Sec. 2.1.3.
    WIDE_CONE = 2, "wide_cone";
    /// The blur standard deviation exceeds the reference dot's along some axis: the dot is
    /// then closer to the aperture's shape than to a Gaussian (see docs/theory.md, ray tracing
    /// table) and the Gaussian bound is optimistic.
    NON_GAUSSIAN = 3, "non_gaussian";
    /// A predicted sigma is below 0.8 px: the closed form (Eq. 35) under-states the exact
    /// bound (NOTES.md §3).
    UNDERSAMPLED = 4, "undersampled";
    /// The displacement field's gradient exceeds 0.1 px/px: the printed dot's image is
    /// stretched by the flow's lens effect, which the effective model leaves out.
    LENSING = 5, "lensing";
    /// The Fisher matrix of the exact bound was singular: the exact bounds are NaN.
    BOUND_SINGULAR = 6, "bound_singular";
    /// The automatic window of the exact bound (±4σ) was capped at ±[`crate::MAX_HALF_WIDTH`]
    /// px: the exact bound is then that of a truncated dot.
    WINDOW_CAPPED = 7, "window_capped";
}
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip() {
        let f = TheoryFlags::CONE_CLAMPED | TheoryFlags::UNDERSAMPLED;
        assert_eq!(f.to_string(), "cone_clamped|undersampled");
        assert_eq!(TheoryFlags::parse("cone_clamped|undersampled").unwrap(), f);
        assert_eq!(TheoryFlags::NONE.to_string(), "");
        assert!(TheoryFlags::parse("bogus").is_err());
    }
}
