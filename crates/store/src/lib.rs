//! The long-term (isochronal) store: per camera, the F_L2 model of every minute bin of
//! the cycle — per block the exponentially weighted mean and variance of `M_L1`, and
//! per bin the number of days that taught it — plus the F_L1 baseline, so that a
//! restarted cascade resumes where it stopped.
//!
//! **Why SQLite.** The store must be readable *while* the cascade writes it:
//! `isochron store export`, the costmap bridge and the planner read it concurrently
//! with the running cascade. Single-process embedded stores (redb, LMDB-style
//! designs with one process holding the file lock) forbid exactly that, and a format
//! of our own would have to re-invent concurrent readers and crash recovery. SQLite
//! in WAL mode gives concurrent readers that never block the writer, atomic and
//! durable commits (`synchronous = FULL`: a committed minute survives a power cut),
//! recovery of a half-written transaction on the next open, and decades of
//! crash-safety testing. It is compiled in (`rusqlite` with `bundled`), so nothing has
//! to be installed.
//!
//! **Layout.** One file per camera, `<state_dir>/<camera>.isochron.sqlite`
//! ([`store_path`]):
//!
//! * `meta`: magic, format version, camera, block grid, cycle, creation time, and a
//!   CRC-32 over them; the file also carries SQLite's `application_id` (`ISOC`) and
//!   `user_version` (the format version);
//! * `bins`: one row per minute bin t* that has learned anything: count (days),
//!   the absolute minute that last taught it, mean and variance per block (f32
//!   little-endian blobs), and a CRC-32 over all of it;
//! * `baseline`: the F_L1 baseline per block with its frame count, rate and time, and
//!   a CRC-32;
//! * `progress`: the last completed minute and how many minutes were committed or
//!   skipped (too few frames).
//!
//! **Crash safety.** The cascade writes one transaction per completed minute
//! ([`Store::commit_minute`]): the bin's new row, the baseline and the progress
//! together, or none of them. A crash at any moment loses at most the minute in
//! progress. A bin learns only from minutes later than the one that last taught it,
//! so data delivered twice (a replay, a restarted producer) never counts twice.
//!
//! **Damage.** Opening checks that the file is SQLite, is an isochron store (not
//! another application's database), has this format version, belongs to the expected
//! camera and (for the writer) grid and cycle. Every row's CRC is checked when it is
//! read, and [`Store::verify`] checks them all plus SQLite's own `quick_check`. Each
//! failure is a [`StoreError`] that names the file and says what to do; damaged data
//! is never used silently.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::Duration;

use rusqlite::{Connection, ErrorCode, OpenFlags, OptionalExtension, TransactionBehavior, params};

use isochron_config::clock::{Cycle, format_rfc3339};
use isochron_wire::geometry::BlockGrid;

/// File name suffix of a store: `<camera>.isochron.sqlite`.
pub const FILE_SUFFIX: &str = ".isochron.sqlite";
/// SQLite `application_id` of an isochron store: the bytes `ISOC`.
pub const APPLICATION_ID: i32 = i32::from_be_bytes(*b"ISOC");
/// Version of the store's layout. Bump it on any change to the tables or blobs.
pub const FORMAT_VERSION: u32 = 1;
/// Value of the `magic` meta row.
const MAGIC: &str = "isochron-store";
/// How long a connection waits for a lock (WAL recovery, checkpoints).
const BUSY_TIMEOUT: Duration = Duration::from_secs(5);

/// The store file of `camera` under `state_dir`.
pub fn store_path(state_dir: &Path, camera: &str) -> PathBuf {
    state_dir.join(format!("{camera}{FILE_SUFFIX}"))
}

/// Why a store cannot be opened, read or written. Every message names the file and
/// says what to do.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StoreError {
    /// No file.
    #[error(
        "{}: no long-term store: the cascade creates it when motion of camera '{camera}' first arrives; check `site.state_dir` and the camera id",
        file.display()
    )]
    NotFound {
        /// The file.
        file: PathBuf,
        /// The camera looked for.
        camera: String,
    },
    /// Not an SQLite file at all.
    #[error(
        "{} is not an isochron store (not an SQLite database: {detail}); move it away, and the cascade starts a new long-term model",
        file.display()
    )]
    NotSqlite {
        /// The file.
        file: PathBuf,
        /// What was found.
        detail: String,
    },
    /// An SQLite database, but not an isochron store.
    #[error(
        "{} is an SQLite database of another application ({detail}), not an isochron store; point to the right file, or move it away",
        file.display()
    )]
    Foreign {
        /// The file.
        file: PathBuf,
        /// What was found.
        detail: String,
    },
    /// An isochron store of another format version.
    #[error(
        "{} is an isochron store of format version {found}, this isochron reads version {FORMAT_VERSION}; use the matching isochron version, or move the file away to start a new model",
        file.display()
    )]
    Version {
        /// The file.
        file: PathBuf,
        /// The version found.
        found: i64,
    },
    /// The store of another camera.
    #[error(
        "{} holds the long-term model of camera '{found}', not '{expected}'; every camera has its own store file: check the file name and `site.state_dir`",
        file.display()
    )]
    Camera {
        /// The file.
        file: PathBuf,
        /// Camera expected.
        expected: String,
        /// Camera in the file.
        found: String,
    },
    /// A model for another block grid.
    #[error(
        "{} holds a model for a {found} block grid, but the motion stream now has {expected} blocks; a model cannot be carried across grids: move the file away to start a new model, or restore the motion settings (block_px, analysis size) it was made with",
        file.display()
    )]
    Grid {
        /// The file.
        file: PathBuf,
        /// Grid of the stream.
        expected: String,
        /// Grid in the file.
        found: String,
    },
    /// A model of another isochronal cycle.
    #[error(
        "{} holds a {found} model, but the config says cascade.cycle = \"{expected}\"; set it back, or move the file away to start a new model",
        file.display()
    )]
    Cycle {
        /// The file.
        file: PathBuf,
        /// Cycle of the config.
        expected: String,
        /// Cycle in the file.
        found: String,
    },
    /// Checksums or SQLite's own checks failed.
    #[error(
        "{} is damaged ({detail}); its long-term model cannot be trusted: restore it from a backup, or move it away to start a new model",
        file.display()
    )]
    Damaged {
        /// The file.
        file: PathBuf,
        /// What is wrong.
        detail: String,
    },
    /// A write on a store opened read-only.
    #[error("{}: opened read-only, cannot write", file.display())]
    ReadOnly {
        /// The file.
        file: PathBuf,
    },
    /// The operating system or SQLite failed (disk full, permissions, I/O error).
    #[error("{}: {detail}", file.display())]
    Io {
        /// The file.
        file: PathBuf,
        /// What failed.
        detail: String,
    },
}

