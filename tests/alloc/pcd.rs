//! PCD reader/writer tests: round trips in all three encodings, crafted files with odd
//! field orders, types and counts, error messages, buffer reuse without allocation,
//! random bytes (PCD parser and LZF), and the real clouds in `../shared/data`.
#![cfg(feature = "std")]

use std::path::PathBuf;

use proptest::prelude::*;
use roomcal::lidar::pcd::{self, PcdError, PcdFormat, PcdReader};
use roomcal::lidar::{lzf, Point};

use crate::common::scratch::Scratch;

// ---------------------------------------------------------------------------------------
// Allocation counting: `crate::counting_alloc` (per thread, so parallel tests do not
// disturb each other)

use crate::counting_alloc::allocations;

// ---------------------------------------------------------------------------------------
// Helpers

/// Deterministic pseudo-random cloud without zero or NaN points.
fn cloud(n: usize, seed: u64) -> Vec<Point> {
    let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    let mut next = move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (s >> 33) as u32
    };
    (0..n)
        .map(|_| Point {
            x: 1.0 + (next() % 100_000) as f32 * 1e-3,
            y: (next() % 100_000) as f32 * 1e-3 - 50.0,
            z: -((next() % 3000) as f32) * 1e-3,
            intensity: (next() % 256) as f32,
            ring: (next() % 64) as u16,
            time: 0.0,
        })
        .collect()
}

fn shared(rel: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data")).join(rel)
}

/// One field of a crafted header: name, SIZE, TYPE, COUNT.
type FieldSpec = (&'static str, usize, char, usize);

/// A PCD header with the given FIELDS/SIZE/TYPE/COUNT columns.
fn header(fields: &[FieldSpec], points: usize, data: &str) -> Vec<u8> {
    let col = |f: &dyn Fn(&FieldSpec) -> String| fields.iter().map(f).collect::<Vec<_>>().join(" ");
    format!(
        "# .PCD v0.7\nVERSION 0.7\nFIELDS {}\nSIZE {}\nTYPE {}\nCOUNT {}\nWIDTH {points}\n\
         HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {points}\nDATA {data}\n",
        col(&|f| f.0.to_string()),
        col(&|f| f.1.to_string()),
        col(&|f| f.2.to_string()),
        col(&|f| f.3.to_string()),
    )
    .into_bytes()
}

/// Little-endian bytes of `v` as PCD type `ty` of `size` bytes.
fn scalar(v: f64, ty: char, size: usize) -> Vec<u8> {
    match (ty, size) {
        ('F', 4) => (v as f32).to_le_bytes().to_vec(),
        ('F', 8) => v.to_le_bytes().to_vec(),
        ('I', 1) => (v as i8).to_le_bytes().to_vec(),
        ('I', 2) => (v as i16).to_le_bytes().to_vec(),
        ('I', 4) => (v as i32).to_le_bytes().to_vec(),
        ('I', 8) => (v as i64).to_le_bytes().to_vec(),
        ('U', 1) => (v as u8).to_le_bytes().to_vec(),
        ('U', 2) => (v as u16).to_le_bytes().to_vec(),
        ('U', 4) => (v as u32).to_le_bytes().to_vec(),
        ('U', 8) => (v as u64).to_le_bytes().to_vec(),
        _ => unreachable!(),
    }
}

// ---------------------------------------------------------------------------------------
// Writer round trips

#[test]
fn written_clouds_read_back_identically() {
    let points = cloud(5000, 1);
    let dir = Scratch::new("pcd-round-trip");
    for format in [PcdFormat::Ascii, PcdFormat::Binary, PcdFormat::BinaryCompressed] {
        let path = dir.join(format!("{format:?}.pcd"));
        pcd::write(&path, &points, format).unwrap();
        let back = pcd::read(&path).unwrap();
        assert_eq!(back.len(), points.len(), "{format:?}");
        assert!(back == points, "{format:?}: points differ");
        let mut out = Vec::new();
        let info = pcd::read_into(&path, &mut out).unwrap();
        assert_eq!((info.format, info.declared_points, info.skipped), (format, 5000, 0));
        assert!(info.has_intensity && info.has_ring && !info.has_time);
    }
    // The header is exactly the documented decoded-cloud layout.
    let text = std::fs::read(dir.join("BinaryCompressed.pcd")).unwrap();
    let text = String::from_utf8_lossy(&text[..200]);
    assert!(text.contains("FIELDS x y z intensity ring\nSIZE 4 4 4 4 2\nTYPE F F F F U\n"));
    // Compression does something on real-looking data.
    let raw = std::fs::metadata(dir.join("Binary.pcd")).unwrap().len();
    let packed = std::fs::metadata(dir.join("BinaryCompressed.pcd")).unwrap().len();
    assert!(packed < raw, "{packed} >= {raw}");
}

#[test]
fn write_replaces_atomically_and_reports_errors() {
    let dir = Scratch::new("pcd-atomic");
    let path = dir.join("c.pcd");
    pcd::write(&path, &cloud(10, 2), PcdFormat::Binary).unwrap();
    pcd::write(&path, &cloud(20, 3), PcdFormat::Binary).unwrap();
    assert_eq!(pcd::read(&path).unwrap().len(), 20);
    let names: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names.len(), 1, "temporary file left behind: {names:?}");
    let err = pcd::write(dir.join("missing/c.pcd"), &[], PcdFormat::Ascii).unwrap_err();
    assert!(err.to_string().contains("missing/c.pcd"), "{err}");
}

