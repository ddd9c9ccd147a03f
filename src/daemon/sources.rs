//! LiDAR sweep sources for the daemon (tokio): live UDP packets (optionally multicast),
//! pcap replay at the capture's own pace, and PCD replay (a file or a folder, looped).
//! Packet sources run a task that feeds a [`SweepAssembler`] and hands finished sweeps
//! over a small channel; a full channel drops sweeps instead of stalling the socket. Each
//! sweep carries its packet counts (decoded, lost, dropped), so a run on an incomplete
//! sweep can say so; the live UDP task logs, at most every [`REPORT_EVERY`], what it
//! dropped and, while no sweep completes, what it is waiting for. Packets of another model
//! than the configured one are named at the first one, by UDP and replay alike.

use std::future::Future;
use std::net::{Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::time::Duration;

use tokio::sync::mpsc;
use tokio::task::JoinHandle;

use crate::lidar::decoder::detect_model;
use crate::lidar::pcap::{read_udp, ReplayPacer};
use crate::lidar::{
    pcd, Calibration, Model, Point, Sweep, SweepAssembler, SweepConfig, SweepStats,
};

/// One sweep (or one replayed cloud), owned.
#[derive(Clone, Debug, PartialEq)]
pub struct OwnedSweep {
    pub points: Vec<Point>,
    /// Time of the first point (the sensor's clock), or replay time for PCD.
    pub time: f64,
    /// Its packets (all zero for a replayed cloud).
    pub counts: PacketCounts,
}

/// Packets of one sweep or of a run's sweeps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PacketCounts {
    /// Data packets decoded.
    pub packets: u64,
    /// Packets the sensor sent that never arrived (timestamp gaps).
    pub lost: u64,
    /// Payloads that arrived and were dropped (malformed, duplicate, out of sequence).
    pub dropped: u64,
}

impl PacketCounts {
    /// Adds another sweep's counts.
    pub fn add(&mut self, other: PacketCounts) {
        self.packets += other.packets;
        self.lost += other.lost;
        self.dropped += other.dropped;
    }

    /// "LiDAR sweep incomplete: 812 of 1800 packets lost (and 90 payloads dropped)" when
    /// packets were lost, else None: what a failed or rejected run's reason adds.
    pub fn incomplete(&self) -> Option<String> {
        if self.lost == 0 {
            return None;
        }
        let sent = self.packets + self.lost;
        let dropped = match self.dropped {
            0 => String::new(),
            n => format!(" (and {n} malformed, duplicate or out-of-sequence payloads dropped)"),
        };
        Some(format!("LiDAR sweep incomplete: {} of {sent} packets lost{dropped}", self.lost))
    }
}

impl std::fmt::Display for PacketCounts {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} packets decoded, {} lost, {} payloads dropped",
            self.packets, self.lost, self.dropped
        )
    }
}

/// Least time between two reports of the live UDP task.
pub const REPORT_EVERY: Duration = Duration::from_secs(5);

/// Errors of sweep sources; each names the socket or file.
#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    #[error("lidar udp {addr}: {source}")]
    Udp { addr: String, source: std::io::Error },
    #[error("lidar replay {path}: {message}")]
    Replay { path: PathBuf, message: String },
    #[error("lidar {0}: source ended")]
    Ended(String),
}

/// Sweeps from a sensor or a replay.
pub trait SweepSource: Send {
    /// What this source reads, for messages.
    fn name(&self) -> &str;
    /// The next sweep.
    fn next_sweep(&mut self) -> impl Future<Output = Result<OwnedSweep, SweepError>> + Send;
}

/// Most points a sweep may hold: a dual-return 64-laser unit at 5 Hz (3600 firings). The
/// assemblers grow to what the sensor really sends ([`SweepAssembler::growing`]).
const SWEEP_CAPACITY: usize = 2 * 64 * 3600;

/// A packet source: a task assembling sweeps, and the channel it fills.
pub struct PacketSweeps {
    name: String,
    rx: mpsc::Receiver<Result<OwnedSweep, SweepError>>,
    task: JoinHandle<()>,
}

