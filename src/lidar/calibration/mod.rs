//! Per-unit angle corrections: fixed-size tables usable without an allocator, built-in
//! nominal tables per model (from the vendors' user manuals), and (std) parsers for Hesai
//! angle-correction CSV files, Velodyne calibration YAML files (the `velodyne_pointcloud`
//! subset: a `lasers:` list of flow or block mappings, `num_lasers`, `distance_resolution`)
//! and Ouster metadata json (beam angles, beam origin, lidar→sensor transform, data format).

use super::common::Model;
pub use super::ouster::geometry::{OusterGeometry, Profile as OusterProfile};

/// The most lasers any supported model has (an Ouster OS-128).
pub const MAX_LASERS: usize = 128;

/// Corrections of one laser, with the trigonometry precomputed.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LaserCorrection {
    /// Elevation, radians, up positive.
    pub elevation: f32,
    /// Added to the firing azimuth, radians, clockwise seen from above positive (Hesai's
    /// "azimuth" column; minus Velodyne's `rot_correction`; Ouster's `beam_azimuth_angles`).
    pub azimuth_offset: f32,
    /// Added to every non-zero range, metres (Velodyne `dist_correction`).
    pub dist_correction: f32,
    /// Velodyne optical-centre offsets, metres.
    pub vert_offset: f32,
    pub horiz_offset: f32,
    pub sin_elevation: f32,
    pub cos_elevation: f32,
    pub sin_azimuth_offset: f32,
    pub cos_azimuth_offset: f32,
}

impl LaserCorrection {
    /// A correction from angles in degrees, other terms zero.
    pub fn from_degrees(elevation_deg: f32, azimuth_offset_deg: f32) -> Self {
        Self::new(elevation_deg.to_radians(), azimuth_offset_deg.to_radians(), 0.0, 0.0, 0.0)
    }

    /// A correction from angles in radians and offsets in metres.
    pub fn new(elevation: f32, azimuth_offset: f32, dist: f32, vert: f32, horiz: f32) -> Self {
        LaserCorrection {
            elevation,
            azimuth_offset,
            dist_correction: dist,
            vert_offset: vert,
            horiz_offset: horiz,
            sin_elevation: libm::sinf(elevation),
            cos_elevation: libm::cosf(elevation),
            sin_azimuth_offset: libm::sinf(azimuth_offset),
            cos_azimuth_offset: libm::cosf(azimuth_offset),
        }
    }
}

/// The angle table of one unit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Calibration {
    pub model: Model,
    /// Indexed by the laser number in the packet (0-based); entries past `model.lasers()` unused.
    pub lasers: [LaserCorrection; MAX_LASERS],
    /// Metres per range count for Velodyne units (Hesai packets carry their own unit).
    pub distance_resolution: f32,
    /// How Velodyne firing azimuths are interpolated between block azimuths.
    pub interpolation: Interpolation,
    /// An Ouster unit's packet layout and beam geometry (unused for other models; the
    /// per-beam altitude and azimuth angles are in `lasers`).
    pub ouster: OusterGeometry,
}

/// How a Velodyne decoder places each firing between two block azimuths.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Interpolation {
    /// By firing time as the user manuals give it (VLP-16: per laser and firing; VLP-32C: per
    /// laser pair; HDL-32E: per laser); the last sequence of a packet reuses the previous
    /// advance.
    #[default]
    Manual,
    /// As tier4/nebula 0.x does, to reproduce its clouds exactly: VLP-16 as the manual but the
    /// first block without a successor gets no advance; VLP-32C advances each of the 32
    /// channel slots by 2.304 µs. Hesai decoding is the same in both modes.
    Nebula,
}

/// Why a calibration table does not fit its model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CalibrationError {
    /// A laser number outside the model's range.
    LaserOutOfRange(usize),
    /// Fewer lasers than the model has.
    MissingLasers { found: usize, expected: usize },
    /// A non-finite or absurd value (|angle| > 90°, resolution ≤ 0).
    BadValue,
}

impl core::fmt::Display for CalibrationError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            CalibrationError::LaserOutOfRange(i) => write!(f, "laser {i} out of range"),
            CalibrationError::MissingLasers { found, expected } => {
                write!(f, "{found} lasers given, the model has {expected}")
            }
            CalibrationError::BadValue => write!(f, "non-finite or out-of-range value"),
        }
    }
}

