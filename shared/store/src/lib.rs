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
//! * `bins`: one row per row of the model ([`Cycle::rows`]: the minute bins t* of
//!   the cycle, and with day types the workday and rest-day profiles after them;
//!   [`isochronal`] says which rows a minute teaches) that has learned anything:
//!   count (days or weeks), the absolute minute that last taught it, mean and
//!   variance per block (f32 little-endian blobs), and a CRC-32 over all of it;
//! * `baseline`: the F_L1 baseline per block with its frame count, rate and time, and
//!   a CRC-32;
//! * `progress`: the last completed minute and how many minutes were committed or
//!   skipped (too few frames);
//! * `spans`: the minutes completed so far as merged spans ([`Spans`]), each with a
//!   CRC-32.
//!
//! **Crash safety.** The cascade writes one transaction per completed minute
//! ([`Store::commit_minute`]): the rows it taught, the baseline, the progress and
//! the spans together, or none of them. A crash at any moment loses at most the
//! minute in progress. A minute inside the completed spans teaches nothing again, so
//! data delivered twice (a replay, a restarted producer) never counts twice; a
//! minute outside them learns whatever its time (a clock corrected after running
//! ahead keeps learning).
//!
//! **Versions.** Format 2 added the day-type rows and the spans. A store of format 1
//! is refused with the command that converts it ([`migrate`], `isochron store
//! migrate`), which keeps everything it learned and the old file beside it.
//!
//! **Damage.** Opening checks that the file is SQLite, is an isochron store (not
//! another application's database), has this format version, belongs to the expected
//! camera and (for the writer) grid and cycle. Every row's CRC is checked when it is
//! read, and [`Store::verify`] checks them all plus SQLite's own `quick_check`. Each
//! failure is a [`StoreError`] that names the file and says what to do; damaged data
//! is never used silently.

use std::path::{Path, PathBuf};
use std::time::Duration;

use rusqlite::{Connection, OpenFlags, OptionalExtension, TransactionBehavior, params};

mod bin;
mod error;
mod file;
pub mod isochronal;
pub mod migrate;
mod model;
mod rows;
mod spans;

#[cfg(test)]
mod tests;

pub use bin::Bin;
pub use error::StoreError;
pub use isochronal::Rules;
pub use model::{Baseline, MinuteCommit, Model, Progress, StoreMeta, VerifyReport};
pub use spans::Spans;

use error::sql_err;
use file::{check_sqlite_header, create, read_meta};
use rows::{RawBin, SELECT_BINS, f32_bytes, f32s_from, insert_bin, span_crc};

use isochron_config::clock::Cycle;
use isochron_wire::geometry::BlockGrid;

/// File name suffix of a store: `<camera>.isochron.sqlite`.
pub const FILE_SUFFIX: &str = ".isochron.sqlite";
/// SQLite `application_id` of an isochron store: the bytes `ISOC`.
pub const APPLICATION_ID: i32 = i32::from_be_bytes(*b"ISOC");
/// Version of the store's layout. Bump it on any change to the tables or blobs.
pub const FORMAT_VERSION: u32 = 2;
/// Value of the `magic` meta row.
const MAGIC: &str = "isochron-store";
/// How long a connection waits for a lock (WAL recovery, checkpoints).
const BUSY_TIMEOUT: Duration = Duration::from_secs(5);

/// The store file of `camera` under `state_dir`.
pub fn store_path(state_dir: &Path, camera: &str) -> PathBuf {
    state_dir.join(format!("{camera}{FILE_SUFFIX}"))
}

