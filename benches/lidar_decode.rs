//! Decode throughput on a real capture, every point written to a preallocated cloud (no
//! criterion: one timed loop, printed as JSON for `scripts/bench_decode.py`). Usage: `cargo bench --bench lidar_decode -- [PCAP] [MODEL] [REPS]`,
//! defaulting to the VLP-16 capture in `../shared/data/pcap`.

use std::hint::black_box;
use std::time::Instant;

use roomcal::lidar::{decode_into, Calibration, Model, Point};

/// Timed batches the repetitions are split into.
const BATCHES: usize = 10;

fn main() {
    let mut args = std::env::args().skip(1).filter(|a| !a.starts_with("--"));
    let path = args.next().unwrap_or_else(|| {
        concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../shared/data/pcap/velodyne-vlp16/velodyne-vlp16.pcap"
        )
        .to_owned()
    });
    let model = args.next().and_then(|m| Model::from_name(&m)).unwrap_or(Model::Vlp16);
    let reps: usize = args.next().and_then(|r| r.parse().ok()).unwrap_or(200);
    let Ok(data) = std::fs::read(&path) else {
        println!("skipped: cannot read {path}");
        return;
    };
    let (payloads, span) = udp_payloads(&data);
    let cal = Calibration::nominal(model);
    // Every point of the capture lands in one preallocated cloud (x y z intensity ring time),
    // as velodyne-decoder returns its cloud array.
    let mut cloud = vec![Point::default(); payloads.len() * 384];
    let mut points = 0usize;
    // The best of several batches: on a shared machine the slowest batches measure the
    // neighbours, not the decoder.
    let batch = reps.div_ceil(BATCHES).max(1);
    let mut per_pass = f64::INFINITY;
    let cpu_start = thread_cpu_ns();
    for _ in 0..BATCHES {
        let start = Instant::now();
        for _ in 0..batch {
            points = 0;
            for p in &payloads {
                if let Ok((n, _)) = decode_into(&cal, p, &mut cloud[points..]) {
                    points += n;
                }
            }
            black_box(&mut cloud);
        }
        per_pass = per_pass.min(start.elapsed().as_secs_f64() / batch as f64);
    }
    let passes = (batch * BATCHES) as f64;
    let cpu_per_pass = match (cpu_start, thread_cpu_ns()) {
        (Some(a), Some(b)) => (b - a) as f64 * 1e-9 / passes,
        _ => per_pass,
    };
    println!(
        "{{\"decoder\": \"roomcal\", \"model\": \"{}\", \"packets\": {}, \"points\": {points}, \
         \"capture_s\": {span:.6}, \"decode_s\": {per_pass:.9}, \"cpu_s\": {cpu_per_pass:.9}, \
         \"real_time_multiple\": {:.1}}}",
        model.name(),
        payloads.len(),
        span / cpu_per_pass
    );
}

/// UDP payloads of a classic little-endian pcap with Ethernet/IPv4/UDP frames, and the time
/// between the first and last frame (seconds).
fn udp_payloads(data: &[u8]) -> (Vec<&[u8]>, f64) {
    let mut out = Vec::new();
    let (mut first, mut last) = (None, 0.0);
    let mut off = 24;
    while off + 16 <= data.len() {
        let word = |o: usize| u32::from_le_bytes([data[o], data[o + 1], data[o + 2], data[o + 3]]);
        let t = f64::from(word(off)) + f64::from(word(off + 4)) * 1e-6;
        let incl = word(off + 8) as usize;
        let Some(frame) = data.get(off + 16..off + 16 + incl) else { break };
        if let Some(payload) = frame.get(42..) {
            out.push(payload);
        }
        first.get_or_insert(t);
        last = t;
        off += 16 + incl;
    }
    (out, last - first.unwrap_or(last))
}

/// CPU time this thread has run, ns (Linux `/proc/thread-self/schedstat`), so that time spent
/// waiting for a shared core is not charged to the decoder.
fn thread_cpu_ns() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    text.split_whitespace().next()?.parse().ok()
}