impl Calibration {
    /// The nominal table of `model` from its user manual.
    pub fn nominal(model: Model) -> Self {
        let mut lasers = [LaserCorrection::default(); MAX_LASERS];
        let (elev, azim): (&[f32], &[f32]) = match model {
            Model::Vlp16 => (&VLP16_ELEVATION, &[0.0; 16]),
            Model::Vlp32c => (&VLP32C_ELEVATION, &VLP32C_AZIMUTH),
            Model::Hdl32e => (&HDL32E_ELEVATION, &[0.0; 32]),
            Model::Pandar40p => (&PANDAR40P_ELEVATION, &PANDAR40P_AZIMUTH),
            Model::Pandar64 => (&PANDAR64_ELEVATION, &PANDAR64_AZIMUTH),
            Model::PandarXt32 => (&PANDARXT32_ELEVATION, &[0.0; 32]),
            Model::PandarQt64 => (&PANDARQT64_ELEVATION, &PANDARQT64_AZIMUTH),
            // No nominal Ouster table: a unit's comes from its metadata json; this is the
            // uniform 32-beam fan of the default geometry, so the type stays total.
            Model::Ouster => (&OUSTER_NOMINAL_ELEVATION, &[0.0; 32]),
        };
        for ((slot, e), a) in lasers.iter_mut().zip(elev).zip(azim) {
            *slot = LaserCorrection::from_degrees(*e, *a);
        }
        let distance_resolution = match model {
            Model::Vlp32c => 0.004,
            Model::Vlp16 | Model::Hdl32e => 0.002,
            Model::Pandar40p | Model::Pandar64 | Model::PandarXt32 | Model::PandarQt64 => 0.004,
            Model::Ouster => 0.001,
        };
        Calibration {
            model,
            lasers,
            distance_resolution,
            interpolation: Interpolation::Manual,
            ouster: OusterGeometry::default(),
        }
    }

    /// Lasers of this unit: the model's count, or an Ouster unit's beams.
    pub fn laser_count(&self) -> usize {
        match self.model {
            Model::Ouster => usize::from(self.ouster.pixels_per_column).min(MAX_LASERS),
            m => m.lasers(),
        }
    }

    /// A table from per-laser elevations and azimuth offsets in degrees (as a Hesai CSV holds
    /// them), other terms zero; the tables must have the model's laser count.
    pub fn from_degrees(
        model: Model,
        elevation_deg: &[f32],
        azimuth_deg: &[f32],
    ) -> Result<Self, CalibrationError> {
        let lasers = model.lasers();
        for found in [elevation_deg.len(), azimuth_deg.len()] {
            if found != lasers {
                return Err(CalibrationError::MissingLasers { found, expected: lasers });
            }
        }
        let mut cal = Calibration::nominal(model);
        for (i, (e, a)) in elevation_deg.iter().zip(azimuth_deg).enumerate() {
            cal.set(i, LaserCorrection::from_degrees(*e, *a))?;
        }
        Ok(cal)
    }

    /// Sets laser `index` (0-based), checking it exists and its values are sane.
    pub fn set(&mut self, index: usize, c: LaserCorrection) -> Result<(), CalibrationError> {
        if index >= self.laser_count() {
            return Err(CalibrationError::LaserOutOfRange(index));
        }
        let sane = |v: f32, lim: f32| v.is_finite() && v.abs() <= lim;
        let half_pi = core::f32::consts::FRAC_PI_2;
        if !(sane(c.elevation, half_pi)
            && sane(c.azimuth_offset, half_pi)
            && sane(c.dist_correction, 10.0)
            && sane(c.vert_offset, 10.0)
            && sane(c.horiz_offset, 10.0))
        {
            return Err(CalibrationError::BadValue);
        }
        self.lasers[index] = c;
        Ok(())
    }

    /// The lasers of the model.
    pub fn active(&self) -> &[LaserCorrection] {
        &self.lasers[..self.laser_count()]
    }

    /// Laser numbers sorted by elevation, bottom first: `rings()[laser]` is the ring index
    /// (0 = lowest beam), as most point-cloud tools number rings.
    pub fn rings(&self) -> [u16; MAX_LASERS] {
        let mut rings = [0u16; MAX_LASERS];
        let active = self.active();
        for (i, c) in active.iter().enumerate() {
            let below = active
                .iter()
                .enumerate()
                .filter(|(j, o)| {
                    o.elevation < c.elevation || (o.elevation == c.elevation && *j < i)
                })
                .count();
            rings[i] = below as u16;
        }
        rings
    }
}

