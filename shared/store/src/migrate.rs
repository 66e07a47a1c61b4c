//! Converting a store to this format and to another cycle, keeping what it learned
//! (`isochron store migrate`).
//!
//! A store of format 1 (daily or weekly, no spans) or of this format with another
//! cycle is rewritten into a new file of this format with the target cycle; the old
//! file is renamed beside it (`<file>.v1`, or `<file>.<old cycle>`), so nothing is
//! lost. What carries over:
//!
//! * into **day types**: a weekly model's weekdays become the weekday rows, and each
//!   day type's profile is the mixture of its weekdays (weighted by how much each
//!   learned); a daily model becomes both day types' profiles (its weekdays start
//!   empty and learn from the next weeks);
//! * into **weekly**: each weekday is the old model's forecast for it;
//! * into **daily**: each minute is the mixture of the old model's weekdays;
//! * the F_L1 baseline and the progress as they were; the completed minutes as one
//!   span from the earliest to the latest minute any row learned (format 1 did not
//!   record them), so replaying the same data again teaches nothing twice.

use std::path::{Path, PathBuf};

use isochron_config::clock::{Cycle, MINUTES_PER_DAY};
use rusqlite::{Connection, OpenFlags, OptionalExtension, params};

use crate::error::sql_err;
use crate::file::{check_sqlite_header, create, read_meta};
use crate::isochronal::{DayType, mix};
use crate::rows::{RawBin, SELECT_BINS, insert_bin, span_crc};
use crate::{APPLICATION_ID, Bin, FORMAT_VERSION, Model, Rules, StoreError, StoreMeta};

/// What [`migrate`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct Migrated {
    /// The format version the file had.
    pub from_version: i64,
    /// The cycle it had.
    pub from_cycle: Cycle,
    /// The cycle it has now.
    pub to_cycle: Cycle,
    /// Rows it holds now.
    pub rows: usize,
    /// Where the old file is now; `None` when nothing had to change.
    pub backup: Option<PathBuf>,
}

/// Converts the store of `camera` at `path` to this format and `rules`' cycle,
/// keeping everything it learned (module doc). Stop the cascade first: the file is
/// replaced.
pub fn migrate(path: &Path, camera: &str, rules: &Rules) -> Result<Migrated, StoreError> {
    check_sqlite_header(path, camera)?;
    let sql = |e| sql_err(path, e);
    let conn = Connection::open_with_flags(path, OpenFlags::SQLITE_OPEN_READ_WRITE).map_err(sql)?;
    let app: i32 = conn
        .pragma_query_value(None, "application_id", |r| r.get(0))
        .map_err(sql)?;
    if app != APPLICATION_ID {
        return Err(StoreError::Foreign {
            file: path.to_path_buf(),
            detail: format!("application_id {app:#010x}"),
        });
    }
    let version: i64 = conn
        .pragma_query_value(None, "user_version", |r| r.get(0))
        .map_err(sql)?;
    if !(1..=FORMAT_VERSION as i64).contains(&version) {
        return Err(StoreError::Version {
            file: path.to_path_buf(),
            found: version,
        });
    }
    let meta = read_meta(&conn, path)?;
    if meta.camera != camera {
        return Err(StoreError::Camera {
            file: path.to_path_buf(),
            expected: camera.to_string(),
            found: meta.camera,
        });
    }
    let old = read_rows(&conn, path, &meta)?;
    let to = rules.cycle();
    if version == FORMAT_VERSION as i64 && meta.cycle == to {
        return Ok(Migrated {
            from_version: version,
            from_cycle: meta.cycle,
            to_cycle: to,
            rows: old.learned().count(),
            backup: None,
        });
    }
    let rows = convert(&old, rules);
    let spans = if version == FORMAT_VERSION as i64 {
        read_span_rows(&conn, path)?
    } else {
        old.learned()
            .map(|b| b.last_minute)
            .min()
            .zip(old.learned().map(|b| b.last_minute).max())
            .into_iter()
            .collect()
    };
    // Fold the WAL into the old file, so that the renamed backup is whole.
    conn.pragma_update(None, "wal_checkpoint", "TRUNCATE")
        .map_err(sql)?;
    let tmp = path.with_extension(format!("migrating-{}", std::process::id()));
    let _ = std::fs::remove_file(&tmp);
    let new_meta = StoreMeta {
        cycle: to,
        ..meta.clone()
    };
    create(&tmp, &new_meta)?;
    copy_into(&conn, path, &tmp, &rows, &spans)?;
    drop(conn);
    let backup = if version == FORMAT_VERSION as i64 {
        path.with_extension(format!("sqlite.{}", meta.cycle.name()))
    } else {
        path.with_extension(format!("sqlite.v{version}"))
    };
    let io = |e: std::io::Error| StoreError::Io {
        file: path.to_path_buf(),
        detail: e.to_string(),
    };
    std::fs::rename(path, &backup).map_err(io)?;
    for ext in ["-wal", "-shm"] {
        let mut side = path.as_os_str().to_owned();
        side.push(ext);
        let _ = std::fs::remove_file(PathBuf::from(side));
    }
    std::fs::rename(&tmp, path).map_err(io)?;
    Ok(Migrated {
        from_version: version,
        from_cycle: meta.cycle,
        to_cycle: to,
        rows: rows.len(),
        backup: Some(backup),
    })
}

