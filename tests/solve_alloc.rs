//! Proves the joint solve and its covariance make no heap allocation: a counting global
//! allocator, enabled only on this test's thread while the solver runs.

mod solve_common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

use roomcal::geometry::{Camera, CameraModel};
use roomcal::solve::ParamMask;
use roomcal::solve::{covariance, BoardObservation, JointParams, JointProblem, LmOptions, Loss};
use solve_common::*;

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.with(|c| c.get()) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if COUNTING.with(|c| c.get()) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn joint_solve_makes_no_heap_allocation() {
    let camera = Camera {
        model: CameraModel::PinholeRadtan,
        width: 1920,
        height: 1200,
        fx: 1400.0,
        fy: 1395.0,
        cx: 962.0,
        cy: 603.0,
        distortion: [-0.12, 0.05, 0.001, -0.0008, 0.01],
    };
    let s = scene_with(camera, 6, 0.3, 0.01, 99);
    let mut p: JointProblem<'_, 16> = JointProblem::new(0.3, 4.0, Loss::Huber(3.0));
    for (corners, lidar) in s.corners.iter().zip(&s.holes_lidar) {
        let obs = BoardObservation {
            object: &s.object,
            corners,
            holes_board: &s.holes,
            holes_lidar: lidar,
            hole_sigma_px: None,
        };
        p.add_board(obs).unwrap();
    }
    let mut params: JointParams<Camera, 16> = JointParams {
        camera: s.camera,
        lidar_to_camera: s.extrinsic,
        board_poses: s.poses.iter().copied().collect(),
    };
    params.camera.fx *= 1.03;
    params.lidar_to_camera.translation.x += 0.05;
    let options = LmOptions::default();

    // Sanity: the counter works on this thread.
    COUNTING.with(|c| c.set(true));
    drop(std::hint::black_box(vec![1u8; 16]));
    COUNTING.with(|c| c.set(false));
    assert_eq!(ALLOCATIONS.swap(0, Ordering::Relaxed), 1);

    COUNTING.with(|c| c.set(true));
    let report = p.solve(&mut params, &options);
    let cov = covariance(&p, &params, ParamMask::free());
    COUNTING.with(|c| c.set(false));
    let count = ALLOCATIONS.load(Ordering::Relaxed);

    let report = report.unwrap();
    assert!(report.iterations > 1, "the solve must actually iterate: {report:?}");
    assert!(cov.unwrap().uncertainty().fx > 0.0);
    assert_eq!(count, 0, "heap allocations inside the solve");
}
