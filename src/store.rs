//! The vehicle config store (std): a directory holding the calibration in force and a
//! bounded history, written so that a power loss at any instant leaves the old or the
//! new record, never a mix.
//!
//! ```text
//! STORE/current.json            the calibration in force (result schema + generation, time, crc32)
//! STORE/camera.yaml             OpenCV FileStorage: camera_matrix, distortion_coefficients
//! STORE/extrinsic.yaml          OpenCV FileStorage: lidar_to_camera rotation/translation (4×4)
//! STORE/history/gen-000042.json every accepted generation (the newest `keep` kept)
//! STORE/rejected/run-….json     rejected runs (the newest `keep` kept); never in force
//! ```
//!
//! Every file is written atomically and durably: a temporary file in the same directory,
//! written, fsync'ed, renamed over the target, then the directory fsync'ed. A generation is
//! written to `history/` before `current.json`, so a valid `current.json` always has its
//! copy in history. `crc32` is the CRC-32 (IEEE) of the record's canonical JSON — the
//! file's bytes before the `"crc32"` member with the closing brace appended, which is
//! exactly `serde_json`'s pretty form of the record without it — written as 8 hex digits.
//! A `current.json` that does not parse or fails its checksum is replaced by the newest
//! valid generation in history (with a warning). Rollback writes the previous generation's
//! calibration again as a *new* generation (generations only grow, so consumers can
//! detect every change); its `"restored_from"` names the generation copied, and a second
//! rollback goes one further back.

use std::fs::{self, File};
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::result::{CalibrationResult, Status};

/// Generations and rejected runs kept by default.
pub const DEFAULT_KEEP: usize = 16;

/// One stored calibration: the result file plus the store's bookkeeping.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Record {
    #[serde(flatten)]
    pub result: CalibrationResult,
    /// +1 per accepted run (and per rollback); 0 is never written.
    pub generation: u32,
    /// Unix seconds when the record was written.
    pub time: u64,
    /// Generation whose calibration a rollback copied.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub restored_from: Option<u32>,
}

/// Errors of the store; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("store {path}: {source}")]
    Io { path: PathBuf, source: io::Error },
    #[error("store {path}: {message}")]
    Corrupt { path: PathBuf, message: String },
    #[error("store: only accepted results can be committed (got a rejected one)")]
    NotAccepted,
    #[error("store {dir}: no earlier generation to roll back to")]
    NoPrevious { dir: PathBuf },
}

/// The store directory.
#[derive(Clone, Debug)]
pub struct Store {
    dir: PathBuf,
    keep: usize,
}

impl Store {
    /// Opens (creating if needed) the store at `dir`, keeping `keep` generations and
    /// `keep` rejected runs (at least 2).
    pub fn open(dir: impl Into<PathBuf>, keep: usize) -> Result<Store, StoreError> {
        let store = Store { dir: dir.into(), keep: keep.max(2) };
        for d in [store.dir.clone(), store.history_dir(), store.rejected_dir()] {
            fs::create_dir_all(&d).map_err(|source| StoreError::Io { path: d.clone(), source })?;
        }
        Ok(store)
    }

    /// The store directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Path of `current.json`.
    pub fn current_path(&self) -> PathBuf {
        self.dir.join("current.json")
    }

    /// The calibration in force; `None` before the first accepted run. A corrupt or
    /// missing `current.json` is repaired from the newest valid generation in history.
    pub fn current(&self) -> Result<Option<Record>, StoreError> {
        let path = self.current_path();
        match read_record(&path) {
            Ok(Some(r)) => return Ok(Some(r)),
            Ok(None) => {}
            Err(e) => tracing::warn!("{e}; falling back to the newest valid generation"),
        }
        let Some(newest) = self.history()?.into_iter().next_back() else {
            return Ok(None);
        };
        // Missing with a history: a crash between the history write and the first install.
        tracing::warn!(
            "{}: restored generation {} from history",
            path.display(),
            newest.generation
        );
        write_atomic(&path, &encode(&newest))?;
        Ok(Some(newest))
    }

    /// Valid generations in history, oldest first (invalid files are skipped with a warning).
    pub fn history(&self) -> Result<Vec<Record>, StoreError> {
        let mut out = Vec::new();
        for path in list_json(&self.history_dir())? {
            match read_record(&path) {
                Ok(Some(r)) => out.push(r),
                Ok(None) => {}
                Err(e) => tracing::warn!("{e}; skipped"),
            }
        }
        out.sort_by_key(|r| r.generation);
        Ok(out)
    }

    /// Rejected runs kept, oldest first.
    pub fn rejected(&self) -> Result<Vec<Record>, StoreError> {
        let mut out = Vec::new();
        for path in list_json(&self.rejected_dir())? {
            if let Ok(Some(r)) = read_record(&path) {
                out.push(r);
            }
        }
        Ok(out)
    }

