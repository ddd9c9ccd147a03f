//! The vehicle daemon (tokio): configuration, sources, the trigger, the calibration task,
//! the store and the UDS service.

pub mod trigger;
