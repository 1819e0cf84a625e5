//! Synthetic dot-target images with exact ground truth
