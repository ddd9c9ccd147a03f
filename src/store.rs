//! The vehicle config store (std): a directory holding the calibration in force and a
//! bounded history, written so that a power loss at any instant leaves the old or the
//! new record, never a mix.
//!
//! ```text
//! STORE/current.json            the calibration in force (result schema + generation, time, crc32)
//! STORE/camera.yaml             OpenCV FileStorage: camera_matrix, distortion_coefficients
//! STORE/extrinsic.yaml          OpenCV FileStorage: lidar_to_camera rotation/translation (4×4)
//! STORE/camera-NAME.yaml        rigs: OpenCV FileStorage of each camera NAME
//! STORE/extrinsics.yaml         rigs: OpenCV FileStorage of every sensor → first camera
//! STORE/*.camera_info.yaml, sensor_kit_calibration.yaml, calib.txt   exports (crate::export)
//! STORE/history/gen-000042.json every accepted generation (the newest `keep` kept)
//! STORE/rejected/run-….json     rejected runs (the newest `keep` kept); never in force
//! STORE/security.json           the UDS SecurityAccess lockout (wrong keys, locked until)
//! STORE/current.json.invalid    an invalid current.json set aside (its generation stays used)
//! ```
//!
//! Every file is written atomically and durably: a temporary file `.NAME.tmp-PID-N` in the
//! same directory, written, fsync'ed, renamed over the target, then the directory fsync'ed.
//! A failed write removes its temporary file; opening the store removes those of processes
//! that are gone (killed mid-write). A generation is written to `history/` before
//! `current.json`, so a valid `current.json` always has its copy in history, and a history
//! generation newer than `current.json` is an update interrupted between the two writes:
//! it is completed (put in force) rather than skipped, so kills leave no gaps. A commit
//! whose `current.json` write *fails* (a full disk) takes its history copy back out before
//! reporting the error, so a result reported as not stored never comes into force later;
//! the number of that generation, which was never in force, is the next one's. A failure
//! after `current.json` was replaced (a YAML view, an export) says that the generation is
//! in force ([`StoreError::InForce`]).
//! `crc32` is the CRC-32 (IEEE) of the record's canonical JSON — the file's bytes before
//! the `"crc32"` member with the closing brace appended, which is exactly `serde_json`'s
//! pretty form of the record without it — written as 8 hex digits.
//!
//! A record is in force only if its checksum holds and it is a valid calibration
//! ([`is_valid_calibration`]); otherwise the newest valid generation in history is (with a
//! warning), and `current.json` is rewritten from it. Generation numbers are never reused:
//! the next one is one more than the highest number found anywhere in the store (records,
//! corrupt ones as far as they parse, history and rejected-run file names), and the store
//! refuses to go past `u32::MAX`. Rollback writes the previous generation's calibration
//! again as a *new* generation (generations only grow, so consumers can detect every
//! change); its `"restored_from"` names the generation copied, and a second rollback goes
//! one further back.

use std::fs::{self, File};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

use serde::{Deserialize, Serialize};

pub use crate::export::{camera_yaml, extrinsic_yaml, rig_extrinsics_yaml};

use crate::export::{directory_problem, NotADirectory};

use crate::result::{CalibrationResult, RigResult, Status};

/// Generations and rejected runs kept by default.
pub const DEFAULT_KEEP: usize = 16;

/// Looks at a held lock's file this many times, 10 ms apart, for the holder's pid.
const LOCK_HOLDER_TRIES: usize = 50;

/// One stored calibration: the result file plus the store's bookkeeping.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Record {
    /// A one-pair room's record holds the one-pair fields alone, a rig's its sensors and
    /// extrinsics too.
    #[serde(flatten)]
    pub result: RigResult,
    /// +1 per accepted run (and per rollback); 0 is never written.
    pub generation: u32,
    /// Unix seconds when the record was written.
    pub time: u64,
    /// Generation whose calibration a rollback copied.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub restored_from: Option<u32>,
}

