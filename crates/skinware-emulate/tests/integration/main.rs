//! The emulators' integration tests, as one test binary (one link instead of
//! one per file): each emulated bus against the real driver, against
//! independent implementations of its protocol (ethercrab, python-can), and
//! over real kernel interfaces (pseudo-terminals, veth pairs).

mod ethercat_driver;
mod ethercat_ethercrab;
mod ethercat_veth;
mod python_can;
mod slcan_mtb;
