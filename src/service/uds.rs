//! UDS (ISO 14229-1) server for roomcal's service interface, and the wire encodings of
//! its data identifiers and routine results.
//!
//! The [`Server`] is a sans-I/O state machine: [`Server::handle`] takes one request
//! message (as ISO-TP delivered it) and returns the response to send, if any;
//! [`Server::poll`] runs the timers (S3 session timeout, the periodic 0x78
//! responsePending while a calibration runs, and the final answer once the
//! [`Backend`] reports it). Time is passed in; randomness for SecurityAccess seeds comes
//! from a caller-supplied [`SeedSource`].
//!
//! Services (see DESIGN.md, "Service over CAN"):
//!
//! | SID  | service | sessions | sub-functions |
//! |------|---------|----------|---------------|
//! | 0x10 | DiagnosticSessionControl | all | 0x01 default, 0x03 extended |
//! | 0x3E | TesterPresent | all | 0x00 |
//! | 0x27 | SecurityAccess | extended | 0x01 requestSeed, 0x02 sendKey |
//! | 0x22 | ReadDataByIdentifier | all | – (DIDs 0xC001–0xC004, 0xC010, 0xC200 + i, 0xC300 + i) |
//! | 0x31 | RoutineControl | extended, unlocked | 0x01 start, 0x03 results (RIDs 0xC100, 0xC101) |
//!
//! Negative responses follow the NRC evaluation order of ISO 14229-1:2013 (7.5):
//! SID supported (0x11) → SID supported in the active session (0x7F) → minimum length
//! (0x13) → sub-function supported (0x12) → service-specific checks (exact length 0x13,
//! identifier 0x31, security 0x33, sequence 0x24, conditions 0x22). The
//! suppress-positive-response bit (0x80 of the sub-function) is honoured by every
//! service that has a sub-function; negative responses are never suppressed, and once a
//! 0x78 has gone out the final positive response is sent regardless (ISO 14229-1 7.5).

use core::fmt;
use core::time::Duration;

use hmac::{Hmac, Mac};
use sha2::Sha256;

use super::Instant;

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
struct Writer<'a> {
    buf: &'a mut [u8],
    pos: usize,
}

impl<'a> Writer<'a> {
    fn new(buf: &'a mut [u8]) -> Self {
        Writer { buf, pos: 0 }
    }

