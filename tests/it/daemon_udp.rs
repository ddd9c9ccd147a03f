//! The daemon binary fed the fixture's Pandar64 capture over loopback UDP with impairments
//! (loss, reordering, duplicates, garbage), as a hostile network or a failing switch would:
//! garbage never costs the sweep, and a run on a sweep that lost packets says so in its
//! reason. Real time (the daemon is another process, the sender a thread here); each case
//! ends with the daemon's first run or after `LIMIT`.
//!
//! The capture is one turn; the sender loops it, moving each pass's timestamps on by one
//! turn, at the sensor's own pace (3000 packets/s). `ROOMCAL_UDP_BIN` runs another build of
//! the binary (how the before/after table was made).

use std::io::Read;
use std::net::UdpSocket;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use roomcal::lidar::{hesai, Model};

use crate::common::fixture;
use crate::common::impair;
use impair::{header_garbage, mixed_garbage, Rng, TAIL_DATE, TAIL_US};

use crate::common::scratch::Scratch;

/// How long a case may take before the daemon is stopped (the study saw no run in 45 s).
const LIMIT: Duration = Duration::from_secs(40);

/// What a case sends besides the capture, per packet (probabilities).
#[derive(Clone, Copy, Debug, Default)]
struct Impairments {
    loss: f64,
    reorder: f64,
    duplicate: f64,
    /// Garbage with a valid Pandar64 header (see `impair::header_garbage`).
    header_garbage: f64,
    /// Garbage of any kind (see `impair::mixed_garbage`).
    mixed_garbage: f64,
    /// Send the garbage only, never the capture's packets.
    garbage_only: bool,
}

/// `packet` with its time moved on by `shift_us` microseconds (carried into seconds, minutes
/// and hours; the fixture's clock is far enough from midnight for any run here).
fn restamped(packet: &[u8], shift_us: u64) -> Vec<u8> {
    let mut p = packet.to_vec();
    let us = u32::from_le_bytes(p[TAIL_US..TAIL_US + 4].try_into().unwrap()) as u64 + shift_us;
    let [h, m, s] = [p[TAIL_DATE + 3], p[TAIL_DATE + 4], p[TAIL_DATE + 5]].map(u64::from);
    let day_s = h * 3600 + m * 60 + s + us / 1_000_000;
    assert!(day_s < 86_400, "the restamped capture crossed midnight");
    p[TAIL_US..TAIL_US + 4].copy_from_slice(&((us % 1_000_000) as u32).to_le_bytes());
    p[TAIL_DATE + 3..TAIL_DATE + 6].copy_from_slice(&[
        (day_s / 3600) as u8,
        (day_s / 60 % 60) as u8,
        (day_s % 60) as u8,
    ]);
    p
}

/// The capture's data payloads and the duration of its one turn, microseconds.
fn capture() -> (Vec<Vec<u8>>, u64) {
    let (datagrams, _) =
        roomcal::lidar::pcap::read_udp(fixture("six-boards-pandar64/cloud.pcap")).unwrap();
    let payloads: Vec<Vec<u8>> = datagrams.into_iter().map(|d| d.payload).collect();
    let time = |p: &[u8]| hesai::Packet::new_checked(p, Model::Pandar64).unwrap().time();
    let period = hesai::packet_period(Model::Pandar64);
    let turn = time(&payloads[payloads.len() - 1]) - time(&payloads[0]) + period;
    (payloads, (turn * 1e6).round() as u64)
}

/// Sends the looped capture with `imp` to `to` at the sensor's pace until `stop`.
fn send(to: std::net::SocketAddr, imp: Impairments, seed: u64, stop: Arc<AtomicBool>) {
    let (payloads, turn_us) = capture();
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    let mut rng = Rng(seed);
    let period = Duration::from_secs_f64(hesai::packet_period(Model::Pandar64));
    let start = Instant::now();
    let mut held: Option<Vec<u8>> = None;
    let mut k = 0u32;
    for pass in 0u64.. {
        for p in &payloads {
            if stop.load(Ordering::Relaxed) {
                return;
            }
            k += 1;
            // The sensor's pace, in bursts of 30 packets (10 ms).
            if k.is_multiple_of(30) {
                let due = start + period * k;
                if let Some(wait) = due.checked_duration_since(Instant::now()) {
                    std::thread::sleep(wait);
                }
            }
            let p = restamped(p, pass * turn_us);
            let mut out = Vec::new();
            if rng.chance(imp.header_garbage) {
                out.push(header_garbage(&mut rng, &p));
            }
            if rng.chance(imp.mixed_garbage) {
                out.push(mixed_garbage(&mut rng, &p));
            }
            if !imp.garbage_only && !rng.chance(imp.loss) {
                if held.is_none() && rng.chance(imp.reorder) {
                    // Sent after the next one.
                    held = Some(p.clone());
                } else {
                    out.push(p.clone());
                    out.extend(held.take());
                }
                if rng.chance(imp.duplicate) {
                    out.push(p);
                }
            }
            for d in out {
                let _ = socket.send_to(&d, to);
            }
        }
    }
}

/// What one case did.
#[derive(Debug)]
struct Outcome {
    /// The daemon ended its run (with `--once`) before `LIMIT`.
    ran: bool,
    accepted: bool,
    /// The lines of the daemon's log mentioning the run's end, the captured sweep and
    /// the LiDAR task's reports.
    lines: Vec<String>,
    log: String,
}

