//! End to end over TCP: the UDS server with a fake backend on a socketcand endpoint
//! (127.0.0.1:0), our client reading every DID, unlocking, starting a calibration and
//! rolling back; the `roomcal query` library pieces; the socketcand handshake as
//! python-can expects it; and SocketCAN's error for a missing interface.
#![cfg(feature = "daemon")]

use std::time::Duration;

use roomcal::service::client::{
    query, ClientError, ClientTiming, QueryCommand, QueryOptions, UdsClient,
};
use roomcal::service::driver::{serve, OsRandom};
use roomcal::service::endpoint::Endpoint;
use roomcal::service::fake::FakeBackend;
use roomcal::service::isotp::Config;
use roomcal::service::socketcand::{SocketcandClient, SocketcandServer};
use roomcal::service::transport::{memory_pair, CanTransport, TransportError};
use roomcal::service::uds::{DaemonState, Server, ServerConfig, Session};
use roomcal::service::{CanFrame, DEFAULT_REQUEST_ID, DEFAULT_RESPONSE_ID};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::oneshot;

use crate::common::scratch::Scratch;

const SECRET: &[u8] = b"e2e vehicle secret";

/// Starts the library server with `backend` on a socketcand endpoint (127.0.0.1:0);
/// returns its address, a stop handle and the task, which ends with the backend.
pub(crate) async fn start_server(
    backend: FakeBackend,
) -> (String, oneshot::Sender<()>, tokio::task::JoinHandle<FakeBackend>) {
    let mut transport = SocketcandServer::bind("127.0.0.1:0", "can0").await.unwrap();
    let addr = transport.local_addr().to_string();
    let (stop, stopped) = oneshot::channel::<()>();
    let task = tokio::spawn(async move {
        let mut server =
            Server::new(backend, OsRandom::open().unwrap(), SECRET, ServerConfig::default());
        let cfg = Config::new(DEFAULT_RESPONSE_ID, DEFAULT_REQUEST_ID);
        serve(&mut transport, &mut server, cfg, async {
            let _ = stopped.await;
        })
        .await
        .unwrap();
        server.backend().clone()
    });
    (addr, stop, task)
}

#[tokio::test]
async fn client_reads_every_did_unlocks_starts_and_rolls_back() {
    let mut backend = FakeBackend::calibrated();
    backend.run_polls = 150; // 1.5 s: the client sees 0x78 first
    let expected = backend.clone();
    let (addr, stop, task) = start_server(backend).await;

    let transport = SocketcandClient::connect(&addr, "can0").await.unwrap();
    let mut c = UdsClient::with_defaults(transport);
    let state = c.status().await.unwrap();
    assert_eq!(state, expected.state);
    assert_eq!(Some(c.intrinsics().await.unwrap()), expected.intrinsics);
    assert_eq!(Some(c.extrinsic().await.unwrap()), expected.extrinsic);
    assert_eq!(Some(c.quality().await.unwrap()), expected.quality);

    // Routines need the extended session and security.
    match c.rollback().await {
        Err(ClientError::Negative { service: 0x31, nrc: 0x7F }) => {}
        other => panic!("expected 0x7F, got {other:?}"),
    }
    let (p2, p2_star) = c.session(Session::Extended).await.unwrap();
    assert_eq!((p2, p2_star), (Duration::from_millis(50), Duration::from_millis(5000)));
    match c.rollback().await {
        Err(ClientError::Negative { service: 0x31, nrc: 0x33 }) => {}
        other => panic!("expected 0x33, got {other:?}"),
    }
    match c.unlock(b"wrong secret").await {
        Err(ClientError::Negative { service: 0x27, nrc: 0x35 }) => {}
        other => panic!("expected 0x35, got {other:?}"),
    }
    c.unlock(SECRET).await.unwrap();
    let t0 = std::time::Instant::now();
    let outcome = c.start_calibration().await.unwrap();
    let took = t0.elapsed();
    assert_eq!(outcome.state, DaemonState::Accepted);
    assert_eq!(outcome.generation, expected.state.generation + 1);
    assert!(
        took >= Duration::from_millis(1400),
        "final answer came before the run ended: {took:?}"
    );
    assert_eq!(c.calibration_results().await.unwrap(), outcome);
    assert_eq!(c.rollback().await.unwrap(), expected.state.generation);
    c.tester_present().await.unwrap();
    println!("calibration round trip over socketcand took {took:?}");
    // Round-trip rate over loopback TCP (single and multi-frame responses).
    let t0 = std::time::Instant::now();
    for _ in 0..500 {
        assert_eq!(c.status().await.unwrap().generation, expected.state.generation);
        assert_eq!(Some(c.intrinsics().await.unwrap()), expected.intrinsics);
    }
    let dt = t0.elapsed();
    println!(
        "1000 ReadDataByIdentifier round trips over socketcand: {:.1} µs each",
        dt.as_secs_f64() * 1e6 / 1000.0
    );

    stop.send(()).unwrap();
    let backend = task.await.unwrap();
    assert_eq!(backend.runs_started, 1);
    assert_eq!(backend.state.generation, expected.state.generation);
}

