//! Ouster OS0/OS1/OS2 lidar data packets (LEGACY and RNG19_RFL8_SIG16_NIR16_DUAL profiles)
//! as a zero-copy view and a `Repr`, and their decoder to points in Ouster's sensor frame.
//!
//! Layouts (little-endian; Ouster's firmware user manual, "lidar data packet format"):
//! LEGACY has no packet header: `columns_per_packet` columns of a 16-byte column header
//! (timestamp ns u64, measurement id u16, frame id u16, encoder count u32), one 12-byte pixel
//! per beam (range bits 0–19 of u32 @0 in mm, flags bits 28–31, reflectivity u8 @4, signal
//! u16 @6, near-IR u16 @8) and a status u32 (`0xFFFFFFFF` = valid). The DUAL profile has a
//! 32-byte packet header (packet type u16 @0, frame id u16 @2, initialisation id u24 @4,
//! serial number u40 @7), columns of a 12-byte header (timestamp u64, measurement id u16,
//! status u16, bit 0 = valid) and 16-byte pixels (range bits 0–18 of u32 @0, flags bits
//! 19–23, reflectivity u8 @3; second return the same @4; signal u16 @8, second signal @10,
//! near-IR @12), and a 32-byte footer. The beam count and columns per packet come from the
//! unit's metadata ([`OusterGeometry`]), so one view serves 16 to 128 beams.
//!
//! Geometry (Ouster's manual, "lidar range to XYZ"): column `m` of a `W`-column frame has
//! encoder angle θe = 2π(1 − m/W); beam `i` adds θa = −azimuth_i and has altitude φ_i; with
//! the beam origin n = `lidar_origin_to_beam_origin_mm` a range r lies at
//! x = (r − n) cos(θe + θa) cos φ + n cos θe, y = (r − n) sin(θe + θa) cos φ + n sin θe,
//! z = (r − n) sin φ in the lidar frame, which `lidar_to_sensor_transform` takes to the
//! sensor frame (x forward, y left, z up; 36.18 mm above the lidar frame on an OS1).

pub mod geometry;

use super::calibration::Calibration;
use super::common::{DecodeError, Model, PacketSummary, Return, ReturnMode};
use super::Point;

pub use geometry::{field, packet_period, OusterGeometry, Profile};

/// A read-only or read-write view of an Ouster lidar data packet.
#[derive(Debug, Clone)]
pub struct Packet<T: AsRef<[u8]>> {
    buffer: T,
    geometry: OusterGeometry,
}

impl<T: AsRef<[u8]>> Packet<T> {
    /// Wraps a buffer without checks; accessors may panic on short buffers.
    pub fn new_unchecked(buffer: T, geometry: OusterGeometry) -> Self {
        Packet { buffer, geometry }
    }

    /// Wraps a buffer after `check`: every accessor is then panic-free for indices within
    /// the geometry (column < columns_per_packet, beam < pixels_per_column).
    pub fn new_checked(buffer: T, geometry: &OusterGeometry) -> Result<Self, DecodeError> {
        let p = Self::new_unchecked(buffer, *geometry);
        p.check()?;
        Ok(p)
    }

    /// Checks the geometry, the length, the DUAL packet type and every column's measurement id.
    pub fn check(&self) -> Result<(), DecodeError> {
        let g = &self.geometry;
        if !g.is_valid() {
            return Err(DecodeError::WrongCalibration);
        }
        let (len, expected) = (self.buffer.as_ref().len(), g.packet_len());
        if len < expected {
            return Err(DecodeError::Truncated { len, expected });
        }
        if len > expected {
            return Err(DecodeError::Oversized { len, expected });
        }
        if g.profile == Profile::Dual && self.packet_type() != field::LIDAR_PACKET_TYPE {
            return Err(DecodeError::BadHeader);
        }
        for c in 0..usize::from(g.columns_per_packet) {
            let m = self.measurement_id(c);
            if m >= g.columns_per_frame {
                return Err(DecodeError::BadAzimuth(m));
            }
        }
        Ok(())
    }

