//! What every vendor module speaks: the supported models (and how the room, rig and result
//! files spell a LiDAR's model), return modes, the decode error enum, the per-return record
//! handed to sinks, the packet summary, and the small helpers (sensor-frame conversion,
//! civil time, azimuth order) the vendors share. A leaf: it imports no vendor module;
//! [`super::decoder`] dispatches to them.

use core::fmt;

use serde::de::{self, Deserializer, EnumAccess, Unexpected, VariantAccess, Visitor};
use serde::{Deserialize, Serialize, Serializer};

use super::Point;

/// A supported LiDAR model: the packet format a unit speaks. A LiDAR whose points come as
/// files has none; the files spell that `pcd` and the types say `Option<Model>` = `None`
/// ([`model_or_pcd`]), so a decoder is never handed a model without a packet format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Model {
    /// Velodyne VLP-16 (Puck), also the Puck Hi-Res / LITE (same packet format).
    Vlp16,
    /// Velodyne VLP-32C (Ultra Puck).
    Vlp32c,
    /// Velodyne HDL-32E.
    Hdl32e,
    /// Hesai Pandar40P.
    Pandar40p,
    /// Hesai Pandar64.
    Pandar64,
    /// Hesai PandarXT32.
    PandarXt32,
    /// Hesai PandarQT64.
    PandarQt64,
    /// Ouster OS0/OS1/OS2 (any beam count and lidar mode; LEGACY and
    /// RNG19_RFL8_SIG16_NIR16_DUAL packets): the geometry comes from the unit's metadata json.
    Ouster,
}

impl Model {
    /// Every supported model.
    pub const ALL: [Model; 8] = [
        Model::Vlp16,
        Model::Vlp32c,
        Model::Hdl32e,
        Model::Pandar40p,
        Model::Pandar64,
        Model::PandarXt32,
        Model::PandarQt64,
        Model::Ouster,
    ];

    /// The names [`Model::from_name`] takes, for messages.
    pub const NAMES: &'static str =
        "pandar64, pandar40p, pandarxt32, pandarqt64, vlp16, vlp32c, hdl32e, ouster";

    /// Parses the names the room and CLI files use (`vlp16`, `vlp32c`, `hdl32e`, `pandar40p`,
    /// `pandar64`, `pandarxt32`, `pandarqt64`, `ouster`; case-insensitive, `-`/`_` ignored).
    pub fn from_name(name: &str) -> Option<Model> {
        let mut buf = [0u8; 16];
        let mut n = 0;
        for b in name.bytes().filter(|b| *b != b'-' && *b != b'_') {
            *buf.get_mut(n)? = b.to_ascii_lowercase();
            n += 1;
        }
        match &buf[..n] {
            b"vlp16" => Some(Model::Vlp16),
            b"vlp32c" | b"vlp32" => Some(Model::Vlp32c),
            b"hdl32e" | b"hdl32" => Some(Model::Hdl32e),
            b"pandar40p" | b"pandar40" => Some(Model::Pandar40p),
            b"pandar64" => Some(Model::Pandar64),
            b"pandarxt32" | b"xt32" => Some(Model::PandarXt32),
            b"pandarqt64" | b"qt64" => Some(Model::PandarQt64),
            b"ouster" => Some(Model::Ouster),
            _ => None,
        }
    }

    /// The canonical lower-case name (also the files' spelling: [`FILE_NAMES`]).
    pub const fn name(self) -> &'static str {
        match self {
            Model::Vlp16 => "vlp16",
            Model::Vlp32c => "vlp32c",
            Model::Hdl32e => "hdl32e",
            Model::Pandar40p => "pandar40p",
            Model::Pandar64 => "pandar64",
            Model::PandarXt32 => "pandarxt32",
            Model::PandarQt64 => "pandarqt64",
            Model::Ouster => "ouster",
        }
    }

    /// Number of lasers (channels); for Ouster the most the family has (a unit's own count,
    /// 16 to 128, is in its metadata: `Calibration::laser_count`).
    pub fn lasers(self) -> usize {
        match self {
            Model::Vlp16 => 16,
            Model::Vlp32c | Model::Hdl32e | Model::PandarXt32 => 32,
            Model::Pandar40p => 40,
            Model::Pandar64 | Model::PandarQt64 => 64,
            Model::Ouster => 128,
        }
    }

    /// Whether the model is a Hesai (the `hesai` module decodes it).
    pub fn is_hesai(self) -> bool {
        matches!(self, Model::Pandar40p | Model::Pandar64 | Model::PandarXt32 | Model::PandarQt64)
    }

    /// Whether the model is a Velodyne (1206 B data packets).
    pub fn is_velodyne(self) -> bool {
        matches!(self, Model::Vlp16 | Model::Vlp32c | Model::Hdl32e)
    }

    /// The factory-default UDP port of the data packets.
    pub fn data_port(self) -> u16 {
        match self {
            Model::Ouster => 7502,
            _ => 2368,
        }
    }

    /// The factory-default UDP port of the position / GPS / IMU packets (ignored by the
    /// decoders).
    pub fn position_port(self) -> u16 {
        match self {
            Model::Ouster => 7503,
            m if m.is_velodyne() => 8308,
            _ => 10110,
        }
    }
}