    fn put(&mut self, bytes: &[u8]) -> Option<()> {
        self.buf.get_mut(self.pos..self.pos + bytes.len())?.copy_from_slice(bytes);
        self.pos += bytes.len();
        Some(())
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
        write!(f, "time:       {} (unix s)", self.time)
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
}

impl fmt::Display for ExtrinsicRecord {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [w, x, y, z] = self.rotation;
        // Rotation angle of the quaternion, for a quick plausibility read.
        let angle = 2.0 * libm::acosf(libm::fabsf(w).min(1.0)) * (180.0 / core::f32::consts::PI);
        writeln!(f, "rotation (w x y z): [{w:.6}, {x:.6}, {y:.6}, {z:.6}] ({angle:.3} deg)")?;
        let [tx, ty, tz] = self.translation;
        write!(f, "translation (m):    [{tx:.4}, {ty:.4}, {tz:.4}]")
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

/// What the UDS server needs from the daemon. Implementations must not block: every
/// method is called from the protocol loop.
pub trait Backend {
    /// Current state and the calibration in force (DID 0xC001).
    fn state(&self) -> StateRecord;
    /// Intrinsics in force (DID 0xC002); `None` before the first calibration
    /// (answered with NRC 0x22).
    fn intrinsics(&self) -> Option<IntrinsicsRecord>;
    /// LiDAR → camera extrinsic in force (DID 0xC003); `None` if there is none.
    fn extrinsic(&self) -> Option<ExtrinsicRecord>;
    /// Quality of the calibration in force (DID 0xC004); `None` if there is none.
    fn quality(&self) -> Option<QualityRecord>;
    /// The vehicle's sensors (DID 0xC010); by default the one-pair rig, camera and LiDAR.
    fn sensors(&self) -> SensorTable {
        SensorTable::one_pair(true)
    }
    /// Intrinsics in force of camera `index` (DIDs 0xC200 + index); by default camera 0's
    /// are [`Backend::intrinsics`].
    fn sensor_intrinsics(&self, index: u8) -> Option<IntrinsicsRecord> {
        one_pair_intrinsics(self, index)
    }
    /// Extrinsic in force of sensor `index` → the first camera (DIDs 0xC300 + index); the
    /// first camera's own is the identity, and by default sensor 1's is
    /// [`Backend::extrinsic`].
    fn sensor_extrinsic(&self, index: u8) -> Option<ExtrinsicRecord> {
        one_pair_extrinsic(self, index)
    }
    /// Starts a calibration run (routine 0xC100 start). Returns at once; the server then
    /// polls [`Backend::calibration_finished`] and answers 0x78 meanwhile.
    fn start_calibration(&mut self) -> Result<(), Refusal>;
    /// `Some` once the run started by `start_calibration` is over.
    fn calibration_finished(&mut self) -> Option<Outcome>;
    /// Puts the previous calibration back in force (routine 0xC101); returns the
    /// generation now in force.
    fn rollback(&mut self) -> Result<u32, Refusal>;
    /// SecurityAccess changed: `failed_attempts` wrong keys in a row, and locked for
    /// `locked_for` from now (`None`: not locked). A backend persists it so that a restart
    /// keeps the lock (see [`Server::restore_security`]); by default it is not kept.
    fn security_changed(&mut self, _failed_attempts: u8, _locked_for: Option<Duration>) {}
}

/// The one-pair rig's camera intrinsics (DIDs 0xC200 + index): camera 0's are DID
/// 0xC002's; there is no other camera.
pub fn one_pair_intrinsics<B: Backend + ?Sized>(
    backend: &B,
    index: u8,
) -> Option<IntrinsicsRecord> {
    (index == 0).then(|| backend.intrinsics())?
}

/// The one-pair rig's extrinsics (DIDs 0xC300 + index): the camera's is the identity, the
/// LiDAR's (sensor 1) DID 0xC003's.
pub fn one_pair_extrinsic<B: Backend + ?Sized>(backend: &B, index: u8) -> Option<ExtrinsicRecord> {
    match index {
        0 => Some(ExtrinsicRecord::IDENTITY),
        1 => backend.extrinsic(),
        _ => None,
    }
}

/// Source of SecurityAccess seeds; must be unpredictable (an OS or hardware RNG).
pub trait SeedSource {
    /// Fills `seed` with fresh random bytes.
    fn fill_seed(&mut self, seed: &mut [u8; SEED_LEN]);
}

impl<F: FnMut(&mut [u8; SEED_LEN])> SeedSource for F {
    fn fill_seed(&mut self, seed: &mut [u8; SEED_LEN]) {
        self(seed)
    }
}

/// The SecurityAccess key for `seed`: the first 16 bytes of HMAC-SHA256(secret, seed).
pub fn security_key(secret: &[u8], seed: &[u8]) -> [u8; SEED_LEN] {
    // HMAC accepts keys of any length, so this cannot fail.
    let mac = <Hmac<Sha256> as Mac>::new_from_slice(secret).ok();
    mac.map_or([0; SEED_LEN], |mac| key_from_mac(mac, seed))
}

fn key_from_mac(mut mac: Hmac<Sha256>, seed: &[u8]) -> [u8; SEED_LEN] {
    mac.update(seed);
    let tag = mac.finalize().into_bytes();
    let mut key = [0; SEED_LEN];
    key.copy_from_slice(&tag[..SEED_LEN]);
    key
}

/// Server timing and security parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ServerConfig {
    /// S3: a non-default session without requests falls back to default after this.
    pub s3: Duration,
    /// P2 server max, reported in the 0x10 response (1 ms resolution).
    pub p2: Duration,
    /// P2* server max, reported in the 0x10 response (10 ms resolution).
    pub p2_star: Duration,
    /// Interval between repeated 0x78 responses while a routine runs (below P2*).
    pub pending_interval: Duration,
    /// How often the backend is asked whether a running calibration is done.
    pub pending_check: Duration,
    /// Wrong keys in a row before SecurityAccess locks.
    pub max_attempts: u8,
    /// How long SecurityAccess stays locked after `max_attempts` wrong keys.
    pub lockout: Duration,
}

impl Default for ServerConfig {
    /// DESIGN.md values: S3 5 s, P2 50 ms, P2* 5000 ms, 3 attempts, 10 s lock.
    fn default() -> Self {
        ServerConfig {
            s3: Duration::from_secs(5),
            p2: Duration::from_millis(50),
            p2_star: Duration::from_millis(5000),
            pending_interval: Duration::from_millis(2000),
            pending_check: Duration::from_millis(10),
            max_attempts: 3,
            lockout: Duration::from_secs(10),
        }
    }
}

/// A routine answered 0x78 and still owes its final response.
#[derive(Clone, Copy, Debug)]
struct Pending {
    next_pending_response: Instant,
    next_check: Instant,
}

/// The UDS server state machine.
pub struct Server<B: Backend, R: SeedSource> {
    backend: B,
    seeds: R,
    mac: Hmac<Sha256>,
    cfg: ServerConfig,
    session: Session,
    s3_deadline: Option<Instant>,
    unlocked: bool,
    seed: Option<[u8; SEED_LEN]>,
    failed_attempts: u8,
    locked_until: Option<Instant>,
    pending: Option<Pending>,
    last_outcome: Option<Outcome>,
}

impl<B: Backend, R: SeedSource> Server<B, R> {
    /// A server in the default session, locked. `secret` is the vehicle secret the
    /// SecurityAccess key is derived from (any length).
    pub fn new(backend: B, seeds: R, secret: &[u8], cfg: ServerConfig) -> Self {
        // HMAC accepts keys of any length; the fallback is unreachable.
        let mac = <Hmac<Sha256> as Mac>::new_from_slice(secret)
            .unwrap_or_else(|_| <Hmac<Sha256> as Mac>::new(&Default::default()));
        Server {
            backend,
            seeds,
            mac,
            cfg,
            session: Session::Default,
            s3_deadline: None,
            unlocked: false,
            seed: None,
            failed_attempts: 0,
            locked_until: None,
            pending: None,
            last_outcome: None,
        }
    }

