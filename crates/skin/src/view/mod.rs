//! The web viewer: an HTTP server (std sockets, one thread per connection)
//! that serves one embedded page and streams the skin to it over a
//! WebSocket, in the compact binary format of [`protocol`] (see
//! `docs/viewer.md`).
//!
//! - [`server`]: HTTP, the page, the WebSocket upgrade;
//! - [`session`]: one browser: geometry, then credit-paced updates;
//! - [`sampler`]: the layers read in the browser's reader mode, newest only;
//! - [`overlays`]: the services' arrows and markers.

#![forbid(unsafe_code)]

pub mod overlays;
pub mod protocol;
pub mod sampler;
pub mod server;
pub mod session;

pub use server::{bind, serve};
pub use session::Site;

/// A virtual skin's geometry, as `skin run` would publish it, for the
/// viewer's tests: `sensors` taxels in two layers, `v-0` and `v-1`.
#[cfg(test)]
pub(crate) fn virtual_geometry(skin: &str, sensors: usize) -> skinware_geometry::SkinGeometry {
    let path = std::env::temp_dir().join(format!("skin-view-{skin}-{}.toml", std::process::id()));
    let config =
        format!("skin = \"{skin}\"\n[[driver]]\nname = \"v\"\nkind = \"virtual\"\nsensors = {sensors}\nlayers = 2\n");
    std::fs::write(&path, config).unwrap();
    let config = skin::config::Config::load(&path);
    let _ = std::fs::remove_file(&path);
    let (layers, calibration, regions) = crate::geometry::inputs(&config.unwrap()).unwrap();
    skinware_geometry::SkinGeometry::build(skin, &layers, &calibration, &regions).unwrap()
}
