//! The memory budget (docs/limits.md): any input the limits admit costs at most
//! [`BUDGET`] of peak RSS, and an input beyond them is refused from its header with a
//! short message naming the file. Each case builds its files in a scratch folder and runs
//! the binary; the peak is the child's own `ru_maxrss`, read by `wait4` when it ends (std
//! has no API for it, so the call is declared here for 64-bit Linux).
//!
//! Linux carries a process's peak across `exec` from the process it was forked from, and
//! this test process holds hundreds of MB while other tests run: a child spawned from here
//! would report this process's peak. So each run is spawned by a fresh, small copy of this
//! test binary ([`measuring_parent`], ignored in ordinary runs) that waits for it and
//! prints its peak.
#![cfg(all(target_os = "linux", target_pointer_width = "64"))]

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use crate::common::png::png_header;
use crate::common::scratch::Scratch;
use crate::common::{fixture, root, BIN};
use roomcal::lidar::pcd::{self, PcdFormat};
use roomcal::lidar::Point;

/// docs/limits.md: "at most 512 MiB of peak RSS for any input the limits admit".
const BUDGET: u64 = 512 << 20;

/// The measuring parent's inputs: roomcal's arguments (separated by U+001F) and the seconds
/// after which the run is ended.
const ARGS_VAR: &str = "ROOMCAL_BUDGET_ARGS";
const KILL_VAR: &str = "ROOMCAL_BUDGET_KILL_S";

/// What a run of the binary left: exit code (-1 for a signal), stderr, peak RSS in bytes.
struct Run {
    code: i32,
    stderr: String,
    peak: u64,
}

/// `struct rusage` of 64-bit Linux: two `timeval`s, then `ru_maxrss` (KiB) and 13 more longs.
#[repr(C)]
struct Rusage {
    times: [i64; 4],
    maxrss: i64,
    rest: [i64; 13],
}

extern "C" {
    fn wait4(pid: i32, status: *mut i32, options: i32, rusage: *mut Rusage) -> i32;
}

