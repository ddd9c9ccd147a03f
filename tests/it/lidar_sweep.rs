//! Sweep assembly and malformed-packet handling: synthetic captures made with the encoder
//! (three turns of a VLP-32C and a Pandar64), then packets dropped, duplicated, swapped,
//! truncated, padded, corrupted or sent to other ports, garbage that passes the header
//! checks, a clock that jumps; an Ouster stream with a wild and a torn packet; and the real
//! VLP-16 capture.

use std::path::Path;

use roomcal::lidar::{
    encode_sweep, sweep, Calibration, Model, Point, SimReturn, SweepAssembler, SweepConfig,
    SweepStats,
};

use crate::common::impair;
use impair::{header_garbage, next_day, Rng, BLOCK0, BLOCK_LEN, TAIL_DATE};

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

/// The assembler that grows its own buffer hands out the very sweeps of a fixed buffer,
/// and counts what passes its limit as overflow, as a full fixed buffer does.
#[test]
fn a_growing_buffer_gives_the_fixed_buffers_sweeps_and_overflows_at_its_limit() {
    let (cal, pk) = packets(Model::Pandar64, 3);
    let input = on_data(&pk);
    let config = SweepConfig::for_calibration(&cal);
    let run = |asm: &mut SweepAssembler<'_>| {
        let mut sweeps: Vec<(bool, Vec<Point>, u64)> = Vec::new();
        for (port, payload) in &input {
            asm.push(*port, payload, &mut |s| {
                sweeps.push((s.complete, s.points.to_vec(), s.overflow))
            });
        }
        asm.flush(&mut |s| sweeps.push((s.complete, s.points.to_vec(), s.overflow)));
        sweeps
    };
    let mut buf = vec![Point::default(); 200_000];
    let fixed = run(&mut SweepAssembler::new(cal, config, &mut buf));
    let grown = run(&mut SweepAssembler::growing(cal, config, 200_000));
    assert_eq!(fixed.len(), 4);
    assert!(fixed == grown, "the growing buffer's sweeps differ from the fixed buffer's");

    let limit = 1000 * Model::Pandar64.lasers();
    let mut small = vec![Point::default(); limit];
    let fixed = run(&mut SweepAssembler::new(cal, config, &mut small));
    let grown = run(&mut SweepAssembler::growing(cal, config, limit));
    let full_turn = fixed.iter().find(|s| s.0).expect("a complete turn");
    assert_eq!((full_turn.1.len(), full_turn.2), (limit, 800 * 64));
    assert!(fixed == grown, "overflow at the limit differs");
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
        crate::common::skipped(format_args!("{} is absent", path.display()));
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

/// Runs an assembler over payloads on the data port; returns the sweeps' (complete, points,
/// packets, lost) and the stats.
fn assemble_counts(
    cal: Calibration,
    input: &[Vec<u8>],
) -> (Vec<(bool, usize, u64, u64)>, SweepStats) {
    let mut buf = vec![Point::default(); 200_000];
    let mut asm = SweepAssembler::new(cal, SweepConfig::for_calibration(&cal), &mut buf);
    let mut sweeps = Vec::new();
    let mut take =
        |s: roomcal::lidar::Sweep<'_>| sweeps.push((s.complete, s.points.len(), s.packets, s.lost));
    for payload in input {
        asm.push(2368, payload, &mut take);
    }
    asm.flush(&mut take);
    (sweeps, asm.stats())
}

fn complete_sizes(sweeps: &[(bool, usize, u64, u64)]) -> Vec<usize> {
    sweeps.iter().filter(|s| s.0).map(|s| s.1).collect()
}

