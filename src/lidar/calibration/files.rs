//! (std) A unit's angle-correction file → a [`Calibration`]: Hesai CSV, Velodyne YAML (the
//! `velodyne_pointcloud` subset), or the Ouster metadata json ([`super::ouster_json`]).

use std::path::{Path, PathBuf};

use super::{Calibration, CalibrationError, LaserCorrection};
use crate::lidar::common::Model;

/// Why a calibration file could not be used; every message names the file.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationFileError {
    #[error("calibration file {path}: cannot read: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("calibration file {path}: line {line}: {message}")]
    Syntax { path: PathBuf, line: usize, message: String },
    #[error("calibration file {path}: {source}")]
    Invalid { path: PathBuf, source: CalibrationError },
}

impl std::error::Error for CalibrationError {}

/// Reads a calibration file for `model`: Hesai CSV for Pandar models, Velodyne YAML for
/// Velodyne models, the sensor's metadata json for Ouster.
pub fn load(model: Model, path: &Path) -> Result<Calibration, CalibrationFileError> {
    let text = std::fs::read_to_string(path)
        .map_err(|source| CalibrationFileError::Read { path: path.to_owned(), source })?;
    match model {
        Model::Ouster => parse_ouster_json(&text, path),
        m if m.is_velodyne() => parse_velodyne_yaml(model, &text, path),
        _ => parse_hesai_csv(model, &text, path),
    }
}

pub use super::ouster_json::parse as parse_ouster_json;

/// Parses a Hesai angle-correction CSV (`Laser id,Elevation,Azimuth`, 1-based ids, degrees;
/// an optional `EEFF` preamble line and trailing hash lines are skipped).
pub fn parse_hesai_csv(
    model: Model,
    text: &str,
    path: &Path,
) -> Result<Calibration, CalibrationFileError> {
    let syntax = |line: usize, message: String| CalibrationFileError::Syntax {
        path: path.to_owned(),
        line,
        message,
    };
    let invalid = |source| CalibrationFileError::Invalid { path: path.to_owned(), source };
    let mut cal = Calibration::nominal(model);
    let mut seen = [false; super::MAX_LASERS];
    for (n, line) in text.lines().enumerate().map(|(i, l)| (i + 1, l.trim())) {
        let cols: Vec<&str> = line.split(',').map(str::trim).collect();
        // Header, preamble and hash lines have a non-numeric first column.
        let Ok(id) = cols[0].parse::<usize>() else { continue };
        if cols.len() < 3 {
            return Err(syntax(n, format!("expected 3 columns, found {}", cols.len())));
        }
        let num =
            |s: &str| s.parse::<f32>().map_err(|_| syntax(n, format!("{s:?} is not a number")));
        let (elev, azim) = (num(cols[1])?, num(cols[2])?);
        let index = id.checked_sub(1).ok_or_else(|| syntax(n, "laser id 0".into()))?;
        cal.set(index, LaserCorrection::from_degrees(elev, azim)).map_err(invalid)?;
        seen[index] = true;
    }
    check_complete(model, &seen).map_err(invalid)?;
    Ok(cal)
}