/// What a store is about; fixed when it is created.
///
/// The `meta` table stores the grid's frame size and block edge, and for readers of
/// the file the model's size `grid_w × grid_h` (every blob has that many values),
/// which must agree with them.
#[derive(Debug, Clone, PartialEq)]
pub struct StoreMeta {
    /// Camera id.
    pub camera: String,
    /// The block grid of the model.
    pub grid: BlockGrid,
    /// The isochronal cycle: the number of bins.
    pub cycle: Cycle,
    /// Wall-clock time of creation, UTC ns.
    pub created_ns: i64,
}

impl StoreMeta {
    /// The meta of a new store of `camera` on `grid`.
    pub fn new(camera: impl Into<String>, grid: BlockGrid, cycle: Cycle, created_ns: i64) -> Self {
        StoreMeta {
            camera: camera.into(),
            grid,
            cycle,
            created_ns,
        }
    }

    /// Number of blocks per bin.
    pub fn blocks(&self) -> usize {
        self.grid.len()
    }

    /// Number of minute bins of the cycle.
    pub fn bins(&self) -> u32 {
        self.cycle.bins()
    }

    /// `WxH`.
    pub fn grid(&self) -> String {
        format!("{}x{}", self.grid.grid_w(), self.grid.grid_h())
    }

    fn rows(&self) -> Vec<(&'static str, String)> {
        vec![
            ("magic", MAGIC.to_string()),
            ("format_version", FORMAT_VERSION.to_string()),
            ("camera", self.camera.clone()),
            ("grid_w", self.grid.grid_w().to_string()),
            ("grid_h", self.grid.grid_h().to_string()),
            ("block_px", self.grid.block_px.to_string()),
            ("frame_width", self.grid.frame_width.to_string()),
            ("frame_height", self.grid.frame_height.to_string()),
            ("cycle", cycle_name(self.cycle).to_string()),
            ("created", format_rfc3339(self.created_ns)),
            ("created_ns", self.created_ns.to_string()),
        ]
    }
}

fn cycle_name(cycle: Cycle) -> &'static str {
    match cycle {
        Cycle::Daily => "daily",
        Cycle::Weekly => "weekly",
    }
}

/// CRC-32 of the meta rows, sorted by key.
fn meta_crc(rows: &[(String, String)]) -> u32 {
    let mut sorted: Vec<_> = rows.iter().filter(|(k, _)| k != "crc").collect();
    sorted.sort();
    let mut h = crc32fast::Hasher::new();
    for (k, v) in sorted {
        h.update(k.as_bytes());
        h.update(b"=");
        h.update(v.as_bytes());
        h.update(b"\n");
    }
    h.finalize()
}

/// The long-term model of one minute bin t*: per block the exponentially weighted
/// mean and variance of the minute means of `M_L1`.
#[derive(Debug, Clone, PartialEq)]
pub struct Bin {
    /// The bin: minute of the cycle.
    pub t_star: u32,
    /// Minutes (one per day, or per week with the weekly cycle) that taught this bin.
    /// All blocks of a bin learn together, so this is every block's count.
    pub count: u32,
    /// Absolute minute (minutes since the Unix epoch) that last taught this bin.
    pub last_minute: i64,
    /// Mean per block (row-major), density units.
    pub mean: Vec<f32>,
    /// Variance per block.
    pub var: Vec<f32>,
}

impl Bin {
    /// A bin that has learned nothing yet.
    pub fn empty(t_star: u32, blocks: usize) -> Bin {
        Bin {
            t_star,
            count: 0,
            last_minute: i64::MIN,
            mean: vec![0.0; blocks],
            var: vec![0.0; blocks],
        }
    }

    /// Standard deviation of block `k` (0 outside the grid).
    pub fn sigma(&self, k: usize) -> f32 {
        self.var.get(k).map_or(0.0, |v| v.max(0.0).sqrt())
    }

    /// Mean of the block means.
    pub fn mean_over_blocks(&self) -> f64 {
        if self.mean.is_empty() {
            return 0.0;
        }
        self.mean.iter().map(|&m| m as f64).sum::<f64>() / self.mean.len() as f64
    }

    /// Mean of the block variances.
    pub fn var_over_blocks(&self) -> f64 {
        if self.var.is_empty() {
            return 0.0;
        }
        self.var.iter().map(|&m| m as f64).sum::<f64>() / self.var.len() as f64
    }

    fn crc(&self) -> u32 {
        crc_of(&[
            &self.t_star.to_le_bytes(),
            &self.count.to_le_bytes(),
            &self.last_minute.to_le_bytes(),
            &f32_bytes(&self.mean),
            &f32_bytes(&self.var),
        ])
    }
}

/// The F_L1 baseline of a camera at a point in (capture) time.
#[derive(Debug, Clone, PartialEq)]
pub struct Baseline {
    /// Capture time of the last frame that went into it, UTC ns.
    pub capture_ns: i64,
    /// Frames it has seen (drives the bias-corrected warm-up).
    pub frames: u64,
    /// Frame rate r in use, frames/s.
    pub frame_rate: f64,
    /// Baseline density per block.
    pub level: Vec<f32>,
}

impl Baseline {
    fn crc(&self) -> u32 {
        crc_of(&[
            &self.capture_ns.to_le_bytes(),
            &self.frames.to_le_bytes(),
            &self.frame_rate.to_le_bytes(),
            &f32_bytes(&self.level),
        ])
    }
}

