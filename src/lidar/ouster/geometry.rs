//! The packet layout and beam geometry of one Ouster unit (from its metadata json): what the
//! packet view needs to find a field and what a unit's [`Calibration`](crate::lidar::Calibration)
//! carries. A leaf, so the calibration tables can hold it without importing the decoder.

/// Which lidar packet profile a unit sends (`udp_profile_lidar`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Profile {
    /// The firmware ≤ 2.1 format (no `udp_profile_lidar` in the metadata).
    #[default]
    Legacy,
    /// `RNG19_RFL8_SIG16_NIR16_DUAL`: two returns per pixel.
    Dual,
}

/// The packet layout and beam geometry of one Ouster unit, from its metadata json.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OusterGeometry {
    pub profile: Profile,
    /// Beams (rows); `Calibration::lasers` holds their angles.
    pub pixels_per_column: u16,
    pub columns_per_packet: u16,
    /// Columns in one turn (512, 1024, 2048, 4096).
    pub columns_per_frame: u16,
    /// Turns per second (10 or 20).
    pub frequency_hz: u16,
    /// First and last measurement id the unit sends (`column_window`).
    pub column_window: (u16, u16),
    /// `lidar_origin_to_beam_origin_mm`, in metres.
    pub beam_origin: f32,
    /// `lidar_to_sensor_transform`: p_sensor = rotation · p_lidar + translation (metres).
    pub rotation: [[f32; 3]; 3],
    pub translation: [f32; 3],
}

impl Default for OusterGeometry {
    /// An OS1's: LEGACY, 32 beams, 1024×10, the standard lidar→sensor transform.
    fn default() -> Self {
        OusterGeometry {
            profile: Profile::Legacy,
            pixels_per_column: 32,
            columns_per_packet: 16,
            columns_per_frame: 1024,
            frequency_hz: 10,
            column_window: (0, 1023),
            beam_origin: 0.0,
            rotation: [[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [0.0, 0.0, 0.036_18],
        }
    }
}

/// Field positions.
pub mod field {
    /// DUAL packet header and footer.
    pub const DUAL_HEADER_LEN: usize = 32;
    pub const DUAL_FOOTER_LEN: usize = 32;
    pub const PACKET_TYPE: usize = 0;
    pub const FRAME_ID: usize = 2;
    pub const INIT_ID: usize = 4;
    pub const SERIAL: usize = 7;
    /// The packet type of lidar data.
    pub const LIDAR_PACKET_TYPE: u16 = 1;
    /// Column header, relative to the column.
    pub const TIMESTAMP: usize = 0;
    pub const MEASUREMENT_ID: usize = 8;
    /// LEGACY: frame id and encoder count in the column header; status after the pixels.
    pub const LEGACY_FRAME_ID: usize = 10;
    pub const LEGACY_ENCODER: usize = 12;
    pub const LEGACY_COLUMN_HEADER_LEN: usize = 16;
    pub const LEGACY_PIXEL_LEN: usize = 12;
    pub const LEGACY_STATUS_LEN: usize = 4;
    /// DUAL: status u16 in the column header.
    pub const DUAL_STATUS: usize = 10;
    pub const DUAL_COLUMN_HEADER_LEN: usize = 12;
    pub const DUAL_PIXEL_LEN: usize = 16;
    /// An IMU packet (sent on its own port; not decoded).
    pub const IMU_PACKET_LEN: usize = 48;
    /// The most beams and columns per packet a unit has.
    pub const MAX_BEAMS: usize = 128;
    pub const MAX_COLUMNS_PER_PACKET: usize = 16;
}

impl OusterGeometry {
    pub(super) fn column_header_len(&self) -> usize {
        match self.profile {
            Profile::Legacy => field::LEGACY_COLUMN_HEADER_LEN,
            Profile::Dual => field::DUAL_COLUMN_HEADER_LEN,
        }
    }

    pub(super) fn pixel_len(&self) -> usize {
        match self.profile {
            Profile::Legacy => field::LEGACY_PIXEL_LEN,
            Profile::Dual => field::DUAL_PIXEL_LEN,
        }
    }

    /// Bytes of one column.
    pub fn column_len(&self) -> usize {
        let status = if self.profile == Profile::Legacy { field::LEGACY_STATUS_LEN } else { 0 };
        self.column_header_len() + usize::from(self.pixels_per_column) * self.pixel_len() + status
    }

    pub(super) fn header_len(&self) -> usize {
        if self.profile == Profile::Dual {
            field::DUAL_HEADER_LEN
        } else {
            0
        }
    }

    /// Bytes of one lidar data packet.
    pub fn packet_len(&self) -> usize {
        let footer = if self.profile == Profile::Dual { field::DUAL_FOOTER_LEN } else { 0 };
        self.header_len() + usize::from(self.columns_per_packet) * self.column_len() + footer
    }

    /// Whether the geometry is one this module can lay out.
    pub fn is_valid(&self) -> bool {
        let beams = usize::from(self.pixels_per_column);
        let cols = usize::from(self.columns_per_packet);
        (1..=field::MAX_BEAMS).contains(&beams)
            && (1..=field::MAX_COLUMNS_PER_PACKET).contains(&cols)
            && self.columns_per_frame > 0
            && self.frequency_hz > 0
            && self.beam_origin.is_finite()
            && self.rotation.iter().flatten().chain(&self.translation).all(|v| v.is_finite())
    }
}

/// Time between lidar packets, seconds.
pub fn packet_period(g: &OusterGeometry) -> f64 {
    let columns_per_s = f64::from(g.columns_per_frame) * f64::from(g.frequency_hz.max(1));
    f64::from(g.columns_per_packet) / columns_per_s.max(1.0)
}
