//! After warm-up, `ChessboardDetector::detect` makes no heap allocation: a counting
//! global allocator (`crate::counting_alloc`) watches every allocation of the calls.

use crate::common::render;

use crate::counting_alloc::count_allocations;
use roomcal::detect::ChessboardDetector;
use roomcal::target::BoardSpec;

#[test]
fn detect_allocates_nothing_after_warm_up() {
    let scene = render::six_boards(960, 600, 680.0, 0.1, 35.0, 11, 3.0);
    let img = scene.render();
    let mut empty = scene.clone();
    empty.boards.truncate(2);
    let fewer = empty.render();
    let spec = BoardSpec {
        width: 1.2,
        height: 1.0,
        inner_corners: [7, 5],
        square: 0.08,
        hole_radius: 0.0,
        holes: heapless::Vec::new(),
        count: 6,
        checker_offset: [0.0, 0.0],
    };
    let mut det = ChessboardDetector::new(960, 600, &spec).unwrap();
    let mut out = Vec::new();
    det.detect(&img, &mut out).unwrap(); // warm-up
    assert_eq!(out.iter().filter(|b| b.complete).count(), 6);

    let mut found = Vec::with_capacity(8);
    let ((), allocs) = count_allocations(|| {
        for frame in [&img, &fewer, &img, &fewer] {
            det.detect(frame, &mut out).unwrap();
            found.push(out.len());
        }
    });
    eprintln!("allocations in 4 detect calls after warm-up: {allocs}; boards {found:?}");
    assert_eq!(found, vec![6, 2, 6, 2]);
    assert_eq!(allocs, 0);
    // Released (as the daemon does after a run), the response buffer is made again on the
    // next frame, and the boards are the same.
    det.detect(&img, &mut out).unwrap();
    let before = out.clone();
    det.release_workspace();
    det.detect(&img, &mut out).unwrap();
    assert_eq!(out, before, "a released detector finds the same boards");
}
