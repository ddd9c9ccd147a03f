//! The wire vocabulary of roomcal's UDS service: service, data and routine identifiers,
//! negative response codes, the data identifiers' records with their `parse`/`emit`, and the
//! byte helpers the server and the request/response views share.

use core::fmt;

use crate::geometry::body::BodyPose;
use crate::geometry::{Se3, Vec3};

/// Service identifiers.
pub mod sid {
    pub const DIAGNOSTIC_SESSION_CONTROL: u8 = 0x10;
    pub const SECURITY_ACCESS: u8 = 0x27;
    pub const READ_DATA_BY_IDENTIFIER: u8 = 0x22;
    pub const ROUTINE_CONTROL: u8 = 0x31;
    pub const TESTER_PRESENT: u8 = 0x3E;
    /// First byte of every negative response.
    pub const NEGATIVE_RESPONSE: u8 = 0x7F;
    /// A positive response's first byte is the request SID plus this.
    pub const POSITIVE_OFFSET: u8 = 0x40;
}

/// Data identifiers served by ReadDataByIdentifier.
pub mod did {
    /// [`super::StateRecord`].
    pub const STATE: u16 = 0xC001;
    /// [`super::IntrinsicsRecord`].
    pub const INTRINSICS: u16 = 0xC002;
    /// [`super::ExtrinsicRecord`].
    pub const EXTRINSIC: u16 = 0xC003;
    /// [`super::QualityRecord`].
    pub const QUALITY: u16 = 0xC004;
    /// [`super::SensorTable`]: the vehicle's sensors; a sensor's index is its place here.
    pub const SENSORS: u16 = 0xC010;
    /// `SENSOR_INTRINSICS + i`: camera `i`'s [`super::IntrinsicsRecord`] (0xC200 = 0xC002's).
    pub const SENSOR_INTRINSICS: u16 = 0xC200;
    /// `SENSOR_EXTRINSIC + i`: sensor `i` → the first camera, [`super::ExtrinsicRecord`]
    /// (0xC300 is the identity; for the one-pair rig 0xC301 = 0xC003).
    pub const SENSOR_EXTRINSIC: u16 = 0xC300;

    /// The sensor index of `did` if it is `base + i` for a sensor index `i` (one of the
    /// per-sensor ranges above), else `None`.
    pub fn sensor_index(did: u16, base: u16) -> Option<u8> {
        let i = did.checked_sub(base)?;
        u8::try_from(i).ok().filter(|i| usize::from(*i) < super::MAX_SENSORS)
    }
}

/// Routine identifiers served by RoutineControl.
pub mod rid {
    /// Start a calibration (0x01), read the last run's result (0x03).
    pub const START_CALIBRATION: u16 = 0xC100;
    /// Roll back to the previous calibration (0x01).
    pub const ROLLBACK: u16 = 0xC101;
}

/// Sub-function bit asking the server not to send a positive response.
pub const SUPPRESS_POSITIVE_RESPONSE: u8 = 0x80;
/// SecurityAccess seed and key length.
pub const SEED_LEN: usize = 16;
/// Most DIDs accepted in one ReadDataByIdentifier request.
pub const MAX_DIDS_PER_REQUEST: usize = 8;
/// Most distortion coefficients in an intrinsics record.
pub const MAX_DISTORTION: usize = 8;
/// Most sensors the sensor table (DID 0xC010) lists: a full rig's cameras and LiDARs.
pub const MAX_SENSORS: usize = crate::rig::MAX_CAMERAS + crate::rig::MAX_LIDARS;
/// Longest sensor name in the sensor table, bytes (rig names are `[a-z0-9_-]+`).
pub const MAX_SENSOR_NAME: usize = crate::rig::MAX_SENSOR_NAME;
/// Largest record: the sensor table with every sensor at the longest name (intrinsics with
/// every distortion coefficient are 18 + 4 · 8 = 50 bytes).
pub const MAX_RECORD: usize = 1 + MAX_SENSORS * (2 + MAX_SENSOR_NAME);
/// Largest response the server builds: what one ISO-TP message carries (4095 bytes). Only
/// a request for the largest sensor table many times over exceeds it (8 × 545 bytes) and
/// gets NRC 0x14 (responseTooLong, meant for just that); every other valid request fits
/// (8 × the largest intrinsics record is 417 bytes).
pub const MAX_RESPONSE: usize = 4095;