    /// What `check` leaves out and a stream of packets relies on (the sweep assembler runs
    /// it), over the valid columns: measurement ids consecutive (a packet holds neighbouring
    /// columns), LEGACY columns of one frame, and timestamps non-decreasing within two packet
    /// periods of the first (a packet spans 15/16 of one). Call after `check`.
    pub fn check_consistency(&self) -> Result<(), DecodeError> {
        let g = &self.geometry;
        let mut valid = (0..usize::from(g.columns_per_packet)).filter(|c| self.column_valid(*c));
        let Some(first) = valid.next() else { return Ok(()) };
        let (id0, frame0, t0) =
            (self.measurement_id(first), self.column_frame_id(first), self.timestamp(first));
        let span_ns = (2.0 * packet_period(g) * 1e9) as u64;
        let mut previous = t0;
        for c in valid {
            if u32::from(self.measurement_id(c)) != u32::from(id0) + (c - first) as u32 {
                return Err(DecodeError::AzimuthOrder(c.min(255) as u8));
            }
            if self.column_frame_id(c) != frame0 {
                return Err(DecodeError::BadHeader);
            }
            let t = self.timestamp(c);
            if t < previous || t - t0 > span_ns {
                return Err(DecodeError::BadTimestamp);
            }
            previous = t;
        }
        Ok(())
    }

    /// Time of the first valid column (of column 0 when none is valid), seconds: the
    /// packet's place in the stream.
    pub fn time(&self) -> f64 {
        let columns = usize::from(self.geometry.columns_per_packet);
        let c = (0..columns).find(|c| self.column_valid(*c)).unwrap_or(0);
        self.timestamp(c) as f64 * 1e-9
    }

    /// Column `c`'s encoder direction in the sensor frame, clockwise from +x, 0.01° (it
    /// grows with the measurement id, as a spinning sensor's block azimuth does).
    pub fn azimuth(&self, c: usize) -> u16 {
        ColumnAngles::new(&self.geometry, self.measurement_id(c)).azimuth
    }

    pub fn geometry(&self) -> &OusterGeometry {
        &self.geometry
    }

    pub fn into_inner(self) -> T {
        self.buffer
    }

    fn u16_at(&self, at: usize) -> u16 {
        let d = self.buffer.as_ref();
        u16::from_le_bytes([d[at], d[at + 1]])
    }

    fn u32_at(&self, at: usize) -> u32 {
        let d = self.buffer.as_ref();
        u32::from_le_bytes([d[at], d[at + 1], d[at + 2], d[at + 3]])
    }

    fn uint_at(&self, at: usize, bytes: usize) -> u64 {
        let d = &self.buffer.as_ref()[at..at + bytes];
        d.iter().rev().fold(0u64, |v, b| (v << 8) | u64::from(*b))
    }

    /// DUAL packet type (1 = lidar data); 1 for LEGACY packets, which have no header.
    pub fn packet_type(&self) -> u16 {
        match self.geometry.profile {
            Profile::Legacy => field::LIDAR_PACKET_TYPE,
            Profile::Dual => self.u16_at(field::PACKET_TYPE),
        }
    }

    /// DUAL header frame id; LEGACY: the first column's.
    pub fn packet_frame_id(&self) -> u16 {
        match self.geometry.profile {
            Profile::Legacy => self.u16_at(self.column_at(0) + field::LEGACY_FRAME_ID),
            Profile::Dual => self.u16_at(field::FRAME_ID),
        }
    }

    /// DUAL initialisation id (24 bits); 0 for LEGACY.
    pub fn init_id(&self) -> u32 {
        match self.geometry.profile {
            Profile::Legacy => 0,
            Profile::Dual => self.uint_at(field::INIT_ID, 3) as u32,
        }
    }

    /// DUAL serial number (40 bits); 0 for LEGACY.
    pub fn serial(&self) -> u64 {
        match self.geometry.profile {
            Profile::Legacy => 0,
            Profile::Dual => self.uint_at(field::SERIAL, 5),
        }
    }

    fn column_at(&self, c: usize) -> usize {
        self.geometry.header_len() + c * self.geometry.column_len()
    }

    fn pixel_at(&self, c: usize, beam: usize) -> usize {
        self.column_at(c) + self.geometry.column_header_len() + beam * self.geometry.pixel_len()
    }

    /// Column `c`'s timestamp, ns.
    pub fn timestamp(&self, c: usize) -> u64 {
        self.uint_at(self.column_at(c) + field::TIMESTAMP, 8)
    }

    pub fn measurement_id(&self, c: usize) -> u16 {
        self.u16_at(self.column_at(c) + field::MEASUREMENT_ID)
    }

