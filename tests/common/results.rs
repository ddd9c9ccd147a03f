//! Result files for the tests of their consumers (exports, store, the daemon's service):
//! a one-pair result with an oblique extrinsic and a four-sensor rig around it.
#![allow(dead_code)]

use roomcal::geometry::se3::so3_exp;
use roomcal::geometry::{CameraModel, Vec3};
use roomcal::result::{
    CalibrationResult, CameraResult, Extrinsic, Quality, RigExtrinsic, RigResult, SensorResult,
    Status, Uncertainty,
};

/// `p_optical = OPTICAL_FROM_LINK · p_link` (REP 103 camera_link → optical frame).
const OPTICAL_FROM_LINK: [[f64; 3]; 3] = [[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]];

fn mul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|i| [0, 1, 2].map(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

/// A result with an oblique extrinsic (every matrix entry non-trivial).
pub fn result(model: CameraModel) -> CalibrationResult {
    let distortion = match model {
        CameraModel::PinholeRadtan => vec![-0.171, 0.0324, 0.00016, -0.00046, 0.0169],
        CameraModel::Fisheye => vec![0.021, -0.0043, 0.0011, -0.00021],
    };
    let nominal = [[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]];
    let tilt = so3_exp(&Vec3::new(0.031, -0.052, 0.017));
    let rotation = mul(&[0, 1, 2].map(|i| [0, 1, 2].map(|j| tilt[(i, j)])), &nominal);
    CalibrationResult {
        status: Status::Accepted,
        reason: None,
        camera: CameraResult {
            model,
            width: 1920,
            height: 1200,
            fx: 1482.4735314244765,
            fy: 1483.7168896297012,
            cx: 965.1525416799066,
            cy: 591.9792557587691,
            distortion,
        },
        lidar_to_camera: Some(Extrinsic { rotation, translation: [0.0518, 0.386, -0.2656] }),
        uncertainty: Uncertainty::default(),
        quality: Quality::default(),
        boards: Vec::new(),
        camera_in_room: None,
        projection_uncertainty: None,
    }
}

/// A rig: `front` (the one-pair fields' camera), a `wide` camera, the `top` LiDAR (the
/// one-pair extrinsic) and a `bumper` LiDAR, every mounting oblique.
pub fn rig_result() -> RigResult {
    let pair = result(CameraModel::PinholeRadtan);
    let mut wide = pair.camera.clone();
    (wide.fx, wide.fy, wide.cx, wide.cy) = (961.25, 960.5, 955.75, 604.125);
    let matrix = |m: roomcal::geometry::Mat3| [0, 1, 2].map(|i| [0, 1, 2].map(|j| m[(i, j)]));
    let wide_to_front = matrix(so3_exp(&Vec3::new(0.012, 0.139, -0.021)));
    let top = pair.lidar_to_camera.clone().unwrap();
    let bumper = mul(&matrix(so3_exp(&Vec3::new(-0.02, 0.035, 0.011))), &OPTICAL_FROM_LINK);
    let extrinsic = |from: &str, rotation, translation| RigExtrinsic {
        from: from.into(),
        to: "front".into(),
        rotation,
        translation,
        sigma_rotation_deg: 0.01,
        sigma_translation_m: 0.002,
    };
    let sensor = |camera: Option<CameraResult>| SensorResult {
        lidar: camera.is_none(),
        uncertainty: camera.as_ref().map(|_| Uncertainty::default()),
        camera,
        camera_in_room: None,
        status: Status::Accepted,
        reason: None,
        solved_with: None,
        projection_uncertainty: None,
    };
    let sensors = [
        ("front", sensor(Some(pair.camera.clone()))),
        ("wide", sensor(Some(wide))),
        ("top", sensor(None)),
        ("bumper", sensor(None)),
    ];
    RigResult {
        pair,
        sensors: sensors.into_iter().map(|(n, s)| (n.to_string(), s)).collect(),
        extrinsics: vec![
            extrinsic("wide", wide_to_front, [-0.25, 0.012, 0.021]),
            extrinsic("top", top.rotation, top.translation),
            extrinsic("bumper", bumper, [0.05, 1.52, 0.72]),
        ],
    }
}
