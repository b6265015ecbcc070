//! The decoders of the `skin` command line, as a library so that they can be
//! tested and fuzzed on their own (`fuzz/`): everything else of `skin` lives
//! in its binary.
//!
//! - [`config`]: the TOML configuration of `skin run` ([`config::Config`]),
//!   parsed and checked from text by [`config::Config::parse`];
//! - [`driver_status`]: what a driver process publishes of its devices (an
//!   EtherCAT SubDevice's identity and state) for `skin ls`, read back by
//!   [`driver_status::DriverStatus::decode`];
//! - [`report`]: an error's chain of causes for people, each cause once;
//! - [`suggest`]: "did you mean ...?" for a mistyped key, kind, skin or
//!   layer ([`suggest::closest`]).
//!
//! The decoder of the web viewer's messages is in `skinware-viewer`, with
//! the viewer.
//!
//! ```
//! use std::path::Path;
//!
//! let text = "skin = \"hand\"\n[[driver]]\nname = \"v\"\nkind = \"virtual\"\nsensors = 240\nlayers = 2\n";
//! let config = skin::config::Config::parse(text, Path::new("hand.toml"))?;
//! assert_eq!(config.drivers[0].name, "v");
//! # Ok::<(), anyhow::Error>(())
//! ```
//!
//! Cargo features: `cli` (default) builds the `skin` binary and its
//! dependencies (the web viewer, the CLI parser); the library needs none of
//! them, and the fuzz targets build it without (`default-features =
//! false`). `bench` adds `skin bench` (the benchmarks, their peers and
//! plots, which `skin run` and `skin demo` never use); `iceoryx2` adds
//! iceoryx2 to `skin bench peers`; `zenoh` adds `skin bridge`, `--remote`
//! and, with `bench`, `skin bench bridge`.

#![forbid(unsafe_code)]

pub mod config;
pub mod driver_status;
pub mod report;
pub mod suggest;