    /// Restores SecurityAccess state kept across a restart: `failed_attempts` wrong keys so
    /// far, and locked for `locked_for` from `now` (ISO 14229-1: the delay timer applies
    /// after power-up too). Values beyond the configuration are clamped to it.
    pub fn restore_security(
        &mut self,
        failed_attempts: u8,
        locked_for: Option<Duration>,
        now: Instant,
    ) {
        self.failed_attempts = failed_attempts.min(self.cfg.max_attempts.saturating_sub(1));
        self.locked_until =
            locked_for.filter(|d| !d.is_zero()).map(|d| now + d.min(self.cfg.lockout));
    }

    /// The backend.
    pub fn backend(&self) -> &B {
        &self.backend
    }

    /// The backend, mutably.
    pub fn backend_mut(&mut self) -> &mut B {
        &mut self.backend
    }

    /// The active session.
    pub fn session(&self) -> Session {
        self.session
    }

    /// True once a correct key was sent in this session.
    pub fn is_unlocked(&self) -> bool {
        self.unlocked
    }

    /// True while a routine owes its final response.
    pub fn is_pending(&self) -> bool {
        self.pending.is_some()
    }

    /// Handles one request; returns the response to send, `None` when there is none
    /// (empty request, or a suppressed positive response).
    pub fn handle(&mut self, request: &[u8], now: Instant) -> Option<Response> {
        let &service = request.first()?;
        self.expire(now);
        if self.pending.is_some() {
            // One request at a time: the running routine still owes its answer.
            return Some(negative(service, Nrc::BusyRepeatRequest));
        }
        if self.session != Session::Default {
            self.s3_deadline = Some(now + self.cfg.s3);
        }
        let result = match service {
            sid::DIAGNOSTIC_SESSION_CONTROL => self.session_control(request, now),
            sid::TESTER_PRESENT => tester_present(request),
            sid::SECURITY_ACCESS => self.security_access(request, now),
            sid::READ_DATA_BY_IDENTIFIER => self.read_data(request),
            sid::ROUTINE_CONTROL => self.routine_control(request, now),
            _ => Err(Nrc::ServiceNotSupported),
        };
        match result {
            Ok(response) => response,
            Err(nrc) => Some(negative(service, nrc)),
        }
    }

