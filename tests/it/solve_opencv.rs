//! The solver on real corners: OpenCV's own corners of its `left01..14` sample views
//! (tests/solve_data/opencv_left.txt, made by scripts/solve_opencv_left.py from
//! ../shared/data) calibrated from a blank camera (Zhang start, intrinsics-only joint LM)
//! must land on OpenCV's `calibrateCamera` result for the same corners.

use roomcal::geometry::{Camera, CameraModel, Vec2, Vec3};
use roomcal::solve::{
    covariance, initialise, BoardObservation, IntrinsicsSeed, JointProblem, LmOptions, Loss,
    ParamMask,
};

const DATA: &str = include_str!("../solve_data/opencv_left.txt");
const COLS: usize = 9;
const SQUARE: f64 = 0.025;

/// OpenCV's expected `[fx fy cx cy k1 k2 p1 p2 k3]`, its RMS, its σ of fx fy cx cy, and
/// the corners per view.
fn load() -> ([f64; 9], f64, [f64; 4], Vec<Vec<Vec2>>) {
    let mut expect = [0.0; 9];
    let mut sigma = [0.0; 4];
    let mut rms = 0.0;
    let mut views: Vec<Vec<Vec2>> = Vec::new();
    for line in DATA.lines().filter(|l| !l.starts_with('#')) {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("expect") => {
                let v: Vec<f64> = it.map(|t| t.parse().unwrap()).collect();
                expect.copy_from_slice(&v[..9]);
                rms = v[9];
            }
            Some("sigma") => {
                let v: Vec<f64> = it.map(|t| t.parse().unwrap()).collect();
                sigma.copy_from_slice(&v[..4]);
            }
            Some("corner") => {
                let v: usize = it.next().unwrap().parse().unwrap();
                let xy: Vec<f64> = it.map(|t| t.parse().unwrap()).collect();
                if views.len() <= v {
                    views.resize(v + 1, Vec::new());
                }
                views[v].push(Vec2::new(xy[0], xy[1]));
            }
            _ => panic!("unexpected line in opencv_left.txt: {line}"),
        }
    }
    (expect, rms, sigma, views)
}

#[test]
fn matches_opencv_calibrate_camera_on_real_corners() {
    let (expect, expect_rms, expect_sigma, views) = load();
    assert_eq!(views.len(), 13);
    let object: Vec<Vec3> = (0..views[0].len())
        .map(|i| Vec3::new((i % COLS) as f64 * SQUARE, (i / COLS) as f64 * SQUARE, 0.0))
        .collect();
    let mut problem: JointProblem<'_, 16> = JointProblem::new(0.4, 1.0, Loss::Squared);
    for corners in &views {
        let obs = BoardObservation { object: &object, corners, ..Default::default() };
        problem.add_board(obs).unwrap();
    }
    // Nothing known but the model and the size.
    let blank = Camera::from_fov(CameraModel::PinholeRadtan, 640, 480, 60.0, [0.0; 5]);
    let seed = IntrinsicsSeed::Zhang { width: 640, height: 480 };
    let (mut params, init) = initialise(&problem, blank, seed).unwrap();
    let z = init.zhang.expect("Zhang works on these tilted views");
    println!("Zhang: {z:?}");
    let report = problem.solve(&mut params, &LmOptions::default()).unwrap();
    let got = params.camera.params();
    let sigma = covariance(&problem, &params, ParamMask::free()).unwrap();
    println!("{report:?}");
    println!("roomcal {got:.5?}\nOpenCV  {expect:.5?}");
    println!(
        "σ fx fy cx cy: {:.3} {:.3} {:.3} {:.3}",
        sigma.sigma(0),
        sigma.sigma(1),
        sigma.sigma(2),
        sigma.sigma(3)
    );
    // Same corners, same cost: the same optimum, to a small fraction of its uncertainty.
    for i in 0..4 {
        assert!((got[i] - expect[i]).abs() < 0.05, "param {i}: {} vs OpenCV {}", got[i], expect[i]);
        assert!((got[i] - expect[i]).abs() < 0.1 * sigma.sigma(i));
    }
    for i in 4..9 {
        assert!((got[i] - expect[i]).abs() < 1e-3, "distortion {i}: {} vs {}", got[i], expect[i]);
    }
    assert!(
        (report.corner_rms_px - expect_rms).abs() < 1e-4,
        "RMS {} vs {}",
        report.corner_rms_px,
        expect_rms
    );
    // OpenCV's standard deviations come from the same JᵀJ and residual variance.
    for (i, opencv) in expect_sigma.iter().enumerate() {
        let ratio = sigma.sigma(i) / opencv;
        assert!((ratio - 1.0).abs() < 0.02, "σ {i}: {} vs OpenCV {opencv}", sigma.sigma(i));
    }
    // Zhang ignores distortion but must already be within a few per cent.
    assert!((z.fx / expect[0] - 1.0).abs() < 0.05 && (z.fy / expect[1] - 1.0).abs() < 0.05);
}
