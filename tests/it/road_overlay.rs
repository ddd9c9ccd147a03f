//! The overlay on a real road scene (../shared/data/road-overlay, OpenCalib's sample)
//! with its published calibration, written to `target/road-overlay.png` for a person to
//! look at (a depth-edge/image-edge score was tried and did not peak at the published
//! calibration, so the check stays visual). Skips with a message when ../shared is absent.

use std::path::{Path, PathBuf};

use roomcal::geometry::{Camera, CameraModel, Mat3, Se3, Vec3};
use roomcal::report::overlay;

fn data_dir() -> Option<PathBuf> {
    let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data/road-overlay"));
    if dir.is_dir() {
        Some(dir.to_path_buf())
    } else {
        crate::common::skipped(format_args!("{} is absent", dir.display()));
        None
    }
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

/// OpenCalib's intrinsic file (its "1080 rows" is wrong: the image has 1200).
fn published_camera(dir: &Path) -> Camera {
    let v = json(&dir.join("center_camera-intrinsic.json"));
    let p = &v["center_camera-intrinsic"]["param"];
    let k = |r: usize, c: usize| p["cam_K"]["data"][r][c].as_f64().unwrap();
    let d = |i: usize| p["cam_dist"]["data"][0][i].as_f64().unwrap();
    Camera {
        model: CameraModel::PinholeRadtan,
        width: 1920,
        height: 1200,
        fx: k(0, 0),
        fy: k(1, 1),
        cx: k(0, 2),
        cy: k(1, 2),
        distortion: [d(0), d(1), d(2), d(3), 0.0],
    }
}

/// OpenCalib's extrinsic: `p_camera = T · p_lidar`.
fn published_extrinsic(dir: &Path) -> Se3 {
    let v = json(&dir.join("top_center_lidar-to-center_camera-extrinsic.json"));
    let m = &v["top_center_lidar-to-center_camera-extrinsic"]["param"]["sensor_calib"]["data"];
    let e = |r: usize, c: usize| m[r][c].as_f64().unwrap();
    Se3 {
        rotation: Mat3::new(
            e(0, 0),
            e(0, 1),
            e(0, 2),
            e(1, 0),
            e(1, 1),
            e(1, 2),
            e(2, 0),
            e(2, 1),
            e(2, 2),
        ),
        translation: Vec3::new(e(0, 3), e(1, 3), e(2, 3)),
    }
}

#[test]
fn published_calibration_draws_the_road_scene() {
    let Some(dir) = data_dir() else { return };
    let camera = published_camera(&dir);
    let extrinsic = published_extrinsic(&dir);
    let image = roomcal::detect::load_grey(dir.join("0.png")).unwrap();
    assert_eq!((image.width, image.height), (camera.width, camera.height));
    let cloud = roomcal::lidar::read_cloud(&dir.join("0.pcd"), None, None).unwrap();
    let drawn = overlay(&image.data, &camera, Some(&extrinsic), &[&cloud], &[]);
    // Range colours are saturated; the frame underneath is grey.
    let coloured = drawn.pixels().filter(|p| p.0.iter().max() != p.0.iter().min()).count();
    println!("{coloured} coloured pixels of {}", drawn.width() * drawn.height());
    assert!(coloured > 50_000, "only {coloured} pixels carry LiDAR points");
    // Looked at: poles, tree trunks and both cars carry their points.
    let out = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/target/road-overlay.png"));
    drawn.save(out).unwrap();
    println!("overlay written to {}", out.display());
}