/// A response message.
pub type Response = heapless::Vec<u8, MAX_RESPONSE>;

/// Negative response codes used by the server (ISO 14229-1 annex A.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Nrc {
    GeneralReject = 0x10,
    ServiceNotSupported = 0x11,
    SubFunctionNotSupported = 0x12,
    IncorrectMessageLengthOrInvalidFormat = 0x13,
    ResponseTooLong = 0x14,
    BusyRepeatRequest = 0x21,
    ConditionsNotCorrect = 0x22,
    RequestSequenceError = 0x24,
    RequestOutOfRange = 0x31,
    SecurityAccessDenied = 0x33,
    InvalidKey = 0x35,
    ExceededNumberOfAttempts = 0x36,
    RequiredTimeDelayNotExpired = 0x37,
    ResponsePending = 0x78,
    SubFunctionNotSupportedInActiveSession = 0x7E,
    ServiceNotSupportedInActiveSession = 0x7F,
}

impl Nrc {
    /// The code for a byte, if the server knows it.
    pub fn from_u8(b: u8) -> Option<Nrc> {
        use Nrc::*;
        Some(match b {
            0x10 => GeneralReject,
            0x11 => ServiceNotSupported,
            0x12 => SubFunctionNotSupported,
            0x13 => IncorrectMessageLengthOrInvalidFormat,
            0x14 => ResponseTooLong,
            0x21 => BusyRepeatRequest,
            0x22 => ConditionsNotCorrect,
            0x24 => RequestSequenceError,
            0x31 => RequestOutOfRange,
            0x33 => SecurityAccessDenied,
            0x35 => InvalidKey,
            0x36 => ExceededNumberOfAttempts,
            0x37 => RequiredTimeDelayNotExpired,
            0x78 => ResponsePending,
            0x7E => SubFunctionNotSupportedInActiveSession,
            0x7F => ServiceNotSupportedInActiveSession,
            _ => return None,
        })
    }

    /// The ISO 14229 name.
    pub fn name(self) -> &'static str {
        use Nrc::*;
        match self {
            GeneralReject => "generalReject",
            ServiceNotSupported => "serviceNotSupported",
            SubFunctionNotSupported => "subFunctionNotSupported",
            IncorrectMessageLengthOrInvalidFormat => "incorrectMessageLengthOrInvalidFormat",
            ResponseTooLong => "responseTooLong",
            BusyRepeatRequest => "busyRepeatRequest",
            ConditionsNotCorrect => "conditionsNotCorrect",
            RequestSequenceError => "requestSequenceError",
            RequestOutOfRange => "requestOutOfRange",
            SecurityAccessDenied => "securityAccessDenied",
            InvalidKey => "invalidKey",
            ExceededNumberOfAttempts => "exceededNumberOfAttempts",
            RequiredTimeDelayNotExpired => "requiredTimeDelayNotExpired",
            ResponsePending => "requestCorrectlyReceived-ResponsePending",
            SubFunctionNotSupportedInActiveSession => "subFunctionNotSupportedInActiveSession",
            ServiceNotSupportedInActiveSession => "serviceNotSupportedInActiveSession",
        }
    }
}

impl fmt::Display for Nrc {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} (0x{:02X})", self.name(), *self as u8)
    }
}

/// Diagnostic session.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Session {
    Default = 0x01,
    Extended = 0x03,
}

/// What the daemon is doing (DID 0xC001, first byte).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DaemonState {
    Idle = 0,
    RoomSeen = 1,
    Capturing = 2,
    Solving = 3,
    Accepted = 4,
    Rejected = 5,
    Error = 6,
}