    /// Runs the timers: S3 session timeout, security lockout expiry, and a pending
    /// routine (repeated 0x78, then the final response once the backend is done).
    /// Returns a response to send, if one is due.
    pub fn poll(&mut self, now: Instant) -> Option<Response> {
        self.expire(now);
        let pending = self.pending?;
        if now >= pending.next_check {
            if let Some(outcome) = self.backend.calibration_finished() {
                self.pending = None;
                self.last_outcome = Some(outcome);
                self.restart_s3(now);
                // After a 0x78 the final positive response is always sent.
                return Some(routine_response(0x01, rid::START_CALIBRATION, Some(&outcome)));
            }
            if let Some(p) = &mut self.pending {
                p.next_check = now + self.cfg.pending_check;
            }
        }
        if now >= pending.next_pending_response {
            if let Some(p) = &mut self.pending {
                p.next_pending_response = now + self.cfg.pending_interval;
            }
            return Some(negative(sid::ROUTINE_CONTROL, Nrc::ResponsePending));
        }
        None
    }

    /// When [`Server::poll`] next has something to do.
    pub fn poll_at(&self) -> Option<Instant> {
        let pending = self.pending.map(|p| p.next_check.min(p.next_pending_response));
        // S3 is stopped while a routine runs (ISO 14229-2: S3 restarts after the response).
        let s3 = if self.pending.is_some() { None } else { self.s3_deadline };
        [pending, s3, self.locked_until].into_iter().flatten().min()
    }

    fn restart_s3(&mut self, now: Instant) {
        if self.session != Session::Default {
            self.s3_deadline = Some(now + self.cfg.s3);
        }
    }

    /// S3 fallback to the default session (relocking) and lockout expiry.
    fn expire(&mut self, now: Instant) {
        if self.pending.is_none() && self.s3_deadline.is_some_and(|d| now >= d) {
            self.enter_session(Session::Default);
        }
        if self.locked_until.is_some_and(|t| now >= t) {
            self.locked_until = None;
        }
    }

    fn enter_session(&mut self, session: Session) {
        // Every session transition relocks security (ISO 14229-1 9.2.1).
        self.session = session;
        self.unlocked = false;
        self.seed = None;
        self.s3_deadline = None;
    }

    fn session_control(&mut self, req: &[u8], now: Instant) -> Result<Option<Response>, Nrc> {
        let (sub, suppress) = sub_function(req, 2)?;
        let session = match sub {
            0x01 => Session::Default,
            0x03 => Session::Extended,
            _ => return Err(Nrc::SubFunctionNotSupported),
        };
        exact_len(req, 2)?;
        self.enter_session(session);
        self.restart_s3(now);
        if suppress {
            return Ok(None);
        }
        let p2 = u16::try_from(self.cfg.p2.as_millis()).unwrap_or(u16::MAX);
        let p2_star = u16::try_from(self.cfg.p2_star.as_millis() / 10).unwrap_or(u16::MAX);
        let mut r = positive(sid::DIAGNOSTIC_SESSION_CONTROL);
        push(&mut r, &[sub]);
        push(&mut r, &p2.to_be_bytes());
        push(&mut r, &p2_star.to_be_bytes());
        Ok(Some(r))
    }

