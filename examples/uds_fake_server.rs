//! A UDS server with an in-memory fake backend on a socketcand endpoint, for bench
//! tools and `scripts/uds_interop.py` (python-can + can-isotp + udsoncan).
//!
//! `cargo run --example uds_fake_server -- [--listen 127.0.0.1:0] [--channel can0]
//!  [--secret-file FILE | --secret TEXT] [--run-polls N] [--no-padding]`
//!
//! Prints `listening on HOST:PORT` once ready; stops on end of standard input or Ctrl-C.

use std::process::ExitCode;

use roomcal::service::driver::{serve, OsRandom};
use roomcal::service::fake::FakeBackend;
use roomcal::service::isotp::Config;
use roomcal::service::socketcand::SocketcandServer;
use roomcal::service::uds::{Server, ServerConfig};
use roomcal::service::{DEFAULT_REQUEST_ID, DEFAULT_RESPONSE_ID};
use tokio::io::AsyncReadExt;

struct Args {
    listen: String,
    channel: String,
    secret: Vec<u8>,
    run_polls: u32,
    padding: bool,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        listen: "127.0.0.1:29536".into(),
        channel: "can0".into(),
        secret: b"roomcal-test-secret".to_vec(),
        run_polls: 100,
        padding: true,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or(format!("{flag} needs a value"));
        match flag.as_str() {
            "--listen" => args.listen = value()?,
            "--channel" => args.channel = value()?,
            "--secret" => args.secret = value()?.into_bytes(),
            "--secret-file" => {
                let path = value()?;
                args.secret = roomcal::service::client::read_secret(path.as_ref())
                    .map_err(|e| e.to_string())?;
            }
            "--run-polls" => {
                args.run_polls = value()?.parse().map_err(|e| format!("--run-polls: {e}"))?
            }
            "--no-padding" => args.padding = false,
            other => return Err(format!("unknown argument `{other}`")),
        }
    }
    Ok(args)
}

#[tokio::main(flavor = "current_thread")]
async fn main() -> ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("uds_fake_server: {e}");
            return ExitCode::from(2);
        }
    };
    let mut transport = match SocketcandServer::bind(&args.listen, &args.channel).await {
        Ok(t) => t,
        Err(e) => {
            eprintln!("uds_fake_server: {e}");
            return ExitCode::from(2);
        }
    };
    let seeds = match OsRandom::open() {
        Ok(s) => s,
        Err(e) => {
            eprintln!("uds_fake_server: /dev/urandom: {e}");
            return ExitCode::from(2);
        }
    };
    println!("listening on {}", transport.local_addr());
    let mut backend = FakeBackend::calibrated();
    backend.run_polls = args.run_polls;
    let mut server = Server::new(backend, seeds, &args.secret, ServerConfig::default());
    let mut cfg = Config::new(DEFAULT_RESPONSE_ID, DEFAULT_REQUEST_ID);
    if !args.padding {
        cfg.padding = None;
    }
    let stop = async {
        let mut stdin = tokio::io::stdin();
        let mut buf = [0u8; 64];
        let eof = async { while stdin.read(&mut buf).await.is_ok_and(|n| n > 0) {} };
        tokio::select! {
            _ = eof => {}
            _ = tokio::signal::ctrl_c() => {}
        }
    };
    match serve(&mut transport, &mut server, cfg, stop).await {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("uds_fake_server: {e}");
            ExitCode::FAILURE
        }
    }
}