/// How far the cascade has got.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Progress {
    /// The last completed minute (minutes since the Unix epoch), if any.
    pub last_minute: Option<i64>,
    /// Minutes that updated a bin.
    pub committed: u64,
    /// Minutes completed without enough frames (or already learned), not learned.
    pub skipped: u64,
}

/// One completed minute, written atomically by [`Store::commit_minute`].
#[derive(Debug, Clone, Copy)]
pub struct MinuteCommit<'a> {
    /// The minute (minutes since the Unix epoch).
    pub minute: i64,
    /// The bin's new state, if the minute taught it; `None` if it was skipped.
    pub bin: Option<&'a Bin>,
    /// The F_L1 baseline at the end of the minute.
    pub baseline: Option<&'a Baseline>,
}

/// The whole long-term model of a camera.
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    /// What the store is about.
    pub meta: StoreMeta,
    /// One entry per bin of the cycle (`None`: never taught).
    pub bins: Vec<Option<Bin>>,
}

impl Model {
    /// The model of `meta` that has learned `bins` (each at its `t_star`, which must
    /// be inside the cycle) and nothing else: a known model without a store.
    pub fn with_bins(meta: StoreMeta, bins: impl IntoIterator<Item = Bin>) -> Model {
        let mut all = vec![None; meta.bins() as usize];
        for bin in bins {
            let t = bin.t_star as usize;
            all[t] = Some(bin);
        }
        Model { meta, bins: all }
    }

    /// The bin at `t_star`, if it has learned anything.
    pub fn bin(&self, t_star: u32) -> Option<&Bin> {
        self.bins.get(t_star as usize).and_then(Option::as_ref)
    }

    /// Bins that have learned anything.
    pub fn learned(&self) -> impl Iterator<Item = &Bin> {
        self.bins.iter().flatten()
    }
}

/// What [`Store::verify`] checked.
#[derive(Debug, Clone, PartialEq)]
pub struct VerifyReport {
    /// Bin rows checked.
    pub bins: usize,
    /// Whether a baseline row is present (and valid).
    pub baseline: bool,
    /// The progress.
    pub progress: Progress,
}

/// An open store: the cascade's writer, or a reader (read-only).
pub struct Store {
    conn: Connection,
    path: PathBuf,
    meta: StoreMeta,
    read_only: bool,
}

impl std::fmt::Debug for Store {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Store")
            .field("path", &self.path)
            .field("meta", &self.meta)
            .field("read_only", &self.read_only)
            .finish()
    }
}

const SCHEMA: &str = "
CREATE TABLE meta (key TEXT PRIMARY KEY NOT NULL, value TEXT NOT NULL);
CREATE TABLE bins (
    t_star INTEGER PRIMARY KEY NOT NULL,
    count INTEGER NOT NULL,
    last_minute INTEGER NOT NULL,
    mean BLOB NOT NULL,
    var BLOB NOT NULL,
    crc INTEGER NOT NULL
);
CREATE TABLE baseline (
    id INTEGER PRIMARY KEY NOT NULL CHECK (id = 0),
    capture_ns INTEGER NOT NULL,
    frames INTEGER NOT NULL,
    frame_rate REAL NOT NULL,
    level BLOB NOT NULL,
    crc INTEGER NOT NULL
);
CREATE TABLE progress (
    id INTEGER PRIMARY KEY NOT NULL CHECK (id = 0),
    last_minute INTEGER,
    committed INTEGER NOT NULL,
    skipped INTEGER NOT NULL
);
INSERT INTO progress (id, last_minute, committed, skipped) VALUES (0, NULL, 0, 0);
";

impl Store {
    /// Opens the store at `path` for writing, creating it for `meta` if it does not
    /// exist. An existing store must belong to `meta.camera`, have `meta.cycle` and
    /// `meta`'s grid, and pass [`Store::verify`].
    pub fn open_or_create(path: &Path, meta: &StoreMeta) -> Result<Store, StoreError> {
        if !path.exists() {
            create(path, meta)?;
        }
        let store = Store::open_writer(path, &meta.camera, meta.cycle)?;
        store.check_grid(&meta.grid)?;
        Ok(store)
    }

    /// Opens an existing store for writing: it must belong to `camera` and have
    /// `cycle`, and pass [`Store::verify`]. The grid is checked by the caller
    /// ([`Store::check_grid`]) once it knows it.
    pub fn open_writer(path: &Path, camera: &str, cycle: Cycle) -> Result<Store, StoreError> {
        let store = Store::open(path, camera, false)?;
        if store.meta.cycle != cycle {
            return Err(StoreError::Cycle {
                file: path.to_path_buf(),
                expected: cycle_name(cycle).into(),
                found: cycle_name(store.meta.cycle).into(),
            });
        }
        store.verify()?;
        Ok(store)
    }

    /// Opens an existing store read-only, e.g. while the cascade writes it. It must
    /// belong to `camera`. Rows are checked as they are read.
    pub fn open_read_only(path: &Path, camera: &str) -> Result<Store, StoreError> {
        Store::open(path, camera, true)
    }