impl DaemonState {
    /// The state for a wire byte.
    pub fn from_u8(b: u8) -> Option<Self> {
        use DaemonState::*;
        Some(match b {
            0 => Idle,
            1 => RoomSeen,
            2 => Capturing,
            3 => Solving,
            4 => Accepted,
            5 => Rejected,
            6 => Error,
            _ => return None,
        })
    }

    /// Lower-case name as printed by `roomcal query`.
    pub fn name(self) -> &'static str {
        use DaemonState::*;
        match self {
            Idle => "idle",
            RoomSeen => "room seen",
            Capturing => "capturing",
            Solving => "solving",
            Accepted => "accepted",
            Rejected => "rejected",
            Error => "error",
        }
    }
}

/// Why a record could not be decoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DecodeError {
    /// Fewer bytes than the record needs.
    Truncated { need: usize, got: usize },
    /// More bytes than the record has.
    TrailingBytes { expected: usize, got: usize },
    /// A field holds a value outside its range (the field's name).
    BadValue(&'static str),
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DecodeError::Truncated { need, got } => {
                write!(f, "record truncated: {got} bytes, need {need}")
            }
            DecodeError::TrailingBytes { expected, got } => {
                write!(f, "record has {got} bytes, expected {expected}")
            }
            DecodeError::BadValue(field) => write!(f, "record field `{field}` out of range"),
        }
    }
}

/// Big-endian reader that reports truncation instead of panicking.
struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn new(bytes: &'a [u8]) -> Self {
        Reader { bytes, pos: 0 }
    }

    fn take<const K: usize>(&mut self, need_total: usize) -> Result<[u8; K], DecodeError> {
        let got = self.bytes.len();
        let chunk = self
            .bytes
            .get(self.pos..self.pos + K)
            .ok_or(DecodeError::Truncated { need: need_total.max(self.pos + K), got })?;
        self.pos += K;
        let mut out = [0; K];
        out.copy_from_slice(chunk);
        Ok(out)
    }

    fn u8(&mut self, need: usize) -> Result<u8, DecodeError> {
        Ok(self.take::<1>(need)?[0])
    }

    fn u32(&mut self, need: usize) -> Result<u32, DecodeError> {
        Ok(u32::from_be_bytes(self.take(need)?))
    }

    fn f32(&mut self, need: usize) -> Result<f32, DecodeError> {
        Ok(f32::from_be_bytes(self.take(need)?))
    }

    fn bytes(&mut self, k: usize) -> Result<&'a [u8], DecodeError> {
        let got = self.bytes.len();
        let chunk = self
            .bytes
            .get(self.pos..self.pos + k)
            .ok_or(DecodeError::Truncated { need: self.pos + k, got })?;
        self.pos += k;
        Ok(chunk)
    }

    fn finish(&self) -> Result<(), DecodeError> {
        if self.pos == self.bytes.len() {
            Ok(())
        } else {
            Err(DecodeError::TrailingBytes { expected: self.pos, got: self.bytes.len() })
        }
    }
}

/// Big-endian writer into a caller's buffer; `None` when it does not fit.
pub(super) struct Writer<'a> {
    buf: &'a mut [u8],
    pos: usize,
}

impl<'a> Writer<'a> {
    pub(super) fn new(buf: &'a mut [u8]) -> Self {
        Writer { buf, pos: 0 }
    }

    pub(super) fn put(&mut self, bytes: &[u8]) -> Option<()> {
        self.buf.get_mut(self.pos..self.pos + bytes.len())?.copy_from_slice(bytes);
        self.pos += bytes.len();
        Some(())
    }

    /// Bytes written so far.
    pub(super) fn len(&self) -> usize {
        self.pos
    }
}

/// DID 0xC001: u8 state, u32 generation, u32 unix time of the current calibration.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StateRecord {
    pub state: DaemonState,
    /// Generation of the calibration in force (0: none yet).
    pub generation: u32,
    /// Unix time (s) the calibration in force was written.
    pub time: u32,
}

