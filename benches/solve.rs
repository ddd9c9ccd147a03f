//! Speed of the joint solve on a synthetic 6-board room (plain `std::time`, no harness):
//! one full LM solve from a perturbed start, one normal-equation accumulation, one Schur
//! step, and how the per-iteration cost scales with the number of boards. Figures are
//! printed as medians and ratios; nothing is asserted. Run: `cargo bench --bench solve`.

#[path = "../tests/common/solve_common.rs"]
mod solve_common;

use std::hint::black_box;
use std::time::{Duration, Instant};

use nalgebra::{DMatrix, DVector};
use roomcal::geometry::{Camera, CameraModel, Vec3};
use roomcal::solve::lm::NormalEquations;
use roomcal::solve::{
    covariance, BoardObservation, JointParams, JointProblem, LmOptions, Loss, ParamMask, SHARED,
};
use solve_common::*;

const B: usize = 16;

fn camera() -> Camera {
    Camera {
        model: CameraModel::PinholeRadtan,
        width: 1920,
        height: 1200,
        fx: 1400.0,
        fy: 1395.0,
        cx: 962.0,
        cy: 603.0,
        distortion: [-0.12, 0.05, 0.001, -0.0008, 0.01],
    }
}

/// Median wall time of `f` over `runs` runs.
fn median(runs: usize, mut f: impl FnMut()) -> Duration {
    let mut t: Vec<Duration> = (0..runs)
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed()
        })
        .collect();
    t.sort();
    t[runs / 2]
}

fn problem(s: &Scene<Camera>) -> JointProblem<'_, B> {
    let mut p = JointProblem::new(0.3, 4.0, Loss::Huber(3.0));
    for (corners, lidar) in s.corners.iter().zip(&s.holes_lidar) {
        let obs = BoardObservation {
            object: &s.object,
            corners,
            holes_board: &s.holes,
            holes_lidar: lidar,
            hole_sigma_px: None,
            plane: None,
        };
        p.add_board(obs).unwrap();
    }
    p
}

fn start(s: &Scene<Camera>) -> JointParams<Camera, B> {
    let mut camera = s.camera;
    camera.fx *= 1.03;
    camera.fy *= 0.98;
    camera.cx += 12.0;
    camera.distortion = [0.0; 5];
    let mut ext = s.extrinsic;
    ext.translation += Vec3::new(0.04, -0.03, 0.05);
    JointParams { camera, lidar_to_camera: ext, board_poses: s.poses.iter().copied().collect() }
}

/// The same damped step done densely: the full Jacobian (heap), `JᵀJ`, Cholesky.
fn dense_step(
    p: &JointProblem<'_, B>,
    params: &JointParams<Camera, B>,
    lambda: f64,
) -> DVector<f64> {
    let n = SHARED + 6 * params.board_poses.len();
    let m = p.residual_count();
    let mut j = DMatrix::<f64>::zeros(m, n);
    let mut r = DVector::<f64>::zeros(m);
    let mut row = 0;
    p.for_each_residual(params, |res| {
        let w = p.loss.eval(res.r.norm_squared()).1.sqrt();
        for k in 0..2 {
            r[row + k] = w * res.r[k];
            for c in 0..SHARED {
                j[(row + k, c)] = w * res.j_shared[(k, c)];
            }
            for c in 0..6 {
                j[(row + k, SHARED + 6 * res.board + c)] = w * res.j_board[(k, c)];
            }
        }
        row += 2;
    })
    .unwrap();
    // Fisheye-style unused columns would be singular; this bench's camera uses all 9.
    let mut a = j.transpose() * &j;
    for i in 0..n {
        a[(i, i)] += lambda * a[(i, i)].max(1e-9);
    }
    let g = j.transpose() * r;
    a.cholesky().unwrap().solve(&(-g))
}

fn main() {
    let s = scene_with(camera(), 6, 0.3, 0.01, 1);
    let p = problem(&s);
    let p0 = start(&s);
    let options = LmOptions::default();
    let report = {
        let mut q = p0.clone();
        p.solve(&mut q, &options).unwrap()
    };
    let solve = median(51, || {
        let mut q = p0.clone();
        black_box(p.solve(&mut q, &options).unwrap());
    });
    let build = median(201, || {
        black_box(NormalEquations::build(&p, &p0).unwrap());
    });
    let ne = NormalEquations::build(&p, &p0).unwrap();
    let step = median(201, || {
        black_box(ne.step(1e-3, ParamMask::free()).unwrap());
    });
    let dense = median(51, || {
        black_box(dense_step(&p, &p0, 1e-3));
    });
    let cov = median(101, || {
        black_box(covariance(&p, &p0, ParamMask::free()).unwrap());
    });
    let residuals = p.residual_count();
    println!("6-board room, {residuals} scalar residuals, {} iterations", report.iterations);
    println!("  full solve            {:>10.3?}", solve);
    println!(
        "  accumulate JᵀJ        {:>10.3?} ({:.1} ns per residual block)",
        build,
        build.as_nanos() as f64 / (residuals / 2) as f64
    );
    println!(
        "  Schur step            {:>10.3?} (step / accumulate = {:.2})",
        step,
        step.as_secs_f64() / build.as_secs_f64()
    );
    println!(
        "  dense J, JᵀJ, Cholesky {:>10.3?} ({:.1}× accumulate + Schur step)",
        dense,
        dense.as_secs_f64() / (build + step).as_secs_f64()
    );
    println!("  covariance            {:>10.3?}", cov);
    println!("  solve / iteration     {:>10.3?}", solve / report.iterations as u32);
    println!(
        "  normal equations size {} bytes (B = {B}), independent of the corner count",
        std::mem::size_of::<NormalEquations<B>>()
    );
    let base = build.as_secs_f64();
    for n in [3, 12, 16] {
        let s = scene_with(camera(), n, 0.3, 0.01, 1);
        let p = problem(&s);
        let q = start(&s);
        let t = median(101, || {
            let ne = NormalEquations::build(&p, &q).unwrap();
            black_box(ne.step(1e-3, ParamMask::free()).unwrap());
        });
        println!(
            "  {n:>2} boards: accumulate + step {:>10.3?} ({:.2}× the 6-board accumulation)",
            t,
            t.as_secs_f64() / base
        );
    }
}
