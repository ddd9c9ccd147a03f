//! `roomcal query`: asks the daemon over CAN (UDS on ISO-TP) for its status or results, or
//! starts a run.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;

use super::{bad_input, Failure};

#[derive(Args)]
pub struct QueryArgs {
    /// `socketcand:HOST:PORT[/CHANNEL]` or `socketcan:IFACE`.
    #[arg(long)]
    endpoint: String,
    /// status, sensors, intrinsics[:SENSOR], extrinsic[:SENSOR], quality, start or rollback
    /// (SENSOR: a name or an index from `sensors`).
    #[arg(default_value = "status")]
    command: String,
    /// The vehicle secret (needed for start and rollback).
    #[arg(long)]
    secret_file: Option<PathBuf>,
    /// CAN ID of requests (hex with 0x, or decimal).
    #[arg(long, default_value = "0x7A0", value_parser = parse_can_id)]
    request_id: u32,
    /// CAN ID of responses.
    #[arg(long, default_value = "0x7A8", value_parser = parse_can_id)]
    response_id: u32,
}

/// `roomcal query`: one request to the daemon over CAN; prints its answer.
pub fn run(args: QueryArgs) -> Result<(), Failure> {
    use roomcal::service::client::{query_blocking, QueryCommand, QueryOptions};
    let command: QueryCommand = args.command.parse().map_err(bad_input)?;
    let options = QueryOptions {
        request_id: args.request_id,
        response_id: args.response_id,
        secret_file: args.secret_file,
        ..QueryOptions::new(&args.endpoint)
    };
    let answer = query_blocking(&options, command)
        .with_context(|| format!("query {} over {}", args.command, args.endpoint))
        .map_err(|error| Failure::new(1, error))?;
    say!("{answer}");
    Ok(())
}

/// A CAN ID: hex with `0x`, or decimal; 29 bits at most.
fn parse_can_id(text: &str) -> Result<u32, String> {
    let parsed = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(hex, 16),
        None => text.parse(),
    };
    parsed.ok().filter(|&id| id < (1 << 29)).ok_or_else(|| format!("`{text}` is not a CAN ID"))
}