#[tokio::test]
async fn query_pieces_print_every_did() {
    let (addr, stop, _task) = start_server(FakeBackend::calibrated()).await;
    let dir = Scratch::new("e2e");
    let secret_file = dir.join("secret");
    std::fs::write(&secret_file, [SECRET, b"\n"].concat()).unwrap();

    let mut opts = QueryOptions::new(&format!("socketcand:{addr}"));
    let status = query(&opts, QueryCommand::Status).await.unwrap();
    assert!(status.contains("generation: 7"), "{status}");
    assert!(status.contains("time:       2023-11-14T22:13:20Z"), "ISO 8601, UTC: {status}");
    let intr = query(&opts, QueryCommand::Intrinsics(None)).await.unwrap();
    assert!(intr.contains("pinhole-radtan") && intr.contains("1000.000, 1000.500"), "{intr}");
    let ext = query(&opts, QueryCommand::Extrinsic(None)).await.unwrap();
    assert!(ext.contains("x -0.2800 y -0.0500 z -0.4200 m in the camera's body frame"), "{ext}");
    let q = query(&opts, QueryCommand::Quality).await.unwrap();
    assert!(q.contains("boards:     6"), "{q}");
    for text in [&status, &intr, &ext, &q] {
        println!("{text}\n");
    }
    // start/rollback need the secret.
    assert!(matches!(
        query(&opts, QueryCommand::Rollback).await,
        Err(ClientError::NeedsSecret("rollback"))
    ));
    opts.secret_file = Some(dir.join("missing"));
    let err = query(&opts, QueryCommand::Start).await.unwrap_err();
    assert!(err.to_string().contains("missing"), "{err}");
    opts.secret_file = Some(secret_file);
    let started = query(&opts, QueryCommand::Start).await.unwrap();
    assert_eq!(started, "calibration accepted; generation in force: 8");
    let rolled = query(&opts, QueryCommand::Rollback).await.unwrap();
    assert_eq!(rolled, "rolled back; generation in force: 7");
    assert!("reboot".parse::<QueryCommand>().is_err());
    stop.send(()).unwrap();

    // Refusals are explained in the daemon's terms: nothing calibrated, nothing older.
    let (addr, stop, _task) = start_server(FakeBackend::empty()).await;
    let mut opts = QueryOptions::new(&format!("socketcand:{addr}"));
    let err = query(&opts, QueryCommand::Intrinsics(None)).await.unwrap_err();
    assert!(matches!(err, ClientError::Refused { service: 0x22, nrc: 0x22, .. }), "{err}");
    assert!(err.to_string().contains("no calibration in force"), "{err}");
    opts.secret_file = Some(dir.join("secret"));
    let err = query(&opts, QueryCommand::Rollback).await.unwrap_err();
    assert!(err.to_string().contains("no earlier calibration"), "{err}");
    std::fs::write(dir.join("secret"), b"not the vehicle's").unwrap();
    let err = query(&opts, QueryCommand::Start).await.unwrap_err();
    assert!(err.to_string().contains("secret file does not match"), "{err}");
    stop.send(()).unwrap();
}

