//! Rigs: a vehicle's several cameras and LiDARs (DESIGN.md "Vehicles with several
//! sensors"). The rig file (`[[camera]]`, `[[lidar]]` tables, each with a `name`) is read
//! into [`RigFile`] and checked into a [`Rig`]: names `[a-z0-9_-]+` and unique, camera
//! models and sizes as the room file's `[camera]` is checked, every sensor but the first
//! camera with a mounting that is finite and a rotation. The first camera is the rig's
//! reference: every mounting is `p_first = rotation · p_sensor + translation`.
//!
//! A room file's `[camera]` and `[lidar]` are the one-pair rig ([`Rig::from_room`]), so a
//! one-pair user sees nothing new. The types are `no_std` and heap-free (heapless, fixed
//! capacities); the TOML is read at the I/O edge ([`load`], with `std`).

use core::fmt;

use serde::{Deserialize, Serialize};

use crate::geometry::{CameraModel, Se3, Vec3};
use crate::lidar::Model;
use crate::target::{matrix_of, validate_mounting, CameraSpec, LidarSpec, Room, RoomError};

/// Most cameras, and most LiDARs, one rig holds.
pub const MAX_CAMERAS: usize = 8;
pub const MAX_LIDARS: usize = 8;
/// Longest sensor name (bytes).
pub const MAX_SENSOR_NAME: usize = 32;
/// The names a room file's one camera and one LiDAR take as a rig.
pub const PAIR_CAMERA: &str = "camera";
pub const PAIR_LIDAR: &str = "lidar";

/// A sensor's name in a rig.
pub type SensorName = heapless::String<MAX_SENSOR_NAME>;

/// A camera or a LiDAR.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SensorKind {
    Camera,
    Lidar,
}

/// A `[[camera]]` table as written: the room file's `[camera]` keys plus `name` and, for
/// every camera but the first, its mounting.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraEntry {
    pub name: SensorName,
    pub model: CameraModel,
    pub width: u32,
    pub height: u32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fy: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cy: Option<f64>,
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "crate::target::lists::distortion"
    )]
    pub distortion: Option<heapless::Vec<f64, 5>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotation: Option<Rows>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translation: Option<heapless::Vec<f64, 3>>,
    /// The part of the image this camera is used in (the room's `[quality] region` for it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub region: Option<[f64; 4]>,
}

/// A `[[lidar]]` table as written.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LidarEntry {
    pub name: SensorName,
    /// As the room file's `lidar.model`: `None` is `pcd`, points that come as files.
    #[serde(with = "crate::lidar::common::model_or_pcd")]
    pub model: Option<Model>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotation: Option<Rows>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translation: Option<heapless::Vec<f64, 3>>,
}

/// A matrix as written (rows of numbers); its shape is checked by [`Rig::from_file`].
pub type Rows = heapless::Vec<heapless::Vec<f64, 3>, 3>;

/// The rig file as written (serde's view of it).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigFile {
    #[serde(default, deserialize_with = "cameras")]
    pub camera: heapless::Vec<CameraEntry, MAX_CAMERAS>,
    #[serde(default, deserialize_with = "lidars")]
    pub lidar: heapless::Vec<LidarEntry, MAX_LIDARS>,
}

fn cameras<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> Result<heapless::Vec<CameraEntry, MAX_CAMERAS>, D::Error> {
    crate::target::capped(d, "cameras ([[camera]] tables)")
}

fn lidars<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> Result<heapless::Vec<LidarEntry, MAX_LIDARS>, D::Error> {
    crate::target::capped(d, "LiDARs ([[lidar]] tables)")
}

/// A checked camera of a rig.
#[derive(Clone, Debug, PartialEq)]
pub struct RigCamera {
    pub name: SensorName,
    pub spec: CameraSpec,
    /// Camera → first camera (identity for the first).
    pub to_reference: Se3,
    /// The part of the image it is used in, when the rig file says (else the room's).
    pub region: Option<[f64; 4]>,
}

/// A checked LiDAR of a rig.
#[derive(Clone, Debug, PartialEq)]
pub struct RigLidar {
    pub name: SensorName,
    /// The packet model; `None`: points come as files.
    pub model: Option<Model>,
    /// LiDAR → first camera, nominal.
    pub to_reference: Se3,
}

