//! Prints the REP-2016 type hash of every message the bridge knows.
fn main() {
    for t in skinware_bridge::ros2::MESSAGE_TYPES {
        println!("{} {}", t.name, skinware_bridge::ros2::type_hash(t.name).unwrap_or_default());
    }
}
