//! `roomcal daemon`: the vehicle daemon — notices the room, calibrates, writes the store,
//! serves UDS — with the process set-up it needs (signals, the allocator's slack).

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;

use super::{bad_input, Failure};

#[derive(Args)]
pub struct DaemonArgs {
    /// The daemon configuration (TOML).
    #[arg(long)]
    config: PathBuf,
    /// Exit after the first calibration run ends.
    #[arg(long)]
    once: bool,
    /// With --once: give up (exit 1, saying what the daemon waited for) when no run has
    /// started this many seconds after the start.
    #[arg(long, value_name = "SECONDS", default_value_t = 600, requires = "once")]
    give_up_after: u64,
}

/// `roomcal daemon`: runs until stopped (or, with `--once`, until the first run ends);
/// prints the runs' tally.
pub fn run(args: DaemonArgs) -> Result<(), Failure> {
    use roomcal::daemon::{room_calibrator::RoomCalibrator, RunOptions};
    bound_allocator_slack();
    roomcal::daemon::init_logging();
    let config = roomcal::daemon::config::load(&args.config).map_err(bad_input)?;
    let room = roomcal::room::load(&config.room).map_err(bad_input)?;
    let mut calibrator = RoomCalibrator::new(room)
        .map_err(bad_input)?
        .with_lidar_angles(roomcal::daemon::room_calibrator::lidar_angles(&config));
    if let Some(rig) = &config.rig {
        calibrator = calibrator.with_rig(rig.rig.clone()).map_err(bad_input)?;
    }
    // A rig's report is one picture per camera, `last-run-NAME.png`.
    calibrator = calibrator.with_report(config.store.join("last-run.png"));
    let store = config.store.clone();
    let runtime = tokio::runtime::Runtime::new()
        .context("starting the async runtime")
        .map_err(|error| Failure::new(1, error))?;
    let summary = runtime
        .block_on(roomcal::daemon::run(
            config,
            calibrator,
            RunOptions {
                once: args.once,
                give_up_after: Some(std::time::Duration::from_secs(args.give_up_after)),
            },
            stop_signal(),
        ))
        .map_err(|e| Failure::new(1, e));
    // A run abandoned by a stop may still be calibrating on a blocking thread: nothing of it
    // can reach the store any more, so the stop does not wait for it (nor for a camera
    // read blocked on a silent device).
    runtime.shutdown_background();
    let summary = summary?;
    say!(
        "roomcal daemon: {} run(s): {} accepted, {} rejected, {} failed; generation {} in force",
        summary.runs,
        summary.accepted,
        summary.rejected,
        summary.failed,
        summary.generation()
    );
    if let Some(record) = &summary.in_force {
        say!("  in force    {}", super::summary::calibration_line(record.pair()));
        if let Some(rig) = record.rig() {
            say!(
                "  rig         {} sensors (above: the first camera and the first LiDAR)",
                rig.sensors.len()
            );
        }
        say!("  store       {}", store.join("current.json").display());
    }
    Ok(())
}

/// Resolves on SIGINT (a terminal) or SIGTERM (`systemctl stop`): either stops the daemon
/// gracefully, between store writes.
async fn stop_signal() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        if let Ok(mut term) = signal(SignalKind::terminate()) {
            tokio::select! {
                _ = tokio::signal::ctrl_c() => {}
                _ = term.recv() => {}
            }
            return;
        }
    }
    let _ = tokio::signal::ctrl_c().await;
}

/// Keeps glibc's allocator from holding on to freed memory (the daemon's peak RSS, issue
/// 17). By default glibc raises its mmap threshold whenever a large block is freed, so the
/// later frame- and sweep-sized buffers come from the heap and stay resident after use, and
/// each thread that allocates may get an arena of its own. A fixed 256 KiB threshold hands
/// every large buffer back to the kernel when it is freed, and two arenas bound the
/// threads' slack. The rig daemon's peak RSS (two 1920×1200 cameras, two LiDARs): 96–104 MB
/// without, 81–83 MB with (docs/design-notes.md, "Daemon and memory").
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[allow(unsafe_code)]
fn bound_allocator_slack() {
    use std::ffi::c_int;
    extern "C" {
        fn mallopt(param: c_int, value: c_int) -> c_int;
    }
    const M_MMAP_THRESHOLD: c_int = -3;
    const M_ARENA_MAX: c_int = -8;
    // SAFETY: mallopt only sets the allocator's parameters (glibc, <malloc.h>); it is called
    // before the runtime starts any thread. A refused setting (return 0) keeps the default.
    unsafe {
        mallopt(M_MMAP_THRESHOLD, 256 * 1024);
        mallopt(M_ARENA_MAX, 2);
    }
}

/// Other allocators keep their own policy.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn bound_allocator_slack() {}
