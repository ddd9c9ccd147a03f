//! Allocations sized from hostile input are bounded by the stated limits (docs/limits.md),
//! even where validation is bypassed: the hole mask of an absurd board, an image whose
//! header claims 20000² pixels, PCD headers claiming more points than their bytes hold.
//!
//! The global allocator (`crate::counting_alloc`) records the largest single allocation
//! made on the test's thread while a closure runs (test threads run in parallel; each
//! tracks only itself).

use crate::common::png::png_claiming;
use crate::counting_alloc::largest_allocation;
use roomcal::detect::holes::{HoleConfig, HoleDetector, MAX_MASK_SIDE};
use roomcal::lidar::pcd::{self, PcdError, PcdFormat};

fn design_room() -> roomcal::target::Room {
    roomcal::room::parse(include_str!("../../config/room.toml"), "room.toml".as_ref()).unwrap()
}

#[test]
fn hole_mask_is_bounded_for_boards_that_bypassed_validation() {
    let room = design_room();
    let (_, normal) = largest_allocation(|| HoleDetector::new(&room.board, HoleConfig::default()));
    println!("design board: largest allocation {normal} B");
    let bound = MAX_MASK_SIDE * MAX_MASK_SIDE;
    for width in [1e308, 1e6, 1e4, 1000.0, f64::INFINITY, f64::NAN] {
        let mut board = room.board.clone();
        board.width = width;
        assert!(board.validate().is_err(), "validation refuses width {width}");
        let (_, largest) = largest_allocation(|| HoleDetector::new(&board, HoleConfig::default()));
        println!("board.width = {width}: largest allocation {largest} B (bound {bound} B)");
        assert!(largest <= bound, "width {width}: {largest} B > {bound} B");
    }
}

#[test]
fn image_size_is_refused_from_the_header_before_decoding() {
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("hostile_alloc");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("huge.png");
    std::fs::write(&path, png_claiming(20000, 20000)).unwrap();
    assert_eq!(roomcal::detect::image_size(&path).unwrap(), (20000, 20000));
    let (result, largest) = largest_allocation(|| roomcal::detect::load_grey(&path));
    let err = result.unwrap_err();
    let message = err.to_string();
    println!("{message}; largest allocation {largest} B");
    assert!(matches!(err, roomcal::detect::DetectError::TooLarge { .. }), "{message}");
    assert!(message.contains("huge.png") && message.contains("20000x20000"), "{message}");
    assert!(largest < 1 << 20, "{largest} B allocated for a {} B file", png_claiming(1, 1).len());
}

#[test]
fn pcd_headers_cannot_size_buffers_beyond_their_bytes() {
    let xyz = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n";
    // binary: 10⁶ points declared (within the limit), 12 bytes present.
    let mut binary =
        format!("{xyz}WIDTH 1000000\nHEIGHT 1\nPOINTS 1000000\nDATA binary\n").into_bytes();
    binary.extend([0u8; 12]);
    let (result, largest) = largest_allocation(|| pcd::parse(&binary, "big.pcd"));
    assert!(matches!(result, Err(PcdError::Truncated { .. })), "{result:?}");
    assert!(largest < 1 << 16, "binary: {largest} B");
    // ascii: as many points as lines, not as the header says.
    let ascii = format!("{xyz}WIDTH 1000000\nHEIGHT 1\nPOINTS 1000000\nDATA ascii\n1 2 3\n");
    let (result, largest) = largest_allocation(|| pcd::parse(ascii.as_bytes(), "big.pcd"));
    assert!(matches!(result, Err(PcdError::Truncated { .. })), "{result:?}");
    assert!(largest < 1 << 16, "ascii: {largest} B");
    // Above the stated point limit: refused from the header.
    let many = pcd::MAX_POINTS + 1;
    let text = format!("{xyz}WIDTH {many}\nHEIGHT 1\nPOINTS {many}\nDATA binary\n");
    let message = pcd::parse(text.as_bytes(), "many.pcd").unwrap_err().to_string();
    assert!(message.contains("many.pcd") && message.contains("more than"), "{message}");
    // WIDTH × HEIGHT must be POINTS.
    let text = format!("{xyz}WIDTH 4\nHEIGHT 2\nPOINTS 7\nDATA ascii\n");
    let message = pcd::parse(text.as_bytes(), "grid.pcd").unwrap_err().to_string();
    assert!(message.contains("POINTS 7 is not WIDTH × HEIGHT = 4 × 2"), "{message}");
}

#[test]
fn compressed_pcd_size_is_checked_against_the_lzf_bound() {
    // A consistent header (uncompressed size = POINTS × 12) whose compressed stream is too
    // short to expand to it: refused before the buffer is allocated.
    let points = 1_000_000usize;
    let raw = (points * 12) as u32;
    let mut bytes = format!(
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {points}\nHEIGHT 1\n\
         POINTS {points}\nDATA binary_compressed\n"
    )
    .into_bytes();
    let compressed = [0u8; 1000];
    bytes.extend((compressed.len() as u32).to_le_bytes());
    bytes.extend(raw.to_le_bytes());
    bytes.extend(compressed);
    let (result, largest) = largest_allocation(|| pcd::parse(&bytes, "lzf.pcd"));
    let message = result.unwrap_err().to_string();
    assert!(message.contains("impossible for 1000 compressed bytes"), "{message}");
    assert!(largest < 1 << 16, "{largest} B");
    // A real compressed cloud still reads.
    let cloud: Vec<roomcal::lidar::Point> = (0..5000)
        .map(|i| roomcal::lidar::Point { x: 1.0, y: i as f32 * 1e-3, z: 0.5, ..Default::default() })
        .collect();
    let mut good = Vec::new();
    pcd::encode(&cloud, PcdFormat::BinaryCompressed, &mut good);
    assert_eq!(pcd::parse(&good, "good.pcd").unwrap().len(), 5000);
}
