//! The minutes a store has completed, as merged spans. A minute inside a span was
//! delivered before (a replay of the same recording, a restarted producer) and
//! teaches nothing again; a minute outside every span is new, whatever its time
//! says about the others — a clock that ran ahead and was corrected, or an older
//! recording, keeps learning.

/// Completed minutes (minutes since the Unix epoch) as sorted, disjoint, inclusive
/// spans, adjacent ones merged.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Spans {
    spans: Vec<(i64, i64)>,
}

impl Spans {
    /// Spans from rows in any order (overlapping or adjacent ones are merged).
    pub fn from_rows(rows: impl IntoIterator<Item = (i64, i64)>) -> Spans {
        let mut rows: Vec<(i64, i64)> = rows.into_iter().filter(|(a, b)| a <= b).collect();
        rows.sort_unstable();
        let mut spans: Vec<(i64, i64)> = Vec::with_capacity(rows.len());
        for (a, b) in rows {
            match spans.last_mut() {
                Some(last) if a <= last.1.saturating_add(1) => last.1 = last.1.max(b),
                _ => spans.push((a, b)),
            }
        }
        Spans { spans }
    }

    /// Whether `minute` was completed before.
    pub fn contains(&self, minute: i64) -> bool {
        self.holding(minute).is_some()
    }

    /// The index of the span holding `minute`.
    fn holding(&self, minute: i64) -> Option<usize> {
        let i = self.spans.partition_point(|&(a, _)| a <= minute);
        (i > 0 && self.spans[i - 1].1 >= minute).then(|| i - 1)
    }

    /// The span that would hold `minute` once added (every span it would replace
    /// lies inside it), without adding it.
    pub fn merged(&self, minute: i64) -> (i64, i64) {
        if let Some(i) = self.holding(minute) {
            return self.spans[i];
        }
        let i = self.spans.partition_point(|&(a, _)| a <= minute);
        let start = match i.checked_sub(1).map(|j| self.spans[j]) {
            Some((a, b)) if b.saturating_add(1) == minute => a,
            _ => minute,
        };
        let end = match self.spans.get(i) {
            Some(&(a, b)) if a == minute.saturating_add(1) => b,
            _ => minute,
        };
        (start, end)
    }

    /// Adds `minute`; returns the span that now holds it (every span it replaced lies
    /// inside it).
    pub fn add(&mut self, minute: i64) -> (i64, i64) {
        if let Some(i) = self.holding(minute) {
            return self.spans[i];
        }
        let i = self.spans.partition_point(|&(a, _)| a <= minute);
        let joins_before = i > 0 && self.spans[i - 1].1.saturating_add(1) == minute;
        let joins_after = i < self.spans.len() && self.spans[i].0 == minute.saturating_add(1);
        match (joins_before, joins_after) {
            (true, true) => {
                self.spans[i - 1].1 = self.spans[i].1;
                self.spans.remove(i);
                self.spans[i - 1]
            }
            (true, false) => {
                self.spans[i - 1].1 = minute;
                self.spans[i - 1]
            }
            (false, true) => {
                self.spans[i].0 = minute;
                self.spans[i]
            }
            (false, false) => {
                self.spans.insert(i, (minute, minute));
                self.spans[i]
            }
        }
    }

    /// The latest completed minute.
    pub fn latest(&self) -> Option<i64> {
        self.spans.last().map(|&(_, b)| b)
    }

    /// The spans, earliest first.
    pub fn iter(&self) -> impl Iterator<Item = (i64, i64)> + '_ {
        self.spans.iter().copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn minutes_merge_into_spans_and_repeats_are_found() {
        let mut s = Spans::default();
        assert_eq!(s.merged(10), (10, 10));
        assert_eq!(s.add(10), (10, 10));
        assert_eq!(s.add(11), (10, 11));
        assert_eq!(s.add(13), (13, 13));
        assert_eq!(s.merged(12), (10, 13));
        assert_eq!(s.add(12), (10, 13));
        assert_eq!(s.iter().count(), 1);
        assert!(s.contains(12) && !s.contains(14) && !s.contains(9));
        // A clock that jumped ahead, then back: the earlier minutes are still new.
        s.add(1_000_000);
        assert!(!s.contains(14));
        assert_eq!(s.add(9), (9, 13));
        assert_eq!(s.latest(), Some(1_000_000));
    }

    #[test]
    fn rows_are_merged() {
        let s = Spans::from_rows([(5, 7), (1, 3), (4, 4), (9, 8)]);
        assert_eq!(s.iter().collect::<Vec<_>>(), vec![(1, 7)]);
    }
}
