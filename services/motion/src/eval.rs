//! Scoring motion blocks against annotated people (MOTChallenge ground truth), to
//! check and tune the motion stage on a recorded video such as PETS 2009 S2.L1
//! (`vtest.avi`).
//!
//! For each frame pair (video frame `n − 1 → n`):
//!
//! * a **moving person** is a box with `flag = 1` in frame `n` whose identity is also
//!   annotated in frame `n − 1` with its centre at least [`MIN_MOVE_PX`] away; it is
//!   **seen** when a block whose density reaches the threshold overlaps it;
//! * a moving person's **core blocks** are the blocks at least half inside its box;
//!   the fraction of them at or above the threshold says how much of the person the
//!   blocks cover (stricter than "seen");
//! * a block is **far** from people when, grown by [`FAR_PX`] on every side, it
//!   overlaps no box (any flag) of frame `n − 1` or `n`; it is **quiet** when its
//!   density is below the threshold.
//!
//! [`Score`] counts both, plus block-level figures that help tuning.

use std::collections::HashMap;

use isochron_wire::BlockMotion;

use crate::kernel::Geometry;

/// Least centre displacement between consecutive frames for a person to count as
/// moving, pixels.
pub const MIN_MOVE_PX: f64 = 1.0;

/// Margin around people inside which blocks are not required to be quiet, pixels:
/// box annotations are loose, people cast shadows, and a block's gradient reaches
/// one pixel beyond it.
pub const FAR_PX: f64 = 16.0;

/// One annotated box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PersonBox {
    /// Track identity.
    pub id: i64,
    /// Left edge, pixels.
    pub left: f64,
    /// Top edge, pixels.
    pub top: f64,
    /// Width, pixels.
    pub width: f64,
    /// Height, pixels.
    pub height: f64,
    /// MOT flag: 1 = consider, 0 = ignore.
    pub flag: i64,
}

impl PersonBox {
    fn centre(&self) -> (f64, f64) {
        (self.left + self.width / 2.0, self.top + self.height / 2.0)
    }

    /// Area of the box inside the pixel rectangle.
    fn overlap_area(&self, (x0, y0, w, h): (usize, usize, usize, usize)) -> f64 {
        let (x0, y0, x1, y1) = (x0 as f64, y0 as f64, (x0 + w) as f64, (y0 + h) as f64);
        let ox = (self.left + self.width).min(x1) - self.left.max(x0);
        let oy = (self.top + self.height).min(y1) - self.top.max(y0);
        ox.max(0.0) * oy.max(0.0)
    }

    /// True if the box, grown by `margin`, overlaps the pixel rectangle.
    fn overlaps(&self, (x0, y0, w, h): (usize, usize, usize, usize), margin: f64) -> bool {
        let (x0, y0, x1, y1) = (x0 as f64, y0 as f64, (x0 + w) as f64, (y0 + h) as f64);
        self.left - margin < x1
            && self.left + self.width + margin > x0
            && self.top - margin < y1
            && self.top + self.height + margin > y0
    }
}

/// A line of a MOTChallenge `gt.txt` that cannot be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MotError {
    /// A field is missing or not a number.
    #[error("line {line}: field {field} is not a number: {text}")]
    NotANumber {
        /// Line number, 1-based.
        line: usize,
        /// Field number, 1-based.
        field: usize,
        /// The line.
        text: String,
    },
    /// A frame number below 1.
    #[error("line {line}: frame numbers start at 1: {text}")]
    Frame {
        /// Line number, 1-based.
        line: usize,
        /// The line.
        text: String,
    },
}

/// Ground truth: the boxes of each video frame (0-based).
#[derive(Debug, Clone, Default)]
pub struct GroundTruth {
    frames: HashMap<u64, Vec<PersonBox>>,
}

impl GroundTruth {
    /// Parses MOTChallenge `gt.txt` (`frame,id,left,top,width,height,flag,...`, frames
    /// 1-based: video frame n is gt frame n + 1).
    pub fn parse_mot(text: &str) -> Result<Self, MotError> {
        let mut frames: HashMap<u64, Vec<PersonBox>> = HashMap::new();
        for (i, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() {
                continue;
            }
            let f: Vec<&str> = line.split(',').map(str::trim).collect();
            let num = |k: usize| -> Result<f64, MotError> {
                f.get(k)
                    .and_then(|v| v.parse::<f64>().ok())
                    .ok_or_else(|| MotError::NotANumber {
                        line: i + 1,
                        field: k + 1,
                        text: line.to_string(),
                    })
            };
            let gt_frame = num(0)?;
            if gt_frame < 1.0 {
                return Err(MotError::Frame {
                    line: i + 1,
                    text: line.to_string(),
                });
            }
            frames
                .entry(gt_frame as u64 - 1)
                .or_default()
                .push(PersonBox {
                    id: num(1)? as i64,
                    left: num(2)?,
                    top: num(3)?,
                    width: num(4)?,
                    height: num(5)?,
                    flag: num(6)? as i64,
                });
        }
        Ok(GroundTruth { frames })
    }

    /// Boxes of video frame `n` (0-based).
    pub fn boxes(&self, n: u64) -> &[PersonBox] {
        self.frames.get(&n).map(Vec::as_slice).unwrap_or(&[])
    }

    /// Number of annotated boxes.
    pub fn len(&self) -> usize {
        self.frames.values().map(Vec::len).sum()
    }