    /// Puts an accepted result in force as the next generation, written at `now` (unix
    /// seconds); returns the record written.
    pub fn commit(&self, result: &CalibrationResult, now: u64) -> Result<Record, StoreError> {
        if result.status != Status::Accepted {
            return Err(StoreError::NotAccepted);
        }
        let record = Record {
            result: result.clone(),
            generation: self.next_generation()?,
            time: now,
            restored_from: None,
        };
        self.install(&record)?;
        Ok(record)
    }

    /// Keeps a rejected run beside the history (never in force); returns its path.
    pub fn record_rejected(
        &self,
        result: &CalibrationResult,
        now: u64,
    ) -> Result<PathBuf, StoreError> {
        let generation = self.current()?.map_or(0, |r| r.generation);
        let record = Record { result: result.clone(), generation, time: now, restored_from: None };
        let seq = list_json(&self.rejected_dir())?.len();
        let mut path = self.rejected_dir().join(format!("run-{now:012}-{seq:04}.json"));
        let mut n = seq;
        while path.exists() {
            n += 1;
            path = self.rejected_dir().join(format!("run-{now:012}-{n:04}.json"));
        }
        write_atomic(&path, &encode(&record))?;
        prune(&self.rejected_dir(), self.keep)?;
        Ok(path)
    }

    /// Puts the generation before the one in force back in force, as a new generation
    /// written at `now`; returns it.
    pub fn rollback(&self, now: u64) -> Result<Record, StoreError> {
        let no_previous = || StoreError::NoPrevious { dir: self.dir.clone() };
        let current = self.current()?.ok_or_else(no_previous)?;
        // Undo chains: rolling back a restored copy goes before the generation it copied.
        let below = current.restored_from.unwrap_or(current.generation);
        let history = self.history()?;
        let previous = history
            .iter()
            .rev()
            .find(|r| r.generation < below && r.restored_from.is_none())
            .ok_or_else(no_previous)?;
        let record = Record {
            result: previous.result.clone(),
            generation: self.next_generation()?,
            time: now,
            restored_from: Some(previous.generation),
        };
        self.install(&record)?;
        Ok(record)
    }

    fn history_dir(&self) -> PathBuf {
        self.dir.join("history")
    }

    fn rejected_dir(&self) -> PathBuf {
        self.dir.join("rejected")
    }

    /// The generation the next commit or rollback will write: one more than any in force
    /// or in history, so file names never clash.
    pub fn next_generation(&self) -> Result<u32, StoreError> {
        let cur = self.current()?.map_or(0, |r| r.generation);
        let hist = self.history()?.last().map_or(0, |r| r.generation);
        Ok(cur.max(hist).saturating_add(1))
    }

    /// History first, then current, then the YAML views, then pruning.
    fn install(&self, record: &Record) -> Result<(), StoreError> {
        let bytes = encode(record);
        let hist = self.history_dir().join(format!("gen-{:06}.json", record.generation));
        write_atomic(&hist, &bytes)?;
        write_atomic(&self.current_path(), &bytes)?;
        write_atomic(&self.dir.join("camera.yaml"), camera_yaml(&record.result).as_bytes())?;
        if let Some(yaml) = extrinsic_yaml(&record.result) {
            write_atomic(&self.dir.join("extrinsic.yaml"), yaml.as_bytes())?;
        }
        crate::export::write_each(&self.dir, &record.result, write_atomic)?;
        prune(&self.history_dir(), self.keep)
    }
}

/// CRC-32 (IEEE 802.3, reflected, polynomial 0xEDB88320), as zlib's `crc32`.
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            // Branch-free: subtract 1 from 0 gives the all-ones mask when the low bit is set.
            let mask = (crc & 1).wrapping_neg();
            crc = (crc >> 1) ^ (0xEDB8_8320 & mask);
        }
    }
    !crc
}

/// The file bytes of a record: its pretty JSON with a trailing `"crc32"` member.
pub fn encode(record: &Record) -> Vec<u8> {
    // Serialising plain data into a String cannot fail.
    let canonical = serde_json::to_string_pretty(record).unwrap_or_default();
    let body = canonical.strip_suffix("\n}").unwrap_or(&canonical);
    let crc = crc32(canonical.as_bytes());
    format!("{body},\n  \"crc32\": \"{crc:08x}\"\n}}\n").into_bytes()
}

