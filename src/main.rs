//! `roomcal`: the command line. Thin: the subcommands (each `Args` + `run` in `cli/`),
//! dispatch, and the exit codes (0 accepted, 2 bad input, 3 rejected by the quality gate).

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cli;

#[derive(Parser)]
#[command(
    name = "roomcal",
    version,
    about = "Calibrates a vehicle's camera and LiDAR together from the boards of a calibration room.",
    after_help = "Example: roomcal calibrate --room room.toml --image image.png --cloud cloud.pcd \
                  --out result.json --report report.png\n\
                  Each subcommand's --help says what it is for, with an example."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Calibrates the camera (and the LiDAR→camera extrinsic) from image/cloud pairs.
    #[command(after_help = "Example: roomcal calibrate --room room.toml --image image.png \
                            --cloud cloud.pcd --out result.json --report report.png --export exports")]
    Calibrate(cli::calibrate::CalibrateArgs),
    /// Detects the boards in one image and/or one cloud and writes them as JSON.
    #[command(after_help = "Example: roomcal detect --room room.toml --image image.png \
                            --cloud cloud.pcd --out detections.json")]
    Detect(cli::detect::DetectArgs),
    /// Draws a cloud onto an image through a calibration, to check any calibration by eye.
    #[command(
        after_help = "Example: roomcal overlay --calibration result.json --image image.png \
                            --cloud cloud.pcd --out overlay.png"
    )]
    Overlay(cli::overlay::OverlayArgs),
    /// Renders a synthetic calibration room with ground truth (image, cloud, truth.json).
    #[command(after_help = "Example: roomcal simulate --room room.toml --out scene --seed 7")]
    Simulate(cli::simulate::SimulateArgs),
    /// Surveys the room: every board's pose and the big planes in one room frame, solved
    /// from several visits; writes the room file again with a [survey] table.
    #[command(after_help = "Example: roomcal survey --room room.toml --visit visit-01/image.png \
                            visit-01/cloud.pcd --visit visit-02/image.png visit-02/cloud.pcd \
                            --out surveyed.toml")]
    Survey(cli::survey::SurveyArgs),
    /// Runs the vehicle daemon: notices the room, calibrates, writes the store, serves UDS.
    #[cfg(feature = "daemon")]
    #[command(after_help = "Example: roomcal daemon --config config/replay.toml --once")]
    Daemon(cli::daemon::DaemonArgs),
    /// Decodes a LiDAR packet capture (pcap/pcapng) into a PCD cloud (x y z intensity ring).
    #[command(after_help = "Example: roomcal decode --lidar vlp16 capture.pcap --out cloud.pcd")]
    Decode(cli::decode::DecodeArgs),
    /// Asks the daemon over CAN (UDS on ISO-TP) for its status or results, or starts a run.
    #[command(after_help = "Example: roomcal query --endpoint socketcand:127.0.0.1:29536 status")]
    Query(cli::query::QueryArgs),
}

fn main() -> ExitCode {
    let outcome = match Cli::parse().command {
        Command::Calibrate(args) => cli::calibrate::run(args),
        Command::Detect(args) => cli::detect::run(args),
        Command::Overlay(args) => cli::overlay::run(args),
        Command::Simulate(args) => cli::simulate::run(args),
        Command::Survey(args) => cli::survey::run(args),
        #[cfg(feature = "daemon")]
        Command::Daemon(args) => cli::daemon::run(args),
        Command::Decode(args) => cli::decode::run(args),
        Command::Query(args) => cli::query::run(args),
    };
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(cli::Failure { code, error }) => {
            if let Some(error) = error {
                eprintln!("roomcal: {}", describe(&error));
            }
            ExitCode::from(code)
        }
    }
}

/// The error and its causes on one line, leaving out a cause its parent already quotes
/// (our file errors put their source in their own message).
fn describe(error: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in error.chain() {
        let part = cause.to_string();
        if !text.contains(&part) {
            if !text.is_empty() {
                text.push_str(": ");
            }
            text.push_str(&part);
        }
    }
    text
}