impl Record {
    /// The rig result this record holds, if it is a rig's.
    pub fn rig(&self) -> Option<&RigResult> {
        Some(&self.result).filter(|r| r.is_rig())
    }

    /// The one-pair fields: the (first) camera, the (first) LiDAR, the verdict.
    pub fn pair(&self) -> &CalibrationResult {
        &self.result.pair
    }
}

/// The UDS SecurityAccess lockout, kept in `STORE/security.json` so that wrong keys
/// followed by a restart (or a power cycle) still lock (ISO 14229-1 applies the delay
/// timer after power-up too).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Lockout {
    /// Wrong keys in a row since the last correct key or lock.
    pub failed_attempts: u8,
    /// Unix seconds until which seeds are refused (0: not locked).
    pub locked_until: u64,
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
    #[error(
        "store {dir}: generation {} (seen in {seen_in}) is the last a u32 holds; refusing to \
         write another (move the store aside to start a new sequence)",
        u32::MAX
    )]
    GenerationsExhausted { dir: PathBuf, seen_in: PathBuf },
    #[error(
        "store {dir}: another roomcal process ({holder}) writes this store; one process at a \
         time may (stop it, or give this one another store)"
    )]
    Locked { dir: PathBuf, holder: String },
    #[error("store {path}: {problem}")]
    NotADirectory { path: PathBuf, problem: NotADirectory },
    /// The commit's record is in force (`current.json` holds it), but a later step failed.
    #[error(
        "{source}; generation {} is in force (current.json holds it), but the YAML views and \
         exports beside it may still show the previous calibration",
        record.generation
    )]
    InForce { record: Box<Record>, source: Box<StoreError> },
    /// `current.json` could not be written and the history copy could not be taken back.
    #[error(
        "{source}; generation {generation} could not be taken back out of history ({}: \
         {undo}) and will be put in force the next time the store is read",
        path.display()
    )]
    Pending { generation: u32, path: PathBuf, source: Box<StoreError>, undo: io::Error },
}

impl StoreError {
    /// The record in force despite the error ([`StoreError::InForce`]).
    pub fn in_force(&self) -> Option<&Record> {
        match self {
            StoreError::InForce { record, .. } => Some(record),
            _ => None,
        }
    }
}

/// Why a record cannot be in force: the first thing wrong with its calibration.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum InvalidRecord {
    #[error("status is not \"accepted\"")]
    NotAccepted,
    /// The one-pair fields fail the result file's own validation.
    #[error("{0}")]
    Calibration(crate::target::RoomError),
    #[error("sensor `{name}` is not accepted")]
    SensorNotAccepted { name: String },
    #[error("camera `{name}`: {problem}")]
    Camera { name: String, problem: crate::target::RoomError },
    #[error("extrinsic {from} → {to}: {problem}")]
    Extrinsic { from: String, to: String, problem: crate::target::RoomError },
}

/// Why a calibration cannot be in force.
///
/// A record in force must be accepted and pass the result file's own validation
/// ([`CalibrationResult::validate`]: image size, focal lengths within the image's scale,
/// principal point on the image, finite bounded distortion of the model's length, a
/// proper rotation with a translation within the vehicle's size).
pub fn is_valid_calibration(result: &CalibrationResult) -> Result<(), InvalidRecord> {
    if result.status != Status::Accepted {
        return Err(InvalidRecord::NotAccepted);
    }
    result.validate().map_err(InvalidRecord::Calibration)
}