#[test]
fn one_bad_packet_never_moves_the_clock_nor_cuts() {
    let (cal, pk) = packets(Model::Pandar64, 3);
    let clean = assemble_counts(cal, &pk);
    let mut input = pk.clone();
    // Consistent in itself but a day ahead: before, every later packet looked reordered
    // and no sweep was ever cut.
    input.insert(10, next_day(&pk[10]));
    // The right time, a wild azimuth (90° on): before, it could cut the sweep.
    let mut wild = pk[20].clone();
    for b in 0..6 {
        let at = BLOCK0 + b * BLOCK_LEN;
        let az = u16::from_le_bytes([wild[at], wild[at + 1]]);
        wild[at..at + 2].copy_from_slice(&((az + 9000) % 36000).to_le_bytes());
    }
    input.insert(20, wild);
    // A flipped bit puts the time 131 ms ahead (within the window): the azimuth is not
    // where the turn rate puts it. Before, the clock followed it and the packets of the
    // next 131 ms were taken as reordered.
    let mut ahead = pk[50].clone();
    ahead[impair::TAIL_US + 2] ^= 0x02;
    input.insert(50, ahead);
    // Month 13; blocks out of order.
    let mut month = pk[30].clone();
    month[TAIL_DATE + 1] = 13;
    input.insert(30, month);
    let mut order = pk[40].clone();
    order.copy_within(BLOCK0..BLOCK0 + 2, BLOCK0 + 3 * BLOCK_LEN);
    input.insert(40, order);
    let (sweeps, stats) = assemble_counts(cal, &input);
    assert_eq!(complete_sizes(&sweeps), complete_sizes(&clean.0), "{sweeps:?}");
    assert_eq!(complete_sizes(&sweeps), [1800 * 64, 1800 * 64]);
    assert_eq!((stats.out_of_sequence, stats.corrupted, stats.lost), (3, 2, 0), "{stats:?}");
    assert_eq!((stats.resyncs, stats.reordered, stats.packets as usize), (0, 0, pk.len()));
}

#[test]
fn garbage_with_a_valid_header_costs_no_sweep() {
    let (cal, pk) = packets(Model::Pandar64, 3);
    let mut rng = Rng(15);
    let mut input = Vec::new();
    let mut garbage = 0;
    for p in &pk {
        if rng.chance(0.2) {
            input.push(header_garbage(&mut rng, p));
            garbage += 1;
        }
        input.push(p.clone());
    }
    let (sweeps, stats) = assemble_counts(cal, &input);
    println!("{garbage} garbage packets among {}: {stats:?}", pk.len());
    assert!(garbage > 150);
    assert_eq!(complete_sizes(&sweeps), [1800 * 64, 1800 * 64], "{sweeps:?}");
    assert_eq!(stats.corrupted + stats.out_of_sequence, garbage, "{stats:?}");
    assert_eq!((stats.lost, stats.packets as usize), (0, pk.len()));
}

#[test]
fn lost_packets_are_counted_exactly_through_reordering_and_duplicates() {
    let (cal, pk) = packets(Model::Pandar64, 3);
    let mut rng = Rng(20);
    let (mut input, mut held, mut lost) = (Vec::new(), None::<Vec<u8>>, 0u64);
    let last = pk.len() - 1;
    for (i, p) in pk.iter().enumerate() {
        // A loss at the very end leaves no later packet to show the gap.
        if i > 0 && i < last - 1 && rng.chance(0.2) {
            lost += 1;
            continue;
        }
        if held.is_none() && i > 0 && i < last && rng.chance(0.2) {
            held = Some(p.clone());
            continue;
        }
        input.push(p.clone());
        input.extend(held.take());
        if rng.chance(0.2) {
            input.push(p.clone());
        }
    }
    let (sweeps, stats) = assemble_counts(cal, &input);
    println!("{lost} lost: {stats:?}; sweeps (complete, points, packets, lost): {sweeps:?}");
    assert!(lost > 150 && stats.reordered > 80 && stats.duplicates > 100, "{stats:?}");
    assert_eq!(stats.lost, lost, "{stats:?}");
    assert_eq!(stats.packets + lost, pk.len() as u64);
    assert_eq!(stats.dropped(), stats.duplicates);
    // Each whole turn is 300 packets, sent or lost (a packet late across the cut may land
    // in the neighbouring sweep).
    let complete: Vec<_> = sweeps.iter().filter(|s| s.0).collect();
    assert_eq!(complete.len(), 2, "{sweeps:?}");
    for s in complete {
        assert!((298..=302).contains(&(s.2 + s.3)), "{s:?}");
        assert!(s.3 > 30, "{s:?}");
    }
}

#[test]
fn a_clock_jump_is_followed_after_packets_agree() {
    // A replay looped without new timestamps: the clock jumps back 0.3 s.
    let (cal, pk) = packets(Model::Pandar64, 3);
    let twice: Vec<Vec<u8>> = pk.iter().chain(&pk).cloned().collect();
    let (sweeps, stats) = assemble_counts(cal, &twice);
    assert_eq!(stats.resyncs, 1, "{stats:?}");
    // The packets that agreed on the new clock before it was taken, but the last.
    assert_eq!(stats.out_of_sequence, u64::from(sweep::RESYNC_AFTER) - 1);
    // Two whole turns per pass; the sweep spanning the jump is not handed out as complete.
    assert_eq!(complete_sizes(&sweeps), [1800 * 64; 4], "{sweeps:?}");
}