/// Parses a Velodyne calibration YAML (`velodyne_pointcloud` format; angles in radians,
/// distances in metres). Unknown keys are ignored; two-point distance and intensity
/// (focal) corrections are not applied.
pub fn parse_velodyne_yaml(
    model: Model,
    text: &str,
    path: &Path,
) -> Result<Calibration, CalibrationFileError> {
    let syntax = |line: usize, message: String| CalibrationFileError::Syntax {
        path: path.to_owned(),
        line,
        message,
    };
    let invalid = |source| CalibrationFileError::Invalid { path: path.to_owned(), source };
    let mut cal = Calibration::nominal(model);
    let mut seen = [false; super::MAX_LASERS];
    let mut entry: Option<(usize, Vec<(String, f64)>)> = None;
    let mut in_lasers = false;
    let mut finish = |entry: Option<(usize, Vec<(String, f64)>)>,
                      cal: &mut Calibration|
     -> Result<(), CalibrationFileError> {
        let Some((line, kv)) = entry else { return Ok(()) };
        let get = |k: &str| kv.iter().find(|(key, _)| key == k).map(|(_, v)| *v as f32);
        let id = get("laser_id").ok_or_else(|| syntax(line, "laser without laser_id".into()))?;
        if id < 0.0 || id.fract() != 0.0 {
            return Err(syntax(line, format!("laser_id {id} is not an index")));
        }
        let c = LaserCorrection::new(
            get("vert_correction").unwrap_or(0.0),
            -get("rot_correction").unwrap_or(0.0),
            get("dist_correction").unwrap_or(0.0),
            get("vert_offset_correction").unwrap_or(0.0),
            get("horiz_offset_correction").unwrap_or(0.0),
        );
        cal.set(id as usize, c).map_err(invalid)?;
        seen[id as usize] = true;
        Ok(())
    };
    for (n, raw) in text.lines().enumerate().map(|(i, l)| (i + 1, l)) {
        let line = raw.split('#').next().unwrap_or("");
        let trimmed = line.trim();
        if trimmed.is_empty() {
            continue;
        }
        let top_level = !line.starts_with(' ') && !line.starts_with('-');
        if top_level {
            finish(entry.take(), &mut cal)?;
            let (key, value) = trimmed.split_once(':').unwrap_or((trimmed, ""));
            in_lasers = key.trim() == "lasers";
            if key.trim() == "distance_resolution" {
                let v: f32 = value.trim().parse().map_err(|_| {
                    syntax(n, format!("distance_resolution {:?} is not a number", value.trim()))
                })?;
                if !(v > 0.0 && v < 1.0) {
                    return Err(invalid(CalibrationError::BadValue));
                }
                cal.distance_resolution = v;
            }
            continue;
        }
        if !in_lasers {
            continue;
        }
        let mut body = trimmed;
        if let Some(rest) = body.strip_prefix('-') {
            finish(entry.take(), &mut cal)?;
            entry = Some((n, Vec::new()));
            body = rest;
        }
        let Some((_, kv)) = entry.as_mut() else {
            return Err(syntax(n, "laser field outside a `- ` list item".into()));
        };
        for item in body.split(',') {
            let item = item.trim().trim_matches(|c| c == '{' || c == '}').trim();
            if item.is_empty() {
                continue;
            }
            let (k, v) = item
                .split_once(':')
                .ok_or_else(|| syntax(n, format!("expected `key: value`, found {item:?}")))?;
            let v: f64 =
                v.trim().parse().map_err(|_| syntax(n, format!("{:?} is not a number", v)))?;
            kv.push((k.trim().to_owned(), v));
        }
    }
    finish(entry.take(), &mut cal)?;
    check_complete(model, &seen).map_err(invalid)?;
    Ok(cal)
}

/// The table as a Hesai angle-correction CSV (`Laser id,Elevation,Azimuth`, degrees), which
/// [`parse_hesai_csv`] reads back to the same table (f32 values print exactly).
pub fn to_hesai_csv(cal: &Calibration) -> String {
    let mut text = String::from("Laser id,Elevation,Azimuth\n");
    for (i, c) in cal.active().iter().enumerate() {
        let (e, a) = (degrees_of(c.elevation), degrees_of(c.azimuth_offset));
        text.push_str(&format!("{},{e},{a}\n", i + 1));
    }
    text
}

/// The f32 degrees that convert to exactly `radians` when there is one nearby (so a
/// table made from degrees prints its own values), else the nearest.
fn degrees_of(radians: f32) -> f32 {
    let d = radians.to_degrees();
    let near = |k: i32| f32::from_bits((d.to_bits() as i32 + k) as u32);
    [0, -1, 1, -2, 2].into_iter().map(near).find(|c| c.to_radians() == radians).unwrap_or(d)
}

pub(crate) fn check_complete(model: Model, seen: &[bool]) -> Result<(), CalibrationError> {
    let found = seen.iter().filter(|s| **s).count();
    if found < model.lasers() {
        return Err(CalibrationError::MissingLasers { found, expected: model.lasers() });
    }
    Ok(())
}
