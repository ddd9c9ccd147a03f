//! Synthetic calibration room with ground truth (filled by the simulator work).