#[test]
fn empty_cloud_round_trips() {
    for format in [PcdFormat::Ascii, PcdFormat::Binary, PcdFormat::BinaryCompressed] {
        let mut bytes = Vec::new();
        pcd::encode(&[], format, &mut bytes);
        assert!(pcd::parse(&bytes, "empty").unwrap().is_empty());
    }
}

// ---------------------------------------------------------------------------------------
// Crafted files

/// Fields in an unusual order with every type, COUNT > 1 and fields we ignore.
const ODD_FIELDS: &[FieldSpec] = &[
    ("rgb", 4, 'U', 1),
    ("t", 8, 'F', 1),
    ("normal", 4, 'F', 3),
    ("z", 8, 'F', 1),
    ("channel", 1, 'U', 1),
    ("x", 4, 'F', 2),
    ("y", 2, 'I', 1),
    ("i", 8, 'U', 1),
    ("pad", 1, 'I', 3),
    ("k", 4, 'I', 1),
    ("m", 8, 'I', 1),
    ("w", 2, 'U', 1),
];

/// (x, y, z, intensity, ring, time) for point `k`; y must be an integer (I2).
fn odd_values(k: usize) -> [f64; 6] {
    let k = k as f64;
    [1.5 + k, -3.0 - k, 0.25 * k, 200.0 - k, 63.0 - k, 1.0e9 + k * 1e-3]
}

/// The value of field `name`, element `e`, of point `k` in the odd layout.
fn odd_field(name: &str, e: usize, k: usize) -> f64 {
    let v = odd_values(k);
    match (name, e) {
        ("x", 0) => v[0],
        ("y", _) => v[1],
        ("z", _) => v[2],
        ("i", _) => v[3],
        ("channel", _) => v[4],
        ("t", _) => v[5],
        _ => (k + e) as f64, // ignored fields: anything
    }
}

fn odd_expected(n: usize) -> Vec<Point> {
    (0..n)
        .map(|k| {
            let v = odd_values(k);
            Point {
                x: v[0] as f32,
                y: v[1] as f32,
                z: v[2] as f32,
                intensity: v[3] as f32,
                ring: v[4] as u16,
                time: v[5],
            }
        })
        .collect()
}

#[test]
fn any_field_order_and_type_binary() {
    let n = 20;
    let mut bytes = header(ODD_FIELDS, n, "binary");
    for k in 0..n {
        for &(name, size, ty, count) in ODD_FIELDS {
            for e in 0..count {
                bytes.extend(scalar(odd_field(name, e, k), ty, size));
            }
        }
    }
    let got = pcd::parse(&bytes, "odd.pcd").unwrap();
    assert_eq!(got, odd_expected(n));
}

#[test]
fn any_field_order_and_type_compressed() {
    let n = 20;
    let mut raw = Vec::new();
    for &(name, size, ty, count) in ODD_FIELDS {
        for k in 0..n {
            for e in 0..count {
                raw.extend(scalar(odd_field(name, e, k), ty, size));
            }
        }
    }
    let mut packed = vec![0; lzf::max_compressed_len(raw.len())];
    let len = lzf::compress(&raw, &mut packed).unwrap();
    let mut bytes = header(ODD_FIELDS, n, "binary_compressed");
    bytes.extend((len as u32).to_le_bytes());
    bytes.extend((raw.len() as u32).to_le_bytes());
    bytes.extend(&packed[..len]);
    assert_eq!(pcd::parse(&bytes, "odd.pcd").unwrap(), odd_expected(n));
}

