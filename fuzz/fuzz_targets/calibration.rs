//! Fuzzes the Hesai CSV, Velodyne YAML and Ouster metadata json calibration parsers: errors, never panics, and
//! accepted tables have sane values.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use roomcal::lidar::calibration::{parse_hesai_csv, parse_ouster_json, parse_velodyne_yaml};
use roomcal::lidar::Model;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    for model in Model::ALL {
        let parsed = if model == Model::Ouster {
            parse_ouster_json(text, Path::new("fuzz.json"))
        } else if model.is_velodyne() {
            parse_velodyne_yaml(model, text, Path::new("fuzz.yaml"))
        } else {
            parse_hesai_csv(model, text, Path::new("fuzz.csv"))
        };
        if let Ok(cal) = parsed {
            assert!(cal.active().iter().all(|l| l.elevation.abs() <= core::f32::consts::FRAC_PI_2));
        }
    }
});
