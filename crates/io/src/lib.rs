//! Image I/O for real camera files.

mod sample;

pub use sample::bos_sample_dir;
