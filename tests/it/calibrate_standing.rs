//! A standing vehicle: several frames and sweeps of one room, averaged and accumulated as
//! the daemon does (and `roomcal calibrate --standing`), against the first frame alone.
//! The LiDAR side gains most: the board planes and hole centres come from four times the
//! points, so the extrinsic's translation σ must shrink and the estimate stay within its
//! uncertainty; the averaged image's corners must fit better. The simulator's first frame must not change when more are asked for.

use crate::common::band_room;

use band_room::{band_options, design_room};
use roomcal::calibrate::{calibrate, CalibrateOptions, Calibration, Detectors, FrameDetections};
use roomcal::capture::mean_pixels;
use roomcal::lidar::Point;
use roomcal::result::Status;
use roomcal::sim::{simulate, ImageNoise, Scene, SimOptions};

const FRAMES: usize = 4;

#[test]
fn standing_frames_shrink_the_extrinsic_uncertainty() {
    let room = design_room();
    // Four sub-samples per axis: at two, the sub-sample grid itself leaves static corner
    // errors that no averaging removes.
    let options = SimOptions { image: ImageNoise::default(), ..band_options(2) };
    let standing =
        simulate(&room, &SimOptions { standing_frames: FRAMES, ..options.clone() }).unwrap();
    assert_eq!(standing.more.len(), FRAMES - 1);
    let alone = simulate(&room, &options).unwrap();
    assert!(alone.more.is_empty());
    assert!(alone.image == standing.image, "the first frame changed with more frames");
    assert!(alone.cloud == standing.cloud, "the first sweep changed with more frames");
    assert!(standing.more.iter().all(|f| f.image != standing.image), "frames share their noise");

    let images: Vec<&[u8]> = std::iter::once(standing.image.as_slice())
        .chain(standing.more.iter().map(|f| f.image.as_slice()))
        .collect();
    let sweeps: Vec<Point> = std::iter::once(standing.cloud.as_ref().unwrap())
        .chain(standing.more.iter().map(|f| f.cloud.as_ref().unwrap()))
        .flatten()
        .copied()
        .collect();
    let one = solve(&standing, &standing.image, standing.cloud.as_ref().unwrap());
    let all = solve(&standing, &mean_pixels(&images).unwrap(), &sweeps);
    for (what, run) in [("one frame", &one), ("four frames", &all)] {
        assert_eq!(run.result.status, Status::Accepted, "{what}: {:?}", run.result.reason);
    }

    let (u1, u4) = (&one.result.uncertainty, &all.result.uncertainty);
    let (_, shift) = standing
        .truth
        .lidar_to_camera
        .as_ref()
        .unwrap()
        .difference(all.result.lidar_to_camera.as_ref().unwrap());
    println!(
        "σ t {:.1} → {:.1} mm, σ rot {:.3} → {:.3}°, hole RMS {:.3} → {:.3} px, corner RMS {:.3} → {:.3} px; \
         four frames: translation off by {:.1} mm",
        1e3 * u1.translation_m,
        1e3 * u4.translation_m,
        u1.rotation_deg,
        u4.rotation_deg,
        one.result.quality.hole_rms_px,
        all.result.quality.hole_rms_px,
        one.result.quality.corner_rms_px,
        all.result.quality.corner_rms_px,
        1e3 * shift
    );
    assert!(
        u4.translation_m < 0.75 * u1.translation_m,
        "σ t {} → {}",
        u1.translation_m,
        u4.translation_m
    );
    assert!(u4.rotation_deg < u1.rotation_deg, "σ rot {} → {}", u1.rotation_deg, u4.rotation_deg);
    // The camera gains less: the sensor noise averages away, the detector's own error on
    // a noise-free image (≈ 0.014 px) does not.
    let (c1, c4) = (one.result.quality.corner_rms_px, all.result.quality.corner_rms_px);
    assert!(c4 < 0.9 * c1, "corner RMS {c1} → {c4}");
    assert!(shift < 4.0 * u4.translation_m.max(1e-3), "translation off by {shift} m");
}

/// Detects the boards in one (possibly averaged) frame and (possibly accumulated) sweep
/// and calibrates.
fn solve(scene: &Scene, image: &[u8], cloud: &[Point]) -> Calibration {
    let mut detectors = Detectors::new(&scene.room).unwrap();
    let frame = FrameDetections {
        camera: detectors.detect_pixels(image).unwrap(),
        lidar: detectors.detect_cloud(cloud),
    };
    calibrate(&scene.room, std::slice::from_ref(&frame), &CalibrateOptions::default())
}
