//! The drivers' integration tests, as one test binary (one link instead of
//! one per file).

mod can_replay;
mod geometry;
mod verify_pattern;