#[test]
fn valid_packets_of_another_clock_never_take_over_a_live_stream() {
    // Every fifth packet also arrives a day later (valid in every field, consistent with
    // each other): they are dropped; the live clock is kept and no sweep is lost.
    let (cal, pk) = packets(Model::Pandar64, 3);
    let mut input = Vec::new();
    for (i, p) in pk.iter().enumerate() {
        input.push(p.clone());
        if i % 5 == 0 {
            input.push(next_day(p));
        }
    }
    let (sweeps, stats) = assemble_counts(cal, &input);
    assert_eq!(complete_sizes(&sweeps), [1800 * 64, 1800 * 64], "{sweeps:?}");
    assert_eq!((stats.resyncs, stats.out_of_sequence as usize), (0, pk.len().div_ceil(5)));
}

/// Three turns (from a quarter turn on) of an OS1-32 (LEGACY, 1024×10, 16 columns a packet), every pixel at 5 m.
fn ouster_packets() -> (Calibration, Vec<Vec<u8>>) {
    use roomcal::lidar::ouster::{ColumnRepr, PixelRepr, Repr};
    let cal = Calibration::nominal(Model::Ouster);
    let g = cal.ouster;
    let (per_packet, per_turn) =
        (usize::from(g.columns_per_packet), usize::from(g.columns_per_frame));
    let column_ns = 1e9 / (per_turn as f64 * f64::from(g.frequency_hz));
    let pixel = PixelRepr { range: 5000, reflectivity: 9, ..PixelRepr::default() };
    let mut out = Vec::new();
    for packet in 0..3 * per_turn / per_packet {
        let mut repr = Repr::<32> {
            geometry: g,
            frame_id: 0,
            init_id: 0,
            serial: 0,
            columns: Default::default(),
        };
        for (c, col) in repr.columns.iter_mut().take(per_packet).enumerate() {
            // From a quarter turn on, so that the cut (behind) falls inside the turns.
            let column = packet * per_packet + c + per_turn / 4;
            *col = ColumnRepr {
                timestamp: 1_000_000_000 + (column as f64 * column_ns) as u64,
                measurement_id: (column % per_turn) as u16,
                frame_id: (column / per_turn) as u16,
                encoder_count: 0,
                status: 0xFFFF_FFFF,
                pixels: [pixel; 32],
            };
        }
        let mut bytes = vec![0u8; repr.buffer_len()];
        repr.emit(&mut bytes[..]).unwrap();
        out.push(bytes);
    }
    (cal, out)
}

#[test]
fn ouster_stream_drops_a_wild_and_a_torn_packet_not_the_sweep() {
    let (cal, pk) = ouster_packets();
    let run = |input: &[Vec<u8>]| {
        let mut buf = vec![Point::default(); 200_000];
        let mut asm = SweepAssembler::new(cal, SweepConfig::for_calibration(&cal), &mut buf);
        let mut sizes = Vec::new();
        for payload in input {
            asm.push(Model::Ouster.data_port(), payload, &mut |s| {
                sizes.push((s.complete, s.points.len()))
            });
        }
        (sizes.iter().filter(|s| s.0).map(|s| s.1).collect::<Vec<_>>(), asm.stats())
    };
    let (clean, stats) = run(&pk);
    assert_eq!(clean, [1024 * 32, 1024 * 32], "{stats:?}");
    assert_eq!((stats.dropped(), stats.lost), (0, 0), "{stats:?}");
    // Consistent in itself, the right time, a quarter turn on (every measurement id + 256):
    // before, Ouster packets were checked by time alone and its 512 points went into the
    // sweep a quarter turn off.
    let mut input = pk.clone();
    let mut wild = pk[20].clone();
    let column_len = 16 + 32 * 12 + 4;
    for c in 0..16 {
        let at = c * column_len + 8;
        let m = u16::from_le_bytes([wild[at], wild[at + 1]]);
        wild[at..at + 2].copy_from_slice(&((m + 256) % 1024).to_le_bytes());
    }
    input.insert(21, wild);
    // One column's measurement id torn (not its neighbours'): before, taken as it came.
    let mut torn = pk[40].clone();
    torn[5 * column_len + 8..5 * column_len + 10].copy_from_slice(&999u16.to_le_bytes());
    input.insert(41, torn);
    let (sizes, stats) = run(&input);
    assert_eq!(sizes, clean, "{stats:?}");
    assert_eq!((stats.out_of_sequence, stats.corrupted, stats.lost), (1, 1, 0), "{stats:?}");
}
