//! The LiDAR board detector on a real Pandar64-class frame: OpenCalib's joint-calibration
//! sample (`../shared/data/holeboard-real`, or under `ROOMCAL_SHARED`). Skips with a note
//! when the data are absent.
//!
//! The board's geometry comes from OpenCalib's own LiDAR circle detector (a 1.2 m square
//! window, circle centres 0.3 m and 0.9 m into it, i.e. a 0.6 m square grid about the
//! centre) and from the points themselves: the outline spans 1.2 m across, the top edge
//! lies between two sparse rings above the dense band, and the widest scan-line gaps
//! across the holes are ≈ 0.22 m (radius ≈ 0.11 m).
//!
//! No reference centres ship with the frame, so the detection is checked against an
//! independent estimate from the raw rings: every ring that crosses a hole leaves a gap
//! whose midpoint lies on the hole's vertical through its centre, and the rings with gaps
//! span the hole's height symmetrically about its centre.

use crate::common::opencalib;

use opencalib::{opencalib_board, opencalib_data_dir};
use roomcal::detect::holes::{HoleConfig, HoleDetector};
use roomcal::lidar::{pcd, Point};

/// Independent estimate of one hole from the raw rings near `guess`: (y along the rings,
/// z) of the centre and the number of rings with a gap there.
fn ring_gap_estimate(points: &[Point], guess: [f64; 3]) -> Option<([f64; 2], usize)> {
    let mut mids = Vec::new();
    let mut zs = Vec::new();
    for ring in 0..64u16 {
        let mut line: Vec<[f64; 3]> = points
            .iter()
            .filter(|p| p.ring == ring)
            .map(|p| [p.x as f64, p.y as f64, p.z as f64])
            .filter(|p| (p[0] - guess[0]).abs() < 0.15 && (p[2] - guess[2]).abs() < 0.14)
            .filter(|p| (p[1] - guess[1]).abs() < 0.3)
            .collect();
        if line.len() < 10 {
            continue;
        }
        line.sort_by(|a, b| a[1].total_cmp(&b[1]));
        let mut spacing: Vec<f64> = line.windows(2).map(|w| w[1][1] - w[0][1]).collect();
        spacing.sort_by(f64::total_cmp);
        let typical = spacing[spacing.len() / 2];
        let widest = line
            .windows(2)
            .filter(|w| ((w[0][1] + w[1][1]) / 2.0 - guess[1]).abs() < 0.1)
            .max_by(|a, b| (a[1][1] - a[0][1]).total_cmp(&(b[1][1] - b[0][1])));
        if let Some(w) = widest {
            // A hole's chord: wider than the sampling, no wider than the hole.
            let gap = w[1][1] - w[0][1];
            if gap > 4.0 * typical && gap < 0.26 {
                mids.push((w[0][1] + w[1][1]) / 2.0);
                zs.push((w[0][2] + w[1][2]) / 2.0);
            }
        }
    }
    if mids.len() < 3 {
        return None;
    }
    let y = mids.iter().sum::<f64>() / mids.len() as f64;
    let (lo, hi) = zs.iter().fold((f64::MAX, f64::MIN), |(l, h), &z| (l.min(z), h.max(z)));
    Some(([y, (lo + hi) / 2.0], mids.len()))
}

#[test]
fn real_board_holes_on_a_0_6_m_grid() {
    let dir = opencalib_data_dir();
    let Ok(entries) = std::fs::read_dir(&dir) else {
        crate::common::skipped(format_args!("{} is absent", dir.display()));
        return;
    };
    let mut files: Vec<_> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "pcd"))
        .collect();
    files.sort();
    let spec = opencalib_board();
    let mut detector = HoleDetector::new(&spec, HoleConfig::default());
    let mut boards = Vec::new();
    for file in &files {
        let points = pcd::read(file).unwrap();
        let t = std::time::Instant::now();
        detector.detect(&points, &mut boards);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        println!(
            "{}: {} points, {} board(s) in {ms:.1} ms",
            file.display(),
            points.len(),
            boards.len()
        );
        for r in detector.refused() {
            println!("  refused at {:?}: {}", r.centroid.as_slice(), r.reason);
        }
        for b in &boards {
            println!(
                "  board at {:?}: lines {:?}, σ {:?} mm, pose σ {:?}",
                b.pose.translation.as_slice(),
                b.hole_scan_lines,
                b.hole_sigma_m.iter().map(|s| (s * 1e4).round() / 10.0).collect::<Vec<_>>(),
                b.pose_sigma
            );
        }
        // One board stands in the scene: any other placement is a board where there is none.
        assert_eq!(boards.len(), 1, "exactly one board");
        let board = &boards[0];
        assert!((board.pose.translation.x - 3.3).abs() < 0.5, "the board about 3.3 m ahead");
        println!(
            "  board centre {:?}, normal {:?}, {} inliers, plane RMS {:.1} mm, lines {:?}",
            board.pose.translation.as_slice(),
            board.normal.as_slice(),
            board.inliers,
            board.plane_rms_m * 1e3,
            board.hole_scan_lines
        );
        for (k, h) in board.holes.iter().enumerate() {
            let est = ring_gap_estimate(&points, [h.x, h.y, h.z]);
            println!(
                "  hole {k}: {:?} σ {:.1} mm; ring gaps say {:?}",
                h.as_slice(),
                board.hole_sigma_m[k] * 1e3,
                est
            );
            let Some(([y, z], rings)) = est else { continue };
            if rings >= 6 {
                assert!((h.y - y).abs() < 0.01, "hole {k}: y {} vs ring gaps {y}", h.y);
                assert!((h.z - z).abs() < 0.015, "hole {k}: z {} vs ring gaps {z}", h.z);
            }
        }
        // Neighbouring holes 0.6 m apart: the rigid model, but also the plane's scale.
        let d01 = (board.holes[0] - board.holes[1]).norm();
        let d02 = (board.holes[0] - board.holes[2]).norm();
        assert!((d01 - 0.6).abs() < 0.01 && (d02 - 0.6).abs() < 0.01);
    }
}