/// A checked rig: at least one camera; the first is the reference.
#[derive(Clone, Debug, PartialEq)]
pub struct Rig {
    pub cameras: heapless::Vec<RigCamera, MAX_CAMERAS>,
    pub lidars: heapless::Vec<RigLidar, MAX_LIDARS>,
}

/// What is wrong with a rig; every variant names the sensor (kind and name or position)
/// and the key.
#[derive(Clone, Debug, PartialEq)]
pub enum RigError {
    /// No `[[camera]]` table: the first camera is every mounting's reference.
    NoCamera,
    /// A name outside `[a-z0-9_-]+` (or empty).
    BadName { kind: SensorKind, index: usize, name: SensorName },
    /// Two sensors with one name.
    DuplicateName { name: SensorName, first: SensorKind, second: SensorKind },
    /// The first camera carries a mounting: it is the reference, its mounting is the identity.
    ReferenceMounting { name: SensorName, key: &'static str },
    /// A sensor other than the first camera without `rotation` or `translation`.
    MissingMounting { kind: SensorKind, name: SensorName, key: &'static str },
    /// `rotation` not 3×3 or `translation` not 3 numbers.
    Shape { kind: SensorKind, name: SensorName, key: &'static str },
    /// A number or a rotation the room file's rules refuse (the key is in the error).
    Invalid { kind: SensorKind, name: SensorName, error: RoomError },
}

impl fmt::Display for SensorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SensorKind::Camera => "camera",
            SensorKind::Lidar => "lidar",
        })
    }
}

impl fmt::Display for RigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RigError::NoCamera => write!(
                f,
                "no [[camera]] table: a rig needs at least one camera (the first is the reference of every mounting)"
            ),
            RigError::BadName { kind, index, name } => write!(
                f,
                "{kind} {}: `name` = \"{name}\": a name is one or more of a-z, 0-9, _ and -",
                index + 1
            ),
            RigError::DuplicateName { name, first, second } => write!(
                f,
                "{second} `{name}`: `name` \"{name}\" is already the name of a {first}: names are unique in a rig"
            ),
            RigError::ReferenceMounting { name, key } => write!(
                f,
                "camera `{name}`: `{key}`: the first camera is the rig's reference (its mounting is the identity); give mountings of the other sensors only"
            ),
            RigError::MissingMounting { kind, name, key } => write!(
                f,
                "{kind} `{name}`: `{key}` is missing: every sensor but the first camera needs its nominal mounting relative to the first camera"
            ),
            RigError::Shape { kind, name, key } => {
                let shape = if *key == "rotation" { "3 rows of 3 numbers" } else { "3 numbers" };
                write!(f, "{kind} `{name}`: `{key}` must be {shape}")
            }
            RigError::Invalid { kind, name, error } => write!(f, "{kind} `{name}`: {error}"),
        }
    }
}

impl Rig {
    /// Checks a rig file's tables (see the module doc); the first problem found.
    pub fn from_file(file: &RigFile) -> Result<Rig, RigError> {
        if file.camera.is_empty() {
            return Err(RigError::NoCamera);
        }
        check_names(file)?;
        let mut rig = Rig { cameras: heapless::Vec::new(), lidars: heapless::Vec::new() };
        for (index, entry) in file.camera.iter().enumerate() {
            let camera = checked_camera(entry, index == 0)?;
            // Capacities are the file's own (heapless refused more while parsing).
            let _ = rig.cameras.push(camera);
        }
        for entry in &file.lidar {
            let to_reference = mounting(SensorKind::Lidar, &entry.name, entry)?;
            let lidar = RigLidar { name: entry.name.clone(), model: entry.model, to_reference };
            let _ = rig.lidars.push(lidar);
        }
        Ok(rig)
    }

