//! How bins and the baseline are stored in their rows: little-endian f32 blobs and
//! a CRC-32 over each row.

use std::path::Path;

use crate::{Baseline, Bin, StoreError};

/// The columns [`RawBin::from_row`] reads.
pub(crate) const SELECT_BINS: &str = "SELECT t_star, count, last_minute, mean, var, crc FROM bins";

/// A `bins` row as SQLite returns it, not yet checked.
pub(crate) struct RawBin {
    t_star: i64,
    count: i64,
    last_minute: i64,
    mean: Vec<u8>,
    var: Vec<u8>,
    crc: i64,
}

impl RawBin {
    /// Reads the columns of [`SELECT_BINS`].
    pub(crate) fn from_row(r: &rusqlite::Row<'_>) -> rusqlite::Result<RawBin> {
        Ok(RawBin {
            t_star: r.get(0)?,
            count: r.get(1)?,
            last_minute: r.get(2)?,
            mean: r.get(3)?,
            var: r.get(4)?,
            crc: r.get(5)?,
        })
    }

    /// The bin, its sizes and checksum checked.
    pub(crate) fn into_bin(self, path: &Path, blocks: usize) -> Result<Bin, StoreError> {
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
pub(crate) fn crc_of(parts: &[&[u8]]) -> u32 {
    let mut h = crc32fast::Hasher::new();
    for part in parts {
        h.update(part);
    }
    h.finalize()
}

/// Writes `bin` as its `bins` row (replacing one of the same row), with its CRC.
pub(crate) fn insert_bin(tx: &rusqlite::Transaction<'_>, bin: &Bin) -> rusqlite::Result<()> {
    tx.prepare_cached(
        "INSERT OR REPLACE INTO bins (t_star, count, last_minute, mean, var, crc) VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
    )?
    .execute(rusqlite::params![
        bin.t_star as i64,
        bin.count as i64,
        bin.last_minute,
        f32_bytes(&bin.mean),
        f32_bytes(&bin.var),
        bin.crc() as i64
    ])?;
    Ok(())
}

/// The CRC-32 of a `spans` row.
pub(crate) fn span_crc(start: i64, end: i64) -> u32 {
    crc_of(&[&start.to_le_bytes(), &end.to_le_bytes()])
}

/// `values` as little-endian bytes.
pub(crate) fn f32_bytes(values: &[f32]) -> Vec<u8> {
    let mut out = Vec::with_capacity(values.len() * 4);
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// `blocks` little-endian f32 values from `bytes`, if it has exactly that many.
pub(crate) fn f32s_from(bytes: &[u8], blocks: usize) -> Option<Vec<f32>> {
    (bytes.len() == blocks * 4).then(|| {
        bytes
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    })
}

impl Bin {
    /// The CRC-32 its row carries.
    pub(crate) fn crc(&self) -> u32 {
        crc_of(&[
            &self.t_star.to_le_bytes(),
            &self.count.to_le_bytes(),
            &self.last_minute.to_le_bytes(),
            &f32_bytes(&self.mean),
            &f32_bytes(&self.var),
        ])
    }
}

impl Baseline {
    /// The CRC-32 its row carries.
    pub(crate) fn crc(&self) -> u32 {
        crc_of(&[
            &self.capture_ns.to_le_bytes(),
            &self.frames.to_le_bytes(),
            &self.frame_rate.to_le_bytes(),
            &f32_bytes(&self.level),
        ])
    }
}
