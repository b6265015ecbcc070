//! What a driver process tells the other commands about itself: its kind
//! and its layers (so that `skin pull` knows whether a layer has a cable it
//! can pull), and for `skin ls` its devices: each EtherCAT SubDevice's
//! identity, AL state and fault.
//!
//! The driver process writes it every [`PUBLISH_EVERY`] as a small JSON file
//! beside the channels (`skinware-driver.SKIN.DRIVER.json` in the segment
//! directory), written to a temporary file and renamed so that a reader sees
//! one whole version. It is removed when the driver stops; a crashed driver's
//! file is recognised by its dead process or its age, left out of listings,
//! and removed by `skin clean` (as is a temporary file it left).
//!
//! Status travels as a file and not as a channel because it changes a few
//! times a second at most and is read by people and scripts. It is gathered
//! without waiting for the driver's real-time threads (see
//! `skinware_drivers::ethercat::EthercatStatus`).

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::{Deserialize, Serialize};

/// How often a driver process rewrites its status.
pub const PUBLISH_EVERY: Duration = Duration::from_millis(200);

/// A status not rewritten for this long belongs to a driver that is stuck or
/// gone, even if its process id is alive (a reused id, a stopped process).
pub const STALE_AFTER: Duration = Duration::from_secs(3);

/// Most bytes a status file may have: a driver has at most a few dozen
/// devices; anything bigger is not ours.
pub const MAX_STATUS_BYTES: usize = 1 << 20;

/// One driver's status.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DriverStatus {
    /// The skin it belongs to.
    pub skin: String,
    /// The driver's name in the config.
    pub driver: String,
    /// Its `kind` in the config (`virtual`, `can`, `ethercat`, `replay`).
    pub kind: String,
    /// The layers it writes (absent in the files of older versions, which
    /// only EtherCAT drivers wrote).
    #[serde(default)]
    pub layers: Vec<String>,
    /// The driver process.
    pub pid: u32,
    /// When this was written, CLOCK_MONOTONIC ns (the file never leaves the
    /// machine, and this clock does not jump with the wall clock).
    pub updated_ns: u64,
    /// Why the whole bus is down, while it is.
    pub bus_fault: Option<String>,
    /// Its devices, in bus order (none for a driver without devices of its
    /// own to report: the virtual skin, a replay, a CAN bus).
    pub devices: Vec<DeviceStatus>,
}

/// One device on a driver's bus (an EtherCAT SubDevice: one tactile segment).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DeviceStatus {
    /// Its position on the bus (0 first).
    pub position: usize,
    /// The layer it feeds.
    pub layer: String,
    /// Its name as it reports it (the SII's order code), once seen.
    pub name: String,
    /// Vendor ID, once seen.
    pub vendor_id: Option<u32>,
    /// Product code, once seen.
    pub product_code: Option<u32>,
    /// Revision, once seen.
    pub revision: Option<u32>,
    /// Serial number, once seen.
    pub serial: Option<u32>,
    /// Its state as last seen (`INIT`, `PRE-OP`, `SAFE-OP`, `OP`), empty before the first.
    pub state: String,
    /// Why its layer is faulted, if it is.
    pub fault: Option<String>,
    /// Cycles whose data it delivered.
    pub cycles: u64,
    /// Its newest sample counter.
    pub counter: u16,
    /// Faults it has had (a fault lasting several cycles counts once).
    pub faults: u64,
    /// Age of its newest good sample when this was written, ms; `None`
    /// before the first. A bus that stopped cycling shows here, whatever
    /// `state` last said.
    pub sample_age_ms: Option<f64>,
}

/// The status file of `driver` of `skin` in `dir`.
pub fn status_path(dir: &Path, skin: &str, driver: &str) -> PathBuf {
    dir.join(format!("skinware-driver.{skin}.{driver}.json"))
}

/// CLOCK_MONOTONIC ns, now: the clock of [`DriverStatus::updated_ns`].
pub fn now_ns() -> u64 {
    skinware::os::monotonic_ns()
}

/// Why a status file's bytes are not a driver status.
#[derive(Debug, thiserror::Error)]
pub enum StatusDecodeError {
    /// More bytes than any status has.
    #[error("{bytes} bytes, more than a driver status has ({MAX_STATUS_BYTES})")]
    TooLong {
        /// Its length.
        bytes: usize,
    },
    /// Not the JSON of a status.
    #[error("not a driver status: {0}")]
    NotAStatus(#[from] serde_json::Error),
}

impl DriverStatus {
    /// Decodes a status file's bytes.
    pub fn decode(bytes: &[u8]) -> Result<DriverStatus, StatusDecodeError> {
        if bytes.len() > MAX_STATUS_BYTES {
            return Err(StatusDecodeError::TooLong { bytes: bytes.len() });
        }
        Ok(serde_json::from_slice(bytes)?)
    }