impl Drop for PacketSweeps {
    fn drop(&mut self) {
        self.task.abort();
    }
}

impl SweepSource for PacketSweeps {
    fn name(&self) -> &str {
        &self.name
    }

    async fn next_sweep(&mut self) -> Result<OwnedSweep, SweepError> {
        self.rx.recv().await.unwrap_or_else(|| Err(SweepError::Ended(self.name.clone())))
    }
}

/// Assembles payloads into sweeps sent on `tx` (dropped when the receiver lags).
struct Feeder {
    asm: SweepAssembler<'static>,
    tx: mpsc::Sender<Result<OwnedSweep, SweepError>>,
    /// Complete sweeps handed on so far.
    sent: usize,
}

/// Owns a finished sweep, with its counts.
fn owned(s: &Sweep<'_>) -> OwnedSweep {
    OwnedSweep {
        points: s.points.to_vec(),
        time: s.start_time,
        counts: PacketCounts { packets: s.packets, lost: s.lost, dropped: s.dropped },
    }
}

impl Feeder {
    /// Feeds one payload; true when the assembler dropped it as no packet of its model
    /// (unknown, truncated, oversized or corrupted).
    fn push(&mut self, port: u16, payload: &[u8]) -> bool {
        let malformed = |s: SweepStats| s.unknown + s.truncated + s.oversized + s.corrupted;
        let before = malformed(self.asm.stats());
        let (tx, sent) = (&self.tx, &mut self.sent);
        self.asm.push(port, payload, &mut |s| {
            if s.complete {
                let _ = tx.try_send(Ok(owned(&s)));
                *sent += 1;
            }
        });
        malformed(self.asm.stats()) > before
    }

    /// The end of a replayed capture: a capture of exactly one turn (as the simulator
    /// writes, cut where the sensor cuts) never crosses the cut, so its only sweep is
    /// handed on here; in longer captures the trailing part-turn is dropped.
    fn end_of_capture(&mut self) {
        if self.sent > 0 {
            return;
        }
        let tx = &self.tx;
        self.asm.flush(&mut |s| {
            let _ = tx.try_send(Ok(owned(&s)));
        });
    }
}

/// Says once, at the first such payload, that a source's packets are another model's
/// (by size and magic, [`detect_model`]): a configured model that is not the sensor's
/// makes no sweep, and the operator must hear why at once, not from drop counts.
struct ForeignModel {
    name: String,
    model: Model,
    said: bool,
}

impl ForeignModel {
    fn new(name: &str, model: Model) -> Self {
        ForeignModel { name: name.to_string(), model, said: false }
    }

    /// Looks at a payload the assembler dropped.
    fn dropped(&mut self, payload: &[u8]) {
        if self.said {
            return;
        }
        let Some(other) = detect_model(payload).filter(|m| *m != self.model) else { return };
        self.said = true;
        tracing::warn!(
            "{}: its packets are a `{}`'s ({} bytes), not the configured `{}`'s: no sweep can \
             be made of them; check the LiDAR's `model` in the room file (or the rig file, or \
             the daemon's [lidar])",
            self.name,
            other.name(),
            payload.len(),
            self.model.name()
        );
    }
}

/// What the live task logs every [`REPORT_EVERY`]: the counters at the last report.
struct Reporter {
    stats: SweepStats,
    sent: usize,
    payloads: u64,
}