    fn open(path: &Path, camera: &str, read_only: bool) -> Result<Store, StoreError> {
        let file = path.to_path_buf();
        check_sqlite_header(path, camera)?;
        let flags = if read_only {
            OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX
        } else {
            OpenFlags::SQLITE_OPEN_READ_WRITE | OpenFlags::SQLITE_OPEN_NO_MUTEX
        };
        let conn = Connection::open_with_flags(path, flags).map_err(|e| sql_err(path, e))?;
        conn.busy_timeout(BUSY_TIMEOUT)
            .map_err(|e| sql_err(path, e))?;
        let app: i32 = conn
            .pragma_query_value(None, "application_id", |r| r.get(0))
            .map_err(|e| sql_err(path, e))?;
        if app != APPLICATION_ID {
            return Err(StoreError::Foreign {
                file,
                detail: format!(
                    "application_id {app:#010x}, an isochron store has {APPLICATION_ID:#010x}"
                ),
            });
        }
        let version: i64 = conn
            .pragma_query_value(None, "user_version", |r| r.get(0))
            .map_err(|e| sql_err(path, e))?;
        if version != FORMAT_VERSION as i64 {
            return Err(StoreError::Version {
                file,
                found: version,
            });
        }
        let meta = read_meta(&conn, path)?;
        if meta.camera != camera {
            return Err(StoreError::Camera {
                file,
                expected: camera.to_string(),
                found: meta.camera,
            });
        }
        if !read_only {
            conn.pragma_update(None, "synchronous", "FULL")
                .map_err(|e| sql_err(path, e))?;
            let mode: String = conn
                .pragma_query_value(None, "journal_mode", |r| r.get(0))
                .map_err(|e| sql_err(path, e))?;
            if !mode.eq_ignore_ascii_case("wal") {
                conn.pragma_update(None, "journal_mode", "WAL")
                    .map_err(|e| sql_err(path, e))?;
            }
        }
        Ok(Store {
            conn,
            path: file,
            meta,
            read_only,
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// What the store is about.
    pub fn meta(&self) -> &StoreMeta {
        &self.meta
    }

    /// Errors unless the store's model has as many blocks per row and rows as `grid`.
    pub fn check_grid(&self, grid: &BlockGrid) -> Result<(), StoreError> {
        let mine = &self.meta.grid;
        if (mine.grid_w(), mine.grid_h()) != (grid.grid_w(), grid.grid_h()) {
            return Err(StoreError::Grid {
                file: self.path.clone(),
                expected: format!("{}x{}", grid.grid_w(), grid.grid_h()),
                found: self.meta.grid(),
            });
        }
        Ok(())
    }

    /// A cached prepared statement of `sql`.
    fn statement(&self, sql: &str) -> Result<rusqlite::CachedStatement<'_>, StoreError> {
        self.conn
            .prepare_cached(sql)
            .map_err(|e| sql_err(&self.path, e))
    }

    /// The model of bin `t_star`, if it has learned anything. Its checksum is
    /// verified.
    pub fn read_bin(&self, t_star: u32) -> Result<Option<Bin>, StoreError> {
        let mut stmt = self.statement(&format!("{SELECT_BINS} WHERE t_star = ?1"))?;
        let raw = stmt
            .query_row(params![t_star as i64], RawBin::from_row)
            .optional()
            .map_err(|e| sql_err(&self.path, e))?;
        raw.map(|r| r.into_bin(&self.path, self.meta.blocks()))
            .transpose()
    }

    /// The whole model, every row's checksum verified.
    pub fn read_model(&self) -> Result<Model, StoreError> {
        let bins_n = self.meta.bins() as usize;
        let mut bins: Vec<Option<Bin>> = vec![None; bins_n];
        let mut stmt = self.statement(&format!("{SELECT_BINS} ORDER BY t_star"))?;
        let rows = stmt
            .query_map([], RawBin::from_row)
            .map_err(|e| sql_err(&self.path, e))?;
        for raw in rows {
            let bin = raw
                .map_err(|e| sql_err(&self.path, e))?
                .into_bin(&self.path, self.meta.blocks())?;
            let t = bin.t_star as usize;
            if t >= bins_n {
                return Err(StoreError::Damaged {
                    file: self.path.clone(),
                    detail: format!("bin {t} is outside the {bins_n} bins of the cycle"),
                });
            }
            bins[t] = Some(bin);
        }
        Ok(Model {
            meta: self.meta.clone(),
            bins,
        })
    }

    /// The stored F_L1 baseline, if any; its checksum is verified.
    pub fn read_baseline(&self) -> Result<Option<Baseline>, StoreError> {
        let raw = self
            .conn
            .query_row(
                "SELECT capture_ns, frames, frame_rate, level, crc FROM baseline WHERE id = 0",
                [],
                |r| {
                    Ok((
                        r.get::<_, i64>(0)?,
                        r.get::<_, i64>(1)?,
                        r.get::<_, f64>(2)?,
                        r.get::<_, Vec<u8>>(3)?,
                        r.get::<_, i64>(4)?,
                    ))
                },
            )
            .optional()
            .map_err(|e| sql_err(&self.path, e))?;
        let Some((capture_ns, frames, frame_rate, level, crc)) = raw else {
            return Ok(None);
        };
        let level = f32s_from(&level, self.meta.blocks()).ok_or_else(|| StoreError::Damaged {
            file: self.path.clone(),
            detail: format!(
                "the F_L1 baseline holds {} bytes, not {} blocks",
                level.len(),
                self.meta.blocks()
            ),
        })?;
        let baseline = Baseline {
            capture_ns,
            frames: frames.max(0) as u64,
            frame_rate,
            level,
        };
        if baseline.crc() as i64 != crc {
            return Err(StoreError::Damaged {
                file: self.path.clone(),
                detail: "checksum mismatch in the F_L1 baseline".into(),
            });
        }
        Ok(Some(baseline))
    }

    /// How far the cascade has got.
    pub fn progress(&self) -> Result<Progress, StoreError> {
        self.conn
            .query_row(
                "SELECT last_minute, committed, skipped FROM progress WHERE id = 0",
                [],
                |r| {
                    Ok(Progress {
                        last_minute: r.get::<_, Option<i64>>(0)?,
                        committed: r.get::<_, i64>(1)?.max(0) as u64,
                        skipped: r.get::<_, i64>(2)?.max(0) as u64,
                    })
                },
            )
            .optional()
            .map_err(|e| sql_err(&self.path, e))?
            .ok_or_else(|| StoreError::Damaged {
                file: self.path.clone(),
                detail: "the progress row is missing".into(),
            })
    }

    /// Checks everything: SQLite's `quick_check`, the meta, every bin's and the
    /// baseline's checksum.
    pub fn verify(&self) -> Result<VerifyReport, StoreError> {
        let mut problems = Vec::new();
        self.conn
            .pragma_query(None, "quick_check", |r| {
                let line: String = r.get(0)?;
                if line != "ok" {
                    problems.push(line);
                }
                Ok(())
            })
            .map_err(|e| sql_err(&self.path, e))?;
        if !problems.is_empty() {
            return Err(StoreError::Damaged {
                file: self.path.clone(),
                detail: format!("SQLite quick_check: {}", problems.join("; ")),
            });
        }
        read_meta(&self.conn, &self.path)?;
        let model = self.read_model()?;
        let baseline = self.read_baseline()?;
        Ok(VerifyReport {
            bins: model.learned().count(),
            baseline: baseline.is_some(),
            progress: self.progress()?,
        })
    }

    /// Commits a hand-made minute: absolute minute `t_star` teaches bin `t_star` the
    /// per-block `mean` with variance 0 after `count` minutes, without a baseline
    /// (how tests and tools write a known long-term model).
    pub fn teach(&mut self, t_star: u32, count: u32, mean: Vec<f32>) -> Result<(), StoreError> {
        let bin = Bin {
            t_star,
            count,
            last_minute: t_star as i64,
            var: vec![0.0; mean.len()],
            mean,
        };
        self.commit_minute(&MinuteCommit {
            minute: t_star as i64,
            bin: Some(&bin),
            baseline: None,
        })
    }

    /// Writes one completed minute atomically and durably: the bin's new state (if the
    /// minute taught it), the baseline, and the progress. When this returns `Ok`, the
    /// minute survives a crash or power cut.
    pub fn commit_minute(&mut self, commit: &MinuteCommit<'_>) -> Result<(), StoreError> {
        if self.read_only {
            return Err(StoreError::ReadOnly {
                file: self.path.clone(),
            });
        }
        let blocks = self.meta.blocks();
        let bins = self.meta.bins();
        let path = self.path.clone();
        let err = |e: rusqlite::Error| sql_err(&path, e);
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .map_err(err)?;
        if let Some(bin) = commit.bin {
            if bin.mean.len() != blocks || bin.var.len() != blocks || bin.t_star >= bins {
                return Err(StoreError::Io {
                    file: path.clone(),
                    detail: format!(
                        "refusing to write bin {} with {} blocks into a store of {blocks} blocks and {bins} bins",
                        bin.t_star,
                        bin.mean.len()
                    ),
                });
            }
            tx.prepare_cached(
                "INSERT OR REPLACE INTO bins (t_star, count, last_minute, mean, var, crc) VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
            )
            .map_err(err)?
            .execute(params![
                bin.t_star as i64,
                bin.count as i64,
                bin.last_minute,
                f32_bytes(&bin.mean),
                f32_bytes(&bin.var),
                bin.crc() as i64
            ])
            .map_err(err)?;
        }
        if let Some(b) = commit.baseline
            && b.level.len() == blocks
        {
            tx.prepare_cached(
                "INSERT OR REPLACE INTO baseline (id, capture_ns, frames, frame_rate, level, crc) VALUES (0, ?1, ?2, ?3, ?4, ?5)",
            )
            .map_err(err)?
            .execute(params![
                b.capture_ns,
                b.frames.min(i64::MAX as u64) as i64,
                b.frame_rate,
                f32_bytes(&b.level),
                b.crc() as i64
            ])
            .map_err(err)?;
        }
        let (committed, skipped) = if commit.bin.is_some() { (1, 0) } else { (0, 1) };
        tx.prepare_cached(
            "UPDATE progress SET last_minute = max(coalesce(last_minute, ?1), ?1), committed = committed + ?2, skipped = skipped + ?3 WHERE id = 0",
        )
        .map_err(err)?
        .execute(params![commit.minute, committed, skipped])
        .map_err(err)?;
        tx.commit().map_err(err)
    }
}

/// Creates a store atomically: built under a temporary name, then renamed into place,
/// so a crash during creation never leaves a half-made store behind.
fn create(path: &Path, meta: &StoreMeta) -> Result<(), StoreError> {
    let io = |e: std::io::Error| StoreError::Io {
        file: path.to_path_buf(),
        detail: e.to_string(),
    };
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty());
    if let Some(dir) = dir {
        std::fs::create_dir_all(dir).map_err(io)?;
    }
    let tmp = path.with_extension(format!("creating-{}", std::process::id()));
    let _ = std::fs::remove_file(&tmp);
    {
        let conn = Connection::open(&tmp).map_err(|e| sql_err(path, e))?;
        let setup = || -> rusqlite::Result<()> {
            conn.pragma_update(None, "application_id", APPLICATION_ID)?;
            conn.pragma_update(None, "user_version", FORMAT_VERSION as i64)?;
            conn.pragma_update(None, "synchronous", "FULL")?;
            let tx = conn.unchecked_transaction()?;
            tx.execute_batch(SCHEMA)?;
            let mut rows: Vec<(String, String)> = meta
                .rows()
                .into_iter()
                .map(|(k, v)| (k.to_string(), v))
                .collect();
            let crc = meta_crc(&rows);
            rows.push(("crc".into(), crc.to_string()));
            for (k, v) in &rows {
                tx.execute(
                    "INSERT INTO meta (key, value) VALUES (?1, ?2)",
                    params![k, v],
                )?;
            }
            tx.commit()?;
            // WAL mode is recorded in the file; closing the connection folds the
            // (empty) WAL back, so the rename moves one complete file.
            conn.pragma_update(None, "journal_mode", "WAL")?;
            Ok(())
        };
        setup().map_err(|e| sql_err(path, e))?;
    }
    std::fs::File::open(&tmp)
        .and_then(|f| f.sync_all())
        .map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)?;
    if let Some(dir) = dir
        && let Ok(d) = std::fs::File::open(dir)
    {
        let _ = d.sync_all();
    }
    Ok(())
}

