//! The config's checks, through `Config::parse` of small configs (the
//! geometry they lead to is tested with the binary's `geometry` module).

use super::*;

fn load(text: &str) -> Result<Config> {
    Config::parse(text, Path::new("test.toml"))
}

#[test]
fn syntax_errors_name_line_and_column() {
    let err = load("skin = \"a\"\n[[driver]]\nname = \"v\"\nkind = \"virtual\"\nlayers = \"two\"\n").unwrap_err();
    let message = format!("{err:#}");
    assert!(message.contains(":5:10:"), "{message}");
    assert!(message.contains("invalid type"), "{message}");
}

#[test]
fn unknown_keys_are_rejected() {
    let err = load("[[driver]]\nname = \"v\"\nkind = \"virtual\"\nlayerz = 2\n").unwrap_err();
    let message = format!("{err:#}");
    assert!(message.contains(":4:1:") && message.contains("unknown field `layerz`"), "{message}");
}

#[test]
fn inconsistent_parameters_are_rejected() {
    let err = load("[[driver]]\nname = \"v\"\nkind = \"virtual\"\nsensors = 3\nlayers = 5\n").unwrap_err();
    assert!(format!("{err:#}").contains("3 sensors cannot be split over 5 layers"), "{err:#}");
    let err = load("[[driver]]\nname = \"v\"\nkind = \"virtual\"\n[[driver.cable_pull]]\nlayer = \"v-9\"\nat_s = 1\nduration_s = 1\n")
        .unwrap_err();
    assert!(format!("{err:#}").contains("v-9"), "{err:#}");
}

const EXPLICIT: &str = "[[driver]]\nname = \"v\"\nkind = \"virtual\"\nrate_hz = 50\n[[driver.layer]]\nname = \"palm\"\nsensors = SENSORS\n[[driver.layer.patch]]\nid = 1\n[[driver.layer.patch.module]]\nid = 1\nuid_range = [1, 12]\n[[driver.layer.patch.module]]\nid = 2\nuids = [UIDS]\n";

fn explicit(sensors: &str, uids: &str) -> Result<Config> {
    load(&EXPLICIT.replace("SENSORS", sensors).replace("UIDS", uids))
}

#[test]
fn explicit_topology_is_checked() {
    let config = explicit("15", "13, 14, 15").unwrap();
    let driver = config.drivers[0].build("s").unwrap();
    let layers = skinware::Driver::layers(&driver);
    assert_eq!(layers[0].topology.sensors.len(), 15);
    assert_eq!(layers[0].topology.rate_hz, 50.0);

    let err = format!("{:#}", explicit("15", "12, 14, 15").unwrap_err());
    assert!(err.contains("uid 12 appears more than once (modules 1 and 2)"), "{err}");
    let err = format!("{:#}", explicit("15", "").unwrap_err());
    assert!(err.contains("module 2 is empty"), "{err}");
    let err = format!(
        "{:#}",
        load("[[driver]]\nname = \"v\"\nkind = \"virtual\"\nrestart = { min_backoff_s = -1, max_backoff_s = 1 }\n")
            .unwrap_err()
    );
    assert!(err.contains("restart backoff"), "{err}");
    let err = format!("{:#}", explicit("20", "13, 14, 15").unwrap_err());
    assert!(err.contains("declares 20 sensors but its modules hold 15"), "{err}");
}

const DRIVER: &str = "[[driver]]\nname = \"v\"\nkind = \"virtual\"\nsensors = 600\nlayers = 2\n";

fn with(extra: &str) -> Result<Config> {
    load(&format!("{DRIVER}{extra}"))
}

#[test]
fn services_are_checked() {
    let ok = with("[[service]]\nname = \"contact\"\nkind = \"contact\"\nrate_hz = 50\n[[service]]\nname = \"motion\"\nkind = \"motion\"\n").unwrap();
    assert_eq!(ok.services.len(), 2);
    assert_eq!(ok.services[1].mode(), skinware_services::framework::ServiceMode::Sporadic);
    let err = format!("{:#}", with("[[service]]\nname = \"m\"\nkind = \"motion\"\nrate_hz = 50\n").unwrap_err());
    assert!(err.contains("service \"m\"") && err.contains("input \"contact\" is not a contact service"), "{err}");
    let err = format!("{:#}", with("[[service]]\nname = \"c\"\nkind = \"contact\"\nmin_speed = 1\n").unwrap_err());
    assert!(err.contains("`min_speed` does not apply to a contact service"), "{err}");
    let err = format!("{:#}", with("[[service]]\nname = \"c\"\nkind = \"contact\"\nrate_hz = -5\n").unwrap_err());
    assert!(err.contains("rate_hz -5 must be from 0.001 to 10000"), "{err}");
    let err = format!("{:#}", with("[[service]]\nname = \"v-1\"\nkind = \"contact\"\n").unwrap_err());
    assert!(err.contains("channel name \"v-1\" is used twice"), "{err}");
    let err = format!("{:#}", with("[[service]]\nname = \"c\"\nkind = \"vision\"\n").unwrap_err());
    assert!(err.contains(":8:8:") && err.contains("unknown variant `vision`"), "{err}");
}

#[test]
fn regions_are_checked() {
    let ok = with("[[region]]\nname = \"arms\"\nlinks = [\"left_forearm\"]\nmodules = [1]\nnear = { point = [0, 0, 1], radius = 0.1 }\n[[region.in_layer]]\nlayer = \"v-1\"\nuid_range = [400, 410]\n").unwrap();
    let spec = ok.regions[0].spec().unwrap();
    assert_eq!(spec.selectors.len(), 4);
    let err = format!("{:#}", with("[[region]]\nname = \"r\"\nuid_range = [9, 3]\n").unwrap_err());
    assert!(err.contains("uid_range [9, 3] is backwards"), "{err}");
    let err = format!("{:#}", with("[[region]]\nname = \"r\"\nlink = \"torso\"\n").unwrap_err());
    assert!(err.contains("unknown field `link`"), "{err}");
}

#[test]
fn example_configs_load() {
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples");
    let mut loaded = 0;
    for entry in std::fs::read_dir(&examples).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            Config::load(&path).unwrap_or_else(|e| panic!("{}: {e:#}", path.display()));
            loaded += 1;
        }
    }
    assert!(loaded >= 2);
}
