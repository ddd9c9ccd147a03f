//! After warm-up, `ChessboardDetector::detect` makes no heap allocation: a counting
//! global allocator (this test binary's own) watches every allocation of the calls.

#[path = "chessboard_synth/render.rs"]
mod render;

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use roomcal::detect::ChessboardDetector;
use roomcal::target::BoardSpec;

struct Counting;

static COUNTING: AtomicBool = AtomicBool::new(false);
static ALLOCS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.load(Ordering::SeqCst) {
            ALLOCS.fetch_add(1, Ordering::SeqCst);
        }
        System.alloc(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if COUNTING.load(Ordering::SeqCst) {
            ALLOCS.fetch_add(1, Ordering::SeqCst);
        }
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

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
    ALLOCS.store(0, Ordering::SeqCst);
    COUNTING.store(true, Ordering::SeqCst);
    for frame in [&img, &fewer, &img, &fewer] {
        det.detect(frame, &mut out).unwrap();
        found.push(out.len());
    }
    COUNTING.store(false, Ordering::SeqCst);
    let allocs = ALLOCS.load(Ordering::SeqCst);
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
