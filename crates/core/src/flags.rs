/// Defines a `u32` bit-flag type whose flags have snake-case names, serialised as `a|b|c`
/// (empty string for none): constants, `NONE`, `bits`/`from_bits`, `contains`, `intersects`,
/// `is_empty`, `insert`, `remove`, `parse`, `names`, `|`, `Display` and serde. Used for
/// [`DotFlags`] and for other crates' flag sets (e.g. `bostrack_theory::TheoryFlags`).
#[macro_export]
macro_rules! bit_flags {
    ($(#[$meta:meta])* $vis:vis struct $T:ident { $($(#[$doc:meta])* $name:ident = $bit:expr, $text:literal;)* }) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
        $vis struct $T(u32);

        impl $T {
            $($(#[$doc])* pub const $name: $T = $T(1 << $bit);)*
            const NAMES: &'static [($T, &'static str)] = &[$(($T::$name, $text)),*];
            pub const NONE: $T = $T(0);
            pub const fn bits(self) -> u32 {
                self.0
            }
            pub const fn from_bits(bits: u32) -> Self {
                $T(bits)
            }
            pub const fn contains(self, other: $T) -> bool {
                self.0 & other.0 == other.0
            }
            pub const fn intersects(self, other: $T) -> bool {
                self.0 & other.0 != 0
            }
            pub const fn is_empty(self) -> bool {
                self.0 == 0
            }
            pub fn insert(&mut self, other: $T) {
                self.0 |= other.0;
            }
            pub fn remove(&mut self, other: $T) {
                self.0 &= !other.0;
            }
            /// Parse `a|b|c` (as written by `Display`).
            pub fn parse(s: &str) -> ::std::result::Result<Self, String> {
                let mut out = $T::NONE;
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
                Self::NAMES.iter().filter(move |(f, _)| self.contains(*f)).map(|(_, n)| *n)
            }
        }

        impl ::std::ops::BitOr for $T {
            type Output = $T;
            fn bitor(self, rhs: $T) -> $T {
                $T(self.0 | rhs.0)
            }
        }

        impl ::std::ops::BitOrAssign for $T {
            fn bitor_assign(&mut self, rhs: $T) {
                self.0 |= rhs.0;
            }
        }

        impl ::std::fmt::Display for $T {
            fn fmt(&self, f: &mut ::std::fmt::Formatter<'_>) -> ::std::fmt::Result {
                let names: Vec<_> = self.names().collect();
                f.write_str(&names.join("|"))
            }
        }

        impl $crate::__serde::Serialize for $T {
            fn serialize<S: $crate::__serde::Serializer>(&self, s: S) -> ::std::result::Result<S::Ok, S::Error> {
                s.collect_str(self)
            }
        }

        impl<'de> $crate::__serde::Deserialize<'de> for $T {
            fn deserialize<D: $crate::__serde::Deserializer<'de>>(d: D) -> ::std::result::Result<Self, D::Error> {
                let s = <String as $crate::__serde::Deserialize>::deserialize(d)?;
                $T::parse(&s).map_err(<D::Error as $crate::__serde::de::Error>::custom)
            }
        }
    };
}

bit_flags! {
    /// Per-dot problems as bit flags (after SEP): data, not errors. Serialised as `a|b|c`
    /// (empty string for none).
    pub struct DotFlags {
    /// The fit window touches the image border.
    BORDER = 0, "border";
    /// The fit window is cut by the mask.
    MASKED = 1, "masked";
    /// The dot is much fainter than its neighbours.
    FAINT = 2, "faint";
    /// No dot at this lattice site: the detector found none, and neither did the fit of the site
    /// (shape held at the image's median dot: no amplitude of 3.5 standard deviations at the
    /// predicted site, nor of 4.5 with the position free in the window).
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
    /// A lattice neighbour of the dot lies inside the image but outside the region of interest
    /// (the mask): light from there, if any, is in no neighbour model and may bias the fit.
    ROI_EDGE = 13, "roi_edge";
    /// The fit did not converge jointly with its neighbours: the neighbour passes stopped at
    /// `[fit] neighbour_passes` while the dot, or the pull of its neighbours, still moved by more
    /// than 5 × `[fit] neighbour_tolerance` standard deviations in the last pass.
    UNCONVERGED = 14, "unconverged";
    /// The window's weighted residual is inconsistent with the noise model: its χ² exceeds the
    /// quantile of the χ² distribution at the false-alarm rate `[fit] residual_false_alarm`
    /// (an unmodelled neighbour, a defect, a speck: the bound does not describe this fit).
    RESIDUAL = 15, "residual";
    /// The dot's fitted centre (in the reference or the gradient image) lies outside the region
    /// of interest: its pixel, the one the centre rounds to, is not kept by the mask.
    OUTSIDE_MASK = 16, "outside_mask";
    /// The shape (σx, σy, ρ) could not be resolved in this window (an undersampled or very
    /// faint dot: the full fit was singular, left its window or was not finite); position, amplitude and background were fitted
    /// with the shape held at the image's median dot, and `crlb_x`, `crlb_y` are the bound for
    /// that known shape. The position is a measurement; `sigma_x`, `sigma_y`, `rho` are not.
    SHAPE_FIXED = 17, "shape_fixed";
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
