//! The dot image model: elliptical Gaussian pixel model (point-sampled and pixel-integrated), its derivatives, and the exact Cramér-Rao bound