#[tokio::test]
async fn query_reads_every_sensor_of_a_rig_by_name_or_index() {
    let (addr, stop, _task) = start_server(FakeBackend::rig()).await;
    let opts = QueryOptions::new(&format!("socketcand:{addr}"));
    let ask = |q: &str| {
        let cmd = q.parse::<QueryCommand>().unwrap();
        let opts = opts.clone();
        async move { query(&opts, cmd).await }
    };
    let table = ask("sensors").await.unwrap();
    assert_eq!(table, "0: front (camera)\n1: wide (camera)\n2: top (LiDAR)\n3: bumper (LiDAR)");
    let wide = ask("intrinsics:wide").await.unwrap();
    assert!(wide.starts_with("camera wide (1):") && wide.contains("600.000, 600.250"), "{wide}");
    assert_eq!(ask("intrinsics:1").await.unwrap(), wide);
    let top = ask("extrinsic:top").await.unwrap();
    // Poses as people read them: in the first camera's body frame (x forward, y left, z
    // up), the expected figures from numpy (the records' quaternions through the optical →
    // body turn): the LiDAR at (z, -x, -y) of its optical translation, the wide camera
    // turned 30° about the optical y axis, i.e. yaw -30° about the body's z.
    assert!(top.contains("in the first camera's body frame"), "{top}");
    assert!(top.contains("x -0.2800 y -0.0500 z -0.4200 m"), "{top}");
    let wide_pose = ask("extrinsic:wide").await.unwrap();
    assert!(wide_pose.contains("roll 0.000° pitch 0.000° yaw -30.000°"), "{wide_pose}");
    assert!(wide_pose.contains("x 0.1000 y -0.4000 z 0.0000 m"), "{wide_pose}");
    // A sensor the vehicle lacks is named with the ones it has; a LiDAR has no intrinsics;
    // an uncalibrated sensor is explained.
    let err = ask("intrinsics:rear").await.unwrap_err();
    assert_eq!(
        err.to_string(),
        "no sensor `rear` on this vehicle; its sensors: front, wide, top, bumper"
    );
    let err = ask("intrinsics:top").await.unwrap_err();
    assert!(err.to_string().contains("no such sensor (or a LiDAR"), "{err}");
    let err = ask("extrinsic:bumper").await.unwrap_err();
    assert!(err.to_string().contains("no calibration in force"), "{err}");
    for bad in ["quality:top", "intrinsics:", "sensor"] {
        assert!(bad.parse::<QueryCommand>().is_err(), "{bad}");
    }
    stop.send(()).unwrap();
}

#[tokio::test]
async fn socketcand_handshake_is_what_python_can_expects() {
    let mut server = SocketcandServer::bind("127.0.0.1:0", "can0").await.unwrap();
    let mut tcp = tokio::net::TcpStream::connect(server.local_addr()).await.unwrap();
    // python-can reads each greeting with one recv() and compares it exactly.
    async fn reply(tcp: &mut tokio::net::TcpStream) -> String {
        let mut buf = [0u8; 256];
        let n = tokio::time::timeout(Duration::from_secs(2), tcp.read(&mut buf))
            .await
            .unwrap()
            .unwrap();
        String::from_utf8(buf[..n].to_vec()).unwrap()
    }
    assert_eq!(reply(&mut tcp).await, "< hi >");
    tcp.write_all(b"< open vcan9 >").await.unwrap();
    assert!(reply(&mut tcp).await.starts_with("< error"));
    tcp.write_all(b"< open can0 >").await.unwrap();
    assert_eq!(reply(&mut tcp).await, "< ok >");
    tcp.write_all(b"< rawmode >").await.unwrap();
    assert_eq!(reply(&mut tcp).await, "< ok >");
    // python-can's send format: hex length, bytes without leading zeros.
    tcp.write_all(b"< send 7A0 8 2 10 3 cc cc cc cc cc >").await.unwrap();
    let f = tokio::time::timeout(Duration::from_secs(2), server.recv()).await.unwrap().unwrap();
    assert_eq!(
        f,
        CanFrame::new_standard(0x7A0, &[2, 0x10, 3, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC]).unwrap()
    );
    server.send(&CanFrame::new_standard(0x7A8, &[0x02, 0x7E, 0x00]).unwrap()).await.unwrap();
    let text = reply(&mut tcp).await;
    assert!(text.starts_with("< frame 7A8 ") && text.ends_with(" 027E00 >"), "{text}");
}

#[tokio::test]
async fn client_reports_timeouts_and_bad_endpoints() {
    // A socketcand bus with nobody answering 0x7A0.
    let server = SocketcandServer::bind("127.0.0.1:0", "can0").await.unwrap();
    let t = SocketcandClient::connect(&server.local_addr().to_string(), "can0").await.unwrap();
    let timing =
        ClientTiming { p2: Duration::from_millis(100), p2_star: Duration::from_millis(100) };
    let mut c = UdsClient::new(t, Config::new(DEFAULT_REQUEST_ID, DEFAULT_RESPONSE_ID), timing);
    let err = c.status().await.unwrap_err();
    assert!(matches!(err, ClientError::Timeout { service: 0x22, .. }), "{err}");

    for bad in [
        "can0",
        "socketcand:",
        "socketcand:host",
        "socketcand:h:99999",
        "socketcan:",
        "tcp:1.2.3.4:5",
    ] {
        assert!(matches!(Endpoint::parse(bad), Err(TransportError::BadEndpoint(_))), "{bad}");
    }
    assert_eq!(
        Endpoint::parse("socketcand:127.0.0.1:29536/vcan1").unwrap(),
        Endpoint::Socketcand { addr: "127.0.0.1:29536".into(), channel: "vcan1".into() }
    );
    // Nothing listens on this port (bound then released).
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let err = SocketcandClient::connect(&format!("127.0.0.1:{port}"), "can0").await.err().unwrap();
    assert!(err.to_string().contains(&format!("127.0.0.1:{port}")), "{err}");
}

