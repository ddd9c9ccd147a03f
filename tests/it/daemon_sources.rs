//! Sweep sources: pcap replay paced by tokio's (paused) clock, live UDP on localhost,
//! PCD replay looped. The packet tests use `../shared/data/pcap` and skip without it.

use std::path::{Path, PathBuf};
use std::time::Duration;

use roomcal::daemon::sources::{self, PcdReplay, SweepSource};
use roomcal::lidar::{pcd, Calibration, Model, Point};

use crate::common::scratch::Scratch;

fn vlp16_pcap() -> Option<PathBuf> {
    let p = Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../shared/data/pcap/velodyne-vlp16/velodyne-vlp16.pcap"
    ));
    if p.exists() {
        Some(p.to_path_buf())
    } else {
        crate::common::skipped(format_args!("{} not found", p.display()));
        None
    }
}

#[tokio::test(start_paused = true)]
async fn pcap_replay_runs_at_the_capture_pace() {
    let Some(path) = vlp16_pcap() else { return };
    let mut src = sources::pcap_replay(&path, Calibration::nominal(Model::Vlp16), 1.0).unwrap();
    let t0 = tokio::time::Instant::now();
    let mut times = Vec::new();
    // The capture holds 3 complete turns: the 4th and 5th come from the second pass.
    for _ in 0..5 {
        let s = src.next_sweep().await.unwrap();
        assert!(s.points.len() > 10_000, "a VLP-16 turn has ~15k returns, got {}", s.points.len());
        times.push((t0.elapsed().as_secs_f64(), s.time));
    }
    // Replay time between sweeps follows the sensor's clock (10 Hz turns).
    for w in times[..3].windows(2) {
        let replay = w[1].0 - w[0].0;
        let sensor = w[1].1 - w[0].1;
        assert!((replay - sensor).abs() < 0.01, "replay {replay:.4} s vs sensor {sensor:.4} s");
        assert!(replay > 0.05 && replay < 0.2, "{replay}");
    }
}

#[tokio::test]
async fn udp_live_assembles_sweeps_from_localhost_packets() {
    let Some(path) = vlp16_pcap() else { return };
    let (datagrams, _) = roomcal::lidar::pcap::read_udp(&path).unwrap();
    let port = std::net::UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let addr = format!("127.0.0.1:{port}").parse().unwrap();
    let mut src = sources::udp(addr, None, Calibration::nominal(Model::Vlp16)).await.unwrap();
    assert!(src.name().contains(&port.to_string()));
    let tx = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
    let sender = tokio::spawn(async move {
        for d in datagrams.iter().filter(|d| d.payload.len() == 1206) {
            tx.send_to(&d.payload, addr).await.unwrap();
            // Gentle pacing so the loopback buffer never overflows.
            tokio::time::sleep(Duration::from_micros(50)).await;
        }
    });
    let s = tokio::time::timeout(Duration::from_secs(20), src.next_sweep()).await.unwrap().unwrap();
    assert!(s.points.len() > 10_000, "{}", s.points.len());
    sender.abort();
}

#[tokio::test]
async fn udp_bind_error_names_the_address() {
    let taken = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap();
    let err = sources::udp(addr, None, Calibration::nominal(Model::Vlp16))
        .await
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains(&addr.to_string()), "{err}");
}

#[tokio::test(start_paused = true)]
async fn pcd_folder_replays_in_order_and_loops() {
    let dir = Scratch::new("pcdreplay");
    for n in 1..=2usize {
        let pts = vec![Point { x: n as f32, ..Point::default() }; n];
        pcd::write(dir.join(format!("{n}.pcd")), &pts, pcd::PcdFormat::Ascii).unwrap();
    }
    let mut src = PcdReplay::open(&dir, Duration::from_millis(100)).unwrap();
    let t0 = tokio::time::Instant::now();
    let lens: Vec<usize> = [0; 5].iter().map(|_| 0).collect();
    let mut got = Vec::new();
    for _ in lens {
        got.push(src.next_sweep().await.unwrap().points.len());
    }
    assert_eq!(got, [1, 2, 1, 2, 1]);
    assert_eq!(t0.elapsed(), Duration::from_millis(400));
    assert!(PcdReplay::open(&dir.join("none"), Duration::from_millis(100)).is_err());
}
