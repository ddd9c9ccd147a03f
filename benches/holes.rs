//! Timing of the LiDAR board detector: one simulated Pandar64 sweep (≈115k points, six
//! boards, floor, walls, clutter), detected repeatedly with one reused workspace; the
//! fastest and median sweep are printed next to the sensor's 100 ms sweep period (the
//! fastest is the one least disturbed by other work on a shared machine). Each is also
//! given as a ratio to a reference run timed in the same process (sorting the sweep's
//! points by a voxel key, a fixed workload the detector's changes do not touch), so
//! figures from a loaded machine or another one compare. Plain timed loop
//! (`cargo bench --bench holes`).

#[path = "../tests/common/opencalib.rs"]
mod opencalib;

use std::path::Path;
use std::time::Instant;

use opencalib::{opencalib_board, opencalib_data_dir};
use roomcal::detect::holes::{HoleConfig, HoleDetector};
use roomcal::geometry::{Se3, Vec6};
use roomcal::sim::{simulate, ImageNoise, SimOptions};

fn main() {
    let room =
        roomcal::room::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml")))
            .expect("config/room.toml");
    let options = SimOptions {
        seed: 7,
        image: ImageNoise { supersample: 1, ..ImageNoise::default() },
        ..SimOptions::default()
    };
    let scene = simulate(&room, &options).expect("simulate");
    let cloud = scene.cloud.expect("a LiDAR sweep");
    let mut detector = HoleDetector::new(&room.board, HoleConfig::default());
    let mut boards = Vec::new();
    detector.detect(&cloud, &mut boards); // warm-up: buffers grow to size here
    let (fastest, median) = time(|| detector.detect(&cloud, &mut boards));
    let (reference, _) = time(|| {
        reference_run(&cloud);
    });
    println!(
        "holes (simulated Pandar64): {} points, {} boards placed, {} refused: \
         {fastest:.1} ms CPU per sweep (median {median:.1} ms; the sweep period is 100 ms); \
         reference run {reference:.2} ms, detector / reference {:.1}",
        cloud.len(),
        boards.len(),
        detector.refused().len(),
        fastest / reference,
    );
    expected_boards(&mut detector, &cloud, &boards, fastest);
    real_frame();
}

/// The same sweep with every board expected where the global detector placed it, moved by
/// a mounting error (1°, 5 cm: the whole sensor frame), as a surveyed room predicts them
/// (`HoleDetector::detect_expected`); its time against the global detector's.
fn expected_boards(
    detector: &mut HoleDetector,
    cloud: &[roomcal::lidar::Point],
    placed: &[roomcal::detect::holes::LidarBoard],
    global_ms: f64,
) {
    let w = 1f64.to_radians() / 3f64.sqrt();
    let error = Se3::exp(&Vec6::new(w, -w, w, 0.03, -0.03, 0.03));
    let expected: Vec<Se3> = placed.iter().map(|b| error.compose(&b.pose)).collect();
    let mut found = Vec::new();
    detector.detect_expected(cloud, &expected, &mut found);
    let (fastest, median) = time(|| detector.detect_expected(cloud, &expected, &mut found));
    println!(
        "holes where expected (simulated Pandar64): {} of {} expected boards placed: \
         {fastest:.1} ms CPU per sweep (median {median:.1} ms), expected / global {:.2}",
        found.iter().flatten().count(),
        expected.len(),
        fastest / global_ms,
    );
}

/// The reference workload: the sweep's points keyed by their 10 cm voxel and sorted, the
/// first step of any voxel grid, written here so that the detector's changes leave it be.
fn reference_run(cloud: &[roomcal::lidar::Point]) -> u64 {
    let mut keys: Vec<u64> = cloud
        .iter()
        .map(|p| {
            let f = |x: f32| ((x * 10.0).floor() as i64 + (1 << 20)) as u64 & ((1 << 21) - 1);
            (f(p.x) << 42) | (f(p.y) << 21) | f(p.z)
        })
        .collect();
    keys.sort_unstable();
    std::hint::black_box(keys.iter().fold(0u64, |a, &k| a.wrapping_mul(31) ^ k))
}

/// The same on the real OpenCalib frame (`../shared/data/holeboard-real`, or under
/// `ROOMCAL_SHARED`) when present.
fn real_frame() {
    let path = opencalib_data_dir().join("2022-01-18-15-25-03-449.pcd");
    let Ok(points) = roomcal::lidar::pcd::read(&path) else {
        println!("holes (real): skipped, {} is absent", path.display());
        return;
    };
    let spec = opencalib_board();
    let mut detector = HoleDetector::new(&spec, HoleConfig::default());
    let mut boards = Vec::new();
    detector.detect(&points, &mut boards);
    let (fastest, median) = time(|| detector.detect(&points, &mut boards));
    println!(
        "holes (real OpenCalib frame): {} points, {} board(s), {} refused: \
         {fastest:.1} ms CPU per sweep (median {median:.1} ms)",
        points.len(),
        boards.len(),
        detector.refused().len()
    );
}

/// Fastest and median of 30 runs (ms): CPU time of this thread where Linux reports it
/// (`CLOCK_THREAD_CPUTIME_ID`, so time waiting for a core shared with other work does not
/// count), else wall time. (`/proc/thread-self/schedstat`, read before, advances only at
/// the scheduler's ticks, 4 ms apart: a run shorter than a tick read as 0 ms.)
fn time(mut f: impl FnMut()) -> (f64, f64) {
    let mut ms: Vec<f64> = (0..30)
        .map(|_| {
            let (start, cpu) = (Instant::now(), cpu_ns());
            f();
            match (cpu, cpu_ns()) {
                (Some(a), Some(b)) => (b - a) as f64 * 1e-6,
                _ => start.elapsed().as_secs_f64() * 1e3,
            }
        })
        .collect();
    ms.sort_by(f64::total_cmp);
    (ms[0], ms[ms.len() / 2])
}

/// Nanoseconds this thread has run on a CPU.
#[cfg(all(target_os = "linux", target_pointer_width = "64"))]
fn cpu_ns() -> Option<u64> {
    #[repr(C)]
    struct Timespec {
        sec: i64,
        nsec: i64,
    }
    extern "C" {
        fn clock_gettime(clock: i32, ts: *mut Timespec) -> i32;
    }
    const CLOCK_THREAD_CPUTIME_ID: i32 = 3;
    let mut ts = Timespec { sec: 0, nsec: 0 };
    // SAFETY: `ts` is a valid, writable timespec (64-bit Linux layout); the call writes
    // only it.
    let rc = unsafe { clock_gettime(CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    (rc == 0).then(|| ts.sec as u64 * 1_000_000_000 + ts.nsec as u64)
}

#[cfg(not(all(target_os = "linux", target_pointer_width = "64")))]
fn cpu_ns() -> Option<u64> {
    None
}