/// Why a record cannot be in force: [`is_valid_calibration`] of its one-pair fields, and
/// for a rig every sensor accepted, every camera valid and every extrinsic a proper
/// rotation with a translation within the vehicle's size.
pub fn is_valid_record(record: &Record) -> Result<(), InvalidRecord> {
    is_valid_calibration(record.pair())?;
    for (name, sensor) in &record.result.sensors {
        if sensor.status != Status::Accepted {
            return Err(InvalidRecord::SensorNotAccepted { name: name.clone() });
        }
        if let Some(camera) = &sensor.camera {
            camera
                .validate()
                .map_err(|problem| InvalidRecord::Camera { name: name.clone(), problem })?;
        }
    }
    for e in &record.result.extrinsics {
        crate::target::validate_mounting(
            "extrinsics.rotation",
            &e.rotation,
            "extrinsics.translation",
            &e.translation,
        )
        .map_err(|problem| InvalidRecord::Extrinsic {
            from: e.from.clone(),
            to: e.to.clone(),
            problem,
        })?;
    }
    Ok(())
}

/// The store directory.
#[derive(Clone, Debug)]
pub struct Store {
    dir: PathBuf,
    keep: usize,
    /// Serialises this process's writes (clones share it): a repair of `current.json` from
    /// the service must not interleave with a commit.
    writes: Arc<Mutex<()>>,
}

/// One process's exclusive hold on a store (`STORE/.lock`, an advisory `flock`): while it
/// lives no other process, and no other hold in this one, can take it. The kernel releases it
/// when the holder exits however it exits, so a killed daemon never leaves the store locked.
/// The file holds the holder's pid, for the message the next one gets.
#[derive(Debug)]
pub struct StoreLock {
    _file: File,
}

impl Store {
    /// Takes the store's writer lock ([`StoreLock`]) for as long as the returned value lives:
    /// two writers on one store would reuse generation numbers and lose accepted runs.
    /// [`StoreError::Locked`] names the holder's pid when another process has it.
    pub fn lock_writer(&self) -> Result<StoreLock, StoreError> {
        let path = self.dir.join(".lock");
        let io_error = |source| StoreError::Io { path: path.clone(), source };
        let mut file = fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(io_error)?;
        // The holder writes its pid just after taking the lock: until then the file is empty
        // or names an earlier holder that is gone, so a refusal waits a moment for a live pid.
        let mut holder = None;
        for _ in 0..LOCK_HOLDER_TRIES {
            match file.try_lock() {
                Ok(()) => {
                    file.set_len(0).map_err(io_error)?;
                    file.write_all(format!("{}\n", std::process::id()).as_bytes())
                        .map_err(io_error)?;
                    return Ok(StoreLock { _file: file });
                }
                Err(fs::TryLockError::WouldBlock) => {
                    holder = fs::read_to_string(&path)
                        .ok()
                        .and_then(|text| text.trim().parse::<u32>().ok())
                        .filter(|&pid| process_alive(pid));
                    if holder.is_some() {
                        break;
                    }
                    std::thread::sleep(std::time::Duration::from_millis(10));
                }
                Err(fs::TryLockError::Error(source)) => return Err(io_error(source)),
            }
        }
        let holder = holder.map_or_else(|| "pid unknown".to_string(), |pid| format!("pid {pid}"));
        Err(StoreError::Locked { dir: self.dir.clone(), holder })
    }