    fn security_access(&mut self, req: &[u8], now: Instant) -> Result<Option<Response>, Nrc> {
        if self.session == Session::Default {
            return Err(Nrc::ServiceNotSupportedInActiveSession);
        }
        let (sub, suppress) = sub_function(req, 2)?;
        match sub {
            0x01 => {
                exact_len(req, 2)?;
                if self.locked_until.is_some_and(|t| now < t) {
                    return Err(Nrc::RequiredTimeDelayNotExpired);
                }
                // Already unlocked: the seed is all zeros (ISO 14229-1 9.4.1).
                let mut seed = [0; SEED_LEN];
                if !self.unlocked {
                    self.seeds.fill_seed(&mut seed);
                    self.seed = Some(seed);
                }
                if suppress {
                    return Ok(None);
                }
                let mut r = positive(sid::SECURITY_ACCESS);
                push(&mut r, &[sub]);
                push(&mut r, &seed);
                Ok(Some(r))
            }
            0x02 => {
                exact_len(req, 2 + SEED_LEN)?;
                let seed = self.seed.take().ok_or(Nrc::RequestSequenceError)?;
                let expected = key_from_mac(self.mac.clone(), &seed);
                if !constant_time_eq(&expected, &req[2..]) {
                    self.failed_attempts = self.failed_attempts.saturating_add(1);
                    if self.failed_attempts >= self.cfg.max_attempts {
                        self.failed_attempts = 0;
                        self.locked_until = Some(now + self.cfg.lockout);
                        // Kept before the answer: a restart right after it still locks.
                        self.backend.security_changed(0, Some(self.cfg.lockout));
                        return Err(Nrc::ExceededNumberOfAttempts);
                    }
                    self.backend.security_changed(self.failed_attempts, None);
                    return Err(Nrc::InvalidKey);
                }
                if self.failed_attempts > 0 {
                    self.backend.security_changed(0, None);
                }
                self.failed_attempts = 0;
                self.unlocked = true;
                if suppress {
                    return Ok(None);
                }
                let mut r = positive(sid::SECURITY_ACCESS);
                push(&mut r, &[sub]);
                Ok(Some(r))
            }
            _ => Err(Nrc::SubFunctionNotSupported),
        }
    }

    fn read_data(&mut self, req: &[u8]) -> Result<Option<Response>, Nrc> {
        let ids = &req[1..];
        if ids.is_empty() || ids.len() % 2 != 0 || ids.len() / 2 > MAX_DIDS_PER_REQUEST {
            return Err(Nrc::IncorrectMessageLengthOrInvalidFormat);
        }
        let sensors = self.backend.sensors();
        let known = |d: u16| served(&sensors, d);
        let dids = ids.chunks_exact(2).map(|c| u16::from_be_bytes([c[0], c[1]]));
        if !dids.clone().any(known) {
            return Err(Nrc::RequestOutOfRange);
        }
        let mut r = positive(sid::READ_DATA_BY_IDENTIFIER);
        // Unsupported DIDs among supported ones are left out (ISO 14229-1 10.2.2).
        for d in dids.filter(|&d| known(d)) {
            let mut buf = [0u8; MAX_RECORD];
            let n = self.encode_did(d, &sensors, &mut buf)?;
            if r.len() + 2 + n > MAX_RESPONSE {
                return Err(Nrc::ResponseTooLong);
            }
            push(&mut r, &d.to_be_bytes());
            push(&mut r, &buf[..n]);
        }
        Ok(Some(r))
    }

