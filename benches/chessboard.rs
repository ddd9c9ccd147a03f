//! Chessboard detection timing on one image (run by `scripts/bench_chessboard.py`):
//! `cargo bench --bench chessboard -- IMAGE COLS ROWS [RUNS]` prints one JSON object with
//! the median and best time per frame (ms) and every board's corners.

use std::time::Instant;

use roomcal::detect::{load_grey, ChessboardDetector};
use roomcal::target::BoardSpec;

fn main() {
    // `cargo bench` passes `--bench`; keep only our positional arguments.
    let args: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with("--")).collect();
    if args.len() < 3 {
        eprintln!("usage: cargo bench --bench chessboard -- IMAGE COLS ROWS [RUNS]");
        return;
    }
    let img = load_grey(&args[0]).unwrap_or_else(|e| panic!("{e}"));
    let cols: u32 = args[1].parse().expect("COLS");
    let rows: u32 = args[2].parse().expect("ROWS");
    let runs: usize = args.get(3).and_then(|r| r.parse().ok()).unwrap_or(30);
    let spec = BoardSpec {
        width: 10.0,
        height: 10.0,
        inner_corners: [cols, rows],
        square: 0.1,
        hole_radius: 0.0,
        holes: heapless::Vec::new(),
        count: 1,
        checker_offset: [0.0, 0.0],
    };
    let mut det = ChessboardDetector::new(img.width, img.height, &spec).expect("detector");
    let mut boards = Vec::new();
    det.detect(&img.data, &mut boards).expect("frame size");
    let mut times: Vec<f64> = (0..runs)
        .map(|_| {
            let t = Instant::now();
            det.detect(&img.data, &mut boards).expect("frame size");
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    times.sort_by(f64::total_cmp);
    let boards_json: Vec<String> = boards
        .iter()
        .map(|b| {
            let corners: Vec<String> = b
                .corners
                .iter()
                .map(|c| format!("[{:.4},{:.4},{:.4}]", c.x, c.y, c.sigma))
                .collect();
            format!(
                "{{\"cols\":{},\"rows\":{},\"complete\":{},\"corners\":[{}]}}",
                b.cols,
                b.rows,
                b.complete,
                corners.join(",")
            )
        })
        .collect();
    println!(
        "{{\"median_ms\":{:.3},\"best_ms\":{:.3},\"runs\":{runs},\"boards\":[{}]}}",
        times[times.len() / 2],
        times[0],
        boards_json.join(",")
    );
}
