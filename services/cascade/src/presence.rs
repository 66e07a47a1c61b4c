//! The presence band: the blocks where something that entered with motion stays,
//! whether it moves or not.
//!
//! The paper's bands are temporal differences: they see change, not presence, so a
//! person who stops fades from S1 within tens of seconds. This band compares each
//! block's *appearance* (mean grey level and texture, measured by the motion stage a
//! few times a second: `BlockMotion::luma`/`texture`) with a slowly learned
//! appearance of the empty block — the idea of dual backgrounds (Porikli et al.
//! 2008), at block level and once a second:
//!
//! * **background** `B` per block: the block's appearance, learned while it is
//!   empty and still (10 %-decay time [`LEARN_S`]); a block that differs from `B`
//!   with no motion near it (a slow local light change, codec drift) is learned
//!   faster ([`DRIFT_S`]). Blocks seen moving at the start are learned once they
//!   are still.
//! * **global light**: every second `a = g·B + c` is fitted over the empty, still
//!   blocks (medians of the darker and the brighter half: robust to what is
//!   present), and folded into every `B` (texture scales by `g` alone), so a light
//!   switching, a cloud or auto-exposure moves the whole background at once;
//! * **differs**: `|a − B|` of the luma is at least `luma_change` grey levels (and
//!   [`LUMA_RELATIVE`] of `B`, and four standard deviations of the block's own
//!   noise), or the texture's at least `texture_change` (and [`TEXTURE_RELATIVE`]
//!   of `B`'s texture and four deviations);
//! * **present**: an empty block that starts to differ in a second when it
//!   moved itself and it or a neighbour had moving activity (S2: motion above the
//!   always-on level F_L1 leaves; or the second before), or that differs next to
//!   a block something entered (the plain middle of a coat has no motion pixels
//!   of its own), has had something enter — unless the
//!   block is restless (it moved in more than [`RESTLESS_MAX`] of the recent
//!   seconds: a flag or a tape in the wind). It is present while it differs (and
//!   is not restless). If it still differs [`ENTER_S`] seconds later, in a second
//!   nothing moved in or around it (or next to a settled block), what entered
//!   has *settled* there (someone walking through moves in every second they
//!   are in the block, if not in it then around it). A settled block stays
//!   present, moving or not, until it matches `B` again for
//!   [`CLEAR_S`] seconds (it left), or its *region* — the 8-connected present
//!   blocks around it — has not moved for `absorb_s` (it becomes background: a box
//!   left on the floor, a parked trolley);
//! * **ghosts**: something that was in view when learning started and then leaves
//!   reveals a background `B` never saw, which differs, with motion. Which of the
//!   two images holds the object decides: across the region's border, the image
//!   with the object has the edge. When `B` differs more from its neighbours'
//!   background across the border than the current appearance differs from theirs
//!   ([`GHOST_RATIO`]) for [`GHOST_S`] seconds in a row while nothing moves in
//!   the region, the region is a hole in the background, not an object: `B` takes
//!   the current appearance.
//!
//! Pure state over motion samples; the cascade feeds it every frame
//! ([`Presence::frame`]) and asks for the band once a second
//! ([`Presence::second`]).

use isochron_wire::{APPEARANCE_SCALE, BlockActivity, BlockMotion, FLAG_APPEARANCE};

use crate::filters::alpha;

/// 10 %-decay time of the background of an empty, still block, seconds.
pub const LEARN_S: f64 = 30.0;
/// ... of a block that differs with nothing moving near it (drift), seconds.
pub const DRIFT_S: f64 = 5.0;
/// A block that something entered becomes present once it has differed this
/// many seconds in a row, the last of them without motion in it or around it
/// (someone walking through moves while they are in the block, if not in every
/// block they cover then in the blocks around it).
pub const ENTER_S: u32 = 2;
/// Something arrived in a block when its moving activity S2 (motion above the
/// block's always-on level, F_L1) reached this in the second or the one before.
pub const ARRIVAL_S2: f32 = 0.01;
/// 10 %-decay time of a block's restlessness (the share of seconds it moved).
pub const RESTLESS_S: f64 = 60.0;
/// A block that moved in more than this share of the recent seconds (a flag or
/// a tape in the wind, a screen, a busy doorway) cannot have something enter.
pub const RESTLESS_MAX: f32 = 0.5;
/// A present block that matches its background this many seconds in a row has
/// been left.
pub const CLEAR_S: u32 = 2;
/// A region's border differs this much more in the background than in the
/// current appearance for it to be a ghost.
pub const GHOST_RATIO: f32 = 1.5;
/// ... for this many seconds in a row, with nothing moving in it.
pub const GHOST_S: u32 = 3;
/// A luma change counts only if it is also at least this fraction of the block's
/// background luma (a gain the global fit leaves, gamma, saturation).
pub const LUMA_RELATIVE: f32 = 0.06;
/// ... and a texture change this fraction of the background texture.
pub const TEXTURE_RELATIVE: f32 = 0.3;
/// The 8 neighbours of a block, as (dx, dy).
const NEIGHBOURS: [(isize, isize); 8] = [
    (-1, -1),
    (0, -1),
    (1, -1),
    (-1, 0),
    (1, 0),
    (-1, 1),
    (0, 1),
    (1, 1),
];
/// The global fit needs at least this many empty, still blocks.
const FIT_MIN_BLOCKS: usize = 8;
/// A block's noise is learned as the EMA of its squared difference at this rate
/// per second, and counts from this many standard deviations.
const NOISE_SIGMAS: f32 = 4.0;