    fn encode_did(&self, d: u16, sensors: &SensorTable, buf: &mut [u8]) -> Result<usize, Nrc> {
        let intrinsics = did::sensor_index(d, did::SENSOR_INTRINSICS);
        let extrinsic = did::sensor_index(d, did::SENSOR_EXTRINSIC);
        let n = match d {
            did::STATE => self.backend.state().emit(buf),
            did::INTRINSICS => self.backend.intrinsics().and_then(|i| i.emit(buf)),
            did::EXTRINSIC => self.backend.extrinsic().and_then(|e| e.emit(buf)),
            did::QUALITY => self.backend.quality().and_then(|q| q.emit(buf)),
            did::SENSORS => sensors.emit(buf),
            _ if intrinsics.is_some() => {
                intrinsics.and_then(|i| self.backend.sensor_intrinsics(i)).and_then(|r| r.emit(buf))
            }
            _ => extrinsic.and_then(|i| self.backend.sensor_extrinsic(i)).and_then(|r| r.emit(buf)),
        };
        n.ok_or(Nrc::ConditionsNotCorrect)
    }

    fn routine_control(&mut self, req: &[u8], now: Instant) -> Result<Option<Response>, Nrc> {
        if self.session == Session::Default {
            return Err(Nrc::ServiceNotSupportedInActiveSession);
        }
        let (sub, suppress) = sub_function(req, 4)?;
        if sub != 0x01 && sub != 0x03 {
            return Err(Nrc::SubFunctionNotSupported);
        }
        let routine = u16::from_be_bytes([req[2], req[3]]);
        if routine != rid::START_CALIBRATION && routine != rid::ROLLBACK {
            return Err(Nrc::RequestOutOfRange);
        }
        if !self.unlocked {
            return Err(Nrc::SecurityAccessDenied);
        }
        exact_len(req, 4)?;
        match (routine, sub) {
            (rid::START_CALIBRATION, 0x01) => {
                self.backend.start_calibration().map_err(|_| Nrc::ConditionsNotCorrect)?;
                self.pending = Some(Pending {
                    next_pending_response: now + self.cfg.pending_interval,
                    next_check: now + self.cfg.pending_check,
                });
                Ok(Some(negative(sid::ROUTINE_CONTROL, Nrc::ResponsePending)))
            }
            (rid::START_CALIBRATION, _) => {
                let outcome = self.last_outcome.ok_or(Nrc::RequestSequenceError)?;
                Ok((!suppress).then(|| routine_response(sub, routine, Some(&outcome))))
            }
            (_, 0x01) => {
                let generation = self.backend.rollback().map_err(|_| Nrc::ConditionsNotCorrect)?;
                let mut r = routine_response(sub, routine, None);
                push(&mut r, &generation.to_be_bytes());
                Ok((!suppress).then_some(r))
            }
            // Roll back has no results to request.
            _ => Err(Nrc::SubFunctionNotSupported),
        }
    }
}

/// Checks the minimum length (0x13) and splits the sub-function byte.
fn sub_function(req: &[u8], min_len: usize) -> Result<(u8, bool), Nrc> {
    if req.len() < min_len {
        return Err(Nrc::IncorrectMessageLengthOrInvalidFormat);
    }
    let b = req[1];
    Ok((b & !SUPPRESS_POSITIVE_RESPONSE, b & SUPPRESS_POSITIVE_RESPONSE != 0))
}

fn exact_len(req: &[u8], len: usize) -> Result<(), Nrc> {
    if req.len() == len {
        Ok(())
    } else {
        Err(Nrc::IncorrectMessageLengthOrInvalidFormat)
    }
}

fn tester_present(req: &[u8]) -> Result<Option<Response>, Nrc> {
    let (sub, suppress) = sub_function(req, 2)?;
    if sub != 0x00 {
        return Err(Nrc::SubFunctionNotSupported);
    }
    exact_len(req, 2)?;
    if suppress {
        return Ok(None);
    }
    let mut r = positive(sid::TESTER_PRESENT);
    push(&mut r, &[0x00]);
    Ok(Some(r))
}

fn routine_response(sub: u8, routine: u16, outcome: Option<&Outcome>) -> Response {
    let mut r = positive(sid::ROUTINE_CONTROL);
    push(&mut r, &[sub]);
    push(&mut r, &routine.to_be_bytes());
    if let Some(o) = outcome {
        let mut buf = [0; Outcome::LEN];
        let n = o.emit(&mut buf).unwrap_or(0);
        push(&mut r, &buf[..n]);
    }
    r
}

fn positive(service: u8) -> Response {
    let mut r = Response::new();
    push(&mut r, &[service.wrapping_add(sid::POSITIVE_OFFSET)]);
    r
}

/// The negative response `7F SID NRC`.
pub fn negative(service: u8, nrc: Nrc) -> Response {
    let mut r = Response::new();
    push(&mut r, &[sid::NEGATIVE_RESPONSE, service, nrc as u8]);
    r
}

/// Whether the server answers DID `d` for a vehicle with `sensors`: the fixed DIDs, the
/// sensor table, intrinsics of each camera and the extrinsic of each sensor in the table.
fn served(sensors: &SensorTable, d: u16) -> bool {
    let fixed = (did::STATE..=did::QUALITY).contains(&d) || d == did::SENSORS;
    let camera = did::sensor_index(d, did::SENSOR_INTRINSICS)
        .is_some_and(|i| sensors.kind(i) == Some(SensorKind::Camera));
    let sensor =
        did::sensor_index(d, did::SENSOR_EXTRINSIC).is_some_and(|i| sensors.kind(i).is_some());
    fixed || camera || sensor
}

/// Appends; the server never builds more than `MAX_RESPONSE` bytes (checked in
/// ReadDataByIdentifier, fixed sizes elsewhere), so nothing is lost.
fn push(r: &mut Response, bytes: &[u8]) {
    let _ = r.extend_from_slice(bytes);
}

fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// A request the server understands, as the client builds it. Parsing is
/// context-free (no session or security): the server itself checks requests in the
/// ISO 14229 NRC order, this is for clients, logs and fuzzing.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum RequestRepr {
    SessionControl {
        session: Session,
        suppress: bool,
    },
    TesterPresent {
        suppress: bool,
    },
    RequestSeed {
        suppress: bool,
    },
    SendKey {
        key: [u8; SEED_LEN],
        suppress: bool,
    },
    ReadData {
        dids: heapless::Vec<u16, MAX_DIDS_PER_REQUEST>,
    },
    /// `sub`: 0x01 start, 0x03 request results.
    RoutineControl {
        sub: u8,
        routine: u16,
        suppress: bool,
    },
}

