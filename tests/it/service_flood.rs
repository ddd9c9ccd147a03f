//! A tester that floods the service with requests whose answers are segmented and never
//! sends the flow control they wait for, and first frames of requests it never finishes:
//! afterwards every request gets its own answer at once (no stale answer queued behind the
//! flood), an unanswered response is abandoned after N_Bs, and the log stays under one
//! warning a second. Through socketcand: the library server in process, and a real
//! `roomcal daemon` with `roomcal query`; on the in-memory bus with tokio's paused clock for
//! the N_Bs boundary.
#![cfg(all(unix, feature = "daemon"))]

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use roomcal::geometry::CameraModel;
use roomcal::service::client::UdsClient;
use roomcal::service::driver::{serve, OsRandom};
use roomcal::service::fake::FakeBackend;
use roomcal::service::isotp::Config;
use roomcal::service::socketcand::SocketcandClient;
use roomcal::service::transport::{memory_pair, CanTransport, MemoryTransport};
use roomcal::service::uds::{Server, ServerConfig};
use roomcal::service::{CanFrame, DEFAULT_REQUEST_ID, DEFAULT_RESPONSE_ID};
use roomcal::store::Store;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::oneshot;

use crate::common::results;
use crate::common::scratch::Scratch;

const SECRET: &[u8] = b"flood vehicle secret";
/// Requests (and unfinished requests) in a flood.
const FLOOD: usize = 1000;

/// N_Bs of the server (ISO 15765-2 default, `Config::new`).
fn n_bs() -> Duration {
    Config::new(DEFAULT_RESPONSE_ID, DEFAULT_REQUEST_ID).n_bs
}

/// The flood as socketcand `send` commands: FLOOD reads of 0xC001..0xC004 (each answer is
/// segmented: 12 to 41 bytes) never given flow control, each followed by the first frame
/// of a 10-byte request whose consecutive frames never come.
fn flood_commands() -> String {
    let mut text = String::new();
    for i in 0..FLOOD {
        let did = 1 + (i % 4);
        text.push_str(&format!("< send 7A0 4 03 22 C0 {did:02X} >"));
        text.push_str("< send 7A0 8 10 0A 22 C0 01 C0 02 C0 >");
    }
    text
}

/// A raw socketcand client that sends the flood in one write and reads (and drops) what
/// the bus sends back, so TCP never stalls; `quiet` tells when the server has stopped
/// answering it.
struct Flooder {
    tcp: tokio::net::tcp::OwnedWriteHalf,
    frames: Arc<AtomicUsize>,
    last_read: Arc<Mutex<Instant>>,
}