    /// Column `c`'s frame id (LEGACY column word; DUAL: 0, the frame id is in the header).
    pub fn column_frame_id(&self, c: usize) -> u16 {
        match self.geometry.profile {
            Profile::Legacy => self.u16_at(self.column_at(c) + field::LEGACY_FRAME_ID),
            Profile::Dual => 0,
        }
    }

    /// Column `c`'s encoder count (LEGACY only; 0 for DUAL).
    pub fn encoder_count(&self, c: usize) -> u32 {
        match self.geometry.profile {
            Profile::Legacy => self.u32_at(self.column_at(c) + field::LEGACY_ENCODER),
            Profile::Dual => 0,
        }
    }

    /// Column `c`'s status (LEGACY u32, DUAL u16 widened); bit 0 = valid.
    pub fn status(&self, c: usize) -> u32 {
        let at = self.column_at(c);
        match self.geometry.profile {
            Profile::Legacy => self.u32_at(at + self.geometry.column_len() - 4),
            Profile::Dual => u32::from(self.u16_at(at + field::DUAL_STATUS)),
        }
    }

    /// Whether column `c` holds a measurement.
    pub fn column_valid(&self, c: usize) -> bool {
        self.status(c) & 1 == 1
    }

    /// The pixel's `n`-th raw 32-bit word (LEGACY 3, DUAL 4 words).
    pub fn raw_word(&self, c: usize, beam: usize, n: usize) -> u32 {
        self.u32_at(self.pixel_at(c, beam) + 4 * n)
    }

    /// Range of return `echo` (0 or 1; LEGACY has one), mm.
    pub fn range(&self, c: usize, beam: usize, echo: usize) -> u32 {
        match (self.geometry.profile, echo) {
            (Profile::Legacy, 0) => self.raw_word(c, beam, 0) & 0x000F_FFFF,
            (Profile::Dual, 0 | 1) => self.raw_word(c, beam, echo) & 0x0007_FFFF,
            _ => 0,
        }
    }

    /// Flags of return `echo` (LEGACY bits 28–31, DUAL bits 19–23).
    pub fn flags(&self, c: usize, beam: usize, echo: usize) -> u8 {
        match (self.geometry.profile, echo) {
            (Profile::Legacy, 0) => (self.raw_word(c, beam, 0) >> 28) as u8,
            (Profile::Dual, 0 | 1) => ((self.raw_word(c, beam, echo) >> 19) & 0x1F) as u8,
            _ => 0,
        }
    }

    /// Reflectivity of return `echo`.
    pub fn reflectivity(&self, c: usize, beam: usize, echo: usize) -> u8 {
        let d = self.buffer.as_ref();
        let at = self.pixel_at(c, beam);
        match (self.geometry.profile, echo) {
            (Profile::Legacy, 0) => d[at + 4],
            (Profile::Dual, 0 | 1) => d[at + 3 + 4 * echo],
            _ => 0,
        }
    }

    /// Signal photons of return `echo`.
    pub fn signal(&self, c: usize, beam: usize, echo: usize) -> u16 {
        let at = self.pixel_at(c, beam);
        match (self.geometry.profile, echo) {
            (Profile::Legacy, 0) => self.u16_at(at + 6),
            (Profile::Dual, 0 | 1) => self.u16_at(at + 8 + 2 * echo),
            _ => 0,
        }
    }

    /// Ambient (near-infrared) photons.
    pub fn near_ir(&self, c: usize, beam: usize) -> u16 {
        let at = self.pixel_at(c, beam);
        match self.geometry.profile {
            Profile::Legacy => self.u16_at(at + 8),
            Profile::Dual => self.u16_at(at + 12),
        }
    }
}

impl<T: AsRef<[u8]> + AsMut<[u8]>> Packet<T> {
    fn put(&mut self, at: usize, bytes: &[u8]) {
        self.buffer.as_mut()[at..at + bytes.len()].copy_from_slice(bytes);
    }
}

/// One pixel's fields (the second return's are 0 for LEGACY).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PixelRepr {
    pub range: u32,
    pub flags: u8,
    pub reflectivity: u8,
    pub signal: u16,
    pub range2: u32,
    pub flags2: u8,
    pub reflectivity2: u8,
    pub signal2: u16,
    pub near_ir: u16,
}

/// One column: its header fields and `BEAMS` pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ColumnRepr<const BEAMS: usize> {
    pub timestamp: u64,
    pub measurement_id: u16,
    /// LEGACY only.
    pub frame_id: u16,
    /// LEGACY only.
    pub encoder_count: u32,
    pub status: u32,
    pub pixels: [PixelRepr; BEAMS],
}