impl RequestRepr {
    /// Parses a request; the error is the NRC a context-free server would answer.
    pub fn parse(bytes: &[u8]) -> Result<Self, Nrc> {
        let &service = bytes.first().ok_or(Nrc::IncorrectMessageLengthOrInvalidFormat)?;
        let sub = |min| sub_function(bytes, min);
        let repr = match service {
            sid::DIAGNOSTIC_SESSION_CONTROL => {
                let (s, suppress) = sub(2)?;
                let session = match s {
                    0x01 => Session::Default,
                    0x03 => Session::Extended,
                    _ => return Err(Nrc::SubFunctionNotSupported),
                };
                exact_len(bytes, 2)?;
                RequestRepr::SessionControl { session, suppress }
            }
            sid::TESTER_PRESENT => {
                let (s, suppress) = sub(2)?;
                if s != 0 {
                    return Err(Nrc::SubFunctionNotSupported);
                }
                exact_len(bytes, 2)?;
                RequestRepr::TesterPresent { suppress }
            }
            sid::SECURITY_ACCESS => match sub(2)? {
                (0x01, suppress) => {
                    exact_len(bytes, 2)?;
                    RequestRepr::RequestSeed { suppress }
                }
                (0x02, suppress) => {
                    exact_len(bytes, 2 + SEED_LEN)?;
                    let mut key = [0; SEED_LEN];
                    key.copy_from_slice(&bytes[2..]);
                    RequestRepr::SendKey { key, suppress }
                }
                _ => return Err(Nrc::SubFunctionNotSupported),
            },
            sid::READ_DATA_BY_IDENTIFIER => {
                let ids = &bytes[1..];
                if ids.is_empty() || ids.len() % 2 != 0 || ids.len() / 2 > MAX_DIDS_PER_REQUEST {
                    return Err(Nrc::IncorrectMessageLengthOrInvalidFormat);
                }
                let mut dids = heapless::Vec::new();
                for c in ids.chunks_exact(2) {
                    // At most MAX_DIDS_PER_REQUEST, checked above.
                    let _ = dids.push(u16::from_be_bytes([c[0], c[1]]));
                }
                RequestRepr::ReadData { dids }
            }
            sid::ROUTINE_CONTROL => {
                let (s, suppress) = sub(4)?;
                if s != 0x01 && s != 0x03 {
                    return Err(Nrc::SubFunctionNotSupported);
                }
                exact_len(bytes, 4)?;
                let routine = u16::from_be_bytes([bytes[2], bytes[3]]);
                RequestRepr::RoutineControl { sub: s, routine, suppress }
            }
            _ => return Err(Nrc::ServiceNotSupported),
        };
        Ok(repr)
    }

