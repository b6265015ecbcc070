//! The config's checks, through `Config::load` of small configs.

use super::*;

fn load(text: &str) -> Result<Config> {
    let path = std::env::temp_dir().join(format!("skin-config-test-{}-{}.toml", std::process::id(), text.len()));
    std::fs::write(&path, text).unwrap();
    let result = Config::load(&path);
    let _ = std::fs::remove_file(&path);
    result
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
    let layers = driver.layers();
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
    // Resolving against the skin happens when the geometry is built.
    let config = with("[[region]]\nname = \"r\"\nlinks = [\"tail\"]\n").unwrap();
    let err = format!("{:#}", crate::geometry::load_or_build_in(&config, &std::env::temp_dir()).unwrap_err());
    assert!(err.contains("region \"r\": no sensor is on link \"tail\""), "{err}");
}

#[test]
fn a_skin_calib_calibration_is_imported() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/calibrated-hand.toml");
    let config = Config::load(&path).unwrap();
    let cache = std::env::temp_dir().join(format!("skin-calib-test-{}", std::process::id()));
    let (geometry, _) = crate::geometry::load_or_build_in(&config, &cache).unwrap();
    let _ = std::fs::remove_dir_all(&cache);
    assert_eq!(geometry.sensor_count(), 24);
    // uid 8: row 1, column 1 of the 5 mm grid.
    assert!((geometry.positions[7][0] - 0.005).abs() < 1e-6 && (geometry.positions[7][1] - 0.005).abs() < 1e-6);
    assert!((geometry.radii[0] - 0.002).abs() < 1e-7);
    assert_eq!(geometry.region("palm").unwrap().len(), 12);
    assert_eq!(geometry.links, ["palm", "fingers"]);
    // A missing calibration file is named.
    let broken = config.drivers[0].clone();
    let mut config = config;
    config.drivers = vec![crate::config::DriverConfig { calibration: Some("missing.calib".into()), ..broken }];
    let err = format!("{:#}", crate::geometry::load_or_build_in(&config, &std::env::temp_dir()).unwrap_err());
    assert!(err.contains("missing.calib") && err.contains("cannot read it"), "{err}");
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

const CAN: &str = "[[driver]]\nname = \"bus\"\nkind = \"can\"\ninterface = \"slcan:///dev/ttyACM0?bitrate=1000000\"\nprotocol = \"icub-mtb\"\n[[driver.board]]\naddress = 1\ntriangles = 16\n";

#[test]
fn can_drivers_are_checked() {
    let config = load(CAN).unwrap();
    let layers = config.drivers[0].build("s").unwrap().layers();
    assert_eq!((layers[0].topology.name.as_str(), layers[0].topology.sensors.len()), ("bus", 192));
    for (from, to, problem) in [
        ("interface = \"slcan:///dev/ttyACM0?bitrate=1000000\"\n", "", "needs `interface`"),
        ("slcan:///dev/ttyACM0?bitrate=1000000", "ttyACM0", "no scheme"),
        ("protocol = \"icub-mtb\"", "protocol = \"mtb\"", "unknown variant `mtb`"),
        ("address = 1", "address = 16", "1 to 15"),
        ("triangles = 16", "triangles = [0, 17]", "0 to 15"),
        ("[[driver.board]]\naddress = 1\ntriangles = 16\n", "", "[[driver.board]]"),
        ("kind = \"can\"", "kind = \"can\"\nsensors = 12", "setting of the virtual skin"),
    ] {
        let err = load(&CAN.replace(from, to)).unwrap_err();
        assert!(format!("{err:#}").contains(problem), "{from} -> {to}: {err:#}");
    }
    let err = load("[[driver]]\nname = \"v\"\nkind = \"virtual\"\nprotocol = \"xela\"\n").unwrap_err();
    assert!(format!("{err:#}").contains("setting of kind = \"can\""), "{err:#}");
}

#[test]
fn emulators_are_checked() {
    let emulator = "[[emulator]]\nname = \"bus0\"\nkind = \"icub-mtb\"\nlink = \"/tmp/x\"\n";
    assert!(load(&format!("{emulator}{CAN}")).is_ok());
    for (from, to, problem) in [
        ("link = \"/tmp/x\"\n", "", "either `link`"),
        (
            "link = \"/tmp/x\"\n",
            "link = \"/tmp/x\"\ncannelloni = \"127.0.0.1:1\"\npeer = \"127.0.0.1:2\"\n",
            "either `link`",
        ),
        ("kind = \"icub-mtb\"", "kind = \"icub-mtb\"\nboards = 16", "1 to 15"),
        ("kind = \"icub-mtb\"", "kind = \"icub-mtb\"\nrate_hz = 0", "rate_hz"),
    ] {
        let err = load(&format!("{}{CAN}", emulator.replace(from, to))).unwrap_err();
        assert!(format!("{err:#}").contains(problem), "{from} -> {to}: {err:#}");
    }
}