/// A LiDAR's `model` as the room, rig and result files spell it, in the order serde's
/// messages list them: each packet model's [`Model::name`], then [`PCD`].
pub const FILE_NAMES: [&str; 9] = [
    Model::Pandar64.name(),
    Model::Pandar40p.name(),
    Model::Vlp16.name(),
    Model::Vlp32c.name(),
    Model::Hdl32e.name(),
    Model::PandarXt32.name(),
    Model::PandarQt64.name(),
    Model::Ouster.name(),
    PCD,
];

/// The files' spelling of a LiDAR whose points come as files, not packets.
pub const PCD: &str = "pcd";

/// The type name serde's messages give a LiDAR model ("expected enum LidarModel"), kept so
/// a file's error reads as it always has.
const SERDE_NAME: &str = "LidarModel";

impl Model {
    /// The files' spelling of a LiDAR's model: its [`Model::name`], or [`PCD`] for `None`.
    pub fn file_name(model: Option<Model>) -> &'static str {
        model.map_or(PCD, Model::name)
    }

    /// Reads the files' spelling exactly (one of [`FILE_NAMES`], no aliases or other case,
    /// unlike [`Model::from_name`]): `Some(None)` for [`PCD`], `None` for anything else.
    pub fn from_file_name(name: &str) -> Option<Option<Model>> {
        if name == PCD {
            return Some(None);
        }
        Model::ALL.into_iter().find(|m| m.name() == name).map(Some)
    }
}

/// A LiDAR's `model` field of type `Option<Model>` (`None`: points come as files), read and
/// written as one of [`FILE_NAMES`] (`#[serde(with = "crate::lidar::common::model_or_pcd")]`).
pub mod model_or_pcd {
    use super::*;

    pub fn serialize<S: Serializer>(model: &Option<Model>, s: S) -> Result<S::Ok, S::Error> {
        let name = Model::file_name(*model);
        // Only binary formats use the index; every name is in the list.
        let index = FILE_NAMES.iter().position(|n| *n == name).unwrap_or(0) as u32;
        s.serialize_unit_variant(SERDE_NAME, index, name)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Model>, D::Error> {
        d.deserialize_enum(SERDE_NAME, &FILE_NAMES, ModelVisitor)
    }
}

/// A packet model where a file names one (the simulator's truth), spelt as in the room file.
impl Serialize for Model {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        model_or_pcd::serialize(&Some(*self), s)
    }
}

/// [`PCD`] is refused here: the field needs a packet format.
impl<'de> Deserialize<'de> for Model {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        model_or_pcd::deserialize(d)?.ok_or_else(|| {
            de::Error::invalid_value(Unexpected::UnitVariant, &"a LiDAR model with packets")
        })
    }
}

/// A unit enum's value as serde's derive reads one (a string, or a one-key table whose
/// value is empty), so the files' messages are the derive's.
struct ModelVisitor;

impl<'de> Visitor<'de> for ModelVisitor {
    type Value = Option<Model>;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(f, "enum {SERDE_NAME}")
    }

    fn visit_enum<A: EnumAccess<'de>>(self, data: A) -> Result<Self::Value, A::Error> {
        let (FileName(model), variant) = data.variant()?;
        variant.unit_variant()?;
        Ok(model)
    }
}

/// One of [`FILE_NAMES`] as an enum's variant name (or its index).
struct FileName(Option<Model>);

impl<'de> Deserialize<'de> for FileName {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_identifier(FileNameVisitor)
    }
}

struct FileNameVisitor;

impl<'de> Visitor<'de> for FileNameVisitor {
    type Value = FileName;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("variant identifier")
    }

    fn visit_u64<E: de::Error>(self, v: u64) -> Result<FileName, E> {
        match FILE_NAMES.get(v as usize) {
            Some(name) => self.visit_str(name),
            None => Err(E::invalid_value(Unexpected::Unsigned(v), &"variant index 0 <= i < 9")),
        }
    }

    fn visit_str<E: de::Error>(self, v: &str) -> Result<FileName, E> {
        Model::from_file_name(v).map(FileName).ok_or_else(|| E::unknown_variant(v, &FILE_NAMES))
    }

    fn visit_bytes<E: de::Error>(self, v: &[u8]) -> Result<FileName, E> {
        match core::str::from_utf8(v) {
            Ok(s) => self.visit_str(s),
            Err(_) => Err(E::invalid_value(Unexpected::Bytes(v), &self)),
        }
    }
}