#[tokio::test]
async fn missing_socketcan_interface_is_named() {
    let err = Endpoint::parse("socketcan:rcnocan7").unwrap().connect().await.err().unwrap();
    let text = err.to_string();
    assert!(matches!(err, TransportError::Open { .. }), "{text}");
    assert!(text.contains("rcnocan7"), "{text}");
    println!("{text}");
}

#[tokio::test]
async fn server_on_memory_bus_times_out_the_session() {
    let (mut bus, client_end) = memory_pair();
    let (stop, stopped) = oneshot::channel::<()>();
    let task = tokio::spawn(async move {
        let cfg = ServerConfig { s3: Duration::from_millis(200), ..ServerConfig::default() };
        let mut server =
            Server::new(FakeBackend::calibrated(), OsRandom::open().unwrap(), SECRET, cfg);
        let tp = Config::new(DEFAULT_RESPONSE_ID, DEFAULT_REQUEST_ID);
        serve(&mut bus, &mut server, tp, async {
            let _ = stopped.await;
        })
        .await
        .unwrap();
    });
    let mut c = UdsClient::with_defaults(client_end);
    c.session(Session::Extended).await.unwrap();
    c.unlock(SECRET).await.unwrap();
    // TesterPresent keeps the session; silence beyond S3 drops it (and the unlock).
    for _ in 0..4 {
        tokio::time::sleep(Duration::from_millis(100)).await;
        c.tester_present().await.unwrap();
    }
    assert_eq!(c.rollback().await.unwrap(), 6, "still extended and unlocked");
    tokio::time::sleep(Duration::from_millis(300)).await;
    match c.rollback().await {
        Err(ClientError::Negative { service: 0x31, nrc: 0x7F }) => {}
        other => panic!("expected 0x7F after S3, got {other:?}"),
    }
    stop.send(()).unwrap();
    task.await.unwrap();
}

/// Half-open connections (no handshake), silent clients and connections beyond the limit
/// are closed, so idle sockets cannot exhaust the daemon's file descriptors.
#[tokio::test]
async fn socketcand_closes_half_open_idle_and_excess_clients() {
    use roomcal::service::socketcand::Limits;
    let limits = Limits {
        max_clients: 4,
        handshake_timeout: Duration::from_millis(300),
        idle_timeout: Duration::from_millis(600),
    };
    let server = SocketcandServer::bind_with_limits("127.0.0.1:0", "can0", limits).await.unwrap();
    let addr = server.local_addr();
    // Reads until EOF (or 3 s): what the server sent before closing.
    async fn until_closed(tcp: &mut tokio::net::TcpStream) -> Option<String> {
        let mut all = Vec::new();
        let mut buf = [0u8; 256];
        loop {
            match tokio::time::timeout(Duration::from_secs(3), tcp.read(&mut buf)).await {
                Ok(Ok(0)) | Ok(Err(_)) => return Some(String::from_utf8_lossy(&all).into()),
                Ok(Ok(n)) => all.extend_from_slice(&buf[..n]),
                Err(_) => return None,
            }
        }
    }
    let mut idle = Vec::new();
    for _ in 0..4 {
        idle.push(tokio::net::TcpStream::connect(addr).await.unwrap());
    }
    tokio::time::sleep(Duration::from_millis(50)).await;
    let mut excess = tokio::net::TcpStream::connect(addr).await.unwrap();
    let said = until_closed(&mut excess).await.expect("the fifth connection is closed");
    assert!(said.contains("too many connections"), "{said}");
    let t0 = std::time::Instant::now();
    for tcp in &mut idle {
        assert_eq!(until_closed(tcp).await.as_deref(), Some("< hi >"), "closed after the greeting");
    }
    let took = t0.elapsed();
    println!("half-open connections closed after {took:?}");
    // Room again: a client completes the handshake, then stays silent and is closed.
    let mut client = SocketcandClient::connect(&addr.to_string(), "can0").await.unwrap();
    let got = tokio::time::timeout(Duration::from_secs(3), client.recv()).await;
    assert!(
        matches!(got, Ok(Err(TransportError::Closed { .. }))),
        "a silent client is closed: {got:?}"
    );
}
