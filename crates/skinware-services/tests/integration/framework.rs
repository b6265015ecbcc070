//! The service framework: typed records, both modes, and the checks a reader
//! gets when it attaches with the wrong type.

use std::time::Duration;

use skinware::{Error, FrameStatus, Stop, Writer, WriterOptions};
use skinware_services::framework::{
    ServiceMode, ServicePayload, ServiceReader, ServiceSpec, ServiceWriter, StepOutcome,
};

#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
struct Count {
    value: u64,
}

impl ServicePayload for Count {
    const SCHEMA: &'static str = "test.count";
    const VERSION: u32 = 2;
}

/// Same schema name, another layout: a reader built against an old version.
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
struct CountV1 {
    value: u32,
}

impl ServicePayload for CountV1 {
    const SCHEMA: &'static str = "test.count";
    const VERSION: u32 = 1;
}

/// Same schema and version, another size: a reader that lies about its type.
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
struct Impostor {
    value: u32,
}

impl ServicePayload for Impostor {
    const SCHEMA: &'static str = "test.count";
    const VERSION: u32 = 2;
}

fn skin(test: &str) -> String {
    format!("svc{test}{}", std::process::id())
}

#[test]
fn a_sporadic_service_answers_each_request() {
    let skin = skin("sporadic");
    let spec = ServiceSpec::new("counter", vec!["a".into(), "b".into()], ServiceMode::Sporadic);
    let mut service = ServiceWriter::<Count>::create(&skin, &spec, &WriterOptions::default()).unwrap();
    let stop = Stop::new();
    service.writer().set_stop(&stop);
    let thread = std::thread::spawn(move || {
        let mut steps = 0u64;
        service
            .run(|records: &mut [Count]| -> Result<StepOutcome, String> {
                steps += 1;
                records[0].value = steps;
                records[1].value = steps * 10;
                Ok(StepOutcome { status: FrameStatus::OK, acquired_ns: Some(42) })
            })
            .unwrap();
        steps
    });
    let mut reader = ServiceReader::<Count>::open(&skin, "counter").unwrap();
    assert_eq!(reader.labels(), ["a", "b"]);
    assert_eq!(reader.info().rate_hz, None);
    for expected in 1..=3u64 {
        let frame = reader.request(Duration::from_secs(5)).unwrap();
        assert_eq!(frame.records, [Count { value: expected }, Count { value: expected * 10 }]);
        assert_eq!(frame.acquired_ns, 42);
    }
    stop.stop();
    assert_eq!(thread.join().unwrap(), 3, "one step per request, none unasked");
}

#[test]
fn a_periodic_service_publishes_at_its_rate_and_flags_faulted_inputs() {
    let skin = skin("periodic");
    let spec = ServiceSpec::unlabelled("ticker", 1, ServiceMode::Periodic { hz: 200.0 });
    let mut service = ServiceWriter::<Count>::create(&skin, &spec, &WriterOptions::default()).unwrap();
    let stop = Stop::new();
    service.writer().set_stop(&stop);
    let thread = std::thread::spawn(move || {
        let mut steps = 0u64;
        service
            .run(|records: &mut [Count]| -> Result<StepOutcome, String> {
                steps += 1;
                records[0].value = steps;
                let status = if steps > 5 { FrameStatus::INPUT_FAULTED } else { FrameStatus::OK };
                Ok(StepOutcome { status, acquired_ns: None })
            })
            .unwrap();
    });
    let mut reader = ServiceReader::<Count>::open(&skin, "ticker").unwrap();
    assert_eq!(reader.info().rate_hz, Some(200.0));
    let mut last = 0;
    loop {
        let frame = reader.wait_newer(Duration::from_secs(5)).unwrap();
        assert!(frame.records[0].value > last);
        last = frame.records[0].value;
        assert_eq!(frame.status.contains(FrameStatus::INPUT_FAULTED), last > 5);
        if last > 8 {
            break;
        }
    }
    stop.stop();
    thread.join().unwrap();
}

#[test]
fn the_wrong_type_is_refused_with_a_typed_error() {
    let skin = skin("types");
    let spec = ServiceSpec::unlabelled("count", 4, ServiceMode::Periodic { hz: 10.0 });
    let mut service = ServiceWriter::<Count>::create(&skin, &spec, &WriterOptions::default()).unwrap();
    service.publish(&[Count { value: 1 }; 4], FrameStatus::OK).unwrap();
    assert!(matches!(service.publish(&[Count { value: 1 }; 3], FrameStatus::OK), Err(Error::InvalidLayout { .. })));

    match ServiceReader::<CountV1>::open(&skin, "count") {
        Err(Error::SchemaMismatch { found_version: 2, expected_version: 1, .. }) => {}
        other => panic!("expected a version mismatch, got {:?}", other.err()),
    }
    match ServiceReader::<Impostor>::open(&skin, "count") {
        Err(e @ Error::NotThisService { .. }) => assert!(e.to_string().contains("records are 8 bytes"), "{e}"),
        other => panic!("expected NotThisService, got {:?}", other.err()),
    }
    let _layer = Writer::create(&skin, "layer", 8, b"a layer", &WriterOptions::default()).unwrap();
    match ServiceReader::<Count>::open(&skin, "layer") {
        Err(e @ Error::NotThisService { .. }) => assert!(e.to_string().contains("it is a layer"), "{e}"),
        other => panic!("expected NotThisService, got {:?}", other.err()),
    }
    let bad = ServiceSpec::new("bad", vec!["two words".into()], ServiceMode::Sporadic);
    assert!(ServiceWriter::<Count>::create(&skin, &bad, &WriterOptions::default()).is_err());
    let bad_rate = ServiceSpec::unlabelled("rate", 1, ServiceMode::Periodic { hz: 0.0 });
    assert!(ServiceWriter::<Count>::create(&skin, &bad_rate, &WriterOptions::default()).is_err());
}