/// Fails with a clear error unless `path` exists and starts like an SQLite database.
fn check_sqlite_header(path: &Path, camera: &str) -> Result<(), StoreError> {
    let mut file = match std::fs::File::open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(StoreError::NotFound {
                file: path.to_path_buf(),
                camera: camera.to_string(),
            });
        }
        Err(e) => {
            return Err(StoreError::Io {
                file: path.to_path_buf(),
                detail: e.to_string(),
            });
        }
    };
    let mut head = [0u8; 16];
    let mut n = 0;
    while n < head.len() {
        match file.read(&mut head[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) => {
                return Err(StoreError::Io {
                    file: path.to_path_buf(),
                    detail: e.to_string(),
                });
            }
        }
    }
    if &head[..n] != b"SQLite format 3\0" {
        let detail = if n == 0 {
            "the file is empty".to_string()
        } else {
            let shown: String = head[..n]
                .iter()
                .map(|&b| {
                    if b.is_ascii_graphic() || b == b' ' {
                        b as char
                    } else {
                        '.'
                    }
                })
                .collect();
            format!("it starts with \"{shown}\"")
        };
        return Err(StoreError::NotSqlite {
            file: path.to_path_buf(),
            detail,
        });
    }
    Ok(())
}

fn read_meta(conn: &Connection, path: &Path) -> Result<StoreMeta, StoreError> {
    let file = path.to_path_buf();
    let mut stmt =
        conn.prepare("SELECT key, value FROM meta")
            .map_err(|e| match e.sqlite_error_code() {
                Some(ErrorCode::Unknown) | None if e.to_string().contains("no such table") => {
                    StoreError::Foreign {
                        file: file.clone(),
                        detail: "it has the isochron application id but no meta table".into(),
                    }
                }
                _ => sql_err(path, e),
            })?;
    let rows: Vec<(String, String)> = stmt
        .query_map([], |r| Ok((r.get(0)?, r.get(1)?)))
        .and_then(|rows| rows.collect())
        .map_err(|e| sql_err(path, e))?;
    let get = |key: &str| rows.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str());
    if get("magic") != Some(MAGIC) {
        return Err(StoreError::Foreign {
            file,
            detail: "no isochron magic in its meta table".into(),
        });
    }
    let damaged = |detail: String| StoreError::Damaged {
        file: path.to_path_buf(),
        detail,
    };
    let stored_crc = get("crc").and_then(|v| v.parse::<u32>().ok());
    if stored_crc != Some(meta_crc(&rows)) {
        return Err(damaged("checksum mismatch in the meta table".into()));
    }
    let num = |key: &str| -> Result<i64, StoreError> {
        get(key)
            .and_then(|v| v.parse::<i64>().ok())
            .ok_or_else(|| damaged(format!("meta `{key}` is missing or not a number")))
    };
    let u32_of = |key: &str| -> Result<u32, StoreError> {
        let v = num(key)?;
        u32::try_from(v).map_err(|_| damaged(format!("meta `{key}` = {v} is out of range")))
    };
    let cycle = match get("cycle") {
        Some("daily") => Cycle::Daily,
        Some("weekly") => Cycle::Weekly,
        other => return Err(damaged(format!("meta `cycle` is {other:?}"))),
    };
    let meta = StoreMeta {
        camera: get("camera")
            .ok_or_else(|| damaged("meta `camera` is missing".into()))?
            .to_string(),
        grid: BlockGrid::new(
            u32_of("frame_width")?,
            u32_of("frame_height")?,
            u32_of("block_px")?,
        ),
        cycle,
        created_ns: num("created_ns")?,
    };
    if meta.grid.block_px == 0 || meta.blocks() == 0 {
        return Err(damaged("the grid has no blocks".into()));
    }
    let stated = (u32_of("grid_w")?, u32_of("grid_h")?);
    if stated != (meta.grid.grid_w(), meta.grid.grid_h()) {
        return Err(damaged(format!(
            "meta says a {}x{} grid, but {} has {}",
            stated.0,
            stated.1,
            meta.grid,
            meta.grid()
        )));
    }
    Ok(meta)
}

