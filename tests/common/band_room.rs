//! The design's room (config/room.toml) laid out for the LiDAR's dense band, as the
//! band-room calibration tests simulate it.

use std::path::Path;

use roomcal::sim::{ImageNoise, Layout, SimOptions};
use roomcal::target::Room;

/// The design's room file.
pub fn design_room() -> Room {
    roomcal::room::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml")))
        .unwrap()
}

/// Band layout with half the default sub-samples per axis (faster to render).
pub fn band_options(seed: u64) -> SimOptions {
    SimOptions {
        seed,
        layout: Layout::Band,
        image: ImageNoise { supersample: 2, ..ImageNoise::default() },
        ..SimOptions::default()
    }
}