impl<const BEAMS: usize> Default for ColumnRepr<BEAMS> {
    fn default() -> Self {
        ColumnRepr {
            timestamp: 0,
            measurement_id: 0,
            frame_id: 0,
            encoder_count: 0,
            status: 0,
            pixels: [PixelRepr::default(); BEAMS],
        }
    }
}

/// A parsed lidar packet of a `BEAMS`-beam unit (columns beyond `columns_per_packet` unused).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Repr<const BEAMS: usize> {
    pub geometry: OusterGeometry,
    /// DUAL header fields (0 for LEGACY).
    pub frame_id: u16,
    pub init_id: u32,
    pub serial: u64,
    pub columns: [ColumnRepr<BEAMS>; field::MAX_COLUMNS_PER_PACKET],
}

impl<const BEAMS: usize> Repr<BEAMS> {
    /// Parses a checked packet whose unit has `BEAMS` beams.
    pub fn parse<T: AsRef<[u8]>>(packet: &Packet<T>) -> Result<Self, DecodeError> {
        packet.check()?;
        let g = packet.geometry;
        if usize::from(g.pixels_per_column) != BEAMS {
            return Err(DecodeError::WrongCalibration);
        }
        let dual = g.profile == Profile::Dual;
        let mut columns = [ColumnRepr::default(); field::MAX_COLUMNS_PER_PACKET];
        for (c, col) in columns.iter_mut().take(usize::from(g.columns_per_packet)).enumerate() {
            col.timestamp = packet.timestamp(c);
            col.measurement_id = packet.measurement_id(c);
            col.frame_id = packet.column_frame_id(c);
            col.encoder_count = packet.encoder_count(c);
            col.status = packet.status(c);
            for (b, px) in col.pixels.iter_mut().enumerate() {
                *px = PixelRepr {
                    range: packet.range(c, b, 0),
                    flags: packet.flags(c, b, 0),
                    reflectivity: packet.reflectivity(c, b, 0),
                    signal: packet.signal(c, b, 0),
                    range2: packet.range(c, b, 1),
                    flags2: packet.flags(c, b, 1),
                    reflectivity2: packet.reflectivity(c, b, 1),
                    signal2: packet.signal(c, b, 1),
                    near_ir: packet.near_ir(c, b),
                };
            }
        }
        Ok(Repr {
            geometry: g,
            frame_id: if dual { packet.packet_frame_id() } else { 0 },
            init_id: packet.init_id(),
            serial: packet.serial(),
            columns,
        })
    }

    /// Bytes `emit` writes.
    pub fn buffer_len(&self) -> usize {
        self.geometry.packet_len()
    }

    /// Writes the packet (unused bits and bytes zero); the buffer must be `buffer_len()` bytes.
    pub fn emit<T: AsRef<[u8]> + AsMut<[u8]>>(&self, buffer: T) -> Result<Packet<T>, DecodeError> {
        let g = self.geometry;
        if !g.is_valid() || usize::from(g.pixels_per_column) != BEAMS {
            return Err(DecodeError::WrongCalibration);
        }
        let (len, expected) = (buffer.as_ref().len(), self.buffer_len());
        if len != expected {
            return Err(if len < expected {
                DecodeError::Truncated { len, expected }
            } else {
                DecodeError::Oversized { len, expected }
            });
        }
        let mut p = Packet::new_unchecked(buffer, g);
        p.buffer.as_mut().fill(0);
        if g.profile == Profile::Dual {
            p.put(field::PACKET_TYPE, &field::LIDAR_PACKET_TYPE.to_le_bytes());
            p.put(field::FRAME_ID, &self.frame_id.to_le_bytes());
            p.put(field::INIT_ID, &self.init_id.to_le_bytes()[..3]);
            p.put(field::SERIAL, &self.serial.to_le_bytes()[..5]);
        }
        for (c, col) in self.columns.iter().take(usize::from(g.columns_per_packet)).enumerate() {
            emit_column(&mut p, c, col);
        }
        Ok(p)
    }
}