/// The columns [`RawBin::from_row`] reads.
const SELECT_BINS: &str = "SELECT t_star, count, last_minute, mean, var, crc FROM bins";

struct RawBin {
    t_star: i64,
    count: i64,
    last_minute: i64,
    mean: Vec<u8>,
    var: Vec<u8>,
    crc: i64,
}

impl RawBin {
    fn from_row(r: &rusqlite::Row<'_>) -> rusqlite::Result<RawBin> {
        Ok(RawBin {
            t_star: r.get(0)?,
            count: r.get(1)?,
            last_minute: r.get(2)?,
            mean: r.get(3)?,
            var: r.get(4)?,
            crc: r.get(5)?,
        })
    }

    fn into_bin(self, path: &Path, blocks: usize) -> Result<Bin, StoreError> {
        let damaged = |detail: String| StoreError::Damaged {
            file: path.to_path_buf(),
            detail,
        };
        let t = self.t_star;
        let (Ok(t_star), Ok(count)) = (u32::try_from(self.t_star), u32::try_from(self.count))
        else {
            return Err(damaged(format!("bin {t}: t* or count out of range")));
        };
        let (Some(mean), Some(var)) = (f32s_from(&self.mean, blocks), f32s_from(&self.var, blocks))
        else {
            return Err(damaged(format!(
                "bin {t}: {} and {} bytes of mean and variance, expected {} blocks of 4 bytes",
                self.mean.len(),
                self.var.len(),
                blocks
            )));
        };
        let bin = Bin {
            t_star,
            count,
            last_minute: self.last_minute,
            mean,
            var,
        };
        if bin.crc() as i64 != self.crc {
            return Err(damaged(format!("checksum mismatch in bin {t}")));
        }
        Ok(bin)
    }
}

/// CRC-32 of `parts`, one after the other.
fn crc_of(parts: &[&[u8]]) -> u32 {
    let mut h = crc32fast::Hasher::new();
    for part in parts {
        h.update(part);
    }
    h.finalize()
}

