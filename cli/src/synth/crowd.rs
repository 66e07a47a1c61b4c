//! The synthetic crowd: people crossing the block grid along straight lines, some
//! pausing, arriving per minute as the activity profile says — as the motion they
//! make.

use std::path::Path;

use anyhow::{Context, bail};
use isochron_wire::{BlockMotion, DIRECTION_NONE};

/// The profile: activity (0..1) per minute of the day, linear between rows.
#[derive(Debug, Clone, PartialEq)]
pub struct Profile {
    rows: Vec<(f64, f64)>,
}

impl Profile {
    /// Reads `minute_of_day,activity` rows (a header line is allowed).
    pub fn load(path: &Path) -> anyhow::Result<Profile> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("--profile: cannot read {}", path.display()))?;
        Profile::parse(&text).with_context(|| format!("--profile {}", path.display()))
    }

    /// Parses CSV text.
    pub fn parse(text: &str) -> anyhow::Result<Profile> {
        let mut rows = Vec::new();
        for (i, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let mut fields = line.split(',').map(str::trim);
            let (Some(a), Some(b)) = (fields.next(), fields.next()) else {
                bail!(
                    "line {}: expected `minute_of_day,activity`, found '{line}'",
                    i + 1
                );
            };
            let (Ok(minute), Ok(activity)) = (a.parse::<f64>(), b.parse::<f64>()) else {
                if rows.is_empty() && a.parse::<f64>().is_err() {
                    continue; // the header
                }
                bail!("line {}: expected two numbers, found '{line}'", i + 1);
            };
            if !(0.0..1440.0).contains(&minute) {
                bail!("line {}: minute_of_day {minute} is outside 0..1440", i + 1);
            }
            if !(0.0..=1.0).contains(&activity) {
                bail!("line {}: activity {activity} is outside 0..1", i + 1);
            }
            rows.push((minute, activity));
        }
        if rows.is_empty() {
            bail!("no `minute_of_day,activity` rows");
        }
        rows.sort_by(|a, b| a.0.total_cmp(&b.0));
        rows.dedup_by(|a, b| a.0 == b.0);
        Ok(Profile { rows })
    }

    /// Activity at `minute` of the day (fractional), interpolated linearly between the
    /// rows, across midnight too.
    pub fn at(&self, minute: f64) -> f64 {
        let rows = &self.rows;
        let m = minute.rem_euclid(1440.0);
        let after = rows.partition_point(|r| r.0 <= m);
        let (a, b) = match after {
            0 => (rows[rows.len() - 1], rows[0]),
            n if n == rows.len() => (rows[n - 1], rows[0]),
            n => (rows[n - 1], rows[n]),
        };
        let span = (b.0 - a.0).rem_euclid(1440.0);
        if span == 0.0 {
            return a.1;
        }
        let f = (m - a.0).rem_euclid(1440.0) / span;
        a.1 + f * (b.1 - a.1)
    }
}

/// SplitMix64: a small, good, seedable generator.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.f64()
    }

    /// Poisson-distributed count with mean `lambda` (small).
    fn poisson(&mut self, lambda: f64) -> u32 {
        if lambda <= 0.0 {
            return 0;
        }
        let (mut k, mut p) = (0u32, (-lambda).exp());
        let mut s = p;
        let u = self.f64();
        while u > s && k < 1000 {
            k += 1;
            p *= lambda / k as f64;
            s += p;
        }
        k
    }
}

/// One synthetic person.
struct Person {
    x: f64,
    y: f64,
    /// Unit direction.
    ux: f64,
    uy: f64,
    /// Blocks per frame.
    step: f64,
    /// Density while walking.
    density: f32,
    /// Steps left until the pause (if any), then frames of pause left.
    steps_to_pause: Option<u32>,
    pause_frames: u32,
}

/// The synthetic scene: people crossing the block grid.
pub(super) struct Synth {
    w: u32,
    h: u32,
    fps: f64,
    rng: Rng,
    arrivals_per_min: f64,
    standing: f64,
    people: Vec<Person>,
}

impl Synth {
    pub(super) fn new(
        w: u32,
        h: u32,
        fps: f64,
        seed: u64,
        arrivals_per_min: f64,
        standing: f64,
    ) -> Self {
        Synth {
            w,
            h,
            fps,
            rng: Rng(seed ^ 0x6A09_E667_F3BC_C908),
            arrivals_per_min,
            standing,
            people: Vec::new(),
        }
    }

