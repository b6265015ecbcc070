//! The services' integration tests, as one test binary (one link instead of
//! one per file).

mod framework;
mod scripted;