impl Reporter {
    /// Logs what changed since the last report: a warning naming what the assembler waits
    /// for when no sweep completed, a note of the drops when some did; nothing when all is
    /// well. `payloads` counts every datagram received.
    fn report(&mut self, name: &str, feeder: &Feeder, payloads: u64, cut_azimuth: u16) {
        let now = feeder.asm.stats();
        let was = std::mem::replace(&mut self.stats, now);
        let sent = std::mem::replace(&mut self.sent, feeder.sent);
        let received = payloads - std::mem::replace(&mut self.payloads, payloads);
        let drops = drop_summary(&was, &now);
        let (lost, secs) = (now.lost.saturating_sub(was.lost), REPORT_EVERY.as_secs());
        if feeder.sent == sent {
            let waiting = if received == 0 {
                "no datagrams at all".to_string()
            } else {
                format!(
                    "the azimuth to pass the cut at {:.2}° ({} points pending)",
                    f64::from(cut_azimuth) / 100.0,
                    feeder.asm.pending().len()
                )
            };
            tracing::warn!(
                "{name}: no complete sweep in {secs} s: {received} datagrams, {} decoded, {lost} \
                 lost, dropped {drops}; waiting for {waiting}",
                now.packets - was.packets
            );
        } else if now.dropped() > was.dropped() || lost > 0 {
            tracing::info!(
                "{name}: {} sweeps in {secs} s; {received} datagrams, {lost} lost, dropped {drops}",
                feeder.sent - sent
            );
        }
    }
}

/// "12 (3 duplicate, 9 corrupted)": payloads dropped between two counters, by reason.
fn drop_summary(was: &SweepStats, now: &SweepStats) -> String {
    let reasons = [
        ("duplicate", now.duplicates - was.duplicates),
        ("unknown", now.unknown - was.unknown),
        ("truncated", now.truncated - was.truncated),
        ("oversized", now.oversized - was.oversized),
        ("corrupted", now.corrupted - was.corrupted),
        ("out of sequence", now.out_of_sequence - was.out_of_sequence),
    ];
    let parts: Vec<String> =
        reasons.iter().filter(|r| r.1 > 0).map(|(what, n)| format!("{n} {what}")).collect();
    let total = now.dropped() - was.dropped();
    if parts.is_empty() {
        "0".into()
    } else {
        format!("{total} ({})", parts.join(", "))
    }
}

/// Live UDP: binds `addr` (joining `group` on all interfaces if given).
pub async fn udp(
    addr: SocketAddr,
    group: Option<Ipv4Addr>,
    cal: Calibration,
) -> Result<PacketSweeps, SweepError> {
    let err = |source| SweepError::Udp { addr: addr.to_string(), source };
    let socket = tokio::net::UdpSocket::bind(addr).await.map_err(err)?;
    if let Some(g) = group {
        socket.join_multicast_v4(g, Ipv4Addr::UNSPECIFIED).map_err(err)?;
    }
    let (tx, rx) = mpsc::channel(4);
    let name = format!("udp {addr}");
    let task_name = name.clone();
    let task = tokio::spawn(async move {
        let config = SweepConfig { data_port: addr.port(), ..SweepConfig::for_calibration(&cal) };
        let asm = SweepAssembler::growing(cal, config, SWEEP_CAPACITY);
        let mut feeder = Feeder { asm, tx, sent: 0 };
        // The largest UDP datagram: Ouster packets run to 33 KB (128 beams, dual returns).
        let mut packet = vec![0u8; 65_536];
        let mut reporter = Reporter { stats: SweepStats::default(), sent: 0, payloads: 0 };
        let mut foreign = ForeignModel::new(&task_name, cal.model);
        let mut payloads = 0u64;
        let mut report = tokio::time::interval(REPORT_EVERY);
        report.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        report.tick().await;
        loop {
            tokio::select! {
                got = socket.recv_from(&mut packet) => match got {
                    Ok((n, _)) => {
                        payloads += 1;
                        if feeder.push(addr.port(), &packet[..n]) {
                            foreign.dropped(&packet[..n]);
                        }
                    }
                    Err(source) => {
                        let e = SweepError::Udp { addr: task_name.clone(), source };
                        let _ = feeder.tx.send(Err(e)).await;
                        return;
                    }
                },
                _ = report.tick() => {
                    reporter.report(&task_name, &feeder, payloads, config.cut_azimuth);
                }
            }
        }
    });
    Ok(PacketSweeps { name, rx, task })
}

