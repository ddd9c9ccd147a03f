//! Detection.
pub mod holes;
