use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::fmt;

/// Conditions under which a [`crate::Prediction`] is computed but the model's assumptions are
/// strained, as bit flags serialised `a|b|c` (empty string for none), like
/// `bostrack_core::DotFlags`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct TheoryFlags(u32);

macro_rules! flags {
    ($($(#[$doc:meta])* $name:ident = $bit:expr, $text:literal;)*) => {
        impl TheoryFlags {
            $($(#[$doc])* pub const $name: TheoryFlags = TheoryFlags(1 << $bit);)*
            const NAMES: &'static [(TheoryFlags, &'static str)] = &[$((TheoryFlags::$name, $text)),*];
        }
    };
}

flags! {
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

impl TheoryFlags {
    pub const NONE: TheoryFlags = TheoryFlags(0);
    pub const fn bits(self) -> u32 {
        self.0
    }
    pub const fn contains(self, other: TheoryFlags) -> bool {
        self.0 & other.0 == other.0
    }
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }
    pub fn insert(&mut self, other: TheoryFlags) {
        self.0 |= other.0;
    }
    /// Parse `a|b|c` (as written by `Display`).
    pub fn parse(s: &str) -> Result<Self, String> {
        let mut out = TheoryFlags::NONE;
        for part in s.split('|').map(str::trim).filter(|p| !p.is_empty()) {
            let (f, _) = Self::NAMES
                .iter()
                .find(|(_, n)| *n == part)
                .ok_or_else(|| format!("unknown flag `{part}`"))?;
            out.insert(*f);
        }
        Ok(out)
    }
    /// Names of the flags that are set.
    pub fn names(self) -> impl Iterator<Item = &'static str> {
        Self::NAMES
            .iter()
            .filter(move |(f, _)| self.contains(*f))
            .map(|(_, n)| *n)
    }
}

impl std::ops::BitOr for TheoryFlags {
    type Output = TheoryFlags;
    fn bitor(self, rhs: TheoryFlags) -> TheoryFlags {
        TheoryFlags(self.0 | rhs.0)
    }
}

impl fmt::Display for TheoryFlags {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let names: Vec<_> = self.names().collect();
        f.write_str(&names.join("|"))
    }
}

impl Serialize for TheoryFlags {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for TheoryFlags {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        TheoryFlags::parse(&s).map_err(serde::de::Error::custom)
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