    /// Encoded length.
    pub fn buffer_len(&self) -> usize {
        match self {
            RequestRepr::SessionControl { .. }
            | RequestRepr::TesterPresent { .. }
            | RequestRepr::RequestSeed { .. } => 2,
            RequestRepr::SendKey { .. } => 2 + SEED_LEN,
            RequestRepr::ReadData { dids } => 1 + 2 * dids.len(),
            RequestRepr::RoutineControl { .. } => 4,
        }
    }

    /// Encodes into `buf`; returns the bytes written, `None` if `buf` is too short.
    pub fn emit(&self, buf: &mut [u8]) -> Option<usize> {
        let spr = |suppress: bool| if suppress { SUPPRESS_POSITIVE_RESPONSE } else { 0 };
        let mut w = Writer::new(buf);
        match self {
            RequestRepr::SessionControl { session, suppress } => {
                w.put(&[sid::DIAGNOSTIC_SESSION_CONTROL, *session as u8 | spr(*suppress)])?
            }
            RequestRepr::TesterPresent { suppress } => {
                w.put(&[sid::TESTER_PRESENT, spr(*suppress)])?
            }
            RequestRepr::RequestSeed { suppress } => {
                w.put(&[sid::SECURITY_ACCESS, 0x01 | spr(*suppress)])?
            }
            RequestRepr::SendKey { key, suppress } => {
                w.put(&[sid::SECURITY_ACCESS, 0x02 | spr(*suppress)])?;
                w.put(key)?;
            }
            RequestRepr::ReadData { dids } => {
                w.put(&[sid::READ_DATA_BY_IDENTIFIER])?;
                for d in dids {
                    w.put(&d.to_be_bytes())?;
                }
            }
            RequestRepr::RoutineControl { sub, routine, suppress } => {
                w.put(&[sid::ROUTINE_CONTROL, (sub & 0x7F) | spr(*suppress)])?;
                w.put(&routine.to_be_bytes())?;
            }
        }
        Some(w.pos)
    }
}

/// A response as the client sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResponseRepr<'a> {
    /// Positive response to `service`; `data` follows the response SID.
    Positive { service: u8, data: &'a [u8] },
    /// Negative response to `service` (the raw NRC byte).
    Negative { service: u8, nrc: u8 },
}

impl<'a> ResponseRepr<'a> {
    /// Parses a response message; `None` if it is empty, a truncated negative
    /// response, or not a response SID.
    pub fn parse(bytes: &'a [u8]) -> Option<Self> {
        match *bytes {
            [sid::NEGATIVE_RESPONSE, service, nrc] => Some(ResponseRepr::Negative { service, nrc }),
            [sid::NEGATIVE_RESPONSE, ..] => None,
            [first, ..] if first & sid::POSITIVE_OFFSET != 0 => Some(ResponseRepr::Positive {
                service: first - sid::POSITIVE_OFFSET,
                data: &bytes[1..],
            }),
            _ => None,
        }
    }
}