    /// The one-pair rig of a room file: its `[camera]` (`camera`) and `[lidar]` (`lidar`).
    pub fn from_room(room: &Room) -> Rig {
        let mut rig = Rig { cameras: heapless::Vec::new(), lidars: heapless::Vec::new() };
        let _ = rig.cameras.push(RigCamera {
            name: name_of(PAIR_CAMERA),
            spec: room.camera.clone(),
            to_reference: Se3::identity(),
            region: None,
        });
        if let Some(lidar) = &room.lidar {
            let to_reference =
                Se3 { rotation: lidar.rotation_matrix(), translation: lidar.translation_vector() };
            let _ = rig.lidars.push(RigLidar {
                name: name_of(PAIR_LIDAR),
                model: lidar.model,
                to_reference,
            });
        }
        rig
    }

    /// The sensor called `name`, if any: its kind and its index among its kind.
    pub fn find(&self, name: &str) -> Option<(SensorKind, usize)> {
        let camera = self.cameras.iter().position(|c| c.name == name);
        let lidar = self.lidars.iter().position(|l| l.name == name);
        camera.map(|i| (SensorKind::Camera, i)).or(lidar.map(|i| (SensorKind::Lidar, i)))
    }

    /// The nominal mounting of LiDAR `lidar` relative to camera `camera`
    /// (`p_camera = R · p_lidar + t`).
    pub fn lidar_to_camera(&self, lidar: usize, camera: usize) -> Se3 {
        self.cameras[camera].to_reference.inverse().compose(&self.lidars[lidar].to_reference)
    }

    /// The room of one camera and (optionally) one LiDAR of the rig: `room` with its
    /// `[camera]` that camera and its `[lidar]` that LiDAR at its nominal mounting relative
    /// to the camera; board, quality and survey stay the room's. This is how every
    /// one-pair step (detection, association, the pair solve) serves a rig.
    pub fn pair_room(&self, room: &Room, camera: usize, lidar: Option<usize>) -> Room {
        let mut pair = room.clone();
        pair.camera = self.cameras[camera].spec.clone();
        if let Some(region) = self.cameras[camera].region {
            pair.quality.region = region;
        }
        pair.lidar = lidar.map(|l| {
            let nominal = self.lidar_to_camera(l, camera);
            LidarSpec {
                model: self.lidars[l].model,
                rotation: rows_of(&nominal),
                translation: nominal.translation.into(),
            }
        });
        pair
    }
}

/// A checked name as a [`SensorName`] (names are short: the constant ones fit).
fn name_of(text: &str) -> SensorName {
    let mut name = SensorName::new();
    let _ = name.push_str(text);
    name
}

/// Names `[a-z0-9_-]+`, unique across cameras and LiDARs.
fn check_names(file: &RigFile) -> Result<(), RigError> {
    let cameras = file.camera.iter().map(|c| (SensorKind::Camera, &c.name));
    let lidars = file.lidar.iter().map(|l| (SensorKind::Lidar, &l.name));
    let all: heapless::Vec<(SensorKind, &SensorName), { MAX_CAMERAS + MAX_LIDARS }> =
        cameras.chain(lidars).collect();
    for (i, (kind, name)) in all.iter().enumerate() {
        let index = if *kind == SensorKind::Camera { i } else { i - file.camera.len() };
        if !valid_name(name) {
            return Err(RigError::BadName { kind: *kind, index, name: (*name).clone() });
        }
        if let Some((first, _)) = all[..i].iter().find(|(_, other)| other == name) {
            return Err(RigError::DuplicateName {
                name: (*name).clone(),
                first: *first,
                second: *kind,
            });
        }
    }
    Ok(())
}

/// Whether `name` is one or more of `a-z 0-9 _ -`.
pub fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_' || b == b'-')
}

fn checked_camera(entry: &CameraEntry, reference: bool) -> Result<RigCamera, RigError> {
    let spec = CameraSpec {
        model: entry.model,
        width: entry.width,
        height: entry.height,
        fx: entry.fx,
        fy: entry.fy,
        cx: entry.cx,
        cy: entry.cy,
        distortion: entry.distortion.clone(),
    };
    let name = &entry.name;
    let invalid = |error| RigError::Invalid { kind: SensorKind::Camera, name: name.clone(), error };
    spec.validate().map_err(invalid)?;
    if let Some(region) = &entry.region {
        crate::target::validate_region("region", region).map_err(invalid)?;
    }
    let to_reference = if reference {
        if entry.rotation.is_some() || entry.translation.is_some() {
            let key = if entry.rotation.is_some() { "rotation" } else { "translation" };
            return Err(RigError::ReferenceMounting { name: name.clone(), key });
        }
        Se3::identity()
    } else {
        mounting(SensorKind::Camera, name, entry)?
    };
    Ok(RigCamera { name: name.clone(), spec, to_reference, region: entry.region })
}