/// The parameters of the band (`[presence]`, and the motion threshold).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PresenceParams {
    /// Compute the band at all.
    pub enabled: bool,
    /// A present region nothing moved in for this long becomes background, seconds.
    pub absorb_s: f64,
    /// Least luma change of a block that differs, grey levels.
    pub luma_change: f32,
    /// Least texture change of a block that differs, grey levels.
    pub texture_change: f32,
    /// A block moved in a frame when its density was at least this
    /// (`motion.density_threshold`).
    pub moving_density: f32,
}

impl Default for PresenceParams {
    fn default() -> Self {
        PresenceParams {
            enabled: true,
            absorb_s: 120.0,
            luma_change: 6.0,
            texture_change: 2.0,
            moving_density: 0.02,
        }
    }
}

/// What the band did so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PresenceStats {
    /// Blocks present after the last second.
    pub present: u32,
    /// Regions that stayed still for `absorb_s` and became background.
    pub absorbed: u64,
    /// Regions found to be holes in the background (ghosts) and cleared.
    pub ghosts: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Not learned yet (moving since the start).
    Unlearned,
    /// Empty: matches its background, or drifts.
    Empty,
    /// Something entered and is there (present while it differs).
    Entered,
    /// Something that entered settled there (present until it left for
    /// [`CLEAR_S`], became background or was a ghost).
    Present,
}

/// The state of one block.
#[derive(Debug, Clone, Copy)]
struct Block {
    state: State,
    bg_luma: f32,
    bg_texture: f32,
    /// EMA of the squared luma and texture differences while empty and still.
    var_luma: f32,
    var_texture: f32,
    /// The last second the block moved.
    moved_s: i64,
    /// Seconds in a row an entered block differed, or a present block matched its
    /// background.
    calm_s: u32,
    /// Seconds in a row the block's region looked like a ghost.
    ghost_s: u32,
    /// Share of the recent seconds the block moved (EMA, [`RESTLESS_S`]).
    restless: f32,
    /// Seconds the restlessness has seen (its warm-up).
    seconds: u32,
    /// The block differed from its background in the last second.
    differs: bool,
}

impl Default for Block {
    fn default() -> Self {
        Block {
            state: State::Unlearned,
            bg_luma: 0.0,
            bg_texture: 0.0,
            var_luma: 0.0,
            var_texture: 0.0,
            moved_s: i64::MIN,
            calm_s: 0,
            ghost_s: 0,
            restless: 0.0,
            seconds: 0,
            differs: false,
        }
    }
}

/// The presence band of one camera's block grid.
#[derive(Debug, Clone)]
pub struct Presence {
    params: PresenceParams,
    grid_w: usize,
    grid_h: usize,
    blocks: Vec<Block>,
    /// The second's latest appearance (grey levels), and whether it had any.
    luma: Vec<f32>,
    texture: Vec<f32>,
    sampled: bool,
    /// Blocks that moved this second and the second before.
    moved: Vec<bool>,
    moved_before: Vec<bool>,
    /// Blocks with moving activity (S2 ≥ [`ARRIVAL_S2`]) this second and the
    /// second before.
    arrived: Vec<bool>,
    arrived_before: Vec<bool>,
    /// Per block, whether it or a neighbour moved (had moving activity) this
    /// second or the one before; made once a second.
    moved_near: Vec<bool>,
    arrived_near: Vec<bool>,
    /// Scratch of [`dilate`].
    rows_or: Vec<bool>,
    learn_rate: f32,
    drift_rate: f32,
    noise_rate: f32,
    restless_rate: f32,
    /// Scratch: region labels and the flood-fill stack.
    region: Vec<u32>,
    stack: Vec<usize>,
    members: Vec<usize>,
    fit: Vec<(f32, f32)>,
    stats: PresenceStats,
}