    /// Writes it to its file in `dir`, whole: a temporary file renamed over it.
    pub fn publish(&self, dir: &Path) -> std::io::Result<PathBuf> {
        let path = status_path(dir, &self.skin, &self.driver);
        let bytes = serde_json::to_vec_pretty(self).map_err(std::io::Error::other)?;
        // A new file, named as skinware's temporary files are (so that `skin
        // clean` removes one left by a process killed before the rename),
        // renamed over the old: never a link followed or a FIFO opened that
        // someone left in the world-writable directory.
        skinware::shm::replace_file(&path, &bytes, 0o644)?;
        Ok(path)
    }

    /// Whether its driver is alive by the file's own account: its process
    /// exists and it was rewritten within [`STALE_AFTER`] of `now_ns`.
    pub fn is_live(&self, now_ns: u64) -> bool {
        let fresh = now_ns.saturating_sub(self.updated_ns) <= STALE_AFTER.as_nanos() as u64;
        fresh && Path::new("/proc").join(self.pid.to_string()).exists()
    }
}

/// A status file found in the segment directory.
#[derive(Debug)]
pub struct Found {
    /// Its path.
    pub path: PathBuf,
    /// What it says, or why it could not be read.
    pub status: Result<DriverStatus, String>,
}

/// Every driver status file in `dir`, of `skin` or of every skin.
pub fn find(dir: &Path, skin: Option<&str>) -> std::io::Result<Vec<Found>> {
    let mut found = Vec::new();
    let entries = match std::fs::read_dir(dir) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(found),
        Err(e) => return Err(e),
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some(rest) = name.strip_prefix("skinware-driver.").and_then(|r| r.strip_suffix(".json")) else {
            continue;
        };
        if skin.is_some_and(|skin| !rest.starts_with(&format!("{skin}."))) {
            continue;
        }
        let path = entry.path();
        let status = skinware::shm::read_regular(&path, MAX_STATUS_BYTES as u64)
            .map_err(|e| format!("cannot read it: {e}"))
            .and_then(|bytes| DriverStatus::decode(&bytes).map_err(|e| e.to_string()));
        found.push(Found { path, status });
    }
    found.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example() -> DriverStatus {
        DriverStatus {
            skin: "arm".into(),
            driver: "bus".into(),
            kind: "ethercat".into(),
            layers: vec!["forearm".into()],
            pid: std::process::id(),
            updated_ns: now_ns(),
            bus_fault: None,
            devices: vec![DeviceStatus {
                position: 0,
                layer: "forearm".into(),
                name: "SKIN-T708".into(),
                vendor_id: Some(0x0053_4B4E),
                product_code: Some(0x7AC7),
                revision: Some(1),
                serial: Some(1),
                state: "OP".into(),
                fault: None,
                cycles: 12,
                counter: 12,
                faults: 0,
                sample_age_ms: Some(0.4),
            }],
        }
    }

    #[test]
    #[cfg_attr(miri, ignore = "opens files, which Miri's isolation refuses")]
    fn published_status_is_found_whole_and_live() {
        let dir = std::env::temp_dir().join(format!("skinware-driver-status-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let status = example();
        let path = status.publish(&dir).unwrap();
        assert_eq!(path, status_path(&dir, "arm", "bus"));
        let found = find(&dir, Some("arm")).unwrap();
        assert_eq!(found.len(), 1);
        assert_eq!(found[0].status.as_ref().unwrap(), &status);
        assert!(status.is_live(now_ns()));
        // Nothing of the temporary file is left, and another skin sees nothing.
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        assert!(find(&dir, Some("ar")).unwrap().is_empty());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    #[cfg_attr(miri, ignore = "looks in /proc, which Miri's isolation refuses")]
    fn an_old_or_dead_status_is_not_live() {
        let mut status = example();
        assert!(!status.is_live(status.updated_ns + STALE_AFTER.as_nanos() as u64 + 1));
        status.pid = u32::MAX;
        assert!(!status.is_live(status.updated_ns));
    }

    #[test]
    fn a_status_of_an_older_version_has_no_layers() {
        let mut json = serde_json::to_value(example()).unwrap();
        json.as_object_mut().unwrap().remove("layers");
        let decoded = DriverStatus::decode(json.to_string().as_bytes()).unwrap();
        assert!(decoded.layers.is_empty());
        assert_eq!(decoded.devices, example().devices);
    }

    #[test]
    fn foreign_bytes_are_an_error_not_a_panic() {
        for bytes in [&b""[..], b"{", b"[]", b"{\"skin\":1}", &[0xff; 64]] {
            assert!(DriverStatus::decode(bytes).is_err(), "{bytes:?}");
        }
        assert!(DriverStatus::decode(&vec![b' '; MAX_STATUS_BYTES + 1]).unwrap_err().to_string().contains("more than"));
    }
}