/// VLP-16 vertical angles by laser number, degrees (manual, table 9-1).
pub const VLP16_ELEVATION: [f32; 16] =
    [-15., 1., -13., 3., -11., 5., -9., 7., -7., 9., -5., 11., -3., 13., -1., 15.];

/// VLP-32C vertical angles by laser number, degrees (manual, table 9-2).
pub const VLP32C_ELEVATION: [f32; 32] = [
    -25., -1., -1.667, -15.639, -11.31, 0., -0.667, -8.843, -7.254, 0.333, -0.333, -6.148, -5.333,
    1.333, 0.667, -4., -4.667, 1.667, 1., -3.667, -3.333, 3.333, 2.333, -2.667, -3., 7., 4.667,
    -2.333, -2., 15., 10.333, -1.333,
];

/// VLP-32C azimuth offsets by laser number, degrees (manual, table 9-2).
pub const VLP32C_AZIMUTH: [f32; 32] = [
    1.4, -4.2, 1.4, -1.4, 1.4, -1.4, 4.2, -1.4, 1.4, -4.2, 1.4, -1.4, 4.2, -1.4, 4.2, -1.4, 1.4,
    -4.2, 1.4, -4.2, 4.2, -1.4, 1.4, -1.4, 1.4, -1.4, 1.4, -4.2, 4.2, -1.4, 1.4, -1.4,
];

/// HDL-32E vertical angles by laser number, degrees: two interleaved fans 4/3° apart.
pub const HDL32E_ELEVATION: [f32; 32] = [
    -30.67, -9.33, -29.33, -8., -28., -6.67, -26.67, -5.33, -25.33, -4., -24., -2.67, -22.67,
    -1.33, -21.33, 0., -20., 1.33, -18.67, 2.67, -17.33, 4., -16., 5.33, -14.67, 6.67, -13.33, 8.,
    -12., 9.33, -10.67, 10.67,
];

/// Pandar40P nominal elevations by channel, degrees (user manual, appendix I).
pub const PANDAR40P_ELEVATION: [f32; 40] = [
    15., 11., 8., 5., 3., 2., 1.67, 1.33, 1., 0.67, 0.33, 0., -0.33, -0.67, -1., -1.33, -1.67, -2.,
    -2.33, -2.67, -3., -3.33, -3.67, -4., -4.33, -4.67, -5., -5.33, -5.67, -6., -7., -8., -9.,
    -10., -11., -12., -13., -14., -19., -25.,
];

/// Pandar40P nominal azimuth offsets by channel, degrees (user manual, appendix I).
pub const PANDAR40P_AZIMUTH: [f32; 40] = {
    let mut a = [-1.042f32; 40];
    let cycle = [3.125f32, -5.208, -1.042];
    let mut i = 6;
    while i < 30 {
        a[i] = cycle[(i - 6) % 3];
        i += 1;
    }
    a
};

/// Pandar64 nominal elevations by channel, degrees (user manual, appendix I).
pub const PANDAR64_ELEVATION: [f32; 64] = [
    14.882, 11.032, 8.059, 5.057, 3.04, 2.028, 1.86, 1.688, 1.522, 1.351, 1.184, 1.013, 0.846,
    0.675, 0.508, 0.337, 0.169, 0., -0.169, -0.337, -0.508, -0.675, -0.845, -1.013, -1.184, -1.351,
    -1.522, -1.688, -1.86, -2.028, -2.198, -2.365, -2.536, -2.7, -2.873, -3.04, -3.21, -3.375,
    -3.548, -3.712, -3.884, -4.05, -4.221, -4.385, -4.558, -4.72, -4.892, -5.057, -5.229, -5.391,
    -5.565, -5.726, -5.898, -6.061, -7.063, -8.059, -9.06, -9.885, -11.032, -12.006, -12.974,
    -13.93, -18.889, -24.897,
];

/// Elevations of one real Pandar64 unit by channel, degrees (the angle-correction file of
/// the unit in `../shared/data/pcap/hesai-pandar64`; its azimuths are the nominal ones). The
/// simulator's Pandar64 uses it so that decoding needs the unit's file, as on a vehicle.
pub const PANDAR64_UNIT_ELEVATION: [f32; 64] = [
    14.9, 11.05, 8.077, 5.075, 3.058, 2.046, 1.878, 1.706, 1.54, 1.369, 1.202, 1.031, 0.864, 0.693,
    0.526, 0.355, 0.187, 0.018, -0.151, -0.319, -0.49, -0.657, -0.827, -0.995, -1.166, -1.333,
    -1.504, -1.67, -1.842, -2.01, -2.18, -2.347, -2.518, -2.682, -2.855, -3.022, -3.192, -3.357,
    -3.53, -3.694, -3.866, -4.032, -4.203, -4.367, -4.54, -4.702, -4.874, -5.039, -5.211, -5.373,
    -5.547, -5.708, -5.88, -6.043, -7.045, -8.041, -9.042, -10.027, -11.014, -11.988, -12.956,
    -13.912, -18.871, -24.879,
];