    /// Opens (creating if needed) the store at `dir`, keeping `keep` generations and
    /// `keep` rejected runs (at least 2). Temporary files left by interrupted writes of
    /// processes that no longer run are removed.
    pub fn open(dir: impl Into<PathBuf>, keep: usize) -> Result<Store, StoreError> {
        let store = Store { dir: dir.into(), keep: keep.max(2), writes: Arc::default() };
        store.create_dirs()?;
        let mut removed = 0;
        for d in [store.dir.clone(), store.history_dir(), store.rejected_dir()] {
            removed += remove_stale_temp_files(&d)?;
        }
        if removed > 0 {
            tracing::info!(
                "store {}: removed {removed} temporary file(s) left by interrupted writes",
                store.dir.display()
            );
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

    /// The calibration in force: the newest valid record (checksum and
    /// [`is_valid_calibration`]) of `current.json` and the history; `None` before the first
    /// accepted run. When that record is not what `current.json` holds (missing, corrupt,
    /// invalid, or older: an update interrupted between its history and current writes),
    /// `current.json` is rewritten from it, and that is logged once it succeeded.
    pub fn current(&self) -> Result<Option<Record>, StoreError> {
        let _writing = self.lock();
        self.current_locked()
    }

    /// Checks `current.json` against `held`, the record this process knows is in force, and
    /// restores it from `held` when it was emptied, corrupted or replaced by something
    /// invalid or older. Returns the record in force (a newer valid one found in the file
    /// wins). Cheap when nothing changed: one small read and compare. With `held = None`,
    /// the same as [`Store::current`].
    pub fn verify_current(&self, held: Option<&Record>) -> Result<Option<Record>, StoreError> {
        let _writing = self.lock();
        let Some(held) = held else {
            return self.current_locked();
        };
        let path = self.current_path();
        let expected = encode(held);
        let problem = match fs::read(&path) {
            Ok(bytes) if bytes == expected => return Ok(Some(held.clone())),
            Ok(bytes) => match decode(&bytes, &path) {
                Ok(r) => match is_valid_record(&r) {
                    Ok(()) if r.generation > held.generation => return Ok(Some(r)),
                    Ok(()) => {
                        format!("held generation {} instead of {}", r.generation, held.generation)
                    }
                    Err(why) => {
                        format!("generation {} is not a valid calibration: {why}", r.generation)
                    }
                },
                Err(e) => e.to_string(),
            },
            Err(e) if e.kind() == io::ErrorKind::NotFound => "missing".to_string(),
            Err(source) => return Err(StoreError::Io { path, source }),
        };
        self.set_aside_higher_current(held.generation)?;
        self.put_in_force(held)?;
        tracing::warn!(
            "{}: {problem}; restored generation {} (the daemon's record)",
            path.display(),
            held.generation
        );
        Ok(Some(held.clone()))
    }

    /// Valid generations in history, oldest first (invalid files are skipped with a warning).
    pub fn history(&self) -> Result<Vec<Record>, StoreError> {
        let mut out = Vec::new();
        for (_, path) in self.history_files()? {
            match read_record(&path) {
                Ok(Some(r)) => match is_valid_record(&r) {
                    Ok(()) => out.push(r),
                    Err(why) => tracing::warn!(
                        "{}: not a valid calibration ({why}); skipped",
                        path.display()
                    ),
                },
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
    /// seconds); returns the record written. A rig's sensors and extrinsics go in force
    /// with its one-pair fields, as one record, with a YAML view per camera and one for
    /// the rig's extrinsics.
    pub fn commit(&self, result: &RigResult, now: u64) -> Result<Record, StoreError> {
        if result.pair.status != Status::Accepted {
            return Err(StoreError::NotAccepted);
        }
        let _writing = self.lock();
        let record = Record {
            result: result.clone(),
            generation: self.next_generation_locked()?,
            time: now,
            restored_from: None,
        };
        self.install(&record)?;
        Ok(record)
    }

    /// Keeps a rejected run beside the history (never in force; a rig's with every
    /// sensor's verdict); returns its path. The name carries the generation in force, so
    /// the sequence survives a lost history.
    pub fn record_rejected(&self, result: &RigResult, now: u64) -> Result<PathBuf, StoreError> {
        let _writing = self.lock();
        let generation = self.current_locked()?.map_or(0, |r| r.generation);
        let record = Record { result: result.clone(), generation, time: now, restored_from: None };
        self.create_dirs()?;
        let mut seq = list_json(&self.rejected_dir())?.len();
        let path = loop {
            let name = format!("run-{now:012}-{seq:04}-gen-{generation:06}.json");
            let path = self.rejected_dir().join(name);
            if !path.exists() {
                break path;
            }
            seq += 1;
        };
        write_atomic(&path, &encode(&record))?;
        prune(&list_json(&self.rejected_dir())?, &self.rejected_dir(), self.keep)?;
        Ok(path)
    }

    /// Puts the generation before the one in force back in force, as a new generation
    /// written at `now`; returns it.
    pub fn rollback(&self, now: u64) -> Result<Record, StoreError> {
        let _writing = self.lock();
        let no_previous = || StoreError::NoPrevious { dir: self.dir.clone() };
        let current = self.current_locked()?.ok_or_else(no_previous)?;
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
            generation: self.next_generation_locked()?,
            time: now,
            restored_from: Some(previous.generation),
        };
        self.install(&record)?;
        Ok(record)
    }

    /// The generation the next commit or rollback will write: one more than the highest
    /// the store has any trace of — the record in force, every record in `current.json`,
    /// history and rejected runs (even invalid or corrupt ones, as far as they parse), and
    /// the numbers in history and rejected-run file names — so no generation is ever
    /// written twice. Refuses past `u32::MAX`.
    pub fn next_generation(&self) -> Result<u32, StoreError> {
        let _writing = self.lock();
        self.next_generation_locked()
    }

    /// The SecurityAccess lockout as last written; the default when there is none. An
    /// unreadable or corrupt file counts as a lock from `now` for `lockout_s` seconds
    /// (fail closed: a wrong key must not be forgotten by damaging the file).
    pub fn lockout(&self, now: u64, lockout_s: u64) -> Lockout {
        let path = self.lockout_path();
        let text = match fs::read(&path) {
            Ok(t) => t,
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Lockout::default(),
            Err(e) => {
                tracing::warn!("{}: {e}; SecurityAccess locked for {lockout_s} s", path.display());
                return Lockout { failed_attempts: 0, locked_until: now + lockout_s };
            }
        };
        serde_json::from_slice(&text).unwrap_or_else(|e| {
            tracing::warn!("{}: {e}; SecurityAccess locked for {lockout_s} s", path.display());
            Lockout { failed_attempts: 0, locked_until: now + lockout_s }
        })
    }

    /// Writes the SecurityAccess lockout (atomically and durably).
    pub fn set_lockout(&self, lockout: &Lockout) -> Result<(), StoreError> {
        let _writing = self.lock();
        // Serialising two integers cannot fail.
        let text = serde_json::to_string(lockout).unwrap_or_default();
        write_atomic(&self.lockout_path(), format!("{text}\n").as_bytes())
    }

    fn lockout_path(&self) -> PathBuf {
        self.dir.join("security.json")
    }

    fn history_dir(&self) -> PathBuf {
        self.dir.join("history")
    }

    fn rejected_dir(&self) -> PathBuf {
        self.dir.join("rejected")
    }

    fn lock(&self) -> MutexGuard<'_, ()> {
        // The guarded data is `()`: a panic elsewhere cannot leave it inconsistent.
        self.writes.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The store's directories, recreated when someone deleted them; a file or a link to
    /// nothing in the way is named as such ([`NotADirectory`]).
    fn create_dirs(&self) -> Result<(), StoreError> {
        for d in [self.dir.clone(), self.history_dir(), self.rejected_dir()] {
            fs::create_dir_all(&d).map_err(|source| match directory_problem(&d) {
                Some(problem) => StoreError::NotADirectory { path: d.clone(), problem },
                None => StoreError::Io { path: d.clone(), source },
            })?;
        }
        Ok(())
    }

    /// `gen-N.json` files of the history with their N, by generation.
    fn history_files(&self) -> Result<Vec<(u32, PathBuf)>, StoreError> {
        let mut out: Vec<(u32, PathBuf)> = list_json(&self.history_dir())?
            .into_iter()
            .filter_map(|p| Some((number_after(&p, "gen-")?, p)))
            .collect();
        out.sort();
        Ok(out)
    }

    fn current_locked(&self) -> Result<Option<Record>, StoreError> {
        let path = self.current_path();
        let in_file = match read_record(&path) {
            Ok(Some(r)) => match is_valid_record(&r) {
                Ok(()) => Some(r),
                Err(why) => {
                    tracing::warn!(
                        "{}: generation {} is not a valid calibration ({why}); not in force",
                        path.display(),
                        r.generation
                    );
                    None
                }
            },
            Ok(None) => None,
            Err(e) => {
                tracing::warn!("{e}; falling back to the newest valid generation");
                None
            }
        };
        let newest = self.history()?.pop();
        let restore = match (&in_file, newest) {
            (Some(cur), Some(h)) if h.generation > cur.generation => h,
            (Some(cur), _) => return Ok(Some(cur.clone())),
            (None, Some(h)) => h,
            (None, None) => return Ok(None),
        };
        self.set_aside_higher_current(restore.generation)?;
        self.put_in_force(&restore)?;
        match in_file {
            Some(cur) => tracing::warn!(
                "{}: history holds generation {}, newer than its {} (an update interrupted \
                 before current.json was replaced); generation {} completed and in force",
                path.display(),
                restore.generation,
                cur.generation,
                restore.generation
            ),
            None => tracing::warn!(
                "{}: restored generation {} from history",
                path.display(),
                restore.generation
            ),
        }
        Ok(Some(restore))
    }

    /// Before `current.json` is replaced by an older generation, a file that states a
    /// higher one (invalid, or failing its checksum) is renamed to `current.json.invalid`,
    /// so its number stays seen and is not given out again.
    fn set_aside_higher_current(&self, generation: u32) -> Result<(), StoreError> {
        let path = self.current_path();
        if generation_in_file(&path).is_some_and(|g| g > generation) {
            let aside = self.set_aside_path();
            fs::rename(&path, &aside).map_err(|source| StoreError::Io { path, source })?;
        }
        Ok(())
    }

    fn set_aside_path(&self) -> PathBuf {
        self.dir.join("current.json.invalid")
    }

    fn next_generation_locked(&self) -> Result<u32, StoreError> {
        let mut highest = (0u32, self.current_path());
        let mut see = |generation: u32, path: &Path| {
            if generation > highest.0 {
                highest = (generation, path.to_path_buf());
            }
        };
        if let Some(r) = self.current_locked()? {
            see(r.generation, &self.current_path());
        }
        for path in [self.current_path(), self.set_aside_path()] {
            if let Some(g) = generation_in_file(&path) {
                see(g, &path);
            }
        }
        for (g, path) in self.history_files()? {
            see(g, &path);
            if let Some(g) = generation_in_file(&path) {
                see(g, &path);
            }
        }
        for path in list_json(&self.rejected_dir())? {
            if let Some(g) = number_after(&path, "-gen-") {
                see(g, &path);
            }
            if let Some(g) = generation_in_file(&path) {
                see(g, &path);
            }
        }
        let (generation, seen_in) = highest;
        generation
            .checked_add(1)
            .ok_or(StoreError::GenerationsExhausted { dir: self.dir.clone(), seen_in })
    }

    /// History first, then current, then the YAML views, then pruning. A failed
    /// `current.json` write takes the history copy back out ([`Store::take_back`]); a
    /// failed view after it is [`StoreError::InForce`]; a failed pruning is a warning.
    fn install(&self, record: &Record) -> Result<(), StoreError> {
        self.create_dirs()?;
        let hist = self.history_dir().join(format!("gen-{:06}.json", record.generation));
        write_atomic(&hist, &encode(record))?;
        if let Err(failure) = write_atomic(&self.current_path(), &encode(record)) {
            return Err(self.take_back(&hist, record, failure));
        }
        let in_force = |source| StoreError::InForce {
            record: Box::new(record.clone()),
            source: Box::new(source),
        };
        self.write_views(record).map_err(in_force)?;
        // The generation is in force with its views: a history longer than `keep` for now
        // is no reason to report the commit as failed.
        let pruned = self.history_files().and_then(|files| {
            let files: Vec<PathBuf> = files.into_iter().map(|(_, p)| p).collect();
            prune(&files, &self.history_dir(), self.keep)
        });
        if let Err(e) = pruned {
            tracing::warn!("{e}; the history keeps more than {} generations for now", self.keep);
        }
        Ok(())
    }

    /// After `failure` to write `current.json`: the generation never came into force, so
    /// its history copy `hist` is removed — left there, the next read of the store would
    /// take it for an interrupted update and put in force a result reported as not stored.
    /// If `current.json` holds the generation after all (renamed, but its directory's sync
    /// failed), it is in force and says so.
    fn take_back(&self, hist: &Path, record: &Record, failure: StoreError) -> StoreError {
        if generation_in_file(&self.current_path()) == Some(record.generation) {
            return StoreError::InForce {
                record: Box::new(record.clone()),
                source: Box::new(failure),
            };
        }
        match fs::remove_file(hist).and_then(|()| sync_dir(&self.history_dir())) {
            Ok(()) => failure,
            Err(undo) => StoreError::Pending {
                generation: record.generation,
                path: hist.to_path_buf(),
                source: Box::new(failure),
                undo,
            },
        }
    }

    /// `current.json` and its views ([`Store::write_views`]).
    fn put_in_force(&self, record: &Record) -> Result<(), StoreError> {
        write_atomic(&self.current_path(), &encode(record))?;
        self.write_views(record)
    }

    /// The YAML views and exports of the record in force (for a rig also one per camera and
    /// the rig's extrinsics; the first camera's and first LiDAR's stay in `camera.yaml` and
    /// `extrinsic.yaml` for one-pair consumers).
    fn write_views(&self, record: &Record) -> Result<(), StoreError> {
        write_atomic(&self.dir.join("camera.yaml"), camera_yaml(&record.pair().camera).as_bytes())?;
        if let Some(yaml) = extrinsic_yaml(record.pair()) {
            write_atomic(&self.dir.join("extrinsic.yaml"), yaml.as_bytes())?;
        }
        let exports = match record.rig() {
            Some(rig) => {
                for sensor in rig.in_order() {
                    if let Some(camera) = sensor.camera {
                        let path = self.dir.join(format!("camera-{}.yaml", sensor.name));
                        write_atomic(&path, camera_yaml(camera).as_bytes())?;
                    }
                }
                write_atomic(
                    &self.dir.join("extrinsics.yaml"),
                    rig_extrinsics_yaml(rig).as_bytes(),
                )?;
                crate::export::rig_files(rig)
            }
            None => crate::export::files(record.pair()),
        };
        crate::export::write_each(&self.dir, &exports, write_atomic)?;
        Ok(())
    }
}

/// The number right after `marker` in a file name (`gen-000042.json` → 42), saturating at
/// `u32::MAX` so an absurd name refuses further generations instead of being ignored.
fn number_after(path: &Path, marker: &str) -> Option<u32> {
    let name = path.file_name()?.to_str()?;
    let digits: &str = name.split_once(marker)?.1;
    let end = digits.find(|c: char| !c.is_ascii_digit()).unwrap_or(digits.len());
    let digits = &digits[..end];
    if digits.is_empty() {
        return None;
    }
    Some(digits.parse::<u32>().unwrap_or(u32::MAX))
}

/// The `"generation"` a record file states, checksum or not (a corrupt record still tells
/// which numbers were used).
fn generation_in_file(path: &Path) -> Option<u32> {
    let bytes = fs::read(path).ok()?;
    let v: serde_json::Value = serde_json::from_slice(&bytes).ok()?;
    let g = v.get("generation")?.as_u64()?;
    Some(u32::try_from(g).unwrap_or(u32::MAX))
}

/// Removes `.NAME.tmp-PID…` files of `dir` whose process is gone (a write interrupted by
/// a kill or power loss); files of this process and of live ones are left alone.
fn remove_stale_temp_files(dir: &Path) -> Result<usize, StoreError> {
    let io_err = |source| StoreError::Io { path: dir.to_path_buf(), source };
    let mut removed = 0;
    for entry in fs::read_dir(dir).map_err(io_err)? {
        let path = entry.map_err(io_err)?.path();
        let Some(name) = path.file_name().and_then(|n| n.to_str()) else { continue };
        if !name.starts_with('.') {
            continue;
        }
        let Some(pid) = number_after(&path, ".tmp-") else { continue };
        if pid == std::process::id() || process_alive(pid) {
            continue;
        }
        match fs::remove_file(&path) {
            Ok(()) => removed += 1,
            Err(e) if e.kind() == io::ErrorKind::NotFound => {}
            Err(source) => return Err(StoreError::Io { path, source }),
        }
    }
    if removed > 0 {
        sync_dir(dir).map_err(io_err)?;
    }
    Ok(removed)
}

/// Whether process `pid` runs (Linux `/proc`; without it every other process counts as gone).
fn process_alive(pid: u32) -> bool {
    Path::new("/proc/self").exists() && Path::new("/proc").join(pid.to_string()).exists()
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
/// A failed write removes its temporary file, so a full disk does not stay full.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), StoreError> {
    // Unique per write: two threads of one process never share a temporary file.
    static WRITES: AtomicU64 = AtomicU64::new(0);
    let io_err = |source| StoreError::Io { path: path.to_path_buf(), source };
    let dir = path.parent().unwrap_or(Path::new("."));
    let name = path.file_name().map_or("file".into(), |n| n.to_string_lossy().into_owned());
    let seq = WRITES.fetch_add(1, Ordering::Relaxed);
    let tmp = dir.join(format!(".{name}.tmp-{}-{seq}", std::process::id()));
    let written = write_synced(&tmp, bytes).and_then(|()| fs::rename(&tmp, path));
    if let Err(e) = written {
        let _ = fs::remove_file(&tmp);
        return Err(io_err(e));
    }
    sync_dir(dir).map_err(io_err)
}

fn write_synced(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let mut f = File::create(path)?;
    f.write_all(bytes)?;
    f.sync_all()
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

/// `*.json` files of a directory (temporary files excluded), sorted by name; none when
/// the directory was deleted.
fn list_json(dir: &Path) -> Result<Vec<PathBuf>, StoreError> {
    let io_err = |source| StoreError::Io { path: dir.to_path_buf(), source };
    let entries = match fs::read_dir(dir) {
        Ok(entries) => entries,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(io_err(e)),
    };
    let mut out = Vec::new();
    for entry in entries {
        let path = entry.map_err(io_err)?.path();
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        if !name.starts_with('.') && name.ends_with(".json") {
            out.push(path);
        }
    }
    out.sort();
    Ok(out)
}

/// Removes all but the newest `keep` of `files` (given oldest first) from `dir`.
fn prune(files: &[PathBuf], dir: &Path, keep: usize) -> Result<(), StoreError> {
    let excess = files.len().saturating_sub(keep);
    for path in &files[..excess] {
        fs::remove_file(path).map_err(|source| StoreError::Io { path: path.clone(), source })?;
    }
    if excess > 0 {
        sync_dir(dir).map_err(|source| StoreError::Io { path: dir.to_path_buf(), source })?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_writer_is_refused_with_the_holders_pid_until_the_first_lets_go() {
        let dir = std::env::temp_dir().join(format!("roomcal-store-lock-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        let store = Store::open(&dir, 4).unwrap();
        let held = store.lock_writer().unwrap();
        let refused = Store::open(&dir, 4).unwrap().lock_writer().unwrap_err();
        let message = refused.to_string();
        assert!(matches!(refused, StoreError::Locked { .. }), "{message}");
        assert!(message.contains(&format!("pid {}", std::process::id())), "{message}");
        drop(held);
        store.lock_writer().expect("free once the holder let go");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn crc32_matches_zlib_check_value() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b""), 0);
    }
}
