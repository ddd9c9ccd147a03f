//! Fuzz target: the daemon configuration parser and its validation must never panic, and
//! an accepted configuration has every number in range (the daemon turns them into
//! `Duration`s, which panic on NaN or negative seconds).
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use roomcal::daemon::config::{parse, MAX_FRAMES, MAX_SECONDS};

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let Ok(config) = parse(text, Path::new("/etc/roomcal/fuzz.toml")) else { return };
    for s in [config.detect_interval_s, config.capture_timeout_s, config.trigger.settle_s] {
        assert!((0.0..=MAX_SECONDS).contains(&s), "{s}");
        let _ = std::time::Duration::from_secs_f64(s);
    }
    assert!(config.replay_fps > 0.0 && config.replay_speed > 0.0);
    let _ = std::time::Duration::from_secs_f64(1.0 / config.replay_fps);
    assert!((1..=MAX_FRAMES).contains(&config.frames) && (1..=MAX_FRAMES).contains(&config.sweeps));
});