/// How many echoes a packet carries per firing, and which.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReturnMode {
    Strongest,
    Last,
    /// Hesai only.
    First,
    /// Two echoes per firing (Velodyne: last + strongest; Hesai: any dual mode).
    Dual,
}

impl ReturnMode {
    /// Echoes per firing.
    pub fn returns(self) -> usize {
        if self == ReturnMode::Dual {
            2
        } else {
            1
        }
    }
}

/// Why a payload was not decoded. Decoders never panic on bytes; they answer one of these.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DecodeError {
    /// Shorter than the format's fixed length.
    Truncated { len: usize, expected: usize },
    /// Longer than the format's fixed length.
    Oversized { len: usize, expected: usize },
    /// A start-of-packet / start-of-block magic is wrong.
    BadMagic,
    /// A header field (laser or block count, distance unit, product id) does not match the model.
    BadHeader,
    /// The return-mode byte is not one the format defines.
    BadReturnMode(u8),
    /// An azimuth is out of range (≥ 360°).
    BadAzimuth(u16),
    /// The calibration is for another model.
    WrongCalibration,
    /// The blocks' azimuths do not advance as a spinning sensor's do (the block's index).
    AzimuthOrder(u8),
    /// A timestamp field is out of its range (month 13, 1.2 million microseconds, ...).
    BadTimestamp,
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DecodeError::Truncated { len, expected } => {
                write!(f, "truncated packet: {len} bytes, expected {expected}")
            }
            DecodeError::Oversized { len, expected } => {
                write!(f, "oversized packet: {len} bytes, expected {expected}")
            }
            DecodeError::BadMagic => write!(f, "bad start-of-packet or start-of-block magic"),
            DecodeError::BadHeader => write!(f, "header does not match the model"),
            DecodeError::BadReturnMode(m) => write!(f, "unknown return mode 0x{m:02x}"),
            DecodeError::BadAzimuth(a) => write!(f, "azimuth {a} out of range (0..36000)"),
            DecodeError::WrongCalibration => write!(f, "calibration is for another model"),
            DecodeError::AzimuthOrder(b) => {
                write!(f, "block {b}'s azimuth does not follow the one before it")
            }
            DecodeError::BadTimestamp => write!(f, "timestamp field out of range"),
        }
    }
}

/// Largest azimuth step between consecutive blocks of one packet, 0.01°: the coarsest
/// firing step of the supported models is 0.8° (a VLP-16 block at 20 Hz); 3° leaves room.
pub const MAX_BLOCK_STEP: u16 = 300;

/// Checks that block azimuths (each < 36000) advance as a spinning sensor's do: clockwise,
/// by at most [`MAX_BLOCK_STEP`] per block (equal azimuths are dual-return pairs or padding),
/// except for one jump where a field-of-view limit skips the blind sector, and less than a
/// turn in all. Random bytes pass this with odds below 10⁻⁷ for ≥ 6 blocks.
pub fn check_azimuth_order(azimuths: impl Iterator<Item = u16>) -> Result<(), DecodeError> {
    let (mut last, mut total, mut jumps) = (None::<u16>, 0u32, 0);
    for (b, az) in azimuths.enumerate() {
        if let Some(prev) = last {
            let step = (36000 + u32::from(az) - u32::from(prev)) % 36000;
            total += step;
            jumps += u32::from(step > u32::from(MAX_BLOCK_STEP));
            if jumps > 1 || total >= 36000 {
                return Err(DecodeError::AzimuthOrder(b.min(255) as u8));
            }
        }
        last = Some(az);
    }
    Ok(())
}

/// One decoded return: the point plus what sweep assembly and filters need.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Return {
    pub point: Point,
    /// Range after distance correction, metres.
    pub distance: f32,
    /// Azimuth of the firing (block azimuth, interpolated per firing where the model needs it),
    /// before the per-laser offset: hundredths of a degree, clockwise seen from above, 0 = +x.
    pub azimuth: u16,
    /// Block index in the packet.
    pub block: u8,
    /// 0 = first echo slot of the firing (strongest/last/first), 1 = second slot (dual).
    pub echo: u8,
}