/// The two mounting keys of an entry.
trait Mounted {
    fn rotation(&self) -> Option<&Rows>;
    fn translation(&self) -> Option<&heapless::Vec<f64, 3>>;
}

impl Mounted for CameraEntry {
    fn rotation(&self) -> Option<&Rows> {
        self.rotation.as_ref()
    }
    fn translation(&self) -> Option<&heapless::Vec<f64, 3>> {
        self.translation.as_ref()
    }
}

impl Mounted for LidarEntry {
    fn rotation(&self) -> Option<&Rows> {
        self.rotation.as_ref()
    }
    fn translation(&self) -> Option<&heapless::Vec<f64, 3>> {
        self.translation.as_ref()
    }
}

/// A sensor's mounting: both keys present, of the right shape, finite, a rotation and a
/// translation within the room file's limits.
fn mounting(kind: SensorKind, name: &SensorName, entry: &impl Mounted) -> Result<Se3, RigError> {
    let missing = |key| RigError::MissingMounting { kind, name: name.clone(), key };
    let shape = |key| RigError::Shape { kind, name: name.clone(), key };
    let rows = entry.rotation().ok_or_else(|| missing("rotation"))?;
    let t = entry.translation().ok_or_else(|| missing("translation"))?;
    if rows.len() != 3 || rows.iter().any(|r| r.len() != 3) {
        return Err(shape("rotation"));
    }
    if t.len() != 3 {
        return Err(shape("translation"));
    }
    let rotation = [0, 1, 2].map(|i| [rows[i][0], rows[i][1], rows[i][2]]);
    let translation = [t[0], t[1], t[2]];
    validate_mounting("rotation", &rotation, "translation", &translation)
        .map_err(|error| RigError::Invalid { kind, name: name.clone(), error })?;
    Ok(Se3 { rotation: matrix_of(&rotation), translation: Vec3::from(translation) })
}

/// A rotation as the room file's row-major array.
fn rows_of(pose: &Se3) -> [[f64; 3]; 3] {
    let r = &pose.rotation;
    [0, 1, 2].map(|i| [r[(i, 0)], r[(i, 1)], r[(i, 2)]])
}

/// Reading rig files (TOML) with errors that name the file, the sensor and the key.
#[cfg(feature = "std")]
mod file {
    use std::path::{Path, PathBuf};

    use super::{Rig, RigError, RigFile};

    /// Why a rig file could not be used.
    #[derive(Debug, thiserror::Error)]
    pub enum RigFileError {
        #[error("rig file {path}: cannot read: {source}")]
        Read { path: PathBuf, source: std::io::Error },
        /// Syntax errors, unknown keys, missing fields, wrong types, too many sensors
        /// (toml names the key and the line).
        #[error("rig file {path}: {message}")]
        Parse { path: PathBuf, message: String },
        #[error("rig file {path}: {source}")]
        Invalid { path: PathBuf, source: Box<RigError> },
    }

    impl std::error::Error for RigError {}

    /// Reads and checks a rig file.
    pub fn load(path: &Path) -> Result<Rig, RigFileError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| RigFileError::Read { path: path.to_owned(), source })?;
        parse(&text, path)
    }

    /// Parses and checks rig-file text; `path` only names the source in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Rig, RigFileError> {
        let file: RigFile = toml::from_str(text).map_err(|e| RigFileError::Parse {
            path: path.to_owned(),
            message: crate::room::toml_message(text, &e),
        })?;
        Rig::from_file(&file).map_err(|source| RigFileError::Invalid {
            path: path.to_owned(),
            source: Box::new(source),
        })
    }
}

#[cfg(feature = "std")]
pub use file::{load, parse, RigFileError};