fn f32_bytes(values: &[f32]) -> Vec<u8> {
    let mut out = Vec::with_capacity(values.len() * 4);
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

fn f32s_from(bytes: &[u8], blocks: usize) -> Option<Vec<f32>> {
    (bytes.len() == blocks * 4).then(|| {
        bytes
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    })
}

/// Maps an SQLite error: corruption and "not a database" are damage, the rest I/O.
fn sql_err(path: &Path, e: rusqlite::Error) -> StoreError {
    let file = path.to_path_buf();
    match e.sqlite_error_code() {
        Some(ErrorCode::DatabaseCorrupt) => StoreError::Damaged {
            file,
            detail: format!("SQLite: {e}"),
        },
        Some(ErrorCode::NotADatabase) => StoreError::NotSqlite {
            file,
            detail: format!("SQLite: {e}"),
        },
        _ => StoreError::Io {
            file,
            detail: format!("SQLite: {e}"),
        },
    }
}

impl isochron_exit::Classify for StoreError {
    /// Foreign, damaged or mismatched files are permanent (restarting cannot
    /// help); I/O may pass.
    fn exit_code(&self) -> i32 {
        use StoreError as E;
        use isochron_exit::{CONFIG, DATA, UNAVAILABLE};
        match self {
            E::Damaged { .. } | E::NotSqlite { .. } => DATA,
            E::Foreign { .. }
            | E::Version { .. }
            | E::Camera { .. }
            | E::Grid { .. }
            | E::Cycle { .. } => CONFIG,
            E::Io { .. } | E::NotFound { .. } | E::ReadOnly { .. } => UNAVAILABLE,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use isochron_exit::Classify;

    /// Commits one minute, which must succeed.
    fn commit(store: &mut Store, minute: i64, bin: Option<&Bin>, baseline: Option<&Baseline>) {
        store
            .commit_minute(&MinuteCommit {
                minute,
                bin,
                baseline,
            })
            .unwrap();
    }

    fn meta(camera: &str) -> StoreMeta {
        StoreMeta::new(
            camera,
            BlockGrid::new(64, 48, 16),
            Cycle::Daily,
            1_700_000_000_000_000_000,
        )
    }

    fn bin(t_star: u32, count: u32, base: f32) -> Bin {
        Bin {
            t_star,
            count,
            last_minute: 29_000_000 + t_star as i64,
            mean: (0..12).map(|k| base + k as f32).collect(),
            var: (0..12).map(|k| 0.5 * k as f32).collect(),
        }
    }

    fn baseline() -> Baseline {
        Baseline {
            capture_ns: 42,
            frames: 1000,
            frame_rate: 29.97,
            level: vec![0.25; 12],
        }
    }

    #[test]
    fn round_trip_bins_baseline_progress() {
        let dir = tempfile::tempdir().unwrap();
        let path = store_path(dir.path(), "cam01");
        assert_eq!(path.file_name().unwrap(), "cam01.isochron.sqlite");
        let mut store = Store::open_or_create(&path, &meta("cam01")).unwrap();
        assert_eq!(store.read_bin(10).unwrap(), None);
        let b10 = bin(10, 1, 0.5);
        let b20 = bin(20, 3, 1.5);
        let bl = baseline();
        commit(&mut store, 100, Some(&b10), Some(&bl));
        commit(&mut store, 101, Some(&b20), None);
        commit(&mut store, 102, None, None);
        drop(store);

        let reader = Store::open_read_only(&path, "cam01").unwrap();
        assert_eq!(reader.meta(), &meta("cam01"));
        assert_eq!(reader.read_bin(10).unwrap(), Some(b10.clone()));
        assert_eq!(reader.read_bin(20).unwrap(), Some(b20.clone()));
        let model = reader.read_model().unwrap();
        assert_eq!(model.bins.len(), 1440);
        assert_eq!(model.learned().count(), 2);
        assert_eq!(model.bin(20), Some(&b20));
        assert_eq!(reader.read_baseline().unwrap(), Some(bl));
        assert_eq!(
            reader.progress().unwrap(),
            Progress {
                last_minute: Some(102),
                committed: 2,
                skipped: 1
            }
        );
        let report = reader.verify().unwrap();
        assert_eq!(report.bins, 2);
        assert!(report.baseline);
        assert!((b20.sigma(2) - 1.0).abs() < 1e-6);
        // Reopening for writing keeps everything; writing read-only is refused.
        let w = Store::open_writer(&path, "cam01", Cycle::Daily).unwrap();
        assert_eq!(w.read_bin(10).unwrap(), Some(b10));
        let mut reader = reader;
        assert!(matches!(
            reader.commit_minute(&MinuteCommit {
                minute: 1,
                bin: None,
                baseline: None
            }),
            Err(StoreError::ReadOnly { .. })
        ));
    }

    #[test]
    fn readers_see_commits_while_the_writer_is_open() {
        let dir = tempfile::tempdir().unwrap();
        let path = store_path(dir.path(), "cam01");
        let mut writer = Store::open_or_create(&path, &meta("cam01")).unwrap();
        let reader = Store::open_read_only(&path, "cam01").unwrap();
        for minute in 0..5u32 {
            let b = bin(minute, minute + 1, minute as f32);
            commit(&mut writer, minute as i64, Some(&b), None);
            assert_eq!(reader.read_bin(minute).unwrap(), Some(b));
            assert_eq!(reader.progress().unwrap().last_minute, Some(minute as i64));
        }
    }

    #[test]
    fn foreign_files_get_clear_errors() {
        let dir = tempfile::tempdir().unwrap();
        // Missing.
        let missing = dir.path().join("none.isochron.sqlite");
        let err = Store::open_read_only(&missing, "cam01").unwrap_err();
        assert!(matches!(err, StoreError::NotFound { .. }), "{err}");
        assert!(err.to_string().contains("site.state_dir"), "{err}");
        // Not SQLite.
        let text = dir.path().join("text.isochron.sqlite");
        std::fs::write(&text, "minute_of_day,mean\n1,2\n").unwrap();
        let err = Store::open_read_only(&text, "cam01").unwrap_err();
        assert!(matches!(err, StoreError::NotSqlite { .. }), "{err}");
        let msg = err.to_string();
        assert!(msg.contains("text.isochron.sqlite") && msg.contains("minute_of_day"));
        assert!(msg.contains("move it away"), "{msg}");
        let empty = dir.path().join("empty.isochron.sqlite");
        std::fs::write(&empty, "").unwrap();
        let err = Store::open_read_only(&empty, "cam01").unwrap_err();
        assert!(err.to_string().contains("empty"), "{err}");
        // Another application's SQLite database.
        let other = dir.path().join("other.sqlite");
        {
            let c = Connection::open(&other).unwrap();
            c.execute_batch("CREATE TABLE t (x); INSERT INTO t VALUES (1);")
                .unwrap();
        }
        let err = Store::open_read_only(&other, "cam01").unwrap_err();
        assert!(matches!(err, StoreError::Foreign { .. }), "{err}");
        assert!(err.to_string().contains("another application"), "{err}");
        // Another camera's store.
        let path = store_path(dir.path(), "cam02");
        Store::open_or_create(&path, &meta("cam02")).unwrap();
        let err = Store::open_read_only(&path, "cam01").unwrap_err();
        assert!(
            matches!(&err, StoreError::Camera { found, .. } if found == "cam02"),
            "{err}"
        );
        // Another grid.
        let mut wide = meta("cam02");
        wide.grid.frame_width = 80;
        let err = Store::open_or_create(&path, &wide).unwrap_err();
        assert!(matches!(err, StoreError::Grid { .. }), "{err}");
        assert!(err.to_string().contains("4x3"), "{err}");
        // Another cycle.
        let err = Store::open_writer(&path, "cam02", Cycle::Weekly).unwrap_err();
        assert!(matches!(err, StoreError::Cycle { .. }), "{err}");
        // Another format version.
        {
            let c = Connection::open(&path).unwrap();
            c.pragma_update(None, "user_version", 99).unwrap();
        }
        let err = Store::open_read_only(&path, "cam02").unwrap_err();
        assert!(
            matches!(err, StoreError::Version { found: 99, .. }),
            "{err}"
        );
        assert!(err.is_permanent());
    }

    #[test]
    fn damaged_rows_are_detected_never_used() {
        let dir = tempfile::tempdir().unwrap();
        let path = store_path(dir.path(), "cam01");
        let mut store = Store::open_or_create(&path, &meta("cam01")).unwrap();
        let b = bin(7, 2, 0.1);
        let bl = baseline();
        commit(&mut store, 7, Some(&b), Some(&bl));
        drop(store);
        // Flip one byte of the stored mean, as a bad disk sector would.
        {
            let c = Connection::open(&path).unwrap();
            let mut mean: Vec<u8> = c
                .query_row("SELECT mean FROM bins WHERE t_star = 7", [], |r| r.get(0))
                .unwrap();
            mean[5] ^= 0x40;
            c.execute("UPDATE bins SET mean = ?1 WHERE t_star = 7", params![mean])
                .unwrap();
        }
        let reader = Store::open_read_only(&path, "cam01").unwrap();
        let err = reader.read_bin(7).unwrap_err();
        assert!(matches!(err, StoreError::Damaged { .. }), "{err}");
        assert!(err.to_string().contains("bin 7"), "{err}");
        assert!(reader.read_model().is_err());
        assert!(reader.verify().is_err());
        let err = Store::open_writer(&path, "cam01", Cycle::Daily).unwrap_err();
        assert!(
            err.to_string().contains("restore it from a backup"),
            "{err}"
        );
        drop(reader);

        // A truncated blob and a tampered meta row.
        {
            let c = Connection::open(&path).unwrap();
            c.execute("UPDATE bins SET var = x'0000' WHERE t_star = 7", [])
                .unwrap();
        }
        let reader = Store::open_read_only(&path, "cam01").unwrap();
        assert!(matches!(
            reader.read_bin(7),
            Err(StoreError::Damaged { .. })
        ));
        drop(reader);
        {
            let c = Connection::open(&path).unwrap();
            c.execute("UPDATE meta SET value = '8' WHERE key = 'grid_w'", [])
                .unwrap();
        }
        let err = Store::open_read_only(&path, "cam01").unwrap_err();
        assert!(err.to_string().contains("meta"), "{err}");
    }

    #[test]
    fn garbage_in_the_middle_of_the_file_is_detected() {
        let dir = tempfile::tempdir().unwrap();
        let path = store_path(dir.path(), "cam01");
        let mut store = Store::open_or_create(&path, &meta("cam01")).unwrap();
        for t in 0..200 {
            let b = bin(t, 1, t as f32);
            commit(&mut store, t as i64, Some(&b), None);
        }
        drop(store); // checkpoints the WAL into the file
        let mut bytes = std::fs::read(&path).unwrap();
        assert!(bytes.len() > 8192, "{}", bytes.len());
        // Overwrite the middle of the file (past the header page) with noise.
        let mid = bytes.len() / 2;
        let mut x: u32 = 99;
        for b in &mut bytes[mid..mid + 2048] {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            *b = (x >> 16) as u8;
        }
        std::fs::write(&path, &bytes).unwrap();
        let result = Store::open_read_only(&path, "cam01").and_then(|s| s.verify());
        let err = result.unwrap_err();
        assert!(matches!(err, StoreError::Damaged { .. }), "{err}");
        assert!(err.to_string().contains(path.to_str().unwrap()), "{err}");
    }

    #[test]
    fn meta_describes_the_block_grid() {
        let m = meta("cam01");
        assert_eq!(m.grid, BlockGrid::new(64, 48, 16));
        assert_eq!((m.grid(), m.blocks()), ("4x3".to_string(), 12));
    }

    #[test]
    fn weekly_stores_have_a_week_of_bins() {
        let dir = tempfile::tempdir().unwrap();
        let path = store_path(dir.path(), "cam01");
        let mut m = meta("cam01");
        m.cycle = Cycle::Weekly;
        let mut store = Store::open_or_create(&path, &m).unwrap();
        let b = bin(10_000, 1, 0.0);
        commit(&mut store, 1, Some(&b), None);
        let model = store.read_model().unwrap();
        assert_eq!(model.bins.len(), 10_080);
        assert_eq!(model.bin(10_000), Some(&b));
        // A bin outside the cycle is refused.
        let bad = bin(10_080, 1, 0.0);
        assert!(
            store
                .commit_minute(&MinuteCommit {
                    minute: 2,
                    bin: Some(&bad),
                    baseline: None
                })
                .is_err()
        );
    }
}