impl StateRecord {
    /// Encoded length.
    pub const LEN: usize = 9;

    /// Decodes the record.
    pub fn parse(bytes: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new(bytes);
        let state = DaemonState::from_u8(r.u8(Self::LEN)?).ok_or(DecodeError::BadValue("state"))?;
        let rec = StateRecord { state, generation: r.u32(Self::LEN)?, time: r.u32(Self::LEN)? };
        r.finish()?;
        Ok(rec)
    }

    /// Encodes into `buf`; returns the bytes written, `None` if `buf` is too short.
    pub fn emit(&self, buf: &mut [u8]) -> Option<usize> {
        let mut w = Writer::new(buf);
        w.put(&[self.state as u8])?;
        w.put(&self.generation.to_be_bytes())?;
        w.put(&self.time.to_be_bytes())?;
        Some(w.pos)
    }
}

impl fmt::Display for StateRecord {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "state:      {}", self.state.name())?;
        writeln!(f, "generation: {}", self.generation)?;
        write!(f, "time:       ")?;
        match self.time {
            0 => write!(f, "none"),
            t => {
                let (y, mo, d, h, mi, s) = crate::lidar::common::civil_from_unix(i64::from(t));
                write!(f, "{y:04}-{mo:02}-{d:02}T{h:02}:{mi:02}:{s:02}Z")
            }
        }
    }
}

/// Camera model byte of DID 0xC002.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraModel {
    /// OpenCV k1 k2 p1 p2 k3.
    PinholeRadtan = 0,
    /// Kannala–Brandt k1..k4.
    Fisheye = 1,
}

impl CameraModel {
    /// Name as in the room and result files.
    pub fn name(self) -> &'static str {
        match self {
            CameraModel::PinholeRadtan => "pinhole-radtan",
            CameraModel::Fisheye => "fisheye",
        }
    }
}

/// DID 0xC002: u8 model, f32 fx fy cx cy, u8 n, n × f32 distortion.
#[derive(Clone, Debug, PartialEq)]
pub struct IntrinsicsRecord {
    pub model: CameraModel,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    pub distortion: heapless::Vec<f32, MAX_DISTORTION>,
}

impl IntrinsicsRecord {
    /// Encoded length.
    pub fn buffer_len(&self) -> usize {
        1 + 16 + 1 + 4 * self.distortion.len()
    }

    /// Decodes the record.
    pub fn parse(bytes: &[u8]) -> Result<Self, DecodeError> {
        const HEAD: usize = 18;
        let mut r = Reader::new(bytes);
        let model = match r.u8(HEAD)? {
            0 => CameraModel::PinholeRadtan,
            1 => CameraModel::Fisheye,
            _ => return Err(DecodeError::BadValue("model")),
        };
        let (fx, fy, cx, cy) = (r.f32(HEAD)?, r.f32(HEAD)?, r.f32(HEAD)?, r.f32(HEAD)?);
        let n = usize::from(r.u8(HEAD)?);
        if n > MAX_DISTORTION {
            return Err(DecodeError::BadValue("distortion count"));
        }
        let mut distortion = heapless::Vec::new();
        for _ in 0..n {
            // n <= capacity, checked above.
            let _ = distortion.push(r.f32(HEAD + 4 * n)?);
        }
        r.finish()?;
        Ok(IntrinsicsRecord { model, fx, fy, cx, cy, distortion })
    }

    /// Encodes into `buf`; returns the bytes written, `None` if `buf` is too short.
    pub fn emit(&self, buf: &mut [u8]) -> Option<usize> {
        let mut w = Writer::new(buf);
        w.put(&[self.model as u8])?;
        for v in [self.fx, self.fy, self.cx, self.cy] {
            w.put(&v.to_be_bytes())?;
        }
        // len <= MAX_DISTORTION = 8.
        w.put(&[self.distortion.len() as u8])?;
        for v in &self.distortion {
            w.put(&v.to_be_bytes())?;
        }
        Some(w.pos)
    }
}