fn run_case(name: &str, imp: Impairments, seed: u64, limit: Duration) -> Outcome {
    let dir = Scratch::new(&format!("daemon-udp-{name}"));
    let port = UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let text = format!(
        "room = {:?}\nstore = {:?}\n[camera]\nsource = \"replay:{}\"\n[lidar]\nsource = \"udp:127.0.0.1:{port}\"\n\
         calibration = {:?}\n[trigger]\nmode = \"auto\"\nsettle_s = 1.0\nsweeps = 1\nmin_boards = 6\n",
        fixture("six-boards-pandar64/room.toml"),
        dir.join("store"),
        fixture("six-boards-pandar64/image.png").display(),
        fixture("six-boards-pandar64/angles.csv"),
    );
    let config = dir.join("roomcal.toml");
    std::fs::write(&config, text).unwrap();
    let binary = std::env::var("ROOMCAL_UDP_BIN").unwrap_or(crate::common::BIN.into());
    let mut child = Command::new(binary)
        .args(["daemon", "--config", config.to_str().unwrap(), "--once"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let to = format!("127.0.0.1:{port}").parse().unwrap();
    let sender = {
        let stop = stop.clone();
        std::thread::spawn(move || send(to, imp, seed, stop))
    };
    let started = Instant::now();
    let ran = loop {
        if child.try_wait().unwrap().is_some() {
            break true;
        }
        if started.elapsed() > limit {
            child.kill().unwrap();
            child.wait().unwrap();
            break false;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    stop.store(true, Ordering::Relaxed);
    sender.join().unwrap();
    let mut log = String::new();
    child.stdout.take().unwrap().read_to_string(&mut log).unwrap();
    child.stderr.take().unwrap().read_to_string(&mut log).unwrap();
    drop(dir);
    let lines = log
        .lines()
        .filter(|l| ["calibration", "sweep", "udp 127", "timed out"].iter().any(|w| l.contains(w)))
        .map(|l| l.to_string())
        .collect();
    Outcome { ran, accepted: log.contains("1 accepted"), lines, log }
}

/// "LiDAR sweep incomplete: L of N packets lost" in `log`: (L, N).
fn incomplete(log: &str) -> Option<(u64, u64)> {
    let at = log.find("LiDAR sweep incomplete: ")? + "LiDAR sweep incomplete: ".len();
    let mut words = log[at..].split(' ');
    let lost = words.next()?.parse().ok()?;
    let sent = words.nth(1)?.parse().ok()?;
    Some((lost, sent))
}

#[test]
fn hostile_udp_input_costs_no_sweep_and_lost_packets_are_named() {
    let none = Impairments::default();
    let cases = [
        ("loss50", Impairments { loss: 0.5, ..none }),
        (
            "each20",
            Impairments { loss: 0.2, reorder: 0.2, duplicate: 0.2, header_garbage: 0.2, ..none },
        ),
        ("header-garbage20", Impairments { header_garbage: 0.2, ..none }),
        ("mixed-garbage50", Impairments { mixed_garbage: 0.5, ..none }),
    ];
    let mut failures = Vec::new();
    for (name, imp) in cases {
        let out = run_case(name, imp, 15, LIMIT);
        println!("--- {name} {imp:?}: ran {}, accepted {}", out.ran, out.accepted);
        out.lines.iter().for_each(|l| println!("    {l}"));
        let mut fail = |why: String| failures.push(format!("{name}: {why}"));
        if !out.ran {
            fail(format!("no run in {} s", LIMIT.as_secs()));
        }
        // Every case logs what the LiDAR task dropped or lost.
        if imp.loss + imp.header_garbage + imp.mixed_garbage > 0.0
            && !out.log.contains("dropped")
            && incomplete(&out.log).is_none()
        {
            fail("nothing logged about dropped or lost packets".into());
        }
        if imp.loss > 0.0 {
            // The captured sweep's lost share is the loss rate (one turn: 300 packets).
            match incomplete(&out.log) {
                Some((lost, sent)) => {
                    let share = lost as f64 / sent as f64;
                    if (share - imp.loss).abs() > 0.12 || !(280..=320).contains(&sent) {
                        fail(format!("{lost} of {sent} lost for a loss of {}", imp.loss));
                    }
                }
                None => fail("no \"LiDAR sweep incomplete\" in the log".into()),
            }
            let failed_run = out
                .lines
                .iter()
                .find(|l| l.contains("calibration failed") || l.contains("calibration rejected"));
            if let Some(l) = failed_run.filter(|l| !l.contains("LiDAR sweep incomplete")) {
                fail(format!("the run's reason does not name the lost packets: {l}"));
            }
        } else if !out.accepted {
            // Garbage alone must cost nothing: the clean capture calibrates — unless the
            // kernel dropped packets (a loaded machine overflows the socket's receive
            // buffer; /proc/net/snmp RcvbufErrors), and then the reason says so.
            let named = out.lines.iter().any(|l| {
                (l.contains("calibration rejected") || l.contains("calibration failed"))
                    && l.contains("LiDAR sweep incomplete")
            });
            if !named {
                fail("the run was not accepted".into());
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn a_lidar_that_sends_only_garbage_is_reported_not_silent() {
    // Before: nothing logged after "state: room seen", however long it ran.
    let imp = Impairments { header_garbage: 1.0, garbage_only: true, ..Default::default() };
    let out = run_case("garbage-only", imp, 16, Duration::from_secs(13));
    out.lines.iter().for_each(|l| println!("    {l}"));
    assert!(!out.ran, "a run without a sweep: {}", out.log);
    let reports: Vec<&String> =
        out.lines.iter().filter(|l| l.contains("no complete sweep in 5 s")).collect();
    // Rate limited: one report per 5 s.
    assert!((1..=3).contains(&reports.len()), "{}", out.log);
    for r in reports {
        assert!(r.contains("waiting for the azimuth to pass the cut at 180.00°"), "{r}");
        assert!(r.contains("corrupted)"), "{r}");
    }
}