/// Parses and verifies a record's file bytes; `name` is used in the messages.
pub fn decode(bytes: &[u8], name: &Path) -> Result<Record, StoreError> {
    let corrupt = |message: String| StoreError::Corrupt { path: name.to_path_buf(), message };
    let text = std::str::from_utf8(bytes).map_err(|_| corrupt("not UTF-8".into()))?;
    const MARK: &str = ",\n  \"crc32\": \"";
    let at = text.rfind(MARK).ok_or_else(|| corrupt("no crc32 member".into()))?;
    let rest = &text[at + MARK.len()..];
    let hex = rest.get(..8).ok_or_else(|| corrupt("truncated crc32".into()))?;
    let want = u32::from_str_radix(hex, 16).map_err(|_| corrupt(format!("bad crc32 `{hex}`")))?;
    if rest.get(8..).map(str::trim_end) != Some("\"\n}") {
        return Err(corrupt("bytes after the crc32 member".into()));
    }
    let canonical = format!("{}\n}}", &text[..at]);
    let got = crc32(canonical.as_bytes());
    if got != want {
        return Err(corrupt(format!(
            "checksum mismatch (file says {want:08x}, content {got:08x})"
        )));
    }
    serde_json::from_str(text).map_err(|e| corrupt(format!("bad JSON: {e}")))
}

/// Writes `bytes` to `path` atomically and durably (temp file, fsync, rename, dir fsync).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), StoreError> {
    let io_err = |source| StoreError::Io { path: path.to_path_buf(), source };
    let dir = path.parent().unwrap_or(Path::new("."));
    let name = path.file_name().map_or("file".into(), |n| n.to_string_lossy().into_owned());
    let tmp = dir.join(format!(".{name}.tmp-{}", std::process::id()));
    let mut f = File::create(&tmp).map_err(io_err)?;
    f.write_all(bytes).map_err(io_err)?;
    f.sync_all().map_err(io_err)?;
    drop(f);
    fs::rename(&tmp, path).map_err(io_err)?;
    sync_dir(dir).map_err(io_err)
}

fn sync_dir(dir: &Path) -> io::Result<()> {
    File::open(dir)?.sync_all()
}

/// `Ok(None)` if the file does not exist.
fn read_record(path: &Path) -> Result<Option<Record>, StoreError> {
    match fs::read(path) {
        Ok(bytes) => decode(&bytes, path).map(Some),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(None),
        Err(source) => Err(StoreError::Io { path: path.to_path_buf(), source }),
    }
}

/// `*.json` files of a directory (temporary files excluded), sorted by name.
fn list_json(dir: &Path) -> Result<Vec<PathBuf>, StoreError> {
    let io_err = |source| StoreError::Io { path: dir.to_path_buf(), source };
    let mut out = Vec::new();
    for entry in fs::read_dir(dir).map_err(io_err)? {
        let path = entry.map_err(io_err)?.path();
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        if !name.starts_with('.') && name.ends_with(".json") {
            out.push(path);
        }
    }
    out.sort();
    Ok(out)
}

/// Removes all but the newest `keep` files (names sort by age).
fn prune(dir: &Path, keep: usize) -> Result<(), StoreError> {
    let files = list_json(dir)?;
    let excess = files.len().saturating_sub(keep);
    for path in &files[..excess] {
        fs::remove_file(path).map_err(|source| StoreError::Io { path: path.clone(), source })?;
    }
    if excess > 0 {
        sync_dir(dir).map_err(|source| StoreError::Io { path: dir.to_path_buf(), source })?;
    }
    Ok(())
}

/// OpenCV FileStorage YAML of the camera (as `cv::FileStorage` reads it).
pub fn camera_yaml(result: &CalibrationResult) -> String {
    let c = &result.camera;
    let model = match c.model {
        crate::geometry::CameraModel::PinholeRadtan => "pinhole-radtan",
        crate::geometry::CameraModel::Fisheye => "fisheye",
    };
    let k = [c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0];
    format!(
        "%YAML:1.0\n---\nimage_width: {}\nimage_height: {}\nmodel: \"{model}\"\n{}{}",
        c.width,
        c.height,
        yaml_matrix("camera_matrix", 3, 3, &k),
        yaml_matrix("distortion_coefficients", 1, c.distortion.len(), &c.distortion),
    )
}

/// OpenCV FileStorage YAML of the LiDAR → camera transform; `None` without one.
pub fn extrinsic_yaml(result: &CalibrationResult) -> Option<String> {
    let e = result.lidar_to_camera.as_ref()?;
    let r = &e.rotation;
    let t = &e.translation;
    let m = [
        r[0][0], r[0][1], r[0][2], t[0], r[1][0], r[1][1], r[1][2], t[1], r[2][0], r[2][1],
        r[2][2], t[2], 0.0, 0.0, 0.0, 1.0,
    ];
    let rot: Vec<f64> = r.iter().flatten().copied().collect();
    Some(format!(
        "%YAML:1.0\n---\n# p_camera = R * p_lidar + t\n{}{}{}",
        yaml_matrix("lidar_to_camera", 4, 4, &m),
        yaml_matrix("rotation", 3, 3, &rot),
        yaml_matrix("translation", 3, 1, t),
    ))
}

fn yaml_matrix(name: &str, rows: usize, cols: usize, data: &[f64]) -> String {
    let values: Vec<String> = data.iter().map(|v| format!("{v:e}")).collect();
    format!(
        "{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {} ]\n",
        values.join(", ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32_matches_zlib_check_value() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b""), 0);
    }
}
