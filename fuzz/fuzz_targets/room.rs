//! Fuzz target: the room file parser and its validation must never panic, and a room
//! they accept has every number inside the stated limits (so nothing sized from it can
//! be huge: the detectors' buffers are built from it) and writes back to TOML that is
//! accepted again.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use roomcal::target::{MAX_BOARD_SIDE_M, MAX_IMAGE_PIXELS, MIN_SQUARE_M};

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let Ok(room) = roomcal::room::parse(text, Path::new("fuzz.toml")) else { return };
    let b = &room.board;
    assert!(b.width > 0.0 && b.width <= MAX_BOARD_SIDE_M, "{}", b.width);
    assert!(b.height > 0.0 && b.height <= MAX_BOARD_SIDE_M, "{}", b.height);
    assert!(b.square >= MIN_SQUARE_M);
    let c = &room.camera;
    assert!(u64::from(c.width) * u64::from(c.height) <= MAX_IMAGE_PIXELS);
    for v in [c.fx, c.fy, c.cx, c.cy].into_iter().flatten() {
        assert!(v.is_finite());
    }
    // What was accepted writes back to TOML that is accepted again.
    let again = roomcal::room::parse(&roomcal::room::to_toml(&room), Path::new("again.toml"));
    assert!(again.is_ok(), "{again:?}");
});
