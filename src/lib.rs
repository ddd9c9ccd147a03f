//! # roomcal — joint camera intrinsic and LiDAR→camera extrinsic calibration
//!
//! A vehicle drives into a calibration room where several boards stand, each a
//! checkerboard with four circular holes around it. roomcal grabs one camera frame and
//! one LiDAR sweep, finds every board in both (ordered sub-pixel corners in the image,
//! hole centres in the cloud), associates them through the room's nominal mounting,
//! starts from a closed-form solution (homographies → Zhang → PnP → Kabsch) and refines
//! intrinsics, distortion, the LiDAR→camera extrinsic and every board pose in one
//! weighted, robust Levenberg–Marquardt problem. A quality gate decides whether the
//! result replaces the calibration in the vehicle config store.
//!
//! The method follows Yan et al., "Joint Camera Intrinsic and LiDAR-Camera Extrinsic
//! Calibration" (OpenCalib); see `DESIGN.md` beside the project for the interfaces.
//!
//! ## Features
//!
//! | feature  | default | what it adds |
//! |----------|---------|--------------|
//! | `std`    | yes     | files, images, JSON/TOML room and result files, the simulator, the CLI |
//! | `daemon` | yes     | the vehicle daemon (async runtime, CAN transports, systemd notify) |
//! | `v4l2`   | no      | V4L2 capture through the `v4l` crate (needs libclang at build time) |
//!
//! Without `std` the crate is `no_std` and allocation-free: the geometry core, the board
//! and room types, the solver, the LiDAR packet views and the service state machines.
//! Fixed-size `nalgebra` matrices and `heapless` containers only; time is passed in,
//! never read.

#![cfg_attr(not(feature = "std"), no_std)]
#![deny(unsafe_code)]

pub mod geometry;
pub mod lidar;
pub mod rig;
pub mod service;
pub mod solve;
pub mod target;

#[cfg(feature = "std")]
pub mod calibrate;
#[cfg(feature = "std")]
pub mod capture;
#[cfg(feature = "daemon")]
pub mod daemon;
#[cfg(feature = "std")]
pub mod detect;
#[cfg(feature = "std")]
pub mod export;
#[cfg(feature = "std")]
pub mod font;
#[cfg(feature = "std")]
pub mod parallel;
#[cfg(feature = "std")]
pub mod report;
#[cfg(feature = "std")]
pub mod result;
#[cfg(feature = "std")]
pub mod room;
#[cfg(feature = "std")]
pub mod sim;
#[cfg(feature = "std")]
pub mod store;