/// What a decoded packet said about itself.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PacketSummary {
    pub model: Model,
    pub return_mode: ReturnMode,
    /// Packet time, seconds: Velodyne = seconds past the top of the hour (sensor clock);
    /// Hesai = Unix seconds from the packet's date/time and microseconds fields.
    pub time: f64,
    /// Azimuth of the first and of the last block, hundredths of a degree.
    pub first_azimuth: u16,
    pub last_azimuth: u16,
    /// Hesai UDP sequence number when the packet carries one.
    pub sequence: Option<u32>,
    /// Returns handed to the sink (zero-range and duplicate dual echoes are not).
    pub returns: usize,
}

/// A simulated return to encode: laser (channel) number, block azimuth (0.01°, before the
/// laser's azimuth offset), range (m), intensity.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SimReturn {
    pub laser: u16,
    pub azimuth: u16,
    pub range: f32,
    pub intensity: u8,
}

/// Converts range and angles to the sensor frame (x forward, y left, z up). `azimuth` is
/// clockwise seen from above with 0 = forward, as both vendors count it; `vert_offset` and
/// `horiz_offset` are Velodyne's optical-centre offsets (0 for Hesai).
#[inline]
pub(crate) fn to_xyz(
    distance: f32,
    sin_az: f32,
    cos_az: f32,
    sin_el: f32,
    cos_el: f32,
    vert_offset: f32,
    horiz_offset: f32,
) -> (f32, f32, f32) {
    let xy = distance * cos_el - vert_offset * sin_el;
    // Velodyne's manual frame is x right, y forward; rotate to x forward, y left.
    let x_right = xy * sin_az - horiz_offset * cos_az;
    let y_fwd = xy * cos_az + horiz_offset * sin_az;
    let z = distance * sin_el + vert_offset * cos_el;
    (y_fwd, -x_right, z)
}

/// Seconds since the Unix epoch of a UTC civil date and time (no leap seconds).
pub(crate) fn unix_seconds(year: i64, month: u32, day: u32, h: u32, m: u32, s: u32) -> i64 {
    // Howard Hinnant's days_from_civil.
    let y = if month <= 2 { year - 1 } else { year };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (i64::from(month) + 9) % 12;
    let doy = (153 * mp + 2) / 5 + i64::from(day) - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    let days = era * 146_097 + doe - 719_468;
    days * 86_400 + i64::from(h) * 3600 + i64::from(m) * 60 + i64::from(s)
}

/// UTC civil date and time (year, month, day, hour, minute, second) of Unix seconds.
pub(crate) fn civil_from_unix(t: i64) -> (i64, u32, u32, u32, u32, u32) {
    let days = t.div_euclid(86_400);
    let sod = t.rem_euclid(86_400) as u32;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let month = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let year = yoe + era * 400 + i64::from(month <= 2);
    (year, month, day, sod / 3600, sod / 60 % 60, sod % 60)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn model_names_round_trip() {
        for m in Model::ALL {
            assert_eq!(Model::from_name(m.name()), Some(m));
        }
        assert_eq!(Model::from_name("VLP-32C"), Some(Model::Vlp32c));
        assert_eq!(Model::from_name("Pandar_64"), Some(Model::Pandar64));
        assert_eq!(Model::from_name("PandarXT-32"), Some(Model::PandarXt32));
        assert_eq!(Model::from_name("OUSTER"), Some(Model::Ouster));
        for m in Model::ALL {
            assert!(Model::NAMES.contains(m.name()), "{m:?}");
        }
        assert_eq!(Model::from_name("hdl64e"), None);
        assert_eq!(Model::from_name("a-very-long-name-indeed"), None);
    }

    #[test]
    fn civil_time_round_trips() {
        assert_eq!(unix_seconds(1970, 1, 1, 0, 0, 0), 0);
        assert_eq!(unix_seconds(2023, 1, 11, 2, 24, 40), 1_673_403_880);
        for t in [0i64, 951_782_400, 1_673_403_880, 4_102_444_799, 4_762_094_400] {
            let (y, mo, d, h, mi, s) = civil_from_unix(t);
            assert_eq!(unix_seconds(y, mo, d, h, mi, s), t, "{t}");
        }
    }

    #[test]
    fn frame_is_x_forward_y_left() {
        // Azimuth 90° clockwise from forward = to the right = -y.
        let (x, y, z) = to_xyz(10.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0);
        assert!(x.abs() < 1e-6 && (y + 10.0).abs() < 1e-6 && z == 0.0);
        let (x, y, _) = to_xyz(10.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0);
        assert!((x - 10.0).abs() < 1e-6 && y.abs() < 1e-6);
    }
}