fn emit_column<T: AsRef<[u8]> + AsMut<[u8]>, const BEAMS: usize>(
    p: &mut Packet<T>,
    c: usize,
    col: &ColumnRepr<BEAMS>,
) {
    let g = p.geometry;
    let at = p.column_at(c);
    p.put(at + field::TIMESTAMP, &col.timestamp.to_le_bytes());
    p.put(at + field::MEASUREMENT_ID, &col.measurement_id.to_le_bytes());
    match g.profile {
        Profile::Legacy => {
            p.put(at + field::LEGACY_FRAME_ID, &col.frame_id.to_le_bytes());
            p.put(at + field::LEGACY_ENCODER, &col.encoder_count.to_le_bytes());
            p.put(at + g.column_len() - 4, &col.status.to_le_bytes());
        }
        Profile::Dual => p.put(at + field::DUAL_STATUS, &(col.status as u16).to_le_bytes()),
    }
    for (b, px) in col.pixels.iter().enumerate() {
        let at = p.pixel_at(c, b);
        match g.profile {
            Profile::Legacy => {
                let word = (px.range & 0x000F_FFFF) | (u32::from(px.flags & 0x0F) << 28);
                p.put(at, &word.to_le_bytes());
                p.put(at + 4, &[px.reflectivity]);
                p.put(at + 6, &px.signal.to_le_bytes());
                p.put(at + 8, &px.near_ir.to_le_bytes());
            }
            Profile::Dual => {
                let word = |range: u32, flags: u8, refl: u8| {
                    (range & 0x0007_FFFF)
                        | (u32::from(flags & 0x1F) << 19)
                        | (u32::from(refl) << 24)
                };
                p.put(at, &word(px.range, px.flags, px.reflectivity).to_le_bytes());
                p.put(at + 4, &word(px.range2, px.flags2, px.reflectivity2).to_le_bytes());
                p.put(at + 8, &px.signal.to_le_bytes());
                p.put(at + 10, &px.signal2.to_le_bytes());
                p.put(at + 12, &px.near_ir.to_le_bytes());
            }
        }
    }
}

/// Decodes an Ouster lidar packet with the unit's calibration: every non-zero return of
/// every valid column, in column, beam, return order, in the sensor frame. `Return::azimuth`
/// is the column's encoder direction in the sensor frame (clockwise from +x, 0.01°), before
/// the beam's azimuth offset; `Point::time` is the column timestamp in seconds.
pub fn decode<F: FnMut(Return) + ?Sized>(
    cal: &Calibration,
    payload: &[u8],
    sink: &mut F,
) -> Result<PacketSummary, DecodeError> {
    if cal.model != Model::Ouster {
        return Err(DecodeError::WrongCalibration);
    }
    let g = cal.ouster;
    let p = Packet::new_checked(payload, &g)?;
    let echoes = if g.profile == Profile::Dual { 2 } else { 1 };
    let beams = usize::from(g.pixels_per_column).min(cal.lasers.len());
    let columns = usize::from(g.columns_per_packet);
    let mut returns = 0;
    for c in (0..columns).filter(|c| p.column_valid(*c)) {
        let column = ColumnAngles::new(&g, p.measurement_id(c));
        let time = p.timestamp(c) as f64 * 1e-9;
        for (beam, corr) in cal.lasers.iter().enumerate().take(beams) {
            for echo in 0..echoes {
                let raw = p.range(c, beam, echo);
                if raw == 0 {
                    continue;
                }
                let distance = raw as f32 * 1e-3;
                let [x, y, z] = column.to_sensor(&g, corr, distance);
                let point = Point {
                    x,
                    y,
                    z,
                    intensity: f32::from(p.reflectivity(c, beam, echo)),
                    ring: beam as u16,
                    time,
                };
                let azimuth = column.azimuth;
                sink(Return { point, distance, azimuth, block: c as u8, echo: echo as u8 });
                returns += 1;
            }
        }
    }
    Ok(PacketSummary {
        model: Model::Ouster,
        return_mode: if echoes == 2 { ReturnMode::Dual } else { ReturnMode::Strongest },
        time: p.timestamp(0) as f64 * 1e-9,
        first_azimuth: p.azimuth(0),
        last_azimuth: p.azimuth(columns - 1),
        sequence: Some(u32::from(p.packet_frame_id())),
        returns,
    })
}

/// The trigonometry of one column: its encoder angle and its direction in the sensor frame.
struct ColumnAngles {
    sin_e: f32,
    cos_e: f32,
    azimuth: u16,
}