#[test]
fn any_field_order_and_type_ascii() {
    let n = 20;
    let mut bytes = header(ODD_FIELDS, n, "ascii");
    for k in 0..n {
        let mut words = Vec::new();
        for &(name, _, _, count) in ODD_FIELDS {
            for e in 0..count {
                words.push(format!("{}", odd_field(name, e, k)));
            }
        }
        bytes.extend(words.join(" ").into_bytes());
        bytes.extend(if k % 2 == 0 { "\r\n" } else { "\n" }.as_bytes());
    }
    assert_eq!(pcd::parse(&bytes, "odd.pcd").unwrap(), odd_expected(n));
}

#[test]
fn nan_and_zero_points_are_skipped() {
    let fields = [("x", 4, 'F', 1), ("y", 4, 'F', 1), ("z", 4, 'F', 1), ("intensity", 4, 'F', 1)];
    let rows =
        ["1 2 3 4", "nan nan nan 0", "0 0 0 9", "NaN 1 1 1", "0 0 1 5", "inf 1 1 1", "4 5 6 7"];
    let mut bytes = header(&fields, rows.len(), "ascii");
    bytes.extend(rows.join("\n").into_bytes());
    let mut out = Vec::new();
    let info = PcdReader::new().parse_into(&bytes, "nan.pcd", &mut out).unwrap();
    let xyz: Vec<_> = out.iter().map(|p| (p.x, p.y, p.z, p.intensity)).collect();
    assert_eq!(xyz, [(1.0, 2.0, 3.0, 4.0), (0.0, 0.0, 1.0, 5.0), (4.0, 5.0, 6.0, 7.0)]);
    assert_eq!((info.skipped, info.has_ring, info.has_time), (4, false, false));
}

/// Parses `bytes` and returns the error text (which must name the file).
fn error_of(bytes: &[u8]) -> (PcdError, String) {
    let err = pcd::parse(bytes, "bad.pcd").unwrap_err();
    let text = err.to_string();
    assert!(text.starts_with("bad.pcd: "), "{text}");
    (err, text)
}

#[test]
fn malformed_headers_are_explained() {
    let good = header(&[("x", 4, 'F', 1), ("y", 4, 'F', 1), ("z", 4, 'F', 1)], 1, "binary");
    let good = String::from_utf8(good).unwrap();
    let cases = [
        ("FIELDS x y z\n", "", "no FIELDS line"),
        ("SIZE 4 4 4", "SIZE 4 4", "SIZE 2"),
        ("TYPE F F F", "TYPE F F Q", "TYPE Q"),
        ("SIZE 4 4 4", "SIZE 4 4 3", "SIZE 3"),
        ("WIDTH 1", "WIDTH one", "WIDTH"),
        ("DATA binary", "DATA zip", "DATA format"),
        ("DATA binary\n", "", "no DATA line"),
        ("VERSION 0.7", "COLOR red", "unknown header keyword"),
        ("COUNT 1 1 1", "COUNT 1 0 1", "COUNT 0"),
    ];
    for (from, to, expect) in cases {
        let text = good.replace(from, to);
        let (err, msg) = error_of(text.as_bytes());
        assert!(matches!(err, PcdError::Header { .. }), "{msg}");
        assert!(msg.contains(expect), "`{msg}` lacks `{expect}`");
    }
    let no_z = good.replace("FIELDS x y z", "FIELDS x y q");
    let (err, msg) = error_of(no_z.as_bytes());
    assert!(matches!(err, PcdError::MissingField { field: "z", .. }), "{msg}");
    let (_, msg) = error_of(b"\xff\xfe binary junk");
    assert!(msg.contains("line 1"), "{msg}");
}