impl Presence {
    /// The band of a `grid_w × grid_h` grid.
    pub fn new(params: PresenceParams, grid_w: usize, grid_h: usize) -> Self {
        let k = grid_w * grid_h;
        Presence {
            params,
            grid_w,
            grid_h,
            blocks: vec![Block::default(); k],
            luma: vec![0.0; k],
            texture: vec![0.0; k],
            sampled: false,
            moved: vec![false; k],
            moved_before: vec![false; k],
            arrived: vec![false; k],
            arrived_before: vec![false; k],
            moved_near: vec![false; k],
            arrived_near: vec![false; k],
            rows_or: vec![false; k],
            learn_rate: (1.0 - alpha(LEARN_S, 1.0)) as f32,
            drift_rate: (1.0 - alpha(DRIFT_S, 1.0)) as f32,
            noise_rate: (1.0 - alpha(LEARN_S, 1.0)) as f32,
            restless_rate: (1.0 - alpha(RESTLESS_S, 1.0)) as f32,
            region: vec![0; k],
            stack: Vec::new(),
            members: Vec::new(),
            fit: Vec::with_capacity(k),
            stats: PresenceStats::default(),
        }
    }

    /// Counters.
    pub fn stats(&self) -> PresenceStats {
        self.stats
    }

    /// Forgets everything (a new timeline: another recording, another scene).
    pub fn reset(&mut self) {
        *self = Presence {
            stats: self.stats,
            ..Presence::new(self.params, self.grid_w, self.grid_h)
        };
    }

    /// Takes one motion frame: which blocks moved, and their appearance if the
    /// header's `flags` say it was measured (the latest of a second is the one
    /// the second is judged on: a snapshot, where a mean over the second would
    /// mix someone walking out with the floor they uncover).
    pub fn frame(&mut self, flags: u32, blocks: &[BlockMotion]) {
        if !self.params.enabled || blocks.len() != self.blocks.len() {
            return;
        }
        let threshold = self.params.moving_density;
        for (m, b) in self.moved.iter_mut().zip(blocks) {
            *m |= b.density >= threshold;
        }
        if flags & FLAG_APPEARANCE != 0 {
            let scale = 1.0 / APPEARANCE_SCALE as f32;
            for ((l, t), b) in self.luma.iter_mut().zip(&mut self.texture).zip(blocks) {
                *l = b.luma as f32 * scale;
                *t = b.texture as f32 * scale;
            }
            self.sampled = true;
        }
    }

    /// Ends second `now_s`: updates the band and writes it into `out[k].present`
    /// (`out` holds the second's other bands: arrivals are read from S2).
    pub fn second(&mut self, now_s: i64, out: &mut [BlockActivity]) {
        if !self.params.enabled || out.len() != self.blocks.len() {
            return;
        }
        for (b, &m) in self.blocks.iter_mut().zip(&self.moved) {
            if m {
                b.moved_s = now_s;
            }
            b.seconds = b.seconds.saturating_add(1);
            let w = self.restless_rate.max(1.0 / b.seconds as f32);
            b.restless += w * (m as u8 as f32 - b.restless);
        }
        for (a, o) in self.arrived.iter_mut().zip(out.iter()) {
            *a = o.s2 >= ARRIVAL_S2;
        }
        if self.sampled {
            let (w, h) = (self.grid_w, self.grid_h);
            dilate(
                (w, h),
                &self.moved,
                &self.moved_before,
                &mut self.rows_or,
                &mut self.moved_near,
            );
            dilate(
                (w, h),
                &self.arrived,
                &self.arrived_before,
                &mut self.rows_or,
                &mut self.arrived_near,
            );
            self.fold_global_light();
            self.update_blocks(now_s);
            self.update_regions(now_s);
        }
        let mut present = 0;
        for (o, b) in out.iter_mut().zip(&self.blocks) {
            let p = matches!(b.state, State::Entered | State::Present);
            o.present = if p { 1.0 } else { 0.0 };
            present += p as u32;
        }
        self.stats.present = present;
        std::mem::swap(&mut self.moved, &mut self.moved_before);
        std::mem::swap(&mut self.arrived, &mut self.arrived_before);
        self.moved.fill(false);
        self.sampled = false;
    }