/// An open store: the cascade's writer, or a reader (read-only).
pub struct Store {
    conn: Connection,
    path: PathBuf,
    meta: StoreMeta,
    read_only: bool,
    /// The completed minutes (the writer's; empty for a reader).
    spans: Spans,
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
        store.check_cycle(cycle)?;
        store.verify()?;
        Ok(store)
    }

    /// Refuses a store of another cycle than `cycle` (`cascade.cycle`): its rows
    /// mean other minutes.
    pub fn check_cycle(&self, cycle: Cycle) -> Result<(), StoreError> {
        if self.meta.cycle == cycle {
            return Ok(());
        }
        Err(StoreError::Cycle {
            file: self.path.clone(),
            expected: cycle.name().into(),
            found: self.meta.cycle.name().into(),
        })
    }

    /// Opens an existing store read-only, e.g. while the cascade writes it. It must
    /// belong to `camera`. Rows are checked as they are read.
    pub fn open_read_only(path: &Path, camera: &str) -> Result<Store, StoreError> {
        Store::open(path, camera, true)
    }

    /// Opens `path` (checked first: the header, then the application id,
    /// the format version and the camera). A read-only open on read-only media
    /// (a write-protected card, a read-only mount), where SQLite cannot make
    /// the shared-memory file WAL mode reads through, reads the file as
    /// immutable: what its writer last checkpointed (all of it, for a writer
    /// that closed).
    fn open(path: &Path, camera: &str, read_only: bool) -> Result<Store, StoreError> {
        let file = path.to_path_buf();
        check_sqlite_header(path, camera)?;
        let flags = if read_only {
            OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX
        } else {
            OpenFlags::SQLITE_OPEN_READ_WRITE | OpenFlags::SQLITE_OPEN_NO_MUTEX
        };
        let (conn, app) = match connect(path, flags) {
            Err(_) if read_only && on_read_only_media(path) => {
                connect_immutable(path).map_err(|e| sql_err(path, e))?
            }
            other => other.map_err(|e| sql_err(path, e))?,
        };
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
            // SQLite opens a file it cannot write read-only without a word; the
            // writer would fail at its first commit.
            if conn
                .is_readonly(rusqlite::MAIN_DB)
                .map_err(|e| sql_err(path, e))?
            {
                return Err(StoreError::NotWritable {
                    file,
                    detail: "SQLite could open it only read-only: its mode or owner, a read-only mount, or a header written by a newer SQLite".into(),
                });
            }
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
        let mut store = Store {
            conn,
            path: file,
            meta,
            read_only,
            spans: Spans::default(),
        };
        if !read_only {
            store.spans = store.read_spans()?;
        }
        Ok(store)
    }

    /// The `spans` table, every row's checksum verified.
    fn read_spans(&self) -> Result<Spans, StoreError> {
        let mut stmt = self.statement("SELECT start, end, crc FROM spans")?;
        let rows = stmt
            .query_map([], |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, i64>(1)?,
                    r.get::<_, i64>(2)?,
                ))
            })
            .map_err(|e| sql_err(&self.path, e))?;
        let mut spans = Vec::new();
        for row in rows {
            let (start, end, crc) = row.map_err(|e| sql_err(&self.path, e))?;
            if span_crc(start, end) as i64 != crc || start > end {
                return Err(StoreError::Damaged {
                    file: self.path.clone(),
                    detail: format!("checksum mismatch in the span of minutes {start}..{end}"),
                });
            }
            spans.push((start, end));
        }
        Ok(Spans::from_rows(spans))
    }

    /// The minutes completed so far (empty for a reader).
    pub fn spans(&self) -> &Spans {
        &self.spans
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

    /// Row `t_star` of the model ([`Bin::t_star`]), if it has learned anything. Its
    /// checksum is verified.
    pub fn read_bin(&self, t_star: u32) -> Result<Option<Bin>, StoreError> {
        let mut stmt = self.statement(&format!("{SELECT_BINS} WHERE t_star = ?1"))?;
        let raw = stmt
            .query_row(params![t_star as i64], RawBin::from_row)
            .optional()
            .map_err(|e| sql_err(&self.path, e))?;
        raw.map(|r| r.into_bin(&self.path, self.meta.blocks()))
            .transpose()
    }

    /// The whole model, every row's checksum verified, read with its cycle's default
    /// rules ([`Model::with_rules`] gives the site's).
    pub fn read_model(&self) -> Result<Model, StoreError> {
        let bins_n = self.meta.rows() as usize;
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
                    detail: format!("bin {t} is outside the {bins_n} rows of the model"),
                });
            }
            bins[t] = Some(bin);
        }
        let mut model = Model::with_bins(self.meta.clone(), []);
        model.bins = bins;
        Ok(model)
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
        self.read_spans()?;
        let model = self.read_model()?;
        let baseline = self.read_baseline()?;
        Ok(VerifyReport {
            bins: model.learned().count(),
            baseline: baseline.is_some(),
            progress: self.progress()?,
        })
    }

    /// Commits a hand-made minute: absolute minute `t_star` teaches row `t_star` the
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
            bins: std::slice::from_ref(&bin),
            baseline: None,
        })
    }

    /// Writes one completed minute atomically and durably: the new state of the rows
    /// it taught, the baseline, the progress and the completed spans. When this
    /// returns `Ok`, the minute survives a crash or power cut.
    pub fn commit_minute(&mut self, commit: &MinuteCommit<'_>) -> Result<(), StoreError> {
        if self.read_only {
            return Err(StoreError::ReadOnly {
                file: self.path.clone(),
            });
        }
        let blocks = self.meta.blocks();
        let bins = self.meta.rows();
        let path = self.path.clone();
        let err = |e: rusqlite::Error| sql_err(&path, e);
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .map_err(err)?;
        for bin in commit.bins {
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
            insert_bin(&tx, bin).map_err(err)?;
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
        let (committed, skipped) = if commit.bins.is_empty() {
            (0, 1)
        } else {
            (1, 0)
        };
        tx.prepare_cached(
            "UPDATE progress SET last_minute = max(coalesce(last_minute, ?1), ?1), committed = committed + ?2, skipped = skipped + ?3 WHERE id = 0",
        )
        .map_err(err)?
        .execute(params![commit.minute, committed, skipped])
        .map_err(err)?;
        let (start, end) = self.spans.merged(commit.minute);
        tx.prepare_cached("DELETE FROM spans WHERE start BETWEEN ?1 AND ?2")
            .map_err(err)?
            .execute(params![start, end])
            .map_err(err)?;
        tx.prepare_cached("INSERT INTO spans (start, end, crc) VALUES (?1, ?2, ?3)")
            .map_err(err)?
            .execute(params![start, end, span_crc(start, end) as i64])
            .map_err(err)?;
        tx.commit().map_err(err)?;
        self.spans.add(commit.minute);
        Ok(())
    }
}

