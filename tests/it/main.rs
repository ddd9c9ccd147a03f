//! The integration tests, one module per subject, in one test binary: the library and
//! the `roomcal` binary are linked once for all of them. The allocation tests, which
//! install their own global allocator, are the other test crate (`tests/alloc`).
//! Helpers are in `tests/common` (`crate::common::…`).

#[path = "../common/mod.rs"]
mod common;

mod calibrate_band;
mod calibrate_detections;
mod calibrate_e2e;
mod calibrate_issue_room;
mod calibrate_pipeline;
mod calibrate_standing;
mod calibrate_surveyed;
mod chessboard_real;
mod chessboard_sim;
mod chessboard_synth;
mod cli_messages;
mod cli_progress;
mod daemon;
mod daemon_lockout_kill;
mod daemon_replay;
mod daemon_sources;
mod daemon_udp;
mod export;
mod fixtures;
mod geometry;
mod holes_expected;
mod holes_real;
mod holes_sim;
mod holes_structures;
mod holes_study;
mod hostile_cli;
mod lidar_decode_cli;
mod lidar_hesai_nebula;
mod lidar_ouster;
mod lidar_random_packets;
mod lidar_reference;
mod lidar_roundtrip;
mod lidar_sweep;
mod memory_budget;
mod pcap;
mod projection_gate;
mod report;
mod rig_calibrate;
mod rig_cli;
mod rig_file;
mod road_overlay;
mod room_file;
mod service_e2e;
mod service_flood;
mod service_isotp;
mod service_uds;
mod sim_capture;
mod sim_layout;
mod sim_scene;
mod solve_camera;
mod solve_init;
mod solve_lm;
mod solve_opencv;
mod solve_rig;
mod store;
mod store_concurrency;
mod survey_bundle;
mod survey_cli;
mod survey_detect;
mod survey_gauge;
mod survey_planes;
mod survey_room;
mod survey_sim;
mod surveyed_rooms;
mod trust;
