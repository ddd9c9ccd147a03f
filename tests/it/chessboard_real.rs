//! Real images: OpenCV's left01–14 (9×6 inner corners) from ../shared/data; every board
//! must be found complete, ordered as the board model numbers its corners.

use roomcal::detect::{load_grey, Board, ChessboardDetector};
use roomcal::target::BoardSpec;

use crate::common::scratch::Scratch;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data/chessboard/opencv-left");

fn spec_9x6() -> BoardSpec {
    BoardSpec {
        width: 0.3,
        height: 0.2,
        inner_corners: [9, 6],
        square: 0.025,
        hole_radius: 0.0,
        holes: heapless::Vec::new(),
        count: 1,
        checker_offset: [0.0, 0.0],
    }
}

/// The left images present, or `None` (with a message) when the data is absent.
fn images() -> Option<Vec<std::path::PathBuf>> {
    let mut files: Vec<_> = std::fs::read_dir(DATA)
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "jpg"))
        .collect();
    files.sort();
    if files.is_empty() {
        return None;
    }
    Some(files)
}

/// Row steps and column steps of a complete board must each point one way.
fn assert_ordered(board: &Board, name: &str) {
    let (cols, rows) = (board.cols as usize, board.rows as usize);
    let at = |i: usize, j: usize| board.corners[j * cols + i];
    for j in 0..rows {
        for i in 0..cols {
            assert_eq!((at(i, j).col as usize, at(i, j).row as usize), (i, j), "{name}");
            if i + 1 < cols {
                let (a, b) = (at(i, j), at(i + 1, j));
                let step = ((b.x - a.x).powi(2) + (b.y - a.y).powi(2)).sqrt();
                assert!(step > 5.0, "{name}: corners ({i},{j}) and ({},{j}) coincide", i + 1);
            }
        }
    }
    // Right-handed like the board frame: cross(col step, row step) > 0.
    let (c0, c1, r1) = (at(0, 0), at(cols - 1, 0), at(0, rows - 1));
    let cross = (c1.x - c0.x) * (r1.y - c0.y) - (c1.y - c0.y) * (r1.x - c0.x);
    assert!(cross > 0.0, "{name}: board is mirrored");
}

#[test]
fn opencv_left_all_boards_complete() {
    let Some(files) = images() else {
        crate::common::skipped(format_args!("{DATA} is absent"));
        return;
    };
    assert_eq!(files.len(), 13, "expected the 13 left images");
    let mut det = ChessboardDetector::new(640, 480, &spec_9x6()).unwrap();
    let mut boards = Vec::new();
    let mut failures = Vec::new();
    for path in &files {
        let img = load_grey(path).unwrap();
        det.detect(&img.data, &mut boards).unwrap();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let complete: Vec<_> = boards.iter().filter(|b| b.complete).collect();
        eprintln!(
            "{name}: {} boards, {} complete, sizes {:?}",
            boards.len(),
            complete.len(),
            boards.iter().map(|b| (b.cols, b.rows, b.corners.len())).collect::<Vec<_>>()
        );
        // left02 and left05 also show small boards on a monitor: found, but incomplete.
        if complete.len() != 1 {
            failures.push(name);
            continue;
        }
        let b = complete[0];
        assert_eq!((b.cols, b.rows, b.corners.len()), (9, 6, 54), "{name}");
        assert_ordered(b, &name);
        for c in &b.corners {
            assert!(c.sigma > 0.0 && c.sigma < 1.0, "{name}: sigma {}", c.sigma);
        }
    }
    assert!(failures.is_empty(), "boards not found complete in {failures:?}");
}

#[test]
fn load_grey_names_the_file() {
    let dir = Scratch::new("chess");
    let missing = dir.join("missing.png");
    let err = load_grey(&missing).unwrap_err().to_string();
    assert!(err.contains("missing.png"), "{err}");
    let corrupt = dir.join("corrupt.png");
    std::fs::write(&corrupt, b"\x89PNG\r\n\x1a\nnot really").unwrap();
    let err = load_grey(&corrupt).unwrap_err().to_string();
    assert!(err.contains("corrupt.png") && err.contains("decode"), "{err}");
    // A truncated JPEG from the real data, when present.
    if let Some(files) = images() {
        let bytes = std::fs::read(&files[0]).unwrap();
        let cut = dir.join("truncated.jpg");
        std::fs::write(&cut, &bytes[..bytes.len() / 3]).unwrap();
        match load_grey(&cut) {
            Err(e) => assert!(e.to_string().contains("truncated.jpg"), "{e}"),
            // Some decoders pad a cut JPEG with grey; then the size must still be right.
            Ok(img) => assert_eq!((img.width, img.height), (640, 480)),
        }
    }
    // Colour PNG → grey.
    let rgb = image::RgbImage::from_fn(4, 3, |x, _| image::Rgb([x as u8 * 60, 0, 0]));
    let png = dir.join("colour.png");
    rgb.save(&png).unwrap();
    let grey = load_grey(&png).unwrap();
    assert_eq!((grey.width, grey.height, grey.data.len()), (4, 3, 12));
    assert!(grey.data[3] > grey.data[0]);
}