    /// A point on edge `e` (0 top, 1 right, 2 bottom, 3 left), in block units.
    fn edge_point(&mut self, e: u32) -> (f64, f64) {
        let (w, h) = (self.w as f64, self.h as f64);
        let u = self.rng.f64();
        match e {
            0 => (u * w, 0.0),
            1 => (w - 1e-6, u * h),
            2 => (u * w, h - 1e-6),
            _ => (0.0, u * h),
        }
    }

    fn spawn(&mut self) {
        let from = (self.rng.f64() * 4.0) as u32 % 4;
        let to = (from + 1 + (self.rng.f64() * 3.0) as u32 % 3) % 4;
        let (x0, y0) = self.edge_point(from);
        let (x1, y1) = self.edge_point(to);
        let (dx, dy) = (x1 - x0, y1 - y0);
        let len = (dx * dx + dy * dy).sqrt().max(1e-3);
        let speed = self.rng.range(1.5, 4.0); // blocks per second
        let step = speed / self.fps;
        let steps_to_pause = (self.rng.f64() < self.standing)
            .then(|| (len * self.rng.range(0.3, 0.7) / step) as u32);
        let pause_frames = (self.rng.range(5.0, 40.0) * self.fps) as u32;
        self.people.push(Person {
            x: x0,
            y: y0,
            ux: dx / len,
            uy: dy / len,
            step,
            density: self.rng.range(0.35, 0.7) as f32,
            steps_to_pause,
            pause_frames,
        });
    }

    /// Fills one frame: new arrivals at `activity` (0..1), everyone moves one frame.
    /// Returns the number of blocks with motion.
    pub(super) fn frame(&mut self, activity: f64, blocks: &mut [BlockMotion]) -> usize {
        blocks.fill(BlockMotion::default());
        let lambda = self.arrivals_per_min * activity / (60.0 * self.fps);
        for _ in 0..self.rng.poisson(lambda) {
            self.spawn();
        }
        let (w, h) = (self.w, self.h);
        let mut people = std::mem::take(&mut self.people);
        let mut changed = 0;
        people.retain_mut(|p| {
            let pausing = match &mut p.steps_to_pause {
                Some(0) if p.pause_frames > 0 => {
                    p.pause_frames -= 1;
                    true
                }
                Some(n) if *n > 0 => {
                    *n -= 1;
                    false
                }
                _ => false,
            };
            if !pausing {
                p.x += p.ux * p.step;
                p.y += p.uy * p.step;
            }
            if p.x < 0.0 || p.y < 0.0 || p.x >= w as f64 || p.y >= h as f64 {
                return false;
            }
            let (bx, by) = (p.x as u32, p.y as u32);
            let (d, ux, uy) = if pausing {
                // Someone standing moves a little, in no particular direction.
                let d = self.rng.range(0.12, 0.28) as f32;
                let a = self.rng.f64() * std::f64::consts::TAU;
                (d, a.cos() * 0.3, a.sin() * 0.3)
            } else {
                (p.density, p.ux * 0.9, p.uy * 0.9)
            };
            changed += mark(blocks, w, bx, by, d, ux, uy);
            if by > 0 {
                // The upper body, one block up.
                changed += mark(blocks, w, bx, by - 1, 0.6 * d, ux, uy);
            }
            true
        });
        self.people = people;
        changed
    }
}

/// Puts motion `d` with direction (ux, uy) (|u| <= 1) into block (x, y), keeping the
/// stronger of two overlapping people. Returns 1 if the block was still.
fn mark(blocks: &mut [BlockMotion], w: u32, x: u32, y: u32, d: f32, ux: f64, uy: f64) -> usize {
    let b = &mut blocks[(y * w + x) as usize];
    let was_still = b.density == 0.0;
    if d > b.density {
        let (dx, dy) = (d * ux as f32, d * uy as f32);
        b.density = d;
        b.dx = dx;
        b.dy = dy;
        b.direction = direction_label(dx, dy);
    }
    was_still as usize
}

/// 8-way label of a flow vector (0 = right, counter-clockwise on screen, y down).
pub(super) fn direction_label(dx: f32, dy: f32) -> u8 {
    if dx.hypot(dy) < 1e-3 {
        return DIRECTION_NONE;
    }
    let angle = (-dy).atan2(dx).to_degrees();
    ((angle / 45.0).round() as i32).rem_euclid(8) as u8
}