#[test]
fn truncated_data_is_explained() {
    let fields = [("x", 4, 'F', 1), ("y", 4, 'F', 1), ("z", 4, 'F', 1)];
    let mut bin = header(&fields, 3, "binary");
    bin.extend([0u8; 35]);
    let (err, msg) = error_of(&bin);
    assert!(matches!(err, PcdError::Truncated { needed: 36, available: 35, .. }), "{msg}");

    let mut asc = header(&fields, 3, "ascii");
    asc.extend(b"1 2 3\n4 5 6\n");
    assert!(matches!(error_of(&asc).0, PcdError::Truncated { .. }));
    let mut short = header(&fields, 1, "ascii");
    short.extend(b"1 2\n");
    let (err, msg) = error_of(&short);
    assert!(matches!(err, PcdError::Ascii { line: 1, .. }) && msg.contains("2 values"), "{msg}");
    let mut word = header(&fields, 1, "ascii");
    word.extend(b"1 two 3\n");
    assert!(error_of(&word).1.contains("`two`"));

    let mut full = Vec::new();
    pcd::encode(&cloud(100, 4), PcdFormat::BinaryCompressed, &mut full);
    for cut in [full.len() - 1, full.len() - 300] {
        let (err, msg) = error_of(&full[..cut]);
        assert!(matches!(err, PcdError::Truncated { .. }), "{msg}");
    }
    let head = full.windows(18).position(|w| w == b"binary_compressed\n").unwrap() + 18;
    let mut lying = full.clone();
    lying[head + 4..head + 8].copy_from_slice(&u32::MAX.to_le_bytes());
    let (err, msg) = error_of(&lying);
    assert!(
        matches!(err, PcdError::Compressed { .. }) && msg.contains("not POINTS × record size"),
        "{msg}"
    );
    let mut corrupt = full.clone();
    corrupt[head + 8] = 0xff; // a back reference before the start
    assert!(matches!(error_of(&corrupt).0, PcdError::Compressed { .. }));
    let err = pcd::read("/nonexistent/cloud.pcd").unwrap_err();
    assert!(err.to_string().contains("/nonexistent/cloud.pcd"));
}

#[test]
fn reading_again_allocates_nothing() {
    let dir = Scratch::new("pcd-alloc");
    let mut reader = PcdReader::new();
    let mut out = Vec::new();
    for format in [PcdFormat::Ascii, PcdFormat::Binary, PcdFormat::BinaryCompressed] {
        let path = dir.join("c.pcd");
        pcd::write(&path, &cloud(3000, 5), format).unwrap();
        reader.read_into(&path, &mut out).unwrap(); // warm-up: buffers grow
        let before = allocations();
        reader.read_into(&path, &mut out).unwrap();
        let made = allocations() - before;
        assert_eq!(made, 0, "{format:?}: {made} allocations on the second read");
        assert_eq!(out.len(), 3000);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let _ = pcd::parse(&bytes, "fuzz");
        let mut out = [0u8; 512];
        let _ = lzf::decompress(&bytes, &mut out);
    }

    #[test]
    fn mutated_files_never_panic(
        format in 0..3usize,
        flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..6),
        cut in any::<usize>(),
    ) {
        let format = [PcdFormat::Ascii, PcdFormat::Binary, PcdFormat::BinaryCompressed][format];
        let mut bytes = Vec::new();
        pcd::encode(&cloud(30, 6), format, &mut bytes);
        for &(at, v) in &flips {
            let n = bytes.len();
            bytes[at % n] ^= v;
        }
        let n = bytes.len();
        let _ = pcd::parse(&bytes[..cut % (n + 1)], "fuzz");
    }

    #[test]
    fn lzf_round_trips(data in proptest::collection::vec(0..4u8, 0..3000)) {
        let mut packed = vec![0; lzf::max_compressed_len(data.len())];
        let n = lzf::compress(&data, &mut packed).unwrap();
        let mut out = vec![0; data.len()];
        prop_assert_eq!(lzf::decompress(&packed[..n], &mut out), Ok(data.len()));
        prop_assert_eq!(out, data);
    }
}

// ---------------------------------------------------------------------------------------
// Real clouds

