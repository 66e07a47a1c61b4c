//! The store file: its schema, its atomic creation, and the checks that it is an
//! isochron store of this format (SQLite header, meta table and its CRC).

use std::io::Read;
use std::path::Path;

use isochron_config::clock::{Cycle, format_rfc3339};
use isochron_wire::geometry::BlockGrid;
use rusqlite::{Connection, ErrorCode, params};

use crate::error::sql_err;
use crate::{APPLICATION_ID, FORMAT_VERSION, MAGIC, StoreError, StoreMeta};

/// The tables of a new store.
pub(crate) const SCHEMA: &str = "
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
CREATE TABLE spans (
    start INTEGER PRIMARY KEY NOT NULL,
    end INTEGER NOT NULL,
    crc INTEGER NOT NULL
);
";

impl StoreMeta {
    /// The rows of the file's `meta` table (without its `crc`).
    pub(crate) fn meta_rows(&self) -> Vec<(&'static str, String)> {
        vec![
            ("magic", MAGIC.to_string()),
            ("format_version", FORMAT_VERSION.to_string()),
            ("camera", self.camera.clone()),
            ("grid_w", self.grid.grid_w().to_string()),
            ("grid_h", self.grid.grid_h().to_string()),
            ("block_px", self.grid.block_px.to_string()),
            ("frame_width", self.grid.frame_width.to_string()),
            ("frame_height", self.grid.frame_height.to_string()),
            ("cycle", self.cycle.name().to_string()),
            ("created", format_rfc3339(self.created_ns)),
            ("created_ns", self.created_ns.to_string()),
        ]
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

/// Creates a store atomically: built under a temporary name, then renamed into place,
/// so a crash during creation never leaves a half-made store behind.
pub(crate) fn create(path: &Path, meta: &StoreMeta) -> Result<(), StoreError> {
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
                .meta_rows()
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
pub(crate) fn check_sqlite_header(path: &Path, camera: &str) -> Result<(), StoreError> {
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

/// The meta table of an open store, its CRC and its grid checked.
pub(crate) fn read_meta(conn: &Connection, path: &Path) -> Result<StoreMeta, StoreError> {
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
    let Some(cycle) = get("cycle").and_then(Cycle::from_name) else {
        return Err(damaged(format!("meta `cycle` is {:?}", get("cycle"))));
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
