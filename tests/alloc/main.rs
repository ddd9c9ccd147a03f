//! The allocation tests: they count or bound heap allocations through this binary's
//! global allocator (`counting_alloc`), which tracks each thread on its own, so these
//! tests share one binary and still run in parallel. They are kept apart from
//! `tests/it` so that a binary's one global allocator is theirs alone.

#[path = "../common/mod.rs"]
mod common;
mod counting_alloc;

mod chessboard_alloc;
mod holes_alloc;
mod hostile_alloc;
mod pcd;
mod solve_alloc;
mod solve_room;