impl Flooder {
    async fn connect(addr: &str) -> Flooder {
        let tcp = tokio::net::TcpStream::connect(addr).await.unwrap();
        let (mut read, mut tcp) = tcp.into_split();
        tcp.write_all(b"< open can0 >< rawmode >").await.unwrap();
        let (oks, frames) = (Arc::new(AtomicUsize::new(0)), Arc::new(AtomicUsize::new(0)));
        let last_read = Arc::new(Mutex::new(Instant::now()));
        let (ok, seen, last) = (oks.clone(), frames.clone(), last_read.clone());
        tokio::spawn(async move {
            let mut buf = vec![0u8; 1 << 16];
            while let Ok(n @ 1..) = read.read(&mut buf).await {
                // Messages may be split across reads; counts are lower bounds, enough here.
                let text = String::from_utf8_lossy(&buf[..n]);
                ok.fetch_add(text.matches("< ok >").count(), Ordering::SeqCst);
                seen.fetch_add(text.matches("< frame 7A8").count(), Ordering::SeqCst);
                *last.lock().unwrap() = Instant::now();
            }
        });
        for _ in 0..500 {
            if oks.load(Ordering::SeqCst) >= 2 {
                return Flooder { tcp, frames, last_read };
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        panic!("no rawmode on {addr}");
    }

    async fn flood(&mut self) {
        self.tcp.write_all(flood_commands().as_bytes()).await.unwrap();
    }

    /// Waits until at least `min_frames` came back and then nothing for 300 ms.
    async fn quiet(&self, min_frames: usize) -> usize {
        let end = Instant::now() + Duration::from_secs(20);
        loop {
            tokio::time::sleep(Duration::from_millis(20)).await;
            let n = self.frames.load(Ordering::SeqCst);
            let silent = self.last_read.lock().unwrap().elapsed() > Duration::from_millis(300);
            if n >= min_frames && silent {
                return n;
            }
            assert!(Instant::now() < end, "the server still answers the flood after 20 s ({n})");
        }
    }
}

/// After a flood of unanswered requests and unfinished requests, a new tester reads every
/// DID and gets each one's own answer, at once (well within N_Bs); before, the answers to
/// the flood were queued and each waited N_Bs for flow control, so the tester's request
/// was dropped or answered with one of the flood's.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn after_a_flood_every_request_gets_its_own_answer_at_once() {
    let backend = FakeBackend::calibrated();
    let (addr, stop, _) = crate::service_e2e::start_server(backend.clone()).await;
    let mut flooder = Flooder::connect(&addr).await;
    flooder.flood().await;
    let seen = flooder.quiet(FLOOD / 2).await;
    println!(
        "the flood ({FLOOD} unanswered reads, {FLOOD} unfinished requests): {seen} frames back"
    );

    let t0 = Instant::now();
    let mut c = UdsClient::with_defaults(SocketcandClient::connect(&addr, "can0").await.unwrap());
    assert_eq!(c.status().await.unwrap(), backend.state);
    assert_eq!(Some(c.intrinsics().await.unwrap()), backend.intrinsics);
    assert_eq!(Some(c.extrinsic().await.unwrap()), backend.extrinsic);
    assert_eq!(Some(c.quality().await.unwrap()), backend.quality);
    let took = t0.elapsed();
    println!("four DIDs read right after the flood in {took:?}");
    assert!(took < n_bs(), "answered in {took:?}, not after the flood's N_Bs timeouts");
    stop.send(()).unwrap();
}

/// On the in-memory bus with a paused clock: 100 requests, each answered at once (its own
/// first frame); nothing is sent later (no answer queued); the last one is abandoned at
/// N_Bs: a flow control 10 ms before gets its consecutive frames, 10 ms after gets nothing.
#[tokio::test(start_paused = true)]
async fn each_request_answered_at_once_and_an_unanswered_one_abandoned_at_n_bs() {
    let (mut bus, mut tester) = memory_pair();
    let (stop, stopped) = oneshot::channel::<()>();
    let task = tokio::spawn(async move {
        let mut server = Server::new(
            FakeBackend::calibrated(),
            OsRandom::open().unwrap(),
            SECRET,
            ServerConfig::default(),
        );
        let tp = Config::new(DEFAULT_RESPONSE_ID, DEFAULT_REQUEST_ID);
        serve(&mut bus, &mut server, tp, async {
            let _ = stopped.await;
        })
        .await
        .unwrap();
    });
    let frame = |data: &[u8]| CanFrame::new_standard(DEFAULT_REQUEST_ID, data).unwrap();
    for i in 0..100u8 {
        let did = 1 + i % 4;
        tester.send(&frame(&[0x03, 0x22, 0xC0, did])).await.unwrap();
        let ff = recv(&mut tester, 10).await.expect("a first frame at once");
        assert_eq!((ff[0], &ff[2..5]), (0x10, &[0x62, 0xC0, did][..]), "request {i}: its own");
    }
    assert_eq!(recv(&mut tester, 3000).await, None, "nothing queued is sent later");
    tester.send(&frame(&[0x30, 0, 0])).await.unwrap();
    assert_eq!(recv(&mut tester, 100).await, None, "the last answer was abandoned at N_Bs");

    let n_bs = n_bs().as_millis() as u64;
    for (wait, continued) in [(n_bs - 10, true), (n_bs + 10, false)] {
        tester.send(&frame(&[0x03, 0x22, 0xC0, 0x02])).await.unwrap();
        let ff = recv(&mut tester, 10).await.unwrap();
        assert_eq!(&ff[..5], &[0x10, 41, 0x62, 0xC0, 0x02]);
        tokio::time::sleep(Duration::from_millis(wait)).await;
        tester.send(&frame(&[0x30, 0, 0])).await.unwrap();
        let mut cfs = Vec::new();
        while let Some(cf) = recv(&mut tester, 100).await {
            cfs.push(cf[0]);
        }
        let want: &[u8] = if continued { &[0x21, 0x22, 0x23, 0x24, 0x25] } else { &[] };
        assert_eq!(cfs, want, "flow control {wait} ms after the first frame");
    }
    tester.send(&frame(&[0x02, 0x3E, 0x00])).await.unwrap();
    assert_eq!(recv(&mut tester, 10).await.unwrap()[..3], [0x02, 0x7E, 0x00]);
    stop.send(()).unwrap();
    task.await.unwrap();
}

/// The next frame's data within `ms` (tokio's clock), `None` if the bus stays quiet.
async fn recv(t: &mut MemoryTransport, ms: u64) -> Option<Vec<u8>> {
    let got = tokio::time::timeout(Duration::from_millis(ms), t.recv()).await;
    got.ok().map(|f| f.unwrap().data.to_vec())
}

/// A replay daemon (manual trigger) with its service on `port` and a calibration in force.
fn daemon_config(dir: &Path, port: u16) -> std::path::PathBuf {
    let store = Store::open(dir.join("store"), 4).unwrap();
    store.commit(&results::result(CameraModel::PinholeRadtan).into(), 1_700_000_000).unwrap();
    crate::common::service_daemon_config(dir, port, b"flood test secret\n")
}

/// A spawned daemon, killed when dropped: a failed assert must not leave it running.
struct Daemon(Child);

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn query_extrinsic(port: u16) -> (i32, String, String, Duration) {
    let t0 = Instant::now();
    let endpoint = format!("socketcand:127.0.0.1:{port}");
    let (code, out, err) = crate::common::roomcal(&["query", "--endpoint", &endpoint, "extrinsic"]);
    (code, out, err, t0.elapsed())
}

fn warn_lines(log: &str) -> Vec<&str> {
    log.lines().filter(|l| l.contains(" WARN ")).collect()
}

/// The case against a real daemon: after the flood `roomcal query extrinsic` works
/// at once and answers what it answered before; the daemon's log holds at most one
/// warning line a second of the flood and its aftermath, and counts every abandoned answer.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn daemon_answers_query_extrinsic_after_a_flood_and_logs_at_most_a_line_a_second() {
    let dir = Scratch::new("service-flood");
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let config = daemon_config(&dir, port);
    let log_path = dir.join("daemon.log");
    let _daemon = Daemon(
        Command::new(crate::common::BIN)
            .args(["daemon", "--config", config.to_str().unwrap()])
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log_path).unwrap())
            .spawn()
            .unwrap(),
    );
    let addr = format!("127.0.0.1:{port}");
    let mut ready = false;
    for _ in 0..100 {
        if SocketcandClient::connect(&addr, "can0").await.is_ok() {
            ready = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(ready, "no daemon listening on {addr} after 10 s");
    let (code, before, err, _) = tokio::task::block_in_place(|| query_extrinsic(port));
    assert_eq!(code, 0, "query before the flood: {err}");

    let mut flooder = Flooder::connect(&addr).await;
    let logged_before = std::fs::read_to_string(&log_path).unwrap().len();
    let t0 = Instant::now();
    flooder.flood().await;
    flooder.quiet(FLOOD / 2).await;
    let (code, after, err, took) = tokio::task::block_in_place(|| query_extrinsic(port));
    println!("roomcal query extrinsic right after the flood: exit {code} in {took:?}");
    assert_eq!((code, after.as_str()), (0, before.as_str()), "query after the flood: {err}");
    assert!(took < n_bs() + Duration::from_millis(500), "answered in {took:?}");

    // Past every N_Bs and N_Cr the flood left running, then count.
    tokio::time::sleep(n_bs() + Duration::from_millis(500)).await;
    let window = t0.elapsed();
    let log = std::fs::read_to_string(&log_path).unwrap();
    let warnings = warn_lines(&log[logged_before..]);
    println!("{} warning lines in {window:?} of flood and aftermath:", warnings.len());
    for w in &warnings {
        println!("  {w}");
    }
    let allowed = window.as_secs() as usize + 1;
    assert!(warnings.len() <= allowed, "{} warning lines in {window:?}", warnings.len());
    // Each read of the flood was abandoned, the last one when the query came: every one is
    // in the log, as a line of its own or in a line's count.
    let reported: u64 = warnings.iter().map(|w| abandoned_in(w)).sum();
    assert_eq!(reported, FLOOD as u64, "abandoned answers the log accounts for");
}

/// Abandoned answers a warning line accounts for: one it names, plus the count of those
/// held back ("N more responses abandoned since the last warning").
fn abandoned_in(line: &str) -> u64 {
    let Some((_, text)) = line.split_once("roomcal service: ") else {
        return 0;
    };
    let before_count = text.split(" more responses abandoned").next().unwrap_or("");
    let held = before_count.rsplit(['(', ' ']).next().and_then(|n| n.parse().ok()).unwrap_or(0);
    u64::from(text.starts_with("response to service")) + held
}
