//! Sweep assembly and malformed-packet handling: synthetic captures made with the encoder
//! (three turns of a VLP-32C and a Pandar64), then packets dropped, duplicated, swapped,
//! truncated, padded, corrupted or sent to other ports; and the real VLP-16 capture.

use std::path::Path;

use roomcal::lidar::{
    encode_sweep, Calibration, Model, Point, SimReturn, SweepAssembler, SweepConfig, SweepStats,
};

/// Three turns at 0.2° steps, every laser returning at a range that varies with azimuth.
fn turns(model: Model, turns: usize) -> Vec<SimReturn> {
    let mut out = Vec::new();
    for step in 0..turns * 1800 {
        let azimuth = ((step * 20 + 1000) % 36000) as u16;
        for laser in 0..model.lasers() as u16 {
            let range = 5.0 + (step % 97) as f32 * 0.05 + f32::from(laser) * 0.01;
            out.push(SimReturn { laser, azimuth, range, intensity: (laser * 3) as u8 });
        }
    }
    out
}

fn packets(model: Model, n_turns: usize) -> (Calibration, Vec<Vec<u8>>) {
    let cal = Calibration::nominal(model);
    let mut out = Vec::new();
    let start = if model.is_velodyne() { 100.0 } else { 1_700_000_000.0 };
    encode_sweep(&cal, &turns(model, n_turns), start, &mut |p| out.push(p.to_vec())).unwrap();
    (cal, out)
}

/// Runs an assembler over (port, payload) pairs; returns the sweeps' (complete, points, lost)
/// and the stats.
fn assemble(cal: Calibration, input: &[(u16, Vec<u8>)]) -> (Vec<(bool, usize, u64)>, SweepStats) {
    let mut buf = vec![Point::default(); 200_000];
    let config = SweepConfig::for_calibration(&cal);
    let mut asm = SweepAssembler::new(cal, config, &mut buf);
    let mut sweeps = Vec::new();
    for (port, payload) in input {
        asm.push(*port, payload, &mut |s| sweeps.push((s.complete, s.points.len(), s.lost)));
    }
    asm.flush(&mut |s| sweeps.push((s.complete, s.points.len(), s.lost)));
    (sweeps, asm.stats())
}

fn on_data(packets: &[Vec<u8>]) -> Vec<(u16, Vec<u8>)> {
    packets.iter().map(|p| (2368, p.clone())).collect()
}

fn total(sweeps: &[(bool, usize, u64)]) -> usize {
    sweeps.iter().map(|s| s.1).sum()
}

#[test]
fn clean_capture_gives_whole_turns() {
    for model in [Model::Vlp32c, Model::Pandar64] {
        let (cal, pk) = packets(model, 3);
        let (sweeps, stats) = assemble(cal, &on_data(&pk));
        let complete: Vec<_> = sweeps.iter().filter(|s| s.0).collect();
        // Starting at 10°, cutting at 180°: partial, two complete turns, partial.
        assert_eq!(complete.len(), 2, "{model:?}: {sweeps:?}");
        for s in &complete {
            assert_eq!(s.1, 1800 * model.lasers(), "{model:?}");
        }
        assert_eq!(total(&sweeps), 3 * 1800 * model.lasers());
        assert_eq!(stats.packets as usize, pk.len());
        assert_eq!((stats.lost, stats.duplicates, stats.reordered, stats.dropped()), (0, 0, 0, 0));
        assert_eq!(stats.sweeps as usize, sweeps.len());
    }
}

#[test]
fn lost_duplicate_and_reordered_packets() {
    for model in [Model::Vlp32c, Model::Pandar64] {
        let (cal, pk) = packets(model, 3);
        // A packet in the middle of the second turn.
        let k = pk.len() / 2;
        let blocks = if model == Model::Pandar64 { 6 } else { 12 };

        let mut lost = pk.clone();
        lost.remove(k);
        lost.remove(k);
        let (sweeps, stats) = assemble(cal, &on_data(&lost));
        assert_eq!(stats.lost, 2, "{model:?}");
        assert_eq!(total(&sweeps), (3 * 1800 - 2 * blocks) * model.lasers());
        assert_eq!(sweeps.iter().map(|s| s.2).sum::<u64>(), 2);

        let mut dup = pk.clone();
        dup.insert(k, pk[k].clone());
        dup.insert(k + 3, pk[k].clone());
        let (sweeps, stats) = assemble(cal, &on_data(&dup));
        assert_eq!((stats.duplicates, stats.lost), (2, 0), "{model:?}");
        assert_eq!(total(&sweeps), 3 * 1800 * model.lasers());

        let mut swapped = pk.clone();
        swapped.swap(k, k + 1);
        let (sweeps, stats) = assemble(cal, &on_data(&swapped));
        assert_eq!(stats.reordered, 1, "{model:?}");
        // A swap looks like one packet lost then found: the gap counts it.
        assert!(stats.lost <= 1);
        assert_eq!(total(&sweeps), 3 * 1800 * model.lasers());
        assert_eq!(sweeps.iter().filter(|s| s.0).count(), 2, "{model:?}: {sweeps:?}");
    }
}