impl fmt::Display for IntrinsicsRecord {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "model:      {}", self.model.name())?;
        writeln!(f, "fx, fy:     {:.3}, {:.3} px", self.fx, self.fy)?;
        writeln!(f, "cx, cy:     {:.3}, {:.3} px", self.cx, self.cy)?;
        write!(f, "distortion: [")?;
        for (i, d) in self.distortion.iter().enumerate() {
            if i > 0 {
                write!(f, ", ")?;
            }
            write!(f, "{d:.6}")?;
        }
        write!(f, "]")
    }
}

/// DID 0xC003: f32 quaternion w x y z, f32 translation x y z (m), LiDAR → camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExtrinsicRecord {
    /// Unit quaternion w, x, y, z.
    pub rotation: [f32; 4],
    /// Metres.
    pub translation: [f32; 3],
}

impl ExtrinsicRecord {
    /// Encoded length.
    pub const LEN: usize = 28;
    /// A sensor to itself.
    pub const IDENTITY: ExtrinsicRecord =
        ExtrinsicRecord { rotation: [1.0, 0.0, 0.0, 0.0], translation: [0.0; 3] };

    /// Decodes the record.
    pub fn parse(bytes: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new(bytes);
        let mut rec = ExtrinsicRecord { rotation: [0.0; 4], translation: [0.0; 3] };
        for q in &mut rec.rotation {
            *q = r.f32(Self::LEN)?;
        }
        for t in &mut rec.translation {
            *t = r.f32(Self::LEN)?;
        }
        r.finish()?;
        Ok(rec)
    }

    /// Encodes into `buf`; returns the bytes written, `None` if `buf` is too short.
    pub fn emit(&self, buf: &mut [u8]) -> Option<usize> {
        let mut w = Writer::new(buf);
        for v in self.rotation.iter().chain(&self.translation) {
            w.put(&v.to_be_bytes())?;
        }
        Some(w.pos)
    }

    /// The sensor's pose in the camera's body frame; `None` for a record whose quaternion
    /// is no rotation (zero, or not finite).
    pub fn body_pose(&self, sensor_is_camera: bool) -> Option<BodyPose> {
        let q = self.rotation.map(f64::from);
        let t = self.translation.map(f64::from);
        let pose = Se3::from_quaternion(&q, &Vec3::new(t[0], t[1], t[2]))?;
        Some(BodyPose::of(&pose, sensor_is_camera))
    }
}

impl fmt::Display for ExtrinsicRecord {
    /// A LiDAR's pose as people read it ([`BodyPose`]); for a camera sensor the client
    /// uses [`ExtrinsicRecord::body_pose`] with its kind.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.body_pose(false) {
            Some(pose) => write!(f, "{pose} in the camera's body frame (x forward, y left, z up)"),
            None => write!(f, "no rotation: quaternion {:?}", self.rotation),
        }
    }
}

/// DID 0xC004: f32 corner RMS px, f32 hole RMS px, u8 boards.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QualityRecord {
    pub corner_rms_px: f32,
    pub hole_rms_px: f32,
    pub boards: u8,
}

impl QualityRecord {
    /// Encoded length.
    pub const LEN: usize = 9;

    /// Decodes the record.
    pub fn parse(bytes: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new(bytes);
        let rec = QualityRecord {
            corner_rms_px: r.f32(Self::LEN)?,
            hole_rms_px: r.f32(Self::LEN)?,
            boards: r.u8(Self::LEN)?,
        };
        r.finish()?;
        Ok(rec)
    }

    /// Encodes into `buf`; returns the bytes written, `None` if `buf` is too short.
    pub fn emit(&self, buf: &mut [u8]) -> Option<usize> {
        let mut w = Writer::new(buf);
        w.put(&self.corner_rms_px.to_be_bytes())?;
        w.put(&self.hole_rms_px.to_be_bytes())?;
        w.put(&[self.boards])?;
        Some(w.pos)
    }
}