/// Every row of an open store of any version, checked.
fn read_rows(conn: &Connection, path: &Path, meta: &StoreMeta) -> Result<Model, StoreError> {
    let mut stmt = conn.prepare(SELECT_BINS).map_err(|e| sql_err(path, e))?;
    let raws = stmt
        .query_map([], RawBin::from_row)
        .map_err(|e| sql_err(path, e))?;
    let mut bins = Vec::new();
    for raw in raws {
        let bin = raw
            .map_err(|e| sql_err(path, e))?
            .into_bin(path, meta.blocks())?;
        if bin.t_star >= meta.rows() {
            return Err(StoreError::Damaged {
                file: path.to_path_buf(),
                detail: format!("bin {} is outside the model", bin.t_star),
            });
        }
        bins.push(bin);
    }
    Ok(Model::with_bins(meta.clone(), bins))
}

fn read_span_rows(conn: &Connection, path: &Path) -> Result<Vec<(i64, i64)>, StoreError> {
    let mut stmt = conn
        .prepare("SELECT start, end FROM spans")
        .map_err(|e| sql_err(path, e))?;
    stmt.query_map([], |r| Ok((r.get(0)?, r.get(1)?)))
        .and_then(|rows| rows.collect())
        .map_err(|e| sql_err(path, e))
}

/// The rows of `old` as a model of `rules`' cycle (module doc).
pub fn convert(old: &Model, rules: &Rules) -> Vec<Bin> {
    let from = old.meta.cycle;
    let to = rules.cycle();
    if from == to {
        return old.learned().cloned().collect();
    }
    let forecast = |t: u32| old.bin(t).map(|b| b.into_owned());
    let mut out = Vec::new();
    let mixed = |days: &[u32], minute: u32, row: u32| -> Option<Bin> {
        let parts: Vec<Bin> = days
            .iter()
            .filter_map(|&d| forecast(d * MINUTES_PER_DAY + minute))
            .collect();
        let total: f64 = parts.iter().map(|b| b.count as f64).sum();
        (total > 0.0).then(|| {
            let weighted: Vec<(&Bin, f64)> =
                parts.iter().map(|b| (b, b.count as f64 / total)).collect();
            let mut bin = mix(&weighted, total.min(u32::MAX as f64) as u32);
            bin.t_star = row;
            bin
        })
    };
    let all_days: Vec<u32> = (0..7).collect();
    for minute in 0..MINUTES_PER_DAY {
        match to {
            Cycle::Daily => out.extend(mixed(&all_days, minute, minute)),
            Cycle::Weekly => {
                for d in 0..7 {
                    let t = d * MINUTES_PER_DAY + minute;
                    out.extend(forecast(t).map(|mut b| {
                        b.t_star = t;
                        b
                    }));
                }
            }
            Cycle::DayTypes => {
                if from == Cycle::Weekly {
                    for d in 0..7 {
                        out.extend(old.row(d * MINUTES_PER_DAY + minute).cloned());
                    }
                }
                for kind in DayType::ALL {
                    let row = kind.first_row() + minute;
                    let bin = if from == Cycle::Daily {
                        old.row(minute).cloned().map(|mut b| {
                            b.t_star = row;
                            b
                        })
                    } else {
                        let days: Vec<u32> =
                            (0..7).filter(|&d| rules.weekday_type(d) == kind).collect();
                        mixed(&days, minute, row)
                    };
                    out.extend(bin);
                }
            }
        }
    }
    out
}

/// Writes `rows`, the baseline and progress of `old`, and `spans` into the new store
/// at `tmp`, in one transaction.
fn copy_into(
    old: &Connection,
    path: &Path,
    tmp: &Path,
    rows: &[Bin],
    spans: &[(i64, i64)],
) -> Result<(), StoreError> {
    let sql = |e| sql_err(path, e);
    let baseline: Option<(i64, i64, f64, Vec<u8>, i64)> = old
        .query_row(
            "SELECT capture_ns, frames, frame_rate, level, crc FROM baseline WHERE id = 0",
            [],
            |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?)),
        )
        .optional()
        .map_err(sql)?;
    let progress: (Option<i64>, i64, i64) = old
        .query_row(
            "SELECT last_minute, committed, skipped FROM progress WHERE id = 0",
            [],
            |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)),
        )
        .map_err(sql)?;
    let mut new = Connection::open(tmp).map_err(|e| sql_err(tmp, e))?;
    let write = |new: &mut Connection| -> rusqlite::Result<()> {
        let tx = new.transaction()?;
        for b in rows {
            insert_bin(&tx, b)?;
        }
        if let Some((capture_ns, frames, rate, level, crc)) = &baseline {
            tx.execute(
                "INSERT INTO baseline (id, capture_ns, frames, frame_rate, level, crc) VALUES (0, ?1, ?2, ?3, ?4, ?5)",
                params![capture_ns, frames, rate, level, crc],
            )?;
        }
        tx.execute(
            "UPDATE progress SET last_minute = ?1, committed = ?2, skipped = ?3 WHERE id = 0",
            params![progress.0, progress.1, progress.2],
        )?;
        for &(start, end) in spans {
            tx.execute(
                "INSERT INTO spans (start, end, crc) VALUES (?1, ?2, ?3)",
                params![start, end, span_crc(start, end) as i64],
            )?;
        }
        tx.commit()
    };
    write(&mut new).map_err(|e| sql_err(tmp, e))?;
    drop(new);
    std::fs::File::open(tmp)
        .and_then(|f| f.sync_all())
        .map_err(|e| StoreError::Io {
            file: tmp.to_path_buf(),
            detail: e.to_string(),
        })
}