    fn index(&self, x: isize, y: isize) -> Option<usize> {
        (x >= 0 && y >= 0 && (x as usize) < self.grid_w && (y as usize) < self.grid_h)
            .then(|| y as usize * self.grid_w + x as usize)
    }

    /// Fits `a = g·B + c` over the empty, still blocks and moves every background
    /// by it.
    fn fold_global_light(&mut self) {
        self.fit.clear();
        for k in 0..self.blocks.len() {
            let b = &self.blocks[k];
            if b.state == State::Empty && !self.moved_near[k] {
                self.fit.push((b.bg_luma, self.luma[k]));
            }
        }
        if self.fit.len() < FIT_MIN_BLOCKS {
            return;
        }
        let (gain, offset) = fit_light(&mut self.fit);
        for b in &mut self.blocks {
            if b.state != State::Unlearned {
                b.bg_luma = gain * b.bg_luma + offset;
                b.bg_texture *= gain;
            }
        }
    }

    /// Per block: learn, and the empty → present → empty transitions.
    fn update_blocks(&mut self, now_s: i64) {
        let p = self.params;
        for k in 0..self.blocks.len() {
            let (a_luma, a_texture) = (self.luma[k], self.texture[k]);
            let moved = self.moved[k];
            let near = self.moved_near[k];
            let arrived = self.arrived_near[k];
            // The block itself moved: something crossed into it (a change that
            // only coincides with motion next to it — a light in a doorway — did
            // not arrive).
            let own = moved || self.moved_before[k];
            let (learn, drift, noise) = (self.learn_rate, self.drift_rate, self.noise_rate);
            let b = &mut self.blocks[k];
            if b.state == State::Unlearned {
                if !near {
                    b.bg_luma = a_luma;
                    b.bg_texture = a_texture;
                    b.state = State::Empty;
                }
                continue;
            }
            let (dl, dt) = (a_luma - b.bg_luma, a_texture - b.bg_texture);
            let luma_tol = p
                .luma_change
                .max(LUMA_RELATIVE * b.bg_luma)
                .max(NOISE_SIGMAS * b.var_luma.sqrt());
            let texture_tol = p
                .texture_change
                .max(TEXTURE_RELATIVE * b.bg_texture)
                .max(NOISE_SIGMAS * b.var_texture.sqrt());
            let differs = dl.abs() >= luma_tol || dt.abs() >= texture_tol;
            b.differs = differs;
            match b.state {
                State::Empty if differs && arrived && own && b.restless <= RESTLESS_MAX => {
                    b.state = State::Entered;
                    b.calm_s = 1;
                    b.ghost_s = 0;
                    b.moved_s = b.moved_s.max(now_s);
                }
                State::Entered if differs && b.restless <= RESTLESS_MAX => {
                    b.calm_s += 1;
                    if b.calm_s >= ENTER_S && !near {
                        b.state = State::Present;
                        b.calm_s = 0;
                    }
                }
                // Left, or restless (a flag, a busy doorway): moving activity has it.
                State::Entered => b.state = State::Empty,
                State::Empty if differs && !near => {
                    b.bg_luma += drift * dl;
                    b.bg_texture += drift * dt;
                }
                State::Empty if !moved => {
                    b.bg_luma += learn * dl;
                    b.bg_texture += learn * dt;
                    b.var_luma += noise * (dl * dl - b.var_luma);
                    b.var_texture += noise * (dt * dt - b.var_texture);
                }
                State::Present if differs => b.calm_s = 0,
                State::Present => {
                    b.calm_s += 1;
                    if b.calm_s >= CLEAR_S {
                        b.state = State::Empty;
                    }
                }
                _ => {}
            }
        }
        self.grow(now_s);
    }