impl fmt::Display for QualityRecord {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "corner RMS: {:.3} px", self.corner_rms_px)?;
        writeln!(f, "hole RMS:   {:.3} px", self.hole_rms_px)?;
        write!(f, "boards:     {}", self.boards)
    }
}

/// What a sensor of the sensor table is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SensorKind {
    Camera = 0,
    Lidar = 1,
}

/// One sensor of the sensor table: its kind and its rig name.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SensorEntry {
    pub kind: SensorKind,
    /// `[a-z0-9_-]{1,32}`.
    pub name: heapless::String<MAX_SENSOR_NAME>,
}

/// DID 0xC010: u8 n, then per sensor u8 kind (0 camera, 1 LiDAR), u8 name length, the
/// name (ASCII `[a-z0-9_-]`). A sensor's index (`i` of DIDs 0xC200 + i and 0xC300 + i) is
/// its place in the table: the rig's cameras in the rig file's order, then its LiDARs; the
/// first camera is the vehicle's reference.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SensorTable {
    pub sensors: heapless::Vec<SensorEntry, MAX_SENSORS>,
}

impl SensorTable {
    /// The one-pair rig of a room file's `[camera]` (and `[lidar]`): `camera` (and `lidar`).
    pub fn one_pair(lidar: bool) -> Self {
        let mut table = SensorTable::default();
        // Two short valid names always fit.
        let _ = table.push(SensorKind::Camera, crate::rig::PAIR_CAMERA);
        if lidar {
            let _ = table.push(SensorKind::Lidar, crate::rig::PAIR_LIDAR);
        }
        table
    }

    /// The table of `sensors` (kind, name), in their order; `Err` when one does not fit
    /// ([`SensorTable::push`]).
    pub fn of<'a>(
        sensors: impl IntoIterator<Item = (SensorKind, &'a str)>,
    ) -> Result<Self, DecodeError> {
        let mut table = SensorTable::default();
        for (kind, name) in sensors {
            table.push(kind, name)?;
        }
        Ok(table)
    }

    /// Appends a sensor; `Err` when the table is full or the name is not a rig name.
    pub fn push(&mut self, kind: SensorKind, name: &str) -> Result<(), DecodeError> {
        if !is_sensor_name(name.as_bytes()) {
            return Err(DecodeError::BadValue("sensor name"));
        }
        let mut owned = heapless::String::new();
        owned.push_str(name).map_err(|_| DecodeError::BadValue("sensor name"))?;
        self.sensors
            .push(SensorEntry { kind, name: owned })
            .map_err(|_| DecodeError::BadValue("sensor count"))
    }

    /// The kind of sensor `index`, `None` past the table.
    pub fn kind(&self, index: u8) -> Option<SensorKind> {
        self.sensors.get(usize::from(index)).map(|s| s.kind)
    }

    /// The index of the sensor called `name`.
    pub fn index_of(&self, name: &str) -> Option<u8> {
        self.sensors.iter().position(|s| s.name == name).map(|i| i as u8)
    }

    /// Encoded length.
    pub fn buffer_len(&self) -> usize {
        1 + self.sensors.iter().map(|s| 2 + s.name.len()).sum::<usize>()
    }

    /// Decodes the record.
    pub fn parse(bytes: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new(bytes);
        let n = usize::from(r.u8(1)?);
        if n > MAX_SENSORS {
            return Err(DecodeError::BadValue("sensor count"));
        }
        let mut table = SensorTable::default();
        for _ in 0..n {
            let kind = match r.u8(r.pos + 2)? {
                0 => SensorKind::Camera,
                1 => SensorKind::Lidar,
                _ => return Err(DecodeError::BadValue("sensor kind")),
            };
            let len = usize::from(r.u8(r.pos + 1)?);
            let name = r.bytes(len)?;
            // `is_sensor_name` admits ASCII only: the bytes are UTF-8.
            let name =
                core::str::from_utf8(name).map_err(|_| DecodeError::BadValue("sensor name"))?;
            table.push(kind, name)?;
        }
        r.finish()?;
        Ok(table)
    }