/// Pandar64 nominal azimuth offsets by channel, degrees (user manual, appendix I).
pub const PANDAR64_AZIMUTH: [f32; 64] = {
    let mut a = [-1.042f32; 64];
    let cycle = [1.042f32, 3.125, 5.208, -5.208, -3.125, -1.042];
    let mut i = 6;
    while i < 54 {
        a[i] = cycle[(i - 6) % 6];
        i += 1;
    }
    a
};

/// PandarXT32 nominal elevations by channel, degrees: 1° apart from +15° to −16° (user
/// manual, channel distribution); nominal azimuth offsets are 0.
pub const PANDARXT32_ELEVATION: [f32; 32] = {
    let mut e = [0f32; 32];
    let mut i = 0;
    while i < 32 {
        e[i] = 15.0 - i as f32;
        i += 1;
    }
    e
};

/// PandarQT64 elevations by channel, degrees: the angle-correction file tier4/nebula ships
/// as the QT64 default (`nebula_hesai_decoders/calibration/PandarQT64.csv`).
pub const PANDARQT64_ELEVATION: [f32; 64] = [
    -52.121, -49.785, -47.577, -45.477, -43.465, -41.528, -39.653, -37.831, -36.055, -34.320,
    -32.619, -30.950, -29.308, -27.690, -26.094, -24.517, -22.964, -21.420, -19.889, -18.372,
    -16.865, -15.368, -13.880, -12.399, -10.925, -9.457, -7.994, -6.535, -5.079, -3.626, -2.175,
    -0.725, 0.725, 2.175, 3.626, 5.079, 6.534, 7.993, 9.456, 10.923, 12.397, 13.877, 15.365,
    16.861, 18.368, 19.885, 21.415, 22.959, 24.524, 26.101, 27.697, 29.315, 30.957, 32.627, 34.328,
    36.064, 37.840, 39.662, 41.537, 43.475, 45.487, 47.587, 49.795, 52.133,
];

/// PandarQT64 azimuth offsets by channel, degrees (the same file).
pub const PANDARQT64_AZIMUTH: [f32; 64] = [
    8.736, 8.314, 7.964, 7.669, 7.417, 7.198, 7.007, 6.838, 6.688, 6.554, 6.434, 6.326, 6.228,
    6.140, 6.059, 5.987, -5.270, -5.216, -5.167, -5.123, -5.083, -5.047, -5.016, -4.988, -4.963,
    -4.942, -4.924, -4.910, -4.898, -4.889, -4.884, -4.881, 5.493, 5.496, 5.502, 5.512, 5.525,
    5.541, 5.561, 5.584, 5.611, 5.642, 5.676, 5.716, 5.759, 5.808, 5.862, 5.921, -5.330, -5.396,
    -5.469, -5.550, -5.640, -5.740, -5.850, -5.974, -6.113, -6.269, -6.447, -6.651, -6.887, -7.163,
    -7.493, -7.892,
];

/// Placeholder Ouster fan, degrees: 32 beams 1° apart, +15.5° to −15.5° (top first, as
/// Ouster numbers beams). Real units always come with their metadata.
const OUSTER_NOMINAL_ELEVATION: [f32; 32] = {
    let mut e = [0f32; 32];
    let mut i = 0;
    while i < 32 {
        e[i] = 15.5 - i as f32;
        i += 1;
    }
    e
};

#[cfg(feature = "std")]
pub use files::{
    load, parse_hesai_csv, parse_ouster_json, parse_velodyne_yaml, to_hesai_csv,
    CalibrationFileError,
};