    /// What differs next to something that entered is part of it: the plain
    /// middle of a coat has no motion pixels of its own (flood from every
    /// entered or settled block through empty blocks that differ where something
    /// arrived); and what entered next to something settled and still differs has
    /// settled too (the arm of someone standing moves while the rest does not).
    fn grow(&mut self, now_s: i64) {
        self.stack.clear();
        self.stack
            .extend((0..self.blocks.len()).filter(|&k| self.blocks[k].state != State::Empty));
        while let Some(k) = self.stack.pop() {
            let state = self.blocks[k].state;
            if !matches!(state, State::Entered | State::Present) {
                continue;
            }
            let (x, y) = ((k % self.grid_w) as isize, (k / self.grid_w) as isize);
            for (dx, dy) in NEIGHBOURS {
                let Some(n) = self.index(x + dx, y + dy) else {
                    continue;
                };
                let b = &mut self.blocks[n];
                let joins = b.differs && b.restless <= RESTLESS_MAX;
                match b.state {
                    State::Empty if joins && self.arrived_near[n] => {
                        b.state = State::Entered;
                        b.calm_s = 1;
                        b.ghost_s = 0;
                        b.moved_s = b.moved_s.max(now_s);
                        self.stack.push(n);
                    }
                    State::Entered if joins && state == State::Present && b.calm_s >= ENTER_S => {
                        b.state = State::Present;
                        b.calm_s = 0;
                        self.stack.push(n);
                    }
                    _ => {}
                }
            }
        }
    }

    /// Per region of 8-connected settled blocks: absorb what stayed still for
    /// `absorb_s`, clear ghosts.
    fn update_regions(&mut self, now_s: i64) {
        let absorb_s = self.params.absorb_s;
        self.region.fill(u32::MAX);
        for start in 0..self.blocks.len() {
            if self.blocks[start].state != State::Present || self.region[start] != u32::MAX {
                continue;
            }
            self.collect_region(start);
            let members = std::mem::take(&mut self.members);
            let last_moved = members
                .iter()
                .map(|&k| self.blocks[k].moved_s)
                .max()
                .unwrap_or(i64::MIN);
            let still_s = now_s.saturating_sub(last_moved);
            if still_s as f64 >= absorb_s {
                self.become_background(&members);
                self.stats.absorbed += 1;
                tracing::info!(
                    "presence: a region of {} blocks nothing moved in for {absorb_s} s became background",
                    members.len()
                );
            } else if still_s >= 1 && self.looks_like_a_ghost(&members, start) {
                let votes = members
                    .iter()
                    .map(|&k| self.blocks[k].ghost_s)
                    .max()
                    .unwrap_or(0)
                    + 1;
                if votes >= GHOST_S {
                    self.become_background(&members);
                    self.stats.ghosts += 1;
                    tracing::info!(
                        "presence: a region of {} blocks was background revealed by something leaving (a ghost): relearned",
                        members.len()
                    );
                } else {
                    for &k in &members {
                        self.blocks[k].ghost_s = votes;
                    }
                }
            } else {
                for &k in &members {
                    self.blocks[k].ghost_s = 0;
                }
            }
            self.members = members;
        }
    }

    /// The present blocks 8-connected to `start`, labelled `start` in `region`,
    /// into `members`.
    fn collect_region(&mut self, start: usize) {
        self.members.clear();
        self.stack.clear();
        self.stack.push(start);
        self.region[start] = start as u32;
        while let Some(k) = self.stack.pop() {
            self.members.push(k);
            let (x, y) = ((k % self.grid_w) as isize, (k / self.grid_w) as isize);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    if let Some(n) = self.index(x + dx, y + dy)
                        && self.region[n] == u32::MAX
                        && self.blocks[n].state == State::Present
                    {
                        self.region[n] = start as u32;
                        self.stack.push(n);
                    }
                }
            }
        }
    }

    /// True if, across the border of the region labelled `label` (its `members`),
    /// the background differs from the neighbours' background more than the
    /// current appearance differs from theirs: the object is in the background.
    fn looks_like_a_ghost(&self, members: &[usize], label: usize) -> bool {
        let p = self.params;
        let (mut in_background, mut in_view) = (0.0f32, 0.0f32);
        for &k in members {
            let (x, y) = ((k % self.grid_w) as isize, (k / self.grid_w) as isize);
            for (dx, dy) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                let Some(n) = self.index(x + dx, y + dy) else {
                    continue;
                };
                if self.region[n] == label as u32 || self.blocks[n].state != State::Empty {
                    continue;
                }
                let (b, nb) = (&self.blocks[k], &self.blocks[n]);
                in_background += (b.bg_luma - nb.bg_luma).abs() / p.luma_change
                    + (b.bg_texture - nb.bg_texture).abs() / p.texture_change;
                in_view += (self.luma[k] - nb.bg_luma).abs() / p.luma_change
                    + (self.texture[k] - nb.bg_texture).abs() / p.texture_change;
            }
        }
        in_background > GHOST_RATIO * in_view && in_background > 1.0
    }

    /// The blocks' backgrounds take their current appearance; they are empty.
    fn become_background(&mut self, members: &[usize]) {
        for &k in members {
            let b = &mut self.blocks[k];
            b.bg_luma = self.luma[k];
            b.bg_texture = self.texture[k];
            b.state = State::Empty;
            b.calm_s = 0;
            b.ghost_s = 0;
        }
    }
}