#[test]
fn malformed_payloads_are_counted_and_dropped() {
    for model in [Model::Vlp32c, Model::Pandar64] {
        let (cal, pk) = packets(model, 1);
        let clean = assemble(cal, &on_data(&pk));
        let good = &pk[5];
        let mut input = on_data(&pk);
        let mut insert = |payload: Vec<u8>, port: u16| input.insert(7, (port, payload));
        insert(good[..good.len() - 1].to_vec(), 2368); // truncated
        insert(good[..100].to_vec(), 2368); // truncated
        insert([good.as_slice(), &[0u8; 9]].concat(), 2368); // oversized
        let mut bad_magic = good.clone();
        bad_magic[if model == Model::Pandar64 { 0 } else { 300 }] ^= 0x55;
        insert(bad_magic, 2368);
        let mut bad_mode = good.clone();
        let mode_at = if model == Model::Pandar64 { 1172 + 14 } else { 1204 };
        bad_mode[mode_at] = 0x77;
        insert(bad_mode, 2368);
        let mut bad_azimuth = good.clone();
        let az_at = if model == Model::Pandar64 { 8 } else { 2 };
        bad_azimuth[az_at..az_at + 2].copy_from_slice(&36500u16.to_le_bytes());
        insert(bad_azimuth, 2368);
        insert(vec![0u8; 512], 8308); // Velodyne position port
        insert(vec![0u8; 64], 10110); // Hesai GPS port
        insert(good.clone(), 9999); // unknown port
                                    // A valid packet of another model of the same vendor on the data port: the same length
                                    // (VLP-16) is recognised as another model, another length (Pandar40P) is oversized.
        let other = if model == Model::Pandar64 { Model::Pandar40p } else { Model::Vlp16 };
        insert(packets(other, 1).1[0].clone(), 2368);
        let other_len_differs = usize::from(model == Model::Pandar64) as u64;
        let (sweeps, stats) = assemble(cal, &input);
        assert_eq!(total(&sweeps), total(&clean.0), "{model:?}: points unchanged");
        assert_eq!(stats.truncated, 2, "{model:?}");
        assert_eq!(stats.oversized, 1 + other_len_differs, "{model:?}");
        assert_eq!(stats.corrupted, 3, "{model:?}");
        assert_eq!(stats.position, 1, "{model:?}");
        // The other vendor's GPS port, the unknown port, and the other model's packet.
        assert_eq!(stats.unknown, 3 - other_len_differs, "{model:?}: {stats:?}");
        assert_eq!(stats.packets as usize, pk.len());
    }
}

#[test]
fn buffer_overflow_is_counted_not_fatal() {
    let (cal, pk) = packets(Model::Vlp32c, 1);
    let mut buf = vec![Point::default(); 1000];
    let mut asm = SweepAssembler::new(cal, SweepConfig::for_calibration(&cal), &mut buf);
    let mut sizes = Vec::new();
    for p in &pk {
        asm.push(2368, p, &mut |s| sizes.push((s.points.len(), s.overflow)));
    }
    asm.flush(&mut |s| sizes.push((s.points.len(), s.overflow)));
    assert!(sizes.iter().all(|s| s.0 <= 1000));
    assert_eq!(sizes.iter().map(|s| s.0 as u64 + s.1).sum::<u64>(), asm.stats().points);
    assert!(asm.stats().overflow > 0);
}

/// (port, payload) of each frame of a classic pcap in `../shared/data/pcap`, or None.
fn capture(name: &str) -> Option<Vec<(u16, Vec<u8>)>> {
    let path = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data/pcap")).join(name);
    if !path.exists() {
        println!("skipped: {} is absent", path.display());
        return None;
    }
    let data = std::fs::read(path).unwrap();
    let mut input = Vec::new();
    let mut off = 24;
    while off + 16 <= data.len() {
        let incl = u32::from_le_bytes(data[off + 8..off + 12].try_into().unwrap()) as usize;
        let frame = &data[off + 16..off + 16 + incl];
        let port = u16::from_be_bytes([frame[36], frame[37]]);
        input.push((port, frame[42..].to_vec()));
        off += 16 + incl;
    }
    Some(input)
}

#[test]
fn real_captures_cut_into_turns() {
    for (name, model) in [
        ("velodyne-vlp16/velodyne-vlp16.pcap", Model::Vlp16),
        ("hesai-pandar64/hesai-pandar64.pcap", Model::Pandar64),
    ] {
        let Some(input) = capture(name) else { return };
        let (sweeps, stats) = assemble(Calibration::nominal(model), &input);
        println!("{name}: {stats:?}; sweeps (complete, points, lost): {sweeps:?}");
        let complete: Vec<_> = sweeps.iter().filter(|s| s.0).collect();
        assert!(complete.len() >= 2, "{name}: {sweeps:?}");
        let (lo, hi) =
            complete.iter().fold((usize::MAX, 0), |(lo, hi), s| (lo.min(s.1), hi.max(s.1)));
        assert!(hi - lo < hi / 10, "{name}: turns of similar size: {complete:?}");
        assert_eq!((stats.dropped(), stats.lost), (0, 0), "{name}");
        assert_eq!(stats.packets as usize, input.len());
    }
}

#[test]
fn real_front_half_capture_counts_the_missing_half() {
    // This VLP-32C sends only azimuths 270° → 90° (a sensor field-of-view setting): one packet
    // per turn holds the last front blocks and the first of the next turn, then nothing for
    // half a turn. Each front half is a sweep; the silent half reads as a timestamp gap of
    // about 75 packets, counted as lost (expect that with a field-of-view limit).
    let Some(input) = capture("velodyne-vlp32c/velodyne-vlp32c.pcap") else { return };
    let (sweeps, stats) = assemble(Calibration::nominal(Model::Vlp32c), &input);
    println!("VLP-32C front halves: {stats:?}; sweeps: {sweeps:?}");
    let complete: Vec<_> = sweeps.iter().filter(|s| s.0).collect();
    assert_eq!(complete.len(), 4, "{sweeps:?}");
    // nebula's reference front half of one turn has 26,216 points in 0.4–50 m.
    assert!(complete.iter().all(|s| (25_000..28_000).contains(&s.1)), "{complete:?}");
    let per_gap = stats.lost as f64 / complete.len() as f64;
    assert!((60.0..95.0).contains(&per_gap), "{per_gap} packets lost per back half");
}