impl ColumnAngles {
    fn new(g: &OusterGeometry, measurement_id: u16) -> Self {
        let turn = f64::from(measurement_id) / f64::from(g.columns_per_frame.max(1));
        // θe in f64 then rounded: the column angle is exact to f32 precision.
        let theta = 2.0 * core::f64::consts::PI * (1.0 - turn);
        let (sin_e, cos_e) = (libm::sin(theta) as f32, libm::cos(theta) as f32);
        // The encoder direction in the sensor frame, as a clockwise azimuth.
        let r = &g.rotation;
        let (dx, dy) = (r[0][0] * cos_e + r[0][1] * sin_e, r[1][0] * cos_e + r[1][1] * sin_e);
        let ccw_deg = f64::from(libm::atan2f(dy, dx)).to_degrees();
        // atan2 is in (−180°, 180°]: 360° − it is in [180°, 540°).
        let cw = libm::round((360.0 - ccw_deg) * 100.0) as u32 % 36000;
        ColumnAngles { sin_e, cos_e, azimuth: cw as u16 }
    }

    /// The manual's range-to-xyz in the lidar frame, then lidar → sensor.
    fn to_sensor(
        &self,
        g: &OusterGeometry,
        c: &super::calibration::LaserCorrection,
        r: f32,
    ) -> [f32; 3] {
        let n = g.beam_origin;
        // cos/sin(θe + θa) with θa = −azimuth_offset, by the angle-sum rule.
        let (sa, ca) = (c.sin_azimuth_offset, c.cos_azimuth_offset);
        let cos_t = self.cos_e * ca + self.sin_e * sa;
        let sin_t = self.sin_e * ca - self.cos_e * sa;
        let along = (r - n) * c.cos_elevation;
        let lidar = [
            along * cos_t + n * self.cos_e,
            along * sin_t + n * self.sin_e,
            (r - n) * c.sin_elevation,
        ];
        let (rot, t) = (&g.rotation, &g.translation);
        core::array::from_fn(|i| {
            rot[i][0] * lidar[0] + rot[i][1] * lidar[1] + rot[i][2] * lidar[2] + t[i]
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geometry(profile: Profile, beams: u16, columns: u16) -> OusterGeometry {
        OusterGeometry {
            profile,
            pixels_per_column: beams,
            columns_per_packet: columns,
            ..OusterGeometry::default()
        }
    }

    /// A LEGACY packet of 2 beams × 1 column, written out by hand.
    fn legacy_bytes() -> [u8; 44] {
        let mut d = [0u8; 16 + 2 * 12 + 4];
        d[0..8].copy_from_slice(&1_000_000_123u64.to_le_bytes());
        d[8..10].copy_from_slice(&512u16.to_le_bytes());
        d[10..12].copy_from_slice(&638u16.to_le_bytes());
        d[12..16].copy_from_slice(&45_056u32.to_le_bytes());
        // Beam 0: 5 m, flags 0x3, reflectivity 7, signal 300, near-IR 40.
        d[16..20].copy_from_slice(&(5000u32 | 0x3 << 28).to_le_bytes());
        d[20] = 7;
        d[22..24].copy_from_slice(&300u16.to_le_bytes());
        d[24..26].copy_from_slice(&40u16.to_le_bytes());
        // Beam 1: no return, near-IR 9.
        d[36..38].copy_from_slice(&9u16.to_le_bytes());
        d[40..44].copy_from_slice(&0xFFFF_FFFFu32.to_le_bytes());
        d
    }

    #[test]
    fn legacy_bytes_to_repr_to_bytes() {
        let g = geometry(Profile::Legacy, 2, 1);
        let bytes = legacy_bytes();
        let p = Packet::new_checked(&bytes[..], &g).unwrap();
        let repr = Repr::<2>::parse(&p).unwrap();
        let col = repr.columns[0];
        assert_eq!((col.timestamp, col.measurement_id, col.frame_id), (1_000_000_123, 512, 638));
        assert_eq!((col.encoder_count, col.status), (45_056, 0xFFFF_FFFF));
        let want = PixelRepr {
            range: 5000,
            flags: 3,
            reflectivity: 7,
            signal: 300,
            near_ir: 40,
            ..PixelRepr::default()
        };
        assert_eq!(col.pixels[0], want);
        assert_eq!(col.pixels[1], PixelRepr { near_ir: 9, ..PixelRepr::default() });
        let mut out = [0u8; 44];
        repr.emit(&mut out[..]).unwrap();
        assert_eq!(out, bytes);
        assert_eq!(Repr::<3>::parse(&p), Err(DecodeError::WrongCalibration));
    }

    #[test]
    fn dual_bytes_to_repr_to_bytes() {
        let g = geometry(Profile::Dual, 1, 2);
        let mut d = [0u8; 32 + 2 * (12 + 16) + 32];
        d[0..2].copy_from_slice(&1u16.to_le_bytes());
        d[2..4].copy_from_slice(&1453u16.to_le_bytes());
        d[4..7].copy_from_slice(&[0xC2, 0x7B, 0x92]);
        d[7..12].copy_from_slice(&[0x8E, 0x00, 0x37, 0x21, 0xE7]);
        for c in 0..2 {
            let at = 32 + c * 28;
            d[at..at + 8].copy_from_slice(&(77u64 + c as u64).to_le_bytes());
            d[at + 8..at + 10].copy_from_slice(&(1000u16 + c as u16).to_le_bytes());
            d[at + 10..at + 12].copy_from_slice(&1u16.to_le_bytes());
            // Return 1: 1.5 m, flags 0x11, reflectivity 200; return 2: 2.5 m, flags 1, 9.
            let w1 = 1500u32 | 0x11 << 19 | 200 << 24;
            let w2 = 2500u32 | 0x01 << 19 | 9 << 24;
            d[at + 12..at + 16].copy_from_slice(&w1.to_le_bytes());
            d[at + 16..at + 20].copy_from_slice(&w2.to_le_bytes());
            d[at + 20..at + 22].copy_from_slice(&11u16.to_le_bytes());
            d[at + 22..at + 24].copy_from_slice(&12u16.to_le_bytes());
            d[at + 24..at + 26].copy_from_slice(&13u16.to_le_bytes());
        }
        let p = Packet::new_checked(&d[..], &g).unwrap();
        assert_eq!(
            (p.packet_frame_id(), p.init_id(), p.serial()),
            (1453, 0x927BC2, 0x00E7_2137_008E)
        );
        let repr = Repr::<1>::parse(&p).unwrap();
        let px = repr.columns[1].pixels[0];
        assert_eq!((px.range, px.flags, px.reflectivity), (1500, 0x11, 200));
        assert_eq!((px.range2, px.flags2, px.reflectivity2), (2500, 1, 9));
        assert_eq!((px.signal, px.signal2, px.near_ir), (11, 12, 13));
        assert_eq!(repr.columns[1].measurement_id, 1001);
        let mut out = [0u8; 120];
        repr.emit(&mut out[..]).unwrap();
        assert_eq!(out[..], d[..]);
    }

    #[test]
    fn rejects_malformed() {
        let g = geometry(Profile::Legacy, 2, 1);
        let bytes = legacy_bytes();
        let check = |d: &[u8]| Packet::new_checked(d, &g).map(|_| ()).unwrap_err();
        assert!(matches!(check(&bytes[..43]), DecodeError::Truncated { .. }));
        let mut long = [0u8; 45];
        long[..44].copy_from_slice(&bytes);
        assert!(matches!(check(&long), DecodeError::Oversized { .. }));
        let mut bad = bytes;
        bad[8..10].copy_from_slice(&1024u16.to_le_bytes());
        assert_eq!(check(&bad), DecodeError::BadAzimuth(1024));
        let dual = geometry(Profile::Dual, 1, 1);
        let zeros = [0u8; 32 + 28 + 32];
        assert_eq!(Packet::new_checked(&zeros[..], &dual).unwrap_err(), DecodeError::BadHeader);
        let silly = OusterGeometry { pixels_per_column: 0, ..g };
        assert_eq!(
            Packet::new_checked(&bytes[..], &silly).unwrap_err(),
            DecodeError::WrongCalibration
        );
    }

    /// A valid LEGACY packet of `columns` columns × 2 beams from measurement id `first`,
    /// one column per 97.65625 µs (1024×10).
    fn legacy_stream_packet(columns: u16, first: u16) -> ([u8; 16 * 44], OusterGeometry) {
        let g = geometry(Profile::Legacy, 2, columns);
        let mut repr = Repr::<2> {
            geometry: g,
            frame_id: 0,
            init_id: 0,
            serial: 0,
            columns: Default::default(),
        };
        for (c, col) in repr.columns.iter_mut().take(usize::from(columns)).enumerate() {
            let m = first + c as u16;
            col.timestamp = 5_000_000_000 + u64::from(m) * 97_656;
            col.measurement_id = m;
            col.frame_id = 7;
            col.status = 0xFFFF_FFFF;
        }
        let mut out = [0u8; 16 * 44];
        repr.emit(&mut out[..g.packet_len()]).unwrap();
        (out, g)
    }

    #[test]
    fn consistency_needs_neighbouring_columns_of_one_frame_in_time_order() {
        let (bytes, g) = legacy_stream_packet(4, 100);
        let len = g.packet_len();
        let consistency = |d: &[u8]| Packet::new_checked(d, &g).unwrap().check_consistency();
        assert_eq!(consistency(&bytes[..len]), Ok(()));
        let p = Packet::new_checked(&bytes[..len], &g).unwrap();
        assert!((p.time() - (5.0 + 100.0 * 97_656e-9)).abs() < 1e-9);
        // Column 2 of 4 says measurement id 150: not a neighbour.
        let mut gap = bytes;
        gap[2 * 44 + 8..2 * 44 + 10].copy_from_slice(&150u16.to_le_bytes());
        assert_eq!(consistency(&gap[..len]), Err(DecodeError::AzimuthOrder(2)));
        // Column 3 in another frame.
        let mut frame = bytes;
        frame[3 * 44 + 10..3 * 44 + 12].copy_from_slice(&8u16.to_le_bytes());
        assert_eq!(consistency(&frame[..len]), Err(DecodeError::BadHeader));
        // Column 1 earlier than column 0; column 3 a second late.
        let mut back = bytes;
        back[44..52].copy_from_slice(&4_000_000_000u64.to_le_bytes());
        assert_eq!(consistency(&back[..len]), Err(DecodeError::BadTimestamp));
        let mut late = bytes;
        late[3 * 44..3 * 44 + 8].copy_from_slice(&6_000_000_000u64.to_le_bytes());
        assert_eq!(consistency(&late[..len]), Err(DecodeError::BadTimestamp));
        // An invalid column (status 0) is not asked to agree: outside the column window a
        // unit may leave it zeroed.
        let mut off = bytes;
        off[2 * 44..2 * 44 + 12].fill(0);
        off[2 * 44 + 40..2 * 44 + 44].fill(0);
        assert_eq!(consistency(&off[..len]), Ok(()));
        // Azimuths grow with the measurement id (column 0 at id 100 of 1024, clockwise).
        assert!(p.azimuth(1) > p.azimuth(0));
    }

    #[test]
    fn range_to_xyz_follows_the_manual() {
        // A beam at altitude 10°, azimuth offset 2°, beam origin 15 mm, column 256 of 1024
        // (θe = 270°), 10 m: worked here in f64 from the manual's formula.
        let mut cal = Calibration::nominal(Model::Ouster);
        cal.ouster = OusterGeometry { beam_origin: 0.015, pixels_per_column: 1, ..cal.ouster };
        cal.lasers[0] = super::super::calibration::LaserCorrection::from_degrees(10.0, 2.0);
        let mut bytes = [0u8; 16 + 12 + 4];
        bytes[8..10].copy_from_slice(&256u16.to_le_bytes());
        bytes[16..20].copy_from_slice(&10_000u32.to_le_bytes());
        bytes[28..32].copy_from_slice(&u32::MAX.to_le_bytes());
        cal.ouster.columns_per_packet = 1;
        let mut got = None;
        decode(&cal, &bytes, &mut |r| got = Some(r)).unwrap();
        let r = got.unwrap();
        let (te, ta, phi, n, range) =
            (270f64.to_radians(), -2f64.to_radians(), 10f64.to_radians(), 0.015, 10.0);
        let x = (range - n) * (te + ta).cos() * phi.cos() + n * te.cos();
        let y = (range - n) * (te + ta).sin() * phi.cos() + n * te.sin();
        let z = (range - n) * phi.sin();
        // Sensor frame: rotated 180° about z, 36.18 mm up.
        let want = [-x, -y, z + 0.03618];
        let p = r.point;
        for (g, w) in [p.x, p.y, p.z].iter().zip(want) {
            assert!((f64::from(*g) - w).abs() < 2e-6, "{:?} vs {want:?}", [p.x, p.y, p.z]);
        }
        // θe = 270° in the lidar frame is +y (left) of the sensor frame: azimuth 270° clockwise.
        assert_eq!(r.azimuth, 27000);
        assert!(p.x.abs() < 0.4 && p.y > 9.0);
    }
}
