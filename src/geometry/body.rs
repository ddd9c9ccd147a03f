//! A sensor's pose as people read it: in the camera's body frame (ROS `camera_link`:
//! x forward, y left, z up), roll, pitch and yaw in degrees (R = Rz(yaw)·Ry(pitch)·Rx(roll))
//! and x y z in metres. Every place a person reads an extrinsic (the `calibrate` summary, the
//! daemon's end summary, `roomcal query`) gives it in this one form; quaternions and optical
//! frames are for machine formats.

use core::fmt;

use super::se3::rotation_to_rpy;
use super::{Mat3, Se3, Vec3};

/// `p_optical = OPTICAL_FROM_LINK · p_link`: the optical frame (x right, y down, z
/// forward; camera_info's and the result file's) from ROS's `camera_link` body frame (x
/// forward, y left, z up). The same fixed joint as Autoware's sensor kits,
/// `camera_link → camera_optical_link` = rpy(−π/2, 0, −π/2).
pub const OPTICAL_FROM_LINK: [[f64; 3]; 3] = [[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]];

/// [`OPTICAL_FROM_LINK`] as a matrix.
pub fn optical_from_link() -> Mat3 {
    let m = &OPTICAL_FROM_LINK;
    Mat3::new(m[0][0], m[0][1], m[0][2], m[1][0], m[1][1], m[1][2], m[2][0], m[2][1], m[2][2])
}

/// A sensor's pose in a camera's body frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodyPose {
    /// Roll, pitch, yaw (degrees).
    pub rpy_deg: [f64; 3],
    /// Position (m).
    pub position_m: Vec3,
}

impl BodyPose {
    /// The pose of a sensor in the camera's body frame, from `sensor_to_camera`
    /// (`p_optical = R · p_sensor + t`). A camera sensor's own optical axes are turned to
    /// its body axes too (`sensor_is_camera`): a sensor mounted with its axes along the
    /// camera's reads roll = pitch = yaw = 0.
    pub fn of(sensor_to_camera: &Se3, sensor_is_camera: bool) -> BodyPose {
        let link = Se3 { rotation: optical_from_link(), translation: Vec3::zeros() };
        let mut pose = link.inverse().compose(sensor_to_camera);
        if sensor_is_camera {
            pose = pose.compose(&link);
        }
        BodyPose {
            rpy_deg: rotation_to_rpy(&pose.rotation).map(|a| a.to_degrees()),
            position_m: pose.translation,
        }
    }
}

impl fmt::Display for BodyPose {
    /// "roll 0.120° pitch -0.300° yaw 90.010°, x 0.0518 y 0.3860 z -0.2656 m".
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [roll, pitch, yaw] = self.rpy_deg.map(|a| unsigned_zero(a, 3));
        let [x, y, z] = [0, 1, 2].map(|i| unsigned_zero(self.position_m[i], 4));
        write!(f, "roll {roll:.3}° pitch {pitch:.3}° yaw {yaw:.3}°, x {x:.4} y {y:.4} z {z:.4} m")
    }
}

/// `v`, or 0 when it prints as zero at `decimals` places: no "-0.000" for a value that is
/// zero but for rounding.
fn unsigned_zero(v: f64, decimals: i32) -> f64 {
    if v.abs() < 0.5 * libm::pow(10.0, -f64::from(decimals)) {
        0.0
    } else {
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::se3::rpy_to_rotation;

    #[test]
    fn a_lidar_along_the_camera_reads_zero_and_its_offsets_in_body_axes() {
        // A LiDAR (x forward, y left, z up) mounted 0.1 m left of and 0.2 m above the
        // camera, its axes along the camera's body axes: in the optical frame it is 0.1 m
        // to the left (x = -0.1) and 0.2 m up (y = -0.2).
        let lidar_to_camera =
            Se3 { rotation: optical_from_link(), translation: Vec3::new(-0.1, -0.2, 0.0) };
        let pose = BodyPose::of(&lidar_to_camera, false);
        assert!(pose.rpy_deg.iter().all(|a| a.abs() < 1e-12), "{pose}");
        assert!((pose.position_m - Vec3::new(0.0, 0.1, 0.2)).norm() < 1e-12, "{pose}");
        assert_eq!(
            pose.to_string(),
            "roll 0.000° pitch 0.000° yaw 0.000°, x 0.0000 y 0.1000 z 0.2000 m"
        );
    }

    #[test]
    fn a_turned_sensor_reads_its_turn_in_body_axes_camera_or_lidar() {
        let turn = rpy_to_rotation(&[0.01, -0.02, 0.3]);
        let m = optical_from_link();
        // A LiDAR turned by `turn` about the body axes.
        let lidar = Se3 { rotation: m * turn, translation: Vec3::zeros() };
        let got = BodyPose::of(&lidar, false).rpy_deg;
        // A second camera turned alike: its optical frame is its body frame through `m`.
        let camera = Se3 { rotation: m * turn * m.transpose(), translation: Vec3::zeros() };
        let as_camera = BodyPose::of(&camera, true).rpy_deg;
        for (want, (a, b)) in [0.01f64, -0.02, 0.3].iter().zip(got.iter().zip(&as_camera)) {
            assert!((want.to_degrees() - a).abs() < 1e-9 && (want.to_degrees() - b).abs() < 1e-9);
        }
    }
}
