//! Parts of the command line that outgrew `main.rs`, one file per concern.

pub mod progress;
pub mod rig;
pub mod summary;
pub mod survey;