/// A connection to `path` with `flags`, and the file's application id (the
/// first read: where opening a WAL database without its shared memory fails).
fn connect(path: &Path, flags: OpenFlags) -> rusqlite::Result<(Connection, i32)> {
    let conn = Connection::open_with_flags(path, flags)?;
    conn.busy_timeout(BUSY_TIMEOUT)?;
    let app = conn.pragma_query_value(None, "application_id", |r| r.get(0))?;
    Ok((conn, app))
}

/// [`connect`] read-only to a file nothing can write (SQLite's `immutable`).
fn connect_immutable(path: &Path) -> rusqlite::Result<(Connection, i32)> {
    let mut uri = url_path(path);
    uri.insert_str(0, "file:");
    uri.push_str("?immutable=1");
    connect(
        Path::new(&uri),
        OpenFlags::SQLITE_OPEN_READ_ONLY
            | OpenFlags::SQLITE_OPEN_NO_MUTEX
            | OpenFlags::SQLITE_OPEN_URI,
    )
}

/// `path`, absolute, with the characters a URI reserves percent-encoded.
fn url_path(path: &Path) -> String {
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut out = String::new();
    for b in absolute.as_os_str().as_encoded_bytes() {
        match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'/' | b'-' | b'_' | b'.' | b'~' => {
                out.push(*b as char)
            }
            _ => out.push_str(&format!("%{b:02X}")),
        }
    }
    out
}

/// True if the directory of `path` cannot be written (a read-only file system,
/// or no write permission): no writer can be changing the file.
fn on_read_only_media(path: &Path) -> bool {
    use std::os::unix::ffi::OsStrExt;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let Ok(c) = std::ffi::CString::new(dir.as_os_str().as_bytes()) else {
        return false;
    };
    // SAFETY: a valid NUL-terminated path.
    unsafe { libc::access(c.as_ptr(), libc::W_OK) != 0 }
}