    /// True if there are no boxes.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Figures over many frame pairs.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Score {
    /// Frame pairs scored.
    pub pairs: u64,
    /// Moving people (flag 1).
    pub moving: u64,
    /// ... of which overlapped a block at or above the threshold.
    pub seen: u64,
    /// Core blocks of moving people.
    pub core_blocks: u64,
    /// ... of which were at or above the threshold.
    pub core_active: u64,
    /// Blocks far from every person.
    pub far_blocks: u64,
    /// ... of which were quiet.
    pub far_quiet: u64,
    /// Blocks at or above the threshold.
    pub active_blocks: u64,
    /// ... of which were near (within [`FAR_PX`] of) a person.
    pub active_near: u64,
}

impl Score {
    /// Fraction of moving people seen.
    pub fn seen_fraction(&self) -> f64 {
        self.seen as f64 / self.moving.max(1) as f64
    }

    /// Fraction of moving people's core blocks at or above the threshold.
    pub fn core_fraction(&self) -> f64 {
        self.core_active as f64 / self.core_blocks.max(1) as f64
    }

    /// Fraction of far blocks that were quiet.
    pub fn quiet_fraction(&self) -> f64 {
        self.far_quiet as f64 / self.far_blocks.max(1) as f64
    }

    /// Fraction of active blocks near a person.
    pub fn active_near_fraction(&self) -> f64 {
        self.active_near as f64 / self.active_blocks.max(1) as f64
    }

    /// Scores the blocks of the pair `n − 1 → n` (`n` = the current frame's source
    /// index) with density threshold `threshold`.
    pub fn add(
        &mut self,
        gt: &GroundTruth,
        n: u64,
        geom: &Geometry,
        blocks: &[BlockMotion],
        threshold: f32,
    ) {
        if n == 0 {
            return;
        }
        self.pairs += 1;
        let (prev, cur) = (gt.boxes(n - 1), gt.boxes(n));
        let active = |b: usize| blocks.get(b).is_some_and(|m| m.density >= threshold);
        for person in cur.iter().filter(|p| p.flag == 1) {
            let Some(before) = prev.iter().find(|p| p.id == person.id) else {
                continue;
            };
            let ((x0, y0), (x1, y1)) = (before.centre(), person.centre());
            if (x1 - x0).hypot(y1 - y0) < MIN_MOVE_PX {
                continue;
            }
            self.moving += 1;
            let mut seen = false;
            for b in 0..geom.blocks() {
                let rect = geom.block_rect(b);
                if !person.overlaps(rect, 0.0) {
                    continue;
                }
                seen |= active(b);
                if 2.0 * person.overlap_area(rect) >= (rect.2 * rect.3) as f64 {
                    self.core_blocks += 1;
                    self.core_active += active(b) as u64;
                }
            }
            self.seen += seen as u64;
        }
        for b in 0..geom.blocks() {
            let rect = geom.block_rect(b);
            let near = prev.iter().chain(cur).any(|p| p.overlaps(rect, FAR_PX));
            if active(b) {
                self.active_blocks += 1;
                self.active_near += near as u64;
            }
            if !near {
                self.far_blocks += 1;
                self.far_quiet += !active(b) as u64;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GT: &str = "1,9,10,10,20,40,1,0,0,0\n2,9,13,10,20,40,1,0,0,0\n2,4,100,5,10,10,0,0,0,0\n";

    fn moving_block() -> BlockMotion {
        BlockMotion {
            density: 0.5,
            ..Default::default()
        }
    }

    #[test]
    fn parses_mot_with_one_based_frames() {
        let gt = GroundTruth::parse_mot(GT).unwrap();
        assert_eq!(gt.len(), 3);
        assert_eq!(gt.boxes(0).len(), 1);
        assert_eq!(gt.boxes(1).len(), 2);
        assert!(gt.boxes(2).is_empty());
        assert!(GroundTruth::parse_mot("0,1,1,1,1,1,1").is_err());
        assert!(GroundTruth::parse_mot("1,x,1,1,1,1,1").is_err());
        assert_eq!(
            GroundTruth::parse_mot("1,x,1,1,1,1,1")
                .unwrap_err()
                .to_string(),
            "line 1: field 2 is not a number: 1,x,1,1,1,1,1"
        );
        assert_eq!(
            GroundTruth::parse_mot("0,1,1,1,1,1,1")
                .unwrap_err()
                .to_string(),
            "line 1: frame numbers start at 1: 0,1,1,1,1,1,1"
        );
    }

    #[test]
    fn scores_seen_people_and_quiet_far_blocks() {
        let gt = GroundTruth::parse_mot(GT).unwrap();
        let g = Geometry::new(128, 64, 16).unwrap(); // 8×4 blocks
        let mut blocks = vec![BlockMotion::default(); g.blocks()];
        let mut s = Score::default();
        s.add(&gt, 1, &g, &blocks, 0.02);
        assert_eq!((s.moving, s.seen), (1, 0));
        let far_total = s.far_blocks;
        assert_eq!(s.far_quiet, far_total);
        // A moving block on the person (block (1, 1): x 16..32, y 16..32), one far.
        blocks[g.grid_w + 1] = moving_block();
        blocks[3 * g.grid_w + 7] = moving_block();
        let mut s = Score::default();
        s.add(&gt, 1, &g, &blocks, 0.02);
        assert_eq!((s.moving, s.seen), (1, 1));
        // Person 13..33 × 10..50: blocks at least half inside are (1, 1) and (1, 2).
        assert_eq!((s.core_blocks, s.core_active), (2, 1));
        assert_eq!(s.far_quiet, s.far_blocks - 1);
        assert_eq!((s.active_blocks, s.active_near), (2, 1));
        assert_eq!(s.seen_fraction(), 1.0);
        // Frame 0 has no pair.
        let mut s = Score::default();
        s.add(&gt, 0, &g, &blocks, 0.02);
        assert_eq!(s.pairs, 0);
    }
}