/// Replays a pcap/pcapng capture at its own pace (`speed` × real time), looped. Pacing
/// uses tokio's clock, so paused-clock tests run it instantly.
pub fn pcap_replay(path: &Path, cal: Calibration, speed: f64) -> Result<PacketSweeps, SweepError> {
    let (datagrams, _) = read_udp(path)
        .map_err(|e| SweepError::Replay { path: path.to_path_buf(), message: e.to_string() })?;
    let Some(first) = datagrams.first() else {
        return Err(SweepError::Replay {
            path: path.to_path_buf(),
            message: "no UDP datagrams".into(),
        });
    };
    let pacer = ReplayPacer::new(first.timestamp_ns).with_speed(speed);
    let (tx, rx) = mpsc::channel(4);
    let name = format!("replay {}", path.display());
    let mut foreign = ForeignModel::new(&name, cal.model);
    let task = tokio::spawn(async move {
        let config = SweepConfig::for_calibration(&cal);
        loop {
            // A fresh assembler per pass: the capture's clock jumps back when it loops, and
            // an assembler would keep those packets as reordered ones, never cutting.
            let asm = SweepAssembler::growing(cal, config, SWEEP_CAPACITY);
            let mut feeder = Feeder { asm, tx: tx.clone(), sent: 0 };
            let start = tokio::time::Instant::now();
            for d in &datagrams {
                let due = start + pacer.delay_until(d.timestamp_ns);
                if due > tokio::time::Instant::now() {
                    tokio::time::sleep_until(due).await;
                }
                if feeder.push(d.dst.port(), &d.payload) {
                    foreign.dropped(&d.payload);
                }
            }
            feeder.end_of_capture();
            if feeder.tx.is_closed() {
                return;
            }
            // The loop restarts one packet interval later, never in a busy loop.
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
    });
    Ok(PacketSweeps { name, rx, task })
}

/// Replays a PCD file or a folder of them (sorted by name), one cloud every `period`, looped.
pub struct PcdReplay {
    name: String,
    clouds: Vec<Vec<Point>>,
    next: usize,
    served: u64,
    period: Duration,
}

impl PcdReplay {
    /// Loads every cloud of `path`.
    pub fn open(path: &Path, period: Duration) -> Result<Self, SweepError> {
        let err = |message: String| SweepError::Replay { path: path.to_path_buf(), message };
        let files = if path.is_dir() {
            let mut v: Vec<PathBuf> = std::fs::read_dir(path)
                .map_err(|e| err(e.to_string()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|x| x.eq_ignore_ascii_case("pcd")))
                .collect();
            v.sort();
            v
        } else {
            vec![path.to_path_buf()]
        };
        let mut clouds = Vec::new();
        for f in &files {
            clouds.push(pcd::read(f).map_err(|e| err(e.to_string()))?);
        }
        if clouds.is_empty() {
            return Err(err("no PCD files".into()));
        }
        Ok(PcdReplay {
            name: format!("replay {}", path.display()),
            clouds,
            next: 0,
            served: 0,
            period,
        })
    }
}

impl SweepSource for PcdReplay {
    fn name(&self) -> &str {
        &self.name
    }

    async fn next_sweep(&mut self) -> Result<OwnedSweep, SweepError> {
        if self.served > 0 {
            tokio::time::sleep(self.period).await;
        }
        let points = self.clouds[self.next].clone();
        self.next = (self.next + 1) % self.clouds.len();
        let time = self.served as f64 * self.period.as_secs_f64();
        self.served += 1;
        Ok(OwnedSweep { points, time, counts: PacketCounts::default() })
    }
}

/// Any of the sweep sources, as the configuration chooses.
pub enum AnySweepSource {
    Packets(PacketSweeps),
    Pcd(PcdReplay),
}

impl SweepSource for AnySweepSource {
    fn name(&self) -> &str {
        match self {
            AnySweepSource::Packets(s) => s.name(),
            AnySweepSource::Pcd(s) => s.name(),
        }
    }

    async fn next_sweep(&mut self) -> Result<OwnedSweep, SweepError> {
        match self {
            AnySweepSource::Packets(s) => s.next_sweep().await,
            AnySweepSource::Pcd(s) => s.next_sweep().await,
        }
    }
}