    /// Encodes into `buf`; returns the bytes written, `None` if `buf` is too short.
    pub fn emit(&self, buf: &mut [u8]) -> Option<usize> {
        let mut w = Writer::new(buf);
        // n <= MAX_SENSORS and names <= MAX_SENSOR_NAME bytes: both fit a byte.
        w.put(&[self.sensors.len() as u8])?;
        for s in &self.sensors {
            w.put(&[s.kind as u8, s.name.len() as u8])?;
            w.put(s.name.as_bytes())?;
        }
        Some(w.pos)
    }
}

impl fmt::Display for SensorTable {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, s) in self.sensors.iter().enumerate() {
            let kind = match s.kind {
                SensorKind::Camera => "camera",
                SensorKind::Lidar => "LiDAR",
            };
            if i > 0 {
                writeln!(f)?;
            }
            write!(f, "{i}: {} ({kind})", s.name)?;
        }
        Ok(())
    }
}

/// A rig name: 1 to [`MAX_SENSOR_NAME`] bytes of `[a-z0-9_-]`.
fn is_sensor_name(name: &[u8]) -> bool {
    (1..=MAX_SENSOR_NAME).contains(&name.len())
        && name
            .iter()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || *b == b'_' || *b == b'-')
}

/// Result of a calibration run (routine 0xC100 status record): u8 state (4 accepted,
/// 5 rejected, 6 error), u32 generation in force afterwards.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Outcome {
    pub state: DaemonState,
    pub generation: u32,
}

impl Outcome {
    /// Encoded length.
    pub const LEN: usize = 5;

    /// Decodes the record.
    pub fn parse(bytes: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new(bytes);
        let state = DaemonState::from_u8(r.u8(Self::LEN)?).ok_or(DecodeError::BadValue("state"))?;
        let rec = Outcome { state, generation: r.u32(Self::LEN)? };
        r.finish()?;
        Ok(rec)
    }

    /// Encodes into `buf`; returns the bytes written, `None` if `buf` is too short.
    pub fn emit(&self, buf: &mut [u8]) -> Option<usize> {
        let mut w = Writer::new(buf);
        w.put(&[self.state as u8])?;
        w.put(&self.generation.to_be_bytes())?;
        Some(w.pos)
    }
}

impl fmt::Display for Outcome {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "calibration {}; generation in force: {}", self.state.name(), self.generation)
    }
}

/// Why the backend refused an action; answered with NRC 0x22 conditionsNotCorrect.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// A run is already in progress.
    Busy,
    /// Nothing to act on (no previous calibration to roll back to, no sensors, ...).
    NotAvailable,
    /// The action failed (store error, ...).
    Failed,
}

/// Checks the minimum length (0x13) and splits the sub-function byte.
pub(super) fn sub_function(req: &[u8], min_len: usize) -> Result<(u8, bool), Nrc> {
    if req.len() < min_len {
        return Err(Nrc::IncorrectMessageLengthOrInvalidFormat);
    }
    let b = req[1];
    Ok((b & !SUPPRESS_POSITIVE_RESPONSE, b & SUPPRESS_POSITIVE_RESPONSE != 0))
}

pub(super) fn exact_len(req: &[u8], len: usize) -> Result<(), Nrc> {
    if req.len() == len {
        Ok(())
    } else {
        Err(Nrc::IncorrectMessageLengthOrInvalidFormat)
    }
}

/// Appends; the server never builds more than `MAX_RESPONSE` bytes (checked in
/// ReadDataByIdentifier, fixed sizes elsewhere), so nothing is lost.
pub(super) fn push(r: &mut Response, bytes: &[u8]) {
    let _ = r.extend_from_slice(bytes);
}
