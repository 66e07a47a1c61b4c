//! What to publish each tick: the full grid, the rectangle that changed, or nothing.
//!
//! * The full grid when nothing was published yet, when the grid's geometry changed,
//!   when the changed rectangle covers more than half the grid, or when deltas went
//!   out and the last full grid is `full_every` old — so the transient-local grid a
//!   late joiner receives is never older than that;
//! * otherwise the bounding rectangle of the changed cells, as an
//!   `OccupancyGridUpdate` (what Nav2's StaticLayer applies with
//!   `subscribe_to_updates: true`);
//! * nothing when no cell changed.

use std::time::{Duration, Instant};

/// One tick's output.
#[derive(Debug, Clone, PartialEq)]
pub enum Output {
    /// Publish the whole grid.
    Full,
    /// Publish the rectangle `x, y, width, height` (cells) with its values.
    Update {
        /// First column.
        x: u32,
        /// First row.
        y: u32,
        /// Columns.
        width: u32,
        /// Rows.
        height: u32,
        /// Values, row-major.
        data: Vec<i8>,
    },
    /// Nothing changed.
    Nothing,
}

/// Remembers what subscribers have, to decide the next [`Output`].
#[derive(Debug, Clone)]
pub struct DeltaTracker {
    full_every: Duration,
    /// Geometry key and cells of the last full grid, and when it went out.
    last_full: Option<(u64, Instant)>,
    /// What subscribers hold now (the last full grid plus the updates since).
    sent: Vec<i8>,
    geometry: u64,
    updates_since_full: usize,
}

impl DeltaTracker {
    /// A tracker that republishes the full grid at least every `full_every` while
    /// deltas go out.
    pub fn new(full_every: Duration) -> DeltaTracker {
        DeltaTracker {
            full_every,
            last_full: None,
            sent: Vec::new(),
            geometry: 0,
            updates_since_full: 0,
        }
    }

    /// Decides what to publish for `cells` of a `width`-wide grid whose geometry
    /// (size, resolution, origin) hashes to `geometry`, and records it as sent.
    pub fn next(&mut self, cells: &[i8], width: u32, geometry: u64, now: Instant) -> Output {
        let full = |me: &mut DeltaTracker| {
            me.last_full = Some((geometry, now));
            me.sent = cells.to_vec();
            me.geometry = geometry;
            me.updates_since_full = 0;
            Output::Full
        };
        let Some((_, last_full_at)) = self.last_full else {
            return full(self);
        };
        if geometry != self.geometry || self.sent.len() != cells.len() || width == 0 {
            return full(self);
        }
        let changed = changed_rect(&self.sent, cells, width);
        let Some((x0, y0, x1, y1)) = changed else {
            if self.updates_since_full > 0 && now.duration_since(last_full_at) >= self.full_every {
                return full(self);
            }
            return Output::Nothing;
        };
        let (w, h) = (x1 - x0 + 1, y1 - y0 + 1);
        let total = cells.len() as u64;
        if (w as u64 * h as u64) * 2 > total
            || (self.updates_since_full > 0 && now.duration_since(last_full_at) >= self.full_every)
        {
            return full(self);
        }
        let mut data = Vec::with_capacity(w as usize * h as usize);
        for y in y0..=y1 {
            let row = (y * width) as usize;
            data.extend_from_slice(&cells[row + x0 as usize..=row + x1 as usize]);
        }
        for y in y0..=y1 {
            let row = (y * width) as usize;
            self.sent[row + x0 as usize..=row + x1 as usize]
                .copy_from_slice(&cells[row + x0 as usize..=row + x1 as usize]);
        }
        self.updates_since_full += 1;
        Output::Update {
            x: x0,
            y: y0,
            width: w,
            height: h,
            data,
        }
    }

    /// Forgets what was sent: the next tick publishes the full grid.
    pub fn reset(&mut self) {
        self.last_full = None;
    }
}

/// The inclusive bounding rectangle `(x0, y0, x1, y1)` of the cells that differ.
fn changed_rect(old: &[i8], new: &[i8], width: u32) -> Option<(u32, u32, u32, u32)> {
    let mut rect: Option<(u32, u32, u32, u32)> = None;
    for (k, (a, b)) in old.iter().zip(new).enumerate() {
        if a != b {
            let (x, y) = ((k as u32) % width, (k as u32) / width);
            rect = Some(match rect {
                None => (x, y, x, y),
                Some((x0, y0, x1, y1)) => (x0.min(x), y0.min(y), x1.max(x), y1.max(y)),
            });
        }
    }
    rect
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn full_then_deltas_then_full_again() {
        let t0 = Instant::now();
        let mut d = DeltaTracker::new(Duration::from_secs(10));
        let mut cells = vec![0i8; 100]; // 10x10
        assert_eq!(d.next(&cells, 10, 1, t0), Output::Full);
        assert_eq!(
            d.next(&cells, 10, 1, t0 + Duration::from_secs(1)),
            Output::Nothing
        );
        cells[3 * 10 + 4] = 50;
        cells[5 * 10 + 6] = 60;
        match d.next(&cells, 10, 1, t0 + Duration::from_secs(2)) {
            Output::Update {
                x,
                y,
                width,
                height,
                data,
            } => {
                assert_eq!((x, y, width, height), (4, 3, 3, 3));
                assert_eq!(data, vec![50, 0, 0, 0, 0, 0, 0, 0, 60]);
            }
            other => panic!("{other:?}"),
        }
        // Unchanged since: nothing until the full grid is due, then the full grid.
        assert_eq!(
            d.next(&cells, 10, 1, t0 + Duration::from_secs(5)),
            Output::Nothing
        );
        assert_eq!(
            d.next(&cells, 10, 1, t0 + Duration::from_secs(10)),
            Output::Full
        );
        // No deltas since that full grid: nothing is due, however long it waits.
        assert_eq!(
            d.next(&cells, 10, 1, t0 + Duration::from_secs(60)),
            Output::Nothing
        );
    }

    #[test]
    fn big_changes_and_new_geometry_send_the_full_grid() {
        let t0 = Instant::now();
        let mut d = DeltaTracker::new(Duration::from_secs(10));
        let cells = vec![0i8; 100];
        assert_eq!(d.next(&cells, 10, 1, t0), Output::Full);
        let mut big = cells.clone();
        big[0] = 1;
        big[99] = 1;
        assert_eq!(d.next(&big, 10, 1, t0), Output::Full);
        assert_eq!(d.next(&big, 10, 2, t0), Output::Full);
        d.reset();
        assert_eq!(d.next(&big, 10, 2, t0), Output::Full);
    }
}