#[test]
fn real_holeboard_cloud() {
    let dir = shared("holeboard-real");
    let Some(path) = std::fs::read_dir(&dir).ok().and_then(|d| {
        d.filter_map(Result::ok).map(|e| e.path()).find(|p| p.extension() == Some("pcd".as_ref()))
    }) else {
        eprintln!("skipping: no PCD in {}", dir.display());
        return;
    };
    let mut out = Vec::new();
    let info = pcd::read_into(&path, &mut out).unwrap();
    assert_eq!(info.format, PcdFormat::BinaryCompressed);
    assert!(info.has_intensity && info.has_ring && info.has_time);
    assert_eq!(out.len() + info.skipped, info.declared_points);
    assert!((100_000..=120_000).contains(&out.len()), "{} points", out.len());
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for p in &out {
        for (k, v) in [p.x, p.y, p.z].into_iter().enumerate() {
            lo[k] = lo[k].min(v);
            hi[k] = hi[k].max(v);
        }
    }
    eprintln!("holeboard: {} points, box {lo:?} .. {hi:?}", out.len());
    for k in 0..3 {
        assert!(lo[k] > -300.0 && hi[k] < 300.0 && hi[k] - lo[k] > 1.0, "axis {k}: {lo:?} {hi:?}");
    }
    // 64 rings, all present; one sweep of about 0.1 s; intensities are 8-bit.
    let max_ring = out.iter().map(|p| p.ring).max().unwrap();
    let mut rings = [false; 64];
    out.iter().for_each(|p| rings[usize::from(p.ring.min(63))] = true);
    assert!(max_ring == 63 && rings.iter().all(|&r| r), "rings up to {max_ring}");
    let t0 = out.iter().map(|p| p.time).fold(f64::MAX, f64::min);
    let t1 = out.iter().map(|p| p.time).fold(f64::MIN, f64::max);
    assert!(t0 > 1.5e9 && (0.05..0.2).contains(&(t1 - t0)), "time {t0}..{t1}");
    assert!(out.iter().all(|p| (0.0..=255.0).contains(&p.intensity)));
    // The board stands about 3.3 m ahead: plenty of returns near it.
    let board = out.iter().filter(|p| (3.0..3.7).contains(&p.x) && p.y.abs() < 1.0).count();
    assert!(board > 200, "{board} points near the board");
    // Our writer's compressed output reads back identically.
    let mut bytes = Vec::new();
    pcd::encode(&out, PcdFormat::BinaryCompressed, &mut bytes);
    let back = pcd::parse(&bytes, "rewritten").unwrap();
    let strip = |v: &[Point]| v.iter().map(|p| Point { time: 0.0, ..*p }).collect::<Vec<_>>();
    assert!(back == strip(&out));
}

/// Independent count of the ascii cloud: lines after `DATA`, first three numbers finite
/// and not all zero.
fn count_ascii_points(text: &str) -> (usize, usize) {
    let data = text.split_once("\nDATA ascii\n").unwrap().1;
    let (mut lines, mut valid) = (0, 0);
    for line in data.lines().filter(|l| !l.trim().is_empty()) {
        lines += 1;
        let v: Vec<f32> = line.split_whitespace().take(3).map(|w| w.parse().unwrap()).collect();
        valid += usize::from(v.iter().all(|x| x.is_finite()) && v.iter().any(|&x| x != 0.0));
    }
    (lines, valid)
}

#[test]
fn real_road_overlay_cloud() {
    let path = shared("road-overlay/0.pcd");
    let Ok(text) = std::fs::read_to_string(&path) else {
        eprintln!("skipping: {} absent", path.display());
        return;
    };
    let (lines, valid) = count_ascii_points(&text);
    let mut out = Vec::new();
    let info = pcd::read_into(&path, &mut out).unwrap();
    eprintln!("road-overlay: {lines} lines, {valid} valid, read {}", out.len());
    assert_eq!(info.declared_points, lines);
    assert_eq!(out.len(), valid);
    assert_eq!(info.skipped, lines - valid);
    assert!(info.has_intensity && !info.has_ring);
    // The first line is reproduced exactly.
    let first = text.split_once("\nDATA ascii\n").unwrap().1.lines().next().unwrap();
    let v: Vec<f32> = first.split_whitespace().map(|w| w.parse().unwrap()).collect();
    assert_eq!([out[0].x, out[0].y, out[0].z, out[0].intensity], v[..4]);
}

#[test]
#[ignore = "timing; run with --release -- --ignored --nocapture"]
fn real_pcd_speed() {
    for rel in ["holeboard-real/2022-01-18-15-25-03-449.pcd", "road-overlay/0.pcd"] {
        let path = shared(rel);
        let Ok(bytes) = std::fs::read(&path) else {
            eprintln!("skipping: {} absent", path.display());
            continue;
        };
        let mut reader = PcdReader::new();
        let mut out = Vec::new();
        let reps = 30;
        let t = std::time::Instant::now();
        for _ in 0..reps {
            reader.parse_into(&bytes, rel, &mut out).unwrap();
        }
        let s = t.elapsed().as_secs_f64() / reps as f64;
        eprintln!(
            "{rel}: {} points, {:.1} ms, {:.0} MB/s, {:.1} Mpoints/s",
            out.len(),
            s * 1e3,
            bytes.len() as f64 / s / 1e6,
            out.len() as f64 / s / 1e6
        );
    }
}

#[test]
fn format_names() {
    for f in [PcdFormat::Ascii, PcdFormat::Binary, PcdFormat::BinaryCompressed] {
        assert_eq!(f.to_string().parse::<PcdFormat>(), Ok(f));
        assert_eq!(f.as_str().to_uppercase().parse::<PcdFormat>(), Ok(f));
    }
    assert!("lzf".parse::<PcdFormat>().unwrap_err().contains("lzf"));
}
