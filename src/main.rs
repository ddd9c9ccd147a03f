//! `roomcal`: the command line. Thin: parses arguments, calls the library, maps errors
//! to exit codes (0 accepted, 2 bad input, 3 rejected by the quality gate).

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "roomcal",
    version,
    about = "Joint camera intrinsic and LiDAR-camera extrinsic calibration"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {}
}