#[cfg(feature = "std")]
mod files;
#[cfg(feature = "std")]
mod ouster_json;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nominal_tables_have_the_model_sizes_and_ranges() {
        for m in Model::ALL {
            let c = Calibration::nominal(m);
            let active = c.active();
            let lasers = if m == Model::Ouster { 32 } else { m.lasers() };
            assert_eq!(active.len(), lasers);
            let top = active.iter().map(|l| l.elevation.to_degrees()).fold(f32::MIN, f32::max);
            let bottom = active.iter().map(|l| l.elevation.to_degrees()).fold(f32::MAX, f32::min);
            // The QT64 is a dome: ±52°.
            let (top_max, bottom_min) =
                if m == Model::PandarQt64 { (53.0, -53.0) } else { (15.501, -31.0) };
            assert!(top > 10.0 && top <= top_max, "{m:?} top {top}");
            assert!(bottom < -14.0 && bottom > bottom_min, "{m:?} bottom {bottom}");
            // Ring numbering is a permutation.
            let mut rings: Vec<u16> = c.rings()[..lasers].to_vec();
            rings.sort_unstable();
            assert!(rings.iter().enumerate().all(|(i, r)| usize::from(*r) == i), "{m:?}");
        }
        let counts = |t: &[f32], v: f32| t.iter().filter(|a| (**a - v).abs() < 1e-6).count();
        assert_eq!(counts(&PANDAR64_AZIMUTH, -1.042), 24);
        assert_eq!(counts(&PANDAR64_AZIMUTH, 5.208), 8);
        assert_eq!(counts(&PANDAR40P_AZIMUTH, -1.042), 24);
    }

    #[test]
    fn set_rejects_bad_values() {
        let mut c = Calibration::nominal(Model::Vlp16);
        assert_eq!(
            c.set(16, LaserCorrection::default()),
            Err(CalibrationError::LaserOutOfRange(16))
        );
        assert_eq!(
            c.set(0, LaserCorrection::from_degrees(f32::NAN, 0.0)),
            Err(CalibrationError::BadValue)
        );
        assert!(c.set(3, LaserCorrection::from_degrees(2.0, 0.5)).is_ok());
    }

    #[cfg(feature = "std")]
    #[test]
    fn parses_both_yaml_styles_and_csv() {
        use std::path::Path;
        let flow = "lasers:\n  - {dist_correction: 0.01, laser_id: 1, rot_correction: 0.1,\n     vert_correction: -0.2}\n";
        let block = "  - laser_id: 0\n    vert_correction: 0.3\n    rot_correction: -0.05\nnum_lasers: 16\ndistance_resolution: 0.002\n";
        // Only two lasers: incomplete.
        let text = format!("{flow}{block}");
        let err = parse_velodyne_yaml(Model::Vlp16, &text, Path::new("x.yaml")).unwrap_err();
        assert!(
            err.to_string().contains("x.yaml") && err.to_string().contains("2 lasers"),
            "{err}"
        );
        let mut full = String::from("lasers:\n");
        for i in 0..16 {
            full.push_str(&format!(
                "  - {{laser_id: {i}, rot_correction: -0.01, vert_correction: {}}}\n",
                0.01 * i as f64
            ));
        }
        full.push_str(flow.trim_start_matches("lasers:\n"));
        full.push_str("distance_resolution: 0.004\n");
        let c = parse_velodyne_yaml(Model::Vlp16, &full, Path::new("x.yaml")).unwrap();
        assert!((c.lasers[1].azimuth_offset + 0.1).abs() < 1e-7);
        assert!((c.lasers[1].dist_correction - 0.01).abs() < 1e-7);
        assert!((c.lasers[5].elevation - 0.05).abs() < 1e-7);
        assert!((c.lasers[5].azimuth_offset - 0.01).abs() < 1e-7);
        assert_eq!(c.distance_resolution, 0.004);
        let blocky = format!("lasers:\n{block}");
        let err = parse_velodyne_yaml(Model::Vlp16, &blocky, Path::new("b.yaml")).unwrap_err();
        assert!(err.to_string().contains("1 lasers given"), "{err}");

        let mut csv = String::from("Laser id,Elevation,Azimuth\n");
        for i in 1..=40 {
            csv.push_str(&format!("{i},{},{}\n", 15.0 - i as f32, 0.5));
        }
        let c = parse_hesai_csv(Model::Pandar40p, &csv, Path::new("a.csv")).unwrap();
        assert!((c.lasers[0].elevation.to_degrees() - 14.0).abs() < 1e-5);
        let bad = csv.replace("3,12,0.5", "3,twelve,0.5");
        let err = parse_hesai_csv(Model::Pandar40p, &bad, Path::new("a.csv")).unwrap_err();
        assert!(err.to_string().contains("line 4"), "{err}");
        let short = "Laser id,Elevation,Azimuth\n1,2,3\n";
        assert!(parse_hesai_csv(Model::Pandar40p, short, Path::new("a.csv")).is_err());
    }
}
