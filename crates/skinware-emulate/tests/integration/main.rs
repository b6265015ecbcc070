//! The emulators' integration tests, as one test binary (one link instead of
//! one per file): each emulated bus against the real driver, against
//! independent implementations of its protocol (ethercrab, python-can), and
//! over real kernel interfaces (pseudo-terminals, veth pairs).

mod ethercat_driver;
mod ethercat_ethercrab;
mod ethercat_veth;
mod python_can;
mod slcan_mtb;

/// The real-time settings of the drivers under test, as a robot's driver
/// runs: SCHED_FIFO (the tests run as root; elsewhere the refusal is only
/// logged). A busy machine's normal threads then cannot stall the bus or a
/// layer past a frame timeout, and fault a segment a test did not touch.
fn driver_rt() -> skinware::RtOptions {
    skinware::RtOptions { fifo_priority: Some(80), ..Default::default() }
}