/// Runs `roomcal ARGS` from a fresh copy of this test binary; after `kill_after` (when
/// given) the run is ended with SIGKILL.
fn run(args: &[OsString], kill_after: Option<Duration>) -> Run {
    let joined: Vec<String> = args.iter().map(|a| a.to_str().unwrap().to_owned()).collect();
    let out = Command::new(std::env::current_exe().unwrap())
        .args(["--ignored", "--exact", "memory_budget::measuring_parent", "--nocapture"])
        .args(["--test-threads", "1"])
        .env(ARGS_VAR, joined.join("\u{1f}"))
        .env(KILL_VAR, kill_after.map_or(String::new(), |d| d.as_secs().to_string()))
        .stdin(Stdio::null())
        .output()
        .expect("the measuring parent runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    // libtest may have begun the line ("test … ... ").
    let line = stdout.lines().find_map(|l| l.split("roomcal-peak ").nth(1));
    let line = line.unwrap_or_else(|| panic!("no peak reported:\n{stdout}"));
    let mut words = line.split(' ').map(|w| w.parse::<i64>().unwrap());
    let (code, peak) = (words.next().unwrap() as i32, words.next().unwrap() as u64);
    Run { code, stderr: String::from_utf8_lossy(&out.stderr).into_owned(), peak }
}

/// The small parent of one measured run (see the module doc): runs roomcal with the
/// arguments in [`ARGS_VAR`], its stderr passed through, and prints
/// `roomcal-peak CODE BYTES`.
#[test]
#[ignore = "the measuring parent of this module's runs, started by them"]
#[allow(clippy::zombie_processes)] // waited for by `wait4`, which std's `wait` cannot replace
fn measuring_parent() {
    let args = std::env::var(ARGS_VAR).expect("started by memory_budget::run");
    let kill = std::env::var(KILL_VAR).unwrap();
    let mut child = Command::new(BIN)
        .args(args.split('\u{1f}'))
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .spawn()
        .expect("roomcal runs");
    if let Ok(seconds) = kill.parse() {
        std::thread::sleep(Duration::from_secs(seconds));
        let _ = child.kill();
    }
    let mut status = 0;
    let mut usage = Rusage { times: [0; 4], maxrss: 0, rest: [0; 13] };
    // SAFETY: the pid is our unwaited child; both pointers are to live locals of the
    // layout the kernel writes.
    let pid = unsafe { wait4(child.id() as i32, &mut status, 0, &mut usage) };
    assert_eq!(pid, child.id() as i32, "wait4 failed");
    let code = if status & 0x7f == 0 { (status >> 8) & 0xff } else { -1 };
    println!("roomcal-peak {code} {}", usage.maxrss * 1024);
}

fn args(words: &[&dyn AsRef<std::ffi::OsStr>]) -> Vec<OsString> {
    words.iter().map(|w| w.as_ref().to_owned()).collect()
}

fn mib(bytes: u64) -> f64 {
    bytes as f64 / (1 << 20) as f64
}

/// Asserts the run's peak within the budget, and prints it for docs/limits.md.
fn assert_within_budget(what: &str, run: &Run) {
    println!("{what}: exit {}, peak RSS {:.0} MiB", run.code, mib(run.peak));
    assert!(run.peak > 0, "{what}: no peak measured");
    assert!(
        run.peak <= BUDGET,
        "{what}: peak RSS {:.0} MiB over the {:.0} MiB budget:\n{}",
        mib(run.peak),
        mib(BUDGET),
        run.stderr
    );
}

/// Asserts a refusal (exit 2) whose message is short and holds every one of `words`.
fn assert_refused(what: &str, run: &Run, words: &[&str]) {
    assert_eq!(run.code, 2, "{what}: exit {}, expected 2:\n{}", run.code, run.stderr);
    assert!(run.stderr.len() < 2000, "{what}: {} bytes of message", run.stderr.len());
    for w in words {
        assert!(run.stderr.contains(w), "{what}: `{w}` missing from:\n{}", run.stderr);
    }
}

/// The design's room with its camera `width × height`.
fn room_with_camera(dir: &Path, width: u32, height: u32) -> PathBuf {
    let room = std::fs::read_to_string(root().join("config/room.toml")).unwrap();
    let camera = format!("width = {width}\nheight = {height}");
    let path = dir.join(format!("room-{width}x{height}.toml"));
    std::fs::write(&path, room.replacen("width = 1920\nheight = 1200", &camera, 1)).unwrap();
    path
}

/// A real grey PNG of `width × height`, a checker of 64 px squares (cheap to detect in).
fn grey_png(path: &Path, width: u32, height: u32) {
    let image = image::GrayImage::from_fn(width, height, |x, y| {
        image::Luma([if (x / 64 + y / 64) % 2 == 0 { 40 } else { 200 }])
    });
    image.save(path).unwrap();
}

/// A `binary_compressed` PCD of `points` copies of one point (x y z, F4), its LZF stream at
/// the format's largest expansion: a few MB that unpack to `points × 12` bytes.
fn pcd_bomb(points: usize) -> Vec<u8> {
    fn repeat(pattern: [u8; 4], total: usize, out: &mut Vec<u8>) {
        out.push(3);
        out.extend(pattern);
        let mut done = 4;
        while done < total {
            let n = (total - done).min(264);
            // A back-reference of n bytes at distance 4 (offset 3), long form.
            out.extend([(7 << 5), (n - 2 - 7) as u8, 3]);
            done += n;
        }
    }
    let mut body = Vec::new();
    for v in [1.0f32, 2.0, 3.0] {
        repeat(v.to_le_bytes(), 4 * points, &mut body);
    }
    let mut bytes = format!(
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {points}\n\
         HEIGHT 1\nPOINTS {points}\nDATA binary_compressed\n"
    )
    .into_bytes();
    bytes.extend((body.len() as u32).to_le_bytes());
    bytes.extend(((points * 12) as u32).to_le_bytes());
    bytes.extend(body);
    bytes
}

/// A binary PCD of `points` points spread over a 20 m room (a fixed pseudo-random walk).
fn pcd_spread(path: &Path, points: usize) {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f32 / (1u64 << 53) as f32
    };
    let cloud: Vec<Point> = (0..points)
        .map(|i| Point {
            x: next() * 20.0 - 10.0,
            y: next() * 20.0 - 10.0,
            z: next() * 5.0 - 2.0,
            intensity: next() * 255.0,
            ring: (i % 64) as u16,
            time: 0.0,
        })
        .collect();
    pcd::write(path, &cloud, PcdFormat::Binary).unwrap();
}

#[test]
fn a_compressed_cloud_beyond_the_point_limit_is_refused_from_its_header() {
    let dir = Scratch::new("budget-pcd-bomb");
    let cloud = dir.join("bomb.pcd");
    std::fs::write(&cloud, pcd_bomb(16 << 20)).unwrap();
    let image = fixture("six-boards-pandar64/image.png");
    let room = root().join("config/room.toml");
    let calibrate_with = |cloud: &Path, out: &Path| {
        let words: [&dyn AsRef<std::ffi::OsStr>; 9] = [
            &"calibrate",
            &"--room",
            &room,
            &"--image",
            &image,
            &"--cloud",
            &cloud,
            &"--out",
            &out,
        ];
        run(&args(&words), None)
    };
    let calibrate = calibrate_with(&cloud, &dir.join("r.json"));
    assert_refused(
        "calibrate, 16 Mi point bomb",
        &calibrate,
        &["bomb.pcd", "16777216", "more than"],
    );
    assert!(calibrate.peak < 64 << 20, "refused from the header: {:.0} MiB", mib(calibrate.peak));
    let good = dir.join("good.json");
    let made = calibrate_with(&fixture("six-boards-pandar64/cloud.pcd"), &good);
    assert_eq!(made.code, 0, "{}", made.stderr);
    let overlay = run(
        &args(&[
            &"overlay",
            &"--calibration",
            &good,
            &"--image",
            &image,
            &"--cloud",
            &cloud,
            &"--out",
            &dir.join("o.png"),
        ]),
        None,
    );
    assert_refused("overlay, 16 Mi point bomb", &overlay, &["bomb.pcd", "16777216"]);
    assert!(overlay.peak < 64 << 20, "overlay: {:.0} MiB", mib(overlay.peak));
}

