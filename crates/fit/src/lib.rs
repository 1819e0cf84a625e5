//! Fit every dot: elliptical least-squares Gaussian engine and cheaper estimators
