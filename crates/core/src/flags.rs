use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::fmt;

/// Per-dot problems as bit flags (after SEP): data, not errors. Serialised as `a|b|c`
/// (empty string for none).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct DotFlags(u32);

macro_rules! flags {
    ($($(#[$doc:meta])* $name:ident = $bit:expr, $text:literal;)*) => {
        impl DotFlags {
            $($(#[$doc])* pub const $name: DotFlags = DotFlags(1 << $bit);)*
            const NAMES: &'static [(DotFlags, &'static str)] = &[$((DotFlags::$name, $text)),*];
        }
    };
}

flags! {
    /// The fit window touches the image border.
    BORDER = 0, "border";
    /// The fit window is cut by the mask.
    MASKED = 1, "masked";
    /// The dot is much fainter than its neighbours.
    FAINT = 2, "faint";
    /// No dot was found at this lattice site.
    MISSING = 3, "missing";
    /// Shape or intensity far from the neighbours' (target defect).
    DEFECT = 4, "defect";
    /// Two dots merged into one blob.
    MERGED = 5, "merged";
    /// Saturated pixels were left out of the fit.
    SATURATED = 6, "saturated";
    /// Non-finite pixels were left out of the fit.
    NAN_PIXELS = 7, "nan_pixels";
    /// The fit did not converge (see the status column).
    FIT_FAILED = 8, "fit_failed";
    /// No partner in the other image.
    UNMATCHED = 9, "unmatched";
    /// The kd-tree match and the grid index disagree.
    GRID_MISMATCH = 10, "grid_mismatch";
    /// Rejected by the displacement validation (threshold or normalised median test).
    OUTLIER = 11, "outlier";
    /// Fitted shape at a parameter bound (sigma or rho at its limit).
    AT_BOUND = 12, "at_bound";
}

impl DotFlags {
    pub const NONE: DotFlags = DotFlags(0);
    pub const fn bits(self) -> u32 {
        self.0
    }
    pub const fn from_bits(bits: u32) -> Self {
        DotFlags(bits)
    }
    pub const fn contains(self, other: DotFlags) -> bool {
        self.0 & other.0 == other.0
    }
    pub const fn intersects(self, other: DotFlags) -> bool {
        self.0 & other.0 != 0
    }
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }
    pub fn insert(&mut self, other: DotFlags) {
        self.0 |= other.0;
    }
    pub fn remove(&mut self, other: DotFlags) {
        self.0 &= !other.0;
    }
    /// Parse `a|b|c` (as written by `Display`).
    pub fn parse(s: &str) -> Result<Self, String> {
        let mut out = DotFlags::NONE;
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

impl std::ops::BitOr for DotFlags {
    type Output = DotFlags;
    fn bitor(self, rhs: DotFlags) -> DotFlags {
        DotFlags(self.0 | rhs.0)
    }
}

impl std::ops::BitOrAssign for DotFlags {
    fn bitor_assign(&mut self, rhs: DotFlags) {
        self.0 |= rhs.0;
    }
}

impl fmt::Display for DotFlags {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let names: Vec<_> = self.names().collect();
        f.write_str(&names.join("|"))
    }
}

impl Serialize for DotFlags {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for DotFlags {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        DotFlags::parse(&s).map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip() {
        let f = DotFlags::BORDER | DotFlags::SATURATED;
        assert_eq!(f.to_string(), "border|saturated");
        assert_eq!(DotFlags::parse("border|saturated").unwrap(), f);
        assert_eq!(DotFlags::NONE.to_string(), "");
        assert!(DotFlags::parse("bogus").is_err());
    }
}