#[test]
fn images_whose_pixels_decode_beyond_the_byte_limit_are_refused_from_their_header() {
    let dir = Scratch::new("budget-png-bytes");
    // 4096 × 4096 is within the pixel limit; at 16-bit RGBA it decodes to 128 MiB.
    let room = room_with_camera(&dir, 4096, 4096);
    let png = dir.join("rgba16.png");
    std::fs::write(&png, png_header(4096, 4096, 16, 6)).unwrap();
    let mut words: Vec<OsString> = args(&[&"calibrate", &"--room", &room]);
    for _ in 0..12 {
        words.extend(args(&[&"--image", &png]));
    }
    words.extend(args(&[&"--out", &dir.join("r.json")]));
    let twelve = run(&words, None);
    assert_refused("twelve 16-bit RGBA", &twelve, &["rgba16.png", "4096x4096", "8 bytes a pixel"]);
    assert!(twelve.peak < 64 << 20, "refused from the header: {:.0} MiB", mib(twelve.peak));
    // A camera above the pixel limit is refused in the room file already.
    let room = room_with_camera(&dir, 8192, 8192);
    let out = dir.join("d.json");
    let detect = run(&args(&[&"detect", &"--room", &room, &"--image", &png, &"--out", &out]), None);
    assert_refused("8192² camera", &detect, &["room-8192x8192.toml", "camera.width", "pixels"]);
}

#[test]
fn a_run_at_the_image_and_point_limits_stays_within_the_budget() {
    let dir = Scratch::new("budget-at-limits");
    let side = 4096; // 16 Mi px, the pixel limit
    let room = room_with_camera(&dir, side, side);
    let png = dir.join("grey.png");
    grey_png(&png, side, side);
    let cloud = dir.join("cloud.pcd");
    pcd_spread(&cloud, pcd::MAX_POINTS);
    for standing in [false, true] {
        let mut words: Vec<OsString> = args(&[&"calibrate", &"--room", &room]);
        for _ in 0..12 {
            words.extend(args(&[&"--image", &png]));
        }
        if standing {
            words.extend(args(&[&"--standing", &"--cloud", &cloud]));
        }
        words.extend(args(&[&"--out", &dir.join("r.json"), &"--report", &dir.join("r.png")]));
        let run = run(&words, None);
        assert!(matches!(run.code, 0 | 3), "exit {}:\n{}", run.code, run.stderr);
        assert_within_budget(&format!("calibrate, 12 × 16 Mi px, standing {standing}"), &run);
    }
    let detect = run(
        &args(&[
            &"detect",
            &"--room",
            &root().join("config/room.toml"),
            &"--cloud",
            &cloud,
            &"--out",
            &dir.join("d.json"),
        ]),
        None,
    );
    assert_eq!(detect.code, 0, "{}", detect.stderr);
    assert_within_budget("detect, 1 Mi points", &detect);
}

#[test]
fn the_daemon_replaying_a_frame_at_the_pixel_limit_stays_within_the_budget() {
    let dir = Scratch::new("budget-daemon");
    let side = 4096;
    let room = room_with_camera(&dir, side, side);
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    for i in 0..3 {
        grey_png(&frames.join(format!("{i}.png")), side, side);
    }
    let config = dir.join("roomcal.toml");
    let text = format!(
        "room = {:?}\nstore = {:?}\n[camera]\nsource = \"replay:{}\"\n[lidar]\nsource = \"replay:{}\"\n\
         [trigger]\nmode = \"auto\"\nsettle_s = 1.0\nsweeps = 1\nmin_boards = 6\n",
        room,
        dir.join("store"),
        frames.display(),
        fixture("six-boards-pandar64/cloud.pcd").display(),
    );
    std::fs::write(&config, text).unwrap();
    // The room's boards are not in these frames: the daemon replays and detects until ended.
    let run =
        run(&args(&[&"daemon", &"--config", &config, &"--once"]), Some(Duration::from_secs(8)));
    assert_within_budget("daemon replaying 16 Mi px frames for 8 s", &run);
    assert!(run.peak > 16 << 20, "the frames were decoded: {:.0} MiB", mib(run.peak));
}

#[test]
fn a_huge_bad_value_in_a_room_file_is_named_not_echoed() {
    let dir = Scratch::new("budget-room-value");
    let room = std::fs::read_to_string(root().join("config/room.toml")).unwrap();
    let bad = dir.join("room.toml");
    let value = "9".repeat(50_000_000);
    std::fs::write(&bad, room.replacen("width = 1.2", &format!("width = {value}x"), 1)).unwrap();
    let image = fixture("six-boards-pandar64/image.png");
    let out = dir.join("d.json");
    let run = run(&args(&[&"detect", &"--room", &bad, &"--image", &image, &"--out", &out]), None);
    assert_refused("50 MB value", &run, &["room.toml", "line 3", "…"]);
    assert_within_budget("a 50 MB bad value", &run);
}
