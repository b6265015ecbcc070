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
fn the_reader_wake_is_chosen_per_driver_and_service() {
    let default = with("").unwrap();
    assert_eq!(default.drivers[0].rt.options().reader_wake, skinware::ReaderWake::Ringer);
    let chosen = with("[driver.rt]\nreader_wake = \"lookout\"\n[[service]]\nname = \"c\"\nkind = \"contact\"\n[service.rt]\nreader_wake = \"writer\"\n").unwrap();
    assert_eq!(chosen.drivers[0].rt.options().reader_wake, skinware::ReaderWake::Lookout);
    assert_eq!(chosen.services[0].rt_options().reader_wake, skinware::ReaderWake::Writer);
    let err = format!("{:#}", with("[driver.rt]\nreader_wake = \"spin\"\n").unwrap_err());
    assert!(err.contains("unknown variant `spin`") && err.contains("lookout") && err.contains("ringer"), "{err}");
}

#[test]
fn services_are_checked() {
    let ok = with("[[service]]\nname = \"contact\"\nkind = \"contact\"\nrate_hz = 50\n[[service]]\nname = \"motion\"\nkind = \"motion\"\n").unwrap();
    assert_eq!(ok.services.len(), 2);
    assert_eq!(ok.services[1].mode(), skinware_services::framework::ServiceMode::Sporadic);
    assert_eq!(ok.services[0].rt_options().fifo_priority, None, "the normal scheduler unless asked");
    let rt = with(
        "[[service]]\nname = \"c\"\nkind = \"contact\"\nrate_hz = 1000\n[service.rt]\nfifo_priority = 60\ncpus = [1]\n",
    )
    .unwrap();
    assert_eq!((rt.services[0].rt_options().fifo_priority, rt.services[0].rt_options().cpus), (Some(60), vec![1]));
    let err = format!(
        "{:#}",
        with("[[service]]\nname = \"c\"\nkind = \"contact\"\n[service.rt]\npriority = 60\n").unwrap_err()
    );
    assert!(err.contains("unknown field `priority`"), "{err}");
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

/// Sizes that a few bytes of config asked for: terabytes of virtual body
/// (`sensors`), 16 GiB of uids (a module's `uid_range`), 20 s of generating
/// layers (`layers`). Each is refused before anything is allocated.
#[test]
fn sizes_the_text_does_not_justify_are_refused() {
    let err = format!("{:#}", with_driver("sensors = 99999999999\n").unwrap_err());
    assert!(err.contains("99999999999 sensors are more than a virtual skin may have (1000000)"), "{err}");
    let err = format!("{:#}", with_driver("sensors = 300000\nlayers = 300000\n").unwrap_err());
    assert!(err.contains("300000 layers are more than a virtual skin may have (1024)"), "{err}");
    let whole_u32 = EXPLICIT
        .replace("SENSORS", "15")
        .replace("UIDS", "13")
        .replace("uid_range = [1, 12]", "uid_range = [0, 4294967295]");
    let err = format!("{:#}", load(&whole_u32).unwrap_err());
    assert!(err.contains("module 1: the driver's layers hold more than 1000000 sensors"), "{err}");
    // The budget is over all the driver's modules, not per module.
    let two_halves = EXPLICIT
        .replace("sensors = SENSORS\n", "")
        .replace("uid_range = [1, 12]", "uid_range = [1, 600000]")
        .replace("uids = [UIDS]", "uid_range = [600001, 1200000]");
    let err = format!("{:#}", load(&two_halves).unwrap_err());
    assert!(err.contains("module 2: the driver's layers hold more than 1000000 sensors"), "{err}");
}

/// A region's `uid_range` is expanded into a list of uids that must all
/// exist: one wider than the skin is refused before it is expanded.
#[test]
fn region_ranges_wider_than_the_skin_are_refused() {
    assert!(with("[[region]]\nname = \"r\"\nuid_range = [1, 600]\n").is_ok());
    let err = format!("{:#}", with("[[region]]\nname = \"r\"\nuid_range = [1, 601]\n").unwrap_err());
    assert!(err.contains("uid_range [1, 601] spans 601 uids, more than the skin's 600 sensors"), "{err}");
    let in_layer = "[[region]]\nname = \"r\"\n[[region.in_layer]]\nlayer = \"v-0\"\nuid_range = [0, 999999]\n";
    let err = format!("{:#}", with(in_layer).unwrap_err());
    assert!(err.contains("spans 1000000 uids"), "{err}");
}

#[test]
fn slots_outside_the_channels_range_are_refused() {
    assert!(with_driver("slots = 64\n").is_ok());
    for slots in ["1", "65", "18446744073709551615"] {
        let err = format!("{:#}", with_driver(&format!("slots = {slots}\n")).unwrap_err());
        assert!(err.contains(&format!("slots = {slots} must be from 2 to 64")), "{err}");
    }
}

#[test]
fn error_positions_inside_a_character_do_not_panic() {
    let text = "a = \"é\"\nb";
    assert_eq!(line_column(text, 6), (1, 6));
    assert_eq!(line_column(text, 9), (2, 1));
    assert_eq!(line_column(text, 99), (2, 2));
}

fn with_driver(keys: &str) -> Result<Config> {
    load(&format!("[[driver]]\nname = \"v\"\nkind = \"virtual\"\n{keys}"))
}

#[test]
fn example_configs_load() {
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples");
    let mut loaded = 0;
    for entry in std::fs::read_dir(&examples).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let loading = Config::load(&path);
            // A ros2 driver needs DDS; without it, the config says how to get it.
            if !cfg!(feature = "dds") && path.ends_with("ros2-sensor.toml") {
                let Err(refusal) = loading else { panic!("a ros2 driver without DDS is refused") };
                let refusal = format!("{refusal:#}");
                assert!(refusal.contains("--features dds"), "{refusal}");
                continue;
            }
            loading.unwrap_or_else(|e| panic!("{}: {e:#}", path.display()));
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

const ETHERCAT: &str = "[[driver]]\nname = \"arm\"\nkind = \"ethercat\"\ninterface = \"eth0\"\nrate_hz = 1000\n[[driver.segment]]\nlayer = \"forearm\"\nvendor_id = 0x00534B4E\nproduct_code = 0x7AC7\ntaxels = 708\nsensors_per_module = 12\n[[driver.segment]]\nvendor_id = 0x00534B4E\nproduct_code = 0x7AC7\ntaxels = 30\nsensors_per_module = 12\n";

#[test]
fn ethercat_drivers_are_checked() {
    let config = load(ETHERCAT).unwrap();
    let layers = config.drivers[0].build("s").unwrap().layers();
    let shape: Vec<(&str, usize, usize)> =
        layers.iter().map(|l| (l.topology.name.as_str(), l.topology.sensors.len(), l.topology.modules.len())).collect();
    // 708 = 59 modules of 12; 30 = 12 + 12 + 6; the second layer is named after the driver.
    assert_eq!(shape, [("forearm", 708, 59), ("arm-1", 30, 3)]);
    assert_eq!(layers[0].topology.rate_hz, 1000.0);
    for (from, to, problem) in [
        ("interface = \"eth0\"\n", "", "needs `interface`"),
        ("interface = \"eth0\"", "interface = \"/dev/eth0\"", "not a network interface name"),
        ("taxels = 30\n", "taxels = 30\nmodules = [12, 18]\n", "not both"),
        ("taxels = 708", "taxels = 0", "1 to 2048"),
        // Counts from the file size nothing before they are checked.
        ("taxels = 708", "taxels = 1000000000000", "1 to 2048"),
        ("taxels = 708", "taxels = 18446744073709551615", "1 to 2048"),
        (
            "taxels = 30\nsensors_per_module = 12\n",
            "taxels = 30\nmodules = [18446744073709551615, 18446744073709551615]\n",
            "add up",
        ),
        ("sensors_per_module = 12\n[[driver.segment]]", "modules = [12, 12]\n[[driver.segment]]", "add up"),
        ("layer = \"forearm\"", "layer = \"arm-1\"", "its own layer"),
        ("rate_hz = 1000", "rate_hz = 1000\nframe_timeout_ms = 0", "frame_timeout_ms = 0"),
        ("rate_hz = 1000", "rate_hz = 1000\nprotocol = \"xela\"", "not a setting of kind = \"ethercat\""),
        ("product_code = 0x7AC7\ntaxels = 708", "taxels = 708", "missing field `product_code`"),
    ] {
        let err = load(&ETHERCAT.replace(from, to)).unwrap_err();
        assert!(format!("{err:#}").contains(problem), "{from} -> {to}: {err:#}");
    }
    let segments = ETHERCAT.split_once("[[driver.segment]]").unwrap().1;
    let err = load(&format!("{CAN}[[driver.segment]]{segments}")).unwrap_err();
    assert!(format!("{err:#}").contains("setting of kind = \"ethercat\""), "{err:#}");
    let err = load(&ETHERCAT.replace("[[driver.segment]]", "[[driver.segmentz]]")).unwrap_err();
    assert!(format!("{err:#}").contains("segmentz"), "{err:#}");
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

#[test]
fn ethercat_emulators_are_checked() {
    let emulator = "[[emulator]]\nname = \"segs\"\nkind = \"ethercat\"\ninterface = \"ecat-b\"\nsegments = 2\n";
    let config = load(&format!("{emulator}{ETHERCAT}")).unwrap();
    match config.emulators[0].emulation() {
        super::Emulation::Ethercat(e) => assert_eq!((e.segments, e.taxels, e.interface.as_str()), (2, 708, "ecat-b")),
        super::Emulation::Mtb(_) => panic!("an EtherCAT table built MTB boards"),
    }
    for (from, to, problem) in [
        ("interface = \"ecat-b\"\n", "", "needs `interface`"),
        ("segments = 2", "segments = 17", "1 to 16"),
        ("segments = 2", "segments = 2\nfault_segment = 2", "0 to 1"),
        ("segments = 2", "segments = 2\nboards = 2", "setting of kind = \"icub-mtb\""),
        ("segments = 2", "segments = 2\nleave_op_after_s = -1", "0 or more seconds"),
        ("segments = 2", "segments = 2\nlate_every = 5", "`late_every` and `late_by_ms` go together"),
        ("segments = 2", "segments = 2\nlate_by_ms = 40", "`late_every` and `late_by_ms` go together"),
    ] {
        let err = load(&format!("{}{ETHERCAT}", emulator.replace(from, to))).unwrap_err();
        assert!(format!("{err:#}").contains(problem), "{from} -> {to}: {err:#}");
    }
    let mtb = "[[emulator]]\nname = \"bus0\"\nkind = \"icub-mtb\"\nlink = \"/tmp/x\"\ntaxels = 5\n";
    let err = load(&format!("{mtb}{CAN}")).unwrap_err();
    assert!(format!("{err:#}").contains("setting of kind = \"ethercat\""), "{err:#}");
    let late = format!("{emulator}late_every = 5\nlate_by_ms = 40\n");
    match load(&format!("{late}{ETHERCAT}")).unwrap().emulators[0].emulation() {
        super::Emulation::Ethercat(e) => assert_eq!(
            (e.faults.late_every_nth_frame, e.faults.late_by),
            (std::num::NonZeroU64::new(5), std::time::Duration::from_millis(40))
        ),
        super::Emulation::Mtb(_) => panic!("an EtherCAT table built MTB boards"),
    }
    let mtb_late = mtb.replace("taxels = 5", "late_by_ms = 40");
    let err = load(&format!("{mtb_late}{CAN}")).unwrap_err();
    assert!(format!("{err:#}").contains("`late_by_ms` is a setting of kind = \"ethercat\""), "{err:#}");
}

#[test]
fn replay_drivers_are_checked_without_reading_their_file() {
    let base = "[[driver]]\nname = \"r\"\nkind = \"replay\"\n";
    let message = |text: &str| format!("{:#}", load(text).unwrap_err());
    assert!(message(base).contains("needs `file`"), "{}", message(base));
    let text = format!("{base}file = \"x.mcap\"\nspeed = 0\n");
    assert!(message(&text).contains("speed = 0 must be a positive number"), "{}", message(&text));
    let text = format!("{base}file = \"x.mcap\"\nsensors = 5\n");
    assert!(message(&text).contains("not a setting of kind = \"replay\""), "{}", message(&text));
    let text = format!("{base}file = \"x.mcap\"\nfrom_s = 5\nto_s = 2\n");
    assert!(message(&text).contains("to_s = 2 must be after from_s = 5"), "{}", message(&text));
    // Parsing reads no file; building the driver finds the recording missing.
    let config = load(&format!("{base}file = \"missing.mcap\"\n")).unwrap();
    let error = format!("{:#}", config.drivers[0].build("s").err().unwrap());
    assert!(error.contains("missing.mcap") && error.contains("is not a file"), "{error}");
}

/// Issue #38: a typo got the list of every key but not the one meant.
#[test]
fn unknown_keys_and_kinds_suggest_the_one_meant() {
    let err = format!("{:#}", with_driver("sensor_per_module = 12\n").unwrap_err());
    assert!(
        err.contains("test.toml:4:1: unknown field `sensor_per_module`; did you mean `sensors_per_module`? (expected one of `name`"),
        "{err}"
    );
    let err = format!("{:#}", load("[[driver]]\nname = \"v\"\nkind = \"virtul\"\n").unwrap_err());
    assert!(err.contains(":3:8:") && err.contains("unknown variant `virtul`; did you mean `virtual`?"), "{err}");
    let err = format!("{:#}", with("[driver.rt]\nfifo_priorty = 80\n").unwrap_err());
    assert!(err.contains("did you mean `fifo_priority`?"), "{err}");
    let err = format!("{:#}", with("[[region]]\nname = \"r\"\nlink = [\"torso\"]\n").unwrap_err());
    assert!(err.contains("did you mean `links`?"), "{err}");
    // Nothing close: the list alone, as before.
    let err = format!("{:#}", with_driver("colour = 1\n").unwrap_err());
    assert!(err.contains("unknown field `colour`, expected one of") && !err.contains("did you mean"), "{err}");
}

#[test]
fn unknown_layer_and_service_names_suggest_the_one_meant() {
    let region = "[[region]]\nname = \"r\"\n[[region.in_layer]]\nlayer = \"LAYER\"\npatches = [1]\n";
    assert!(with(&region.replace("LAYER", "v-1")).is_ok());
    let err = format!("{:#}", with(&region.replace("LAYER", "v1")).unwrap_err());
    assert!(
        err.contains(
            "region \"r\": layer \"v1\" is not a layer of this config; did you mean \"v-1\"? its layers: v-0, v-1"
        ),
        "{err}"
    );
    let err = format!("{:#}", with(&region.replace("LAYER", "torso")).unwrap_err());
    assert!(err.contains("layer \"torso\" is not a layer of this config; its layers: v-0, v-1"), "{err}");
    let services = "[[service]]\nname = \"contact\"\nkind = \"contact\"\nrate_hz = 50\n[[service]]\nname = \"motion\"\nkind = \"motion\"\ninput = \"INPUT\"\nrate_hz = 50\n";
    let err = format!("{:#}", with(&services.replace("INPUT", "contcat")).unwrap_err());
    assert!(
        err.contains("its input \"contcat\" is not a contact service of this config; did you mean \"contact\"?"),
        "{err}"
    );
    let err = format!("{:#}", with(&services.replace("INPUT", "touch")).unwrap_err());
    assert!(err.contains("the contact services: contact"), "{err}");
}

/// TOML's basic-string quoting of `text`, for keys made of any characters.
fn toml_quoted(text: &str) -> String {
    let mut quoted = String::from("\"");
    for c in text.chars() {
        match c {
            '"' => quoted.push_str("\\\""),
            '\\' => quoted.push_str("\\\\"),
            c if c.is_control() => quoted.push_str(&format!("\\U{:08X}", u32::from(c))),
            c => quoted.push(c),
        }
    }
    quoted.push('"');
    quoted
}

/// The keys of a `[[driver]]` table, as the parser's own report lists them.
fn driver_keys() -> Vec<String> {
    let err = format!("{:#}", with_driver("zzzzzzzzzzzzzzzz = 1\n").unwrap_err());
    let list = &err[err.find("expected one of").expect("the list of keys")..];
    list.split('`').skip(1).step_by(2).map(str::to_owned).collect()
}

mod properties {
    use proptest::prelude::*;

    use super::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(if cfg!(miri) { 4 } else { 256 }))]

        /// Any key, of any characters (backticks, quotes, controls, other
        /// scripts), is refused with its name, or suggested for, never a panic.
        #[test]
        fn arbitrary_keys_never_panic(key in "\\PC{0,24}|[a-z_`]{0,24}|sensors?_?per_?modu?le?s?") {
            let keys = driver_keys();
            let result = with_driver(&format!("{} = 1\n", toml_quoted(&key)));
            if keys.contains(&key) {
                return Ok(());
            }
            let err = format!("{:#}", result.expect_err("an unknown key is refused"));
            prop_assert!(err.contains(&format!("unknown field `{key}`")), "{}", err);
            if let Some(at) = err.find("did you mean `") {
                let suggested = &err[at + "did you mean `".len()..];
                let suggested = &suggested[..suggested.find('`').unwrap()];
                prop_assert!(keys.iter().any(|k| k == suggested), "{}", err);
            }
        }

        /// Text shaped like a config, with any keys and values: a config or
        /// an error, never a panic (the fuzz target `config` does the same
        /// with arbitrary bytes).
        #[test]
        fn arbitrary_toml_never_panics(
            lines in proptest::collection::vec(
                "\\[\\[(driver|region|service)\\]\\]|\\[driver\\.(rt|restart)\\]|[a-z_]{1,18} = (\"[a-z0-9-]{0,10}\"|[0-9]{1,4}|true|\\[[0-9, ]{0,8}\\])|\\PC{0,20}",
                0..14,
            )
        ) {
            let _ = load(&lines.join("\n"));
        }
    }
}
