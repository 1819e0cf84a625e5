//! `--shard K/N`: a deterministic 1/N of the frames of a campaign.

use std::fmt;
use std::str::FromStr;

/// One of `count` disjoint parts of a campaign, numbered from 1.
///
/// Frames are numbered from 1 in natural order of their file names (the order of
/// [`Plan::gradients`](crate::Plan::gradients)); frame `n` belongs to shard
/// `((n - 1) mod count) + 1`. Shard `K/N` therefore takes frames `K, K + N, K + 2N, ...`: every
/// frame is in exactly one shard, and the shards of a campaign differ in size by at most one
/// frame.
///
/// ```
/// use bostrack_pipeline::Shard;
/// let s: Shard = "2/3".parse().unwrap();
/// let frames: Vec<usize> = (1..=10).filter(|&n| s.contains(n)).collect();
/// assert_eq!(frames, [2, 5, 8]);
/// assert!("0/3".parse::<Shard>().is_err()); // shards are numbered from 1
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Shard {
    index: usize,
    count: usize,
}

/// Why a shard specification was rejected.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("invalid shard `{text}`: {message}")]
pub struct ShardError {
    /// The text as given.
    pub text: String,
    /// What is wrong with it.
    pub message: String,
}

impl Shard {
    /// Shard `index` of `count` (1 ≤ index ≤ count).
    pub fn new(index: usize, count: usize) -> Result<Shard, ShardError> {
        if count == 0 || index == 0 || index > count {
            return Err(ShardError {
                text: format!("{index}/{count}"),
                message: "K/N needs 1 <= K <= N (shards are numbered from 1)".into(),
            });
        }
        Ok(Shard { index, count })
    }

    /// K, from 1.
    pub fn index(self) -> usize {
        self.index
    }

    /// N.
    pub fn count(self) -> usize {
        self.count
    }

    /// Whether frame number `frame` (from 1, natural order) belongs to this shard.
    pub fn contains(self, frame: usize) -> bool {
        frame >= 1 && (frame - 1) % self.count == self.index - 1
    }

    /// `shard-K-of-N`: the name of this shard's records under `DIR/shards/`.
    pub fn label(self) -> String {
        format!("shard-{}-of-{}", self.index, self.count)
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl FromStr for Shard {
    type Err = ShardError;

    /// `K/N`, e.g. `3/8`.
    fn from_str(s: &str) -> Result<Shard, ShardError> {
        let err = |message: &str| ShardError {
            text: s.to_string(),
            message: message.to_string(),
        };
        let (k, n) = s
            .split_once('/')
            .ok_or_else(|| err("expected K/N, e.g. 1/4"))?;
        let k: usize = k
            .trim()
            .parse()
            .map_err(|_| err("K is not a whole number"))?;
        let n: usize = n
            .trim()
            .parse()
            .map_err(|_| err("N is not a whole number"))?;
        Shard::new(k, n).map_err(|e| err(&e.message))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_rejects() {
        assert_eq!("3/8".parse::<Shard>().unwrap(), Shard::new(3, 8).unwrap());
        assert_eq!(" 1 / 1 ".parse::<Shard>().unwrap().to_string(), "1/1");
        for bad in ["0/4", "5/4", "1/0", "x/4", "1/y", "14", "", "-1/4"] {
            let e = bad.parse::<Shard>().unwrap_err();
            assert!(e.to_string().contains(&format!("`{bad}`")), "{e}");
        }
    }

    #[test]
    fn shards_partition_the_frames() {
        for n in 1..=7 {
            let shards: Vec<Shard> = (1..=n).map(|k| Shard::new(k, n).unwrap()).collect();
            let mut sizes = vec![0usize; n];
            for frame in 1..=50 {
                let owners: Vec<usize> = shards
                    .iter()
                    .filter(|s| s.contains(frame))
                    .map(|s| s.index())
                    .collect();
                assert_eq!(owners.len(), 1, "frame {frame} of {n} shards: {owners:?}");
                assert_eq!(owners[0], (frame - 1) % n + 1);
                sizes[owners[0] - 1] += 1;
            }
            let (lo, hi) = (sizes.iter().min().unwrap(), sizes.iter().max().unwrap());
            assert!(hi - lo <= 1, "{sizes:?}");
        }
        assert!(!Shard::new(1, 2).unwrap().contains(0));
        assert_eq!(Shard::new(2, 5).unwrap().label(), "shard-2-of-5");
    }
}
