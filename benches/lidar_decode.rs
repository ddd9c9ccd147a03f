//! Decode throughput on a real capture (no criterion: one timed loop, printed as JSON for
//! `scripts/bench_decode.py`). Usage: `cargo bench --bench lidar_decode -- [PCAP] [MODEL] [REPS]`,
//! defaulting to the VLP-16 capture in `../shared/data/pcap`.

use std::hint::black_box;
use std::time::Instant;

use roomcal::lidar::{decode_packet, Calibration, Model, Return};

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
    let mut points = 0usize;
    let mut sum = 0.0f32;
    let start = Instant::now();
    for _ in 0..reps {
        points = 0;
        for p in &payloads {
            let _ = decode_packet(&cal, p, &mut |r: Return| {
                sum += r.point.x;
                points += 1;
            });
        }
    }
    let per_pass = start.elapsed().as_secs_f64() / reps as f64;
    black_box(sum);
    println!(
        "{{\"decoder\": \"roomcal\", \"model\": \"{}\", \"packets\": {}, \"points\": {points}, \
         \"capture_s\": {span:.6}, \"decode_s\": {per_pass:.9}, \"real_time_multiple\": {:.1}}}",
        model.name(),
        payloads.len(),
        span / per_pass
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
