//! One file per verb.

#[cfg(feature = "bench")]
pub mod bench;
pub mod bridge;
pub mod bridge_dds;
pub mod clean;
pub mod demo;
pub mod driver;
pub mod echo;
pub mod emulate;
pub mod geometry;
pub mod info;
pub mod ls;
pub mod pull;
pub mod record;
pub mod region;
pub mod replay;
pub mod run;
pub mod service;
pub mod services;
pub mod top;
pub mod view;