/// `out[k]` = `a[n] || b[n]` for block `k` or one of its 8 neighbours `n`, on a
/// `w × h` grid (`rows` is scratch): a 3 × 3 dilation, along rows then columns.
fn dilate((w, h): (usize, usize), a: &[bool], b: &[bool], rows: &mut [bool], out: &mut [bool]) {
    for y in 0..h {
        let line = y * w..(y + 1) * w;
        let (a, b) = (&a[line.clone()], &b[line.clone()]);
        for (x, r) in rows[line].iter_mut().enumerate() {
            let (x0, x1) = (x.saturating_sub(1), (x + 1).min(w - 1));
            *r = (x0..=x1).any(|i| a[i] || b[i]);
        }
    }
    for y in 0..h {
        let (y0, y1) = (y.saturating_sub(1), (y + 1).min(h - 1));
        for x in 0..w {
            out[y * w + x] = (y0..=y1).any(|j| rows[j * w + x]);
        }
    }
}

/// The global light change `a = g·B + c` from `(B, a)` pairs of empty blocks: a
/// first line through the medians of the darker and the brighter half, then least
/// squares over the pairs near that line (what differs for another reason — a
/// shadow, someone the band missed — is left out). A gain alone (`c = 0`) when the
/// blocks are too alike in brightness to tell an offset from a gain. `g` is kept
/// within 0.2..=5.
fn fit_light(pairs: &mut [(f32, f32)]) -> (f32, f32) {
    // The darker and the brighter half (by B), each in no order.
    let half = pairs.len() / 2;
    pairs.select_nth_unstable_by(half, |a, b| a.0.total_cmp(&b.0));
    let (b_lo, a_lo) = medians(&mut pairs[..half]);
    let (b_hi, a_hi) = medians(&mut pairs[half..]);
    let spread = b_hi - b_lo >= 16.0;
    let (gain, offset) = if spread {
        let gain = ((a_hi - a_lo) / (b_hi - b_lo)).clamp(0.2, 5.0);
        (gain, a_lo - gain * b_lo)
    } else {
        let (b, a) = medians(pairs);
        if b > 1.0 {
            ((a / b).clamp(0.2, 5.0), 0.0)
        } else {
            return (1.0, a - b);
        }
    };
    // Refine on the inliers: within 8 grey levels (or 10 %) of the first line.
    let (mut n, mut sb, mut sa, mut sbb, mut sba) = (0.0f64, 0.0f64, 0.0, 0.0, 0.0);
    for &(b, a) in pairs.iter() {
        let predicted = gain * b + offset;
        if (a - predicted).abs() <= 8.0f32.max(0.1 * predicted) {
            let (b, a) = (b as f64, a as f64);
            n += 1.0;
            sb += b;
            sa += a;
            sbb += b * b;
            sba += b * a;
        }
    }
    if n < FIT_MIN_BLOCKS as f64 {
        return (gain, offset);
    }
    if !spread {
        return if sbb > 0.0 {
            (((sba / sbb) as f32).clamp(0.2, 5.0), 0.0)
        } else {
            (gain, offset)
        };
    }
    let det = n * sbb - sb * sb;
    if det <= 0.0 {
        return (gain, offset);
    }
    let g = (((n * sba - sb * sa) / det) as f32).clamp(0.2, 5.0);
    (g, ((sa - g as f64 * sb) / n) as f32)
}

/// The medians of both coordinates of `pairs` (reordered).
fn medians(pairs: &mut [(f32, f32)]) -> (f32, f32) {
    if pairs.is_empty() {
        return (0.0, 0.0);
    }
    let mid = pairs.len() / 2;
    let b = pairs
        .select_nth_unstable_by(mid, |x, y| x.0.total_cmp(&y.0))
        .1
        .0;
    let a = pairs
        .select_nth_unstable_by(mid, |x, y| x.1.total_cmp(&y.1))
        .1
        .1;
    (b, a)
}

#[cfg(test)]
mod tests;
