//! (std) An Ouster unit's metadata json → a [`Calibration`]: its beam angles, beam origin,
//! lidar→sensor transform and packet layout.

use std::path::Path;

use crate::lidar::calibration::{
    Calibration, CalibrationError, CalibrationFileError, LaserCorrection, MAX_LASERS,
};
use crate::lidar::common::Model;
use crate::lidar::ouster::geometry::{OusterGeometry, Profile};

/// Parses an Ouster metadata json (the flat firmware 2.x `get_metadata` form, or the SDK's
/// nested one with `beam_intrinsics`, `lidar_intrinsics`, `lidar_data_format` and
/// `config_params`). `udp_profile_lidar` absent means LEGACY; profiles other than LEGACY
/// and RNG19_RFL8_SIG16_NIR16_DUAL are refused.
pub fn parse(text: &str, path: &Path) -> Result<Calibration, CalibrationFileError> {
    let syntax = |line: usize, message: String| CalibrationFileError::Syntax {
        path: path.to_owned(),
        line,
        message,
    };
    let invalid = |source| CalibrationFileError::Invalid { path: path.to_owned(), source };
    let json: serde_json::Value =
        serde_json::from_str(text).map_err(|e| syntax(e.line(), e.to_string()))?;
    let find = |key: &str| -> Option<&serde_json::Value> {
        let nests = ["", "beam_intrinsics", "lidar_intrinsics", "lidar_data_format"];
        let nests = nests.iter().chain(&["config_params", "data_format", "sensor_info"]);
        nests
            .filter_map(|n| if n.is_empty() { Some(&json) } else { json.get(n) })
            .find_map(|v| v.get(key))
    };
    let missing = |key: &str| syntax(0, format!("no `{key}`"));
    let numbers = |key: &str| -> Result<Vec<f64>, CalibrationFileError> {
        let list = find(key).and_then(|v| v.as_array()).ok_or_else(|| missing(key))?;
        list.iter()
            .map(|v| v.as_f64().ok_or_else(|| syntax(0, format!("`{key}`: {v} is not a number"))))
            .collect()
    };
    let integer = |key: &str, default: Option<u64>| -> Result<u16, CalibrationFileError> {
        let v = match find(key) {
            Some(v) => v.as_u64().ok_or_else(|| syntax(0, format!("`{key}`: not an integer")))?,
            None => default.ok_or_else(|| missing(key))?,
        };
        u16::try_from(v).map_err(|_| syntax(0, format!("`{key}` = {v} is out of range")))
    };
    let altitude = numbers("beam_altitude_angles")?;
    let azimuth = numbers("beam_azimuth_angles")?;
    let beams = altitude.len();
    if azimuth.len() != beams || beams == 0 || beams > MAX_LASERS {
        return Err(syntax(
            0,
            format!("{beams} altitude and {} azimuth angles (1..=128, equal)", azimuth.len()),
        ));
    }
    let (columns_per_frame, frequency_hz) =
        lidar_mode(find("lidar_mode")).map_err(|m| syntax(0, format!("`lidar_mode`: {m}")))?;
    let profile = match find("udp_profile_lidar").and_then(|v| v.as_str()) {
        None | Some("LEGACY") => Profile::Legacy,
        Some("RNG19_RFL8_SIG16_NIR16_DUAL") => Profile::Dual,
        Some(other) => {
            return Err(syntax(0, format!("udp_profile_lidar {other:?} is not supported")))
        }
    };
    let window = numbers("column_window").unwrap_or_else(|_| vec![0.0, 1e9]);
    let (rotation, translation) = transform(&numbers("lidar_to_sensor_transform")?)
        .ok_or_else(|| syntax(0, "`lidar_to_sensor_transform`: 16 numbers needed".into()))?;
    let geometry = OusterGeometry {
        profile,
        pixels_per_column: integer("pixels_per_column", Some(beams as u64))?,
        columns_per_packet: integer("columns_per_packet", Some(16))?,
        columns_per_frame: integer("columns_per_frame", Some(u64::from(columns_per_frame)))?,
        frequency_hz,
        column_window: (
            window.first().map_or(0, |v| v.clamp(0.0, 65535.0) as u16),
            window.get(1).map_or(u16::MAX, |v| v.clamp(0.0, 65535.0) as u16),
        ),
        beam_origin: (number(find("lidar_origin_to_beam_origin_mm")).unwrap_or(0.0) * 1e-3) as f32,
        rotation,
        translation,
    };
    if usize::from(geometry.pixels_per_column) != beams || !geometry.is_valid() {
        return Err(invalid(CalibrationError::BadValue));
    }
    let mut cal = Calibration::nominal(Model::Ouster);
    cal.ouster = geometry;
    cal.lasers = [LaserCorrection::default(); MAX_LASERS];
    for (i, (alt, az)) in altitude.iter().zip(&azimuth).enumerate() {
        let c = LaserCorrection::from_degrees(*alt as f32, *az as f32);
        cal.set(i, c).map_err(invalid)?;
    }
    Ok(cal)
}

fn number(v: Option<&serde_json::Value>) -> Option<f64> {
    v.and_then(|v| v.as_f64())
}

/// `"1024x10"` → (1024, 10).
fn lidar_mode(v: Option<&serde_json::Value>) -> Result<(u16, u16), String> {
    let Some(mode) = v.and_then(|v| v.as_str()) else { return Ok((1024, 10)) };
    let parsed = mode.split_once('x').and_then(|(w, f)| Some((w.parse().ok()?, f.parse().ok()?)));
    parsed.filter(|(w, f)| *w > 0 && *f > 0).ok_or_else(|| format!("{mode:?} is not WIDTHxHZ"))
}

/// A row-major 4×4 (translation in mm) → rotation and translation in metres.
fn transform(m: &[f64]) -> Option<([[f32; 3]; 3], [f32; 3])> {
    if m.len() != 16 {
        return None;
    }
    let rotation = core::array::from_fn(|i| core::array::from_fn(|j| m[4 * i + j] as f32));
    let translation = core::array::from_fn(|i| (m[4 * i + 3] * 1e-3) as f32);
    Some((rotation, translation))
}
