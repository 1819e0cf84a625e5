//! "Did you mean" suggestions for misspelt keys.

/// Levenshtein distance (insertions, deletions, substitutions, each cost 1) between two strings,
/// counted in characters.
pub fn edit_distance(a: &str, b: &str) -> usize {
    let a: Vec<char> = a.chars().collect();
    let b: Vec<char> = b.chars().collect();
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    let mut cur = vec![0usize; b.len() + 1];
    for i in 1..=a.len() {
        cur[0] = i;
        for j in 1..=b.len() {
            let sub = prev[j - 1] + usize::from(a[i - 1] != b[j - 1]);
            cur[j] = sub.min(prev[j] + 1).min(cur[j - 1] + 1);
        }
        std::mem::swap(&mut prev, &mut cur);
    }
    prev[b.len()]
}

/// The candidate closest to `word` if it is close enough to be a likely misspelling: an edit
/// distance of at most a third of the word's length (at least 1, at most 3), or one of the two is
/// a prefix of the other (case-insensitively). Ties go to the first candidate.
pub fn did_you_mean<'a>(word: &str, candidates: &[&'a str]) -> Option<&'a str> {
    let lower = word.to_lowercase();
    let limit = (word.chars().count() / 3).clamp(1, 3);
    let mut best: Option<(usize, &'a str)> = None;
    for &c in candidates {
        let cl = c.to_lowercase();
        let d = edit_distance(&lower, &cl);
        let prefix = lower.len() >= 3 && (cl.starts_with(&lower) || lower.starts_with(&cl));
        if (d <= limit || prefix) && best.is_none_or(|(bd, _)| d < bd) {
            best = Some((d, c));
        }
    }
    best.map(|(_, c)| c)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distances() {
        assert_eq!(edit_distance("", ""), 0);
        assert_eq!(edit_distance("kitten", "sitting"), 3);
        assert_eq!(edit_distance("serach_radius", "search_radius"), 2);
        assert_eq!(edit_distance("abc", ""), 3);
    }

    #[test]
    fn suggestions() {
        let keys = ["search_radius", "median_epsilon", "median_threshold"];
        assert_eq!(did_you_mean("serach_radius", &keys), Some("search_radius"));
        assert_eq!(
            did_you_mean("median_treshold", &keys),
            Some("median_threshold")
        );
        assert_eq!(did_you_mean("Search_Radius", &keys), Some("search_radius"));
        assert_eq!(did_you_mean("search", &keys), Some("search_radius"));
        assert_eq!(did_you_mean("colour", &keys), None);
        assert_eq!(
            did_you_mean("mach", &["input", "match", "fit"]),
            Some("match")
        );
    }
}
