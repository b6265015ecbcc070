//! The exchange between a writer and readers in one process: reader modes,
//! writer modes, statistics, liveness, revival, read-only mapping, cleaning.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crate::util::SegmentDir;
use skinware::{
    Error, FrameStatus, Reader, ReaderOptions, ReaderWake, RtOptions, Stop, Ticker, Writer, WriterOptions, WriterState,
};

fn publish(writer: &mut Writer, value: u16) -> u64 {
    let mut frame = writer.begin();
    let n = frame.len_responses();
    frame.write_responses(0, &vec![value; n]).unwrap();
    frame.publish()
}

#[test]
fn latest_returns_newest_with_metadata_and_skips() {
    let dir = SegmentDir::new("latest");
    let mut writer = Writer::create("skin", "layer", 16, b"", &dir.writer()).unwrap();
    let mut reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
    assert!(matches!(reader.latest(), Err(Error::NoFrameYet { .. })));
    publish(&mut writer, 1);
    let first = reader.latest().unwrap();
    assert_eq!((first.seq(), first.skipped(), first.is_fresh()), (1, 0, true));
    for value in 2..=5 {
        publish(&mut writer, value);
    }
    let frame = reader.latest().unwrap();
    assert_eq!(frame.seq(), 5);
    assert_eq!(frame.skipped(), 3);
    assert_eq!(frame.responses(), &[5; 8]);
    assert!(frame.published_ns() >= frame.acquired_ns());
    let again = reader.latest().unwrap();
    assert!(!again.is_fresh());
    assert_eq!(reader.stats().reads, 3);
    assert_eq!(reader.stats().skipped, 3);
    assert!(reader.stats().read_ns_max >= reader.stats().read_ns_min);
}

/// A frame read again is not copied again: the reader gives its own copy,
/// which must then be that frame's, also after a read into a caller's
/// buffer (which leaves the reader's own copy behind).
#[test]
fn a_frame_read_again_is_the_readers_copy_of_that_frame() {
    let dir = SegmentDir::new("again");
    let mut writer = Writer::create("skin", "layer", 16, b"", &dir.writer()).unwrap();
    let mut reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
    publish(&mut writer, 1);
    assert_eq!(reader.latest().unwrap().responses(), &[1; 8]);
    publish(&mut writer, 2);
    let mut out = [0u8; 16];
    assert_eq!(reader.latest_into(&mut out).unwrap().seq, 2);
    let after_into = reader.latest().unwrap();
    assert_eq!((after_into.seq(), after_into.is_fresh()), (2, false));
    assert_eq!(after_into.responses(), &[2; 8], "frame 2's bytes, not the copy of frame 1");
    let again = reader.latest().unwrap();
    assert_eq!((again.seq(), again.is_fresh(), again.responses()), (2, false, &[2u16; 8][..]));
    publish(&mut writer, 3);
    assert_eq!(reader.latest().unwrap().responses(), &[3; 8]);
    assert_eq!(reader.stats().reads, 5);
}

#[test]
fn reads_into_a_callers_buffer_copy_the_frame_once_at_any_alignment() {
    let dir = SegmentDir::new("into");
    // 13 responses: 26 bytes, a ragged last word.
    let mut writer = Writer::create("skin", "layer", 26, b"", &dir.writer()).unwrap();
    let mut reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
    let mut storage = [0xEEu8; 26 + 3 + 1];
    assert!(matches!(reader.latest_into(&mut storage[3..29]), Err(Error::NoFrameYet { .. })));
    let values: Vec<u16> = (0..13).map(|i| 1000 + i * 3).collect();
    let mut frame = writer.begin();
    frame.write_responses(0, &values).unwrap();
    frame.publish();
    // An odd start: the caller's buffer need not be aligned.
    let info = reader.latest_into(&mut storage[3..29]).unwrap();
    assert_eq!((info.seq, info.skipped, info.fresh), (1, 0, true));
    let read: Vec<u16> = storage[3..29].chunks_exact(2).map(|b| u16::from_ne_bytes([b[0], b[1]])).collect();
    assert_eq!(read, values);
    assert_eq!(&storage[..3], &[0xEE; 3], "nothing written before the buffer");
    assert_eq!(storage[29], 0xEE, "nothing written past the frame");
    assert!(reader.last_frame().is_none(), "the reader's own copy is not the one refreshed");
    let again = reader.latest_into(&mut storage[3..29]).unwrap();
    assert!(!again.fresh);
    match reader.latest_into(&mut storage[..25]) {
        Err(Error::BufferTooSmall { needed: 26, given: 25, .. }) => {}
        other => panic!("a short buffer: {other:?}"),
    }
    let mut frame = writer.begin();
    frame.write_responses(0, &[9; 13]).unwrap();
    frame.publish();
    let info = reader.wait_newer_into(Duration::from_secs(1), &mut storage[..26]).unwrap();
    assert_eq!((info.seq, info.fresh), (2, true));
    assert_eq!(&storage[..26], &[9, 0].repeat(13)[..]);
}

#[test]
fn the_last_frame_copied_is_there_again_until_a_read_fails() {
    let dir = SegmentDir::new("last-frame");
    let mut writer = Writer::create("skin", "layer", 16, b"", &dir.writer()).unwrap();
    let mut reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
    assert!(reader.last_frame().is_none(), "nothing copied yet");
    publish(&mut writer, 7);
    let seq = reader.latest().unwrap().seq();
    publish(&mut writer, 8);
    let again = reader.last_frame().expect("the frame read before");
    assert_eq!((again.seq(), again.is_fresh(), again.skipped()), (seq, false, 0));
    assert_eq!(again.responses(), &[7; 8], "the copy, not the channel's newer frame");
    for value in 9..30 {
        publish(&mut writer, value);
    }
    assert!(reader.read_seq(1).is_none(), "frame 1 was overwritten long ago");
    assert!(reader.last_frame().is_none(), "a failed read leaves no frame to look at again");
    let newest = reader.latest().unwrap().seq();
    assert_eq!(reader.last_frame().map(|f| f.seq()), Some(newest));
}

#[test]
fn responses_written_one_by_one_or_from_any_offset_read_back_in_order() {
    // 75 responses: more than one 16-word block of the wide copy, an odd
    // count, so every path (wide blocks, whole words, partial words) is used.
    let dir = SegmentDir::new("lanes");
    let mut writer = Writer::create("skin", "layer", 150, b"", &dir.writer()).unwrap();
    let mut reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
    let expected: Vec<u16> = (0..75u16).map(|i| i.wrapping_mul(877) ^ 0x5a5a).collect();

    let mut frame = writer.begin();
    assert_eq!(frame.len_responses(), 75);
    for (index, &value) in expected.iter().enumerate().rev() {
        frame.set_response(index, value).unwrap();
    }
    frame.publish();
    assert_eq!(reader.latest().unwrap().responses(), expected.as_slice());

    for first in [1, 2, 3, 5, 17, 74] {
        let mut frame = writer.begin();
        frame.write_responses(0, &[0xffff; 75]).unwrap();
        frame.write_responses(first, &expected[first..]).unwrap();
        frame.write_responses(0, &expected[..first]).unwrap();
        frame.publish();
        assert_eq!(reader.latest().unwrap().responses(), expected.as_slice(), "first = {first}");
    }

    let mut frame = writer.begin();
    frame.write_responses(0, &expected).unwrap();
    frame.set_response(40, 7).unwrap();
    frame.publish();
    let mut changed = expected.clone();
    changed[40] = 7;
    assert_eq!(reader.latest().unwrap().responses(), changed.as_slice());
}

#[test]
fn frames_carry_status_and_acquisition_time() {
    let dir = SegmentDir::new("status");
    let mut writer = Writer::create("skin", "layer", 8, b"", &dir.writer()).unwrap();
    let mut reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
    let mut frame = writer.begin();
    frame.set_acquired_ns(42);
    frame.set_status(FrameStatus::PARTIAL);
    frame.publish();
    let frame = reader.latest().unwrap();
    assert_eq!(frame.acquired_ns(), 42);
    assert_eq!(frame.status(), FrameStatus::PARTIAL);
    assert_eq!(writer.stats().frames, 1);
}

#[test]
fn dropped_frame_is_never_seen() {
    let dir = SegmentDir::new("dropped");
    let mut writer = Writer::create("skin", "layer", 8, b"", &dir.writer()).unwrap();
    let mut reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
    publish(&mut writer, 7);
    let fill_half = |writer: &mut Writer| -> Result<(), Error> {
        let mut frame = writer.begin();
        frame.write_responses(0, &[9, 9])?;
        frame.write_responses(3, &[9, 9])?; // out of range: the early return drops the frame
        frame.publish();
        Ok(())
    };
    assert!(fill_half(&mut writer).is_err());
    let frame = reader.latest().unwrap();
    assert_eq!((frame.seq(), frame.responses()), (1, &[7u16, 7, 7, 7][..]), "half a frame was published");
}

#[test]
fn discarded_frame_is_never_seen() {
    let dir = SegmentDir::new("discard");
    let mut writer = Writer::create("skin", "layer", 8, b"", &dir.writer()).unwrap();
    let mut reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
    publish(&mut writer, 7);
    let mut frame = writer.begin();
    frame.write_responses(0, &[9, 9, 9, 9]).unwrap();
    frame.discard();
    let frame = reader.latest().unwrap();
    assert_eq!((frame.seq(), frame.responses()), (1, &[7u16, 7, 7, 7][..]));
    assert_eq!(publish(&mut writer, 8), 2, "a discarded frame used up a sequence number");
}

#[test]
fn as_soon_as_available_reader_wakes_on_publish() {
    let dir = SegmentDir::new("asap");
    let mut writer = Writer::create("skin", "layer", 8, b"", &dir.writer()).unwrap();
    let mut reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
    let (tid_tx, tid) = std::sync::mpsc::channel();
    let waiter = std::thread::spawn(move || {
        tid_tx.send(rustix::thread::gettid().as_raw_nonzero().get()).unwrap();
        let started = Instant::now();
        let seq = reader.wait_newer(Duration::from_secs(20)).unwrap().seq();
        (seq, started.elapsed())
    });
    // Published only once the reader sleeps (in its wait: it does nothing
    // else), so that the frame can only reach it by the wake.
    wait_until_asleep(&[tid.recv().unwrap()], || true);
    publish(&mut writer, 3);
    let (seq, waited) = waiter.join().unwrap();
    assert_eq!(seq, 1);
    assert!(waited < Duration::from_secs(10), "missed the wake-up: {waited:?}");
}

/// A segment directory so deep that the channel's socket cannot be bound
/// gets an error that says so and what to shorten, not the kernel's bare
/// "path must be shorter than SUN_LEN" about a path that looks short enough.
#[test]
fn a_segment_directory_too_deep_for_a_socket_address_is_a_clear_error() {
    let dir = SegmentDir::new("deep");
    let deep = dir.path.join("d".repeat(60));
    std::fs::create_dir_all(&deep).unwrap();
    let options = WriterOptions { dir: Some(deep), ..dir.writer() };
    let error = Writer::create("skin", "layer", 8, b"", &options).unwrap_err().to_string();
    assert!(
        error.contains("does not fit a Unix socket address (107 bytes)") && error.contains("SKINWARE_SHM_DIR"),
        "{error}"
    );
}

/// A periodic writer's lookout: three readers asleep for each of 300 frames
/// at 500 Hz get every one, in order, whoever woke them; the lookout (where it
/// can run: a real-time writer with a second CPU) woke some; and dropping the
/// writer ends the lookout's thread (a hang here would hang the test).
#[test]
fn a_periodic_writers_lookout_wakes_readers_and_loses_none() {
    std::thread::spawn(publish_periodically_to_sleeping_readers).join().unwrap();
}

fn publish_periodically_to_sleeping_readers() {
    let realtime = RtOptions { fifo_priority: Some(10), ..RtOptions::default() }.apply().is_empty();
    let cpus = std::thread::available_parallelism().map_or(1, usize::from);
    let dir = SegmentDir::new("lookout");
    let period = Duration::from_millis(2);
    let options = WriterOptions { reader_wake: ReaderWake::Lookout, period: Some(period), ..dir.writer() };
    let mut writer = Writer::create("skin", "layer", 8, b"", &options).unwrap();
    const FRAMES: u64 = 300;
    let waiters: Vec<_> = (0..3)
        .map(|_| {
            let mut reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
            std::thread::spawn(move || {
                let mut seen = Vec::new();
                while seen.last() != Some(&FRAMES) {
                    seen.push(reader.wait_newer(Duration::from_secs(10)).expect("a wake went missing").seq());
                }
                seen
            })
        })
        .collect();
    std::thread::sleep(Duration::from_millis(100));
    let stop = Stop::new();
    let mut ticker = Ticker::new(period);
    for value in 1..=FRAMES {
        ticker.wait(&stop).unwrap();
        publish(&mut writer, value as u16);
    }
    for waiter in waiters {
        let seen = waiter.join().unwrap();
        assert!(seen.windows(2).all(|pair| pair[0] < pair[1]), "frames out of order: {seen:?}");
    }
    let counts = writer.wake_counts();
    assert!(counts.by_lookout + counts.by_ringer + counts.by_writer <= FRAMES, "more wakes than frames: {counts:?}");
    if realtime && cpus > 1 {
        assert!(counts.by_lookout > 0, "the lookout woke no reader in {FRAMES} frames: {counts:?}");
        eprintln!("wakes by the lookout / ringer / writer: {counts:?}");
    } else {
        eprintln!("no SCHED_FIFO or a single CPU here: the writer (or its ringer) wakes the readers: {counts:?}");
    }
    drop(writer);
}

/// Readers asleep for every frame get every frame whichever thread wakes
/// them, and the writer says which did; dropping the writer stops its ringer
/// (a drop that hung on the ringer's thread would hang the test). A ringer
/// needs a real-time writer: without the privilege, the writer wakes its
/// readers itself, which the test then checks instead.
#[test]
fn sleeping_readers_are_woken_by_the_ringer_or_by_the_writer_as_chosen() {
    std::thread::spawn(publish_to_sleeping_readers).join().unwrap();
}

fn publish_to_sleeping_readers() {
    let realtime = RtOptions { fifo_priority: Some(10), ..RtOptions::default() }.apply().is_empty();
    if !realtime {
        eprintln!("no SCHED_FIFO here: checking that a normal-scheduler writer wakes its readers itself");
    }
    for wake in [ReaderWake::Ringer, ReaderWake::Writer] {
        let dir = SegmentDir::new("ringer");
        let options = WriterOptions { reader_wake: wake, ..dir.writer() };
        let mut writer = Writer::create("skin", "layer", 8, b"", &options).unwrap();
        // Each reader says which frame it read last (an atomic: no lock and
        // no allocation between that and its next wait). A reader that has
        // read the last frame and sleeps is inside its wait, announced.
        let (tids_tx, tids) = std::sync::mpsc::channel();
        let last_read: Arc<[AtomicU64; 3]> = Arc::new(Default::default());
        let waiters: Vec<_> = (0..3)
            .map(|k| {
                let mut reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
                let (tids_tx, last_read) = (tids_tx.clone(), last_read.clone());
                std::thread::spawn(move || {
                    tids_tx.send(rustix::thread::gettid().as_raw_nonzero().get()).unwrap();
                    let mut seen = Vec::with_capacity(20);
                    while seen.last() != Some(&20) {
                        let seq = reader.wait_newer(Duration::from_secs(10)).expect("a wake went missing").seq();
                        seen.push(seq);
                        last_read[k].store(seq, Ordering::Release);
                    }
                    seen
                })
            })
            .collect();
        let tids: Vec<i32> = tids.iter().take(3).collect();
        for value in 1..=20 {
            // Every frame finds all three readers asleep, however loaded the
            // machine: each publish then has someone to wake.
            wait_until_asleep(&tids, || last_read.iter().all(|read| read.load(Ordering::Acquire) == value - 1));
            publish(&mut writer, value as u16);
        }
        for waiter in waiters {
            let seen = waiter.join().unwrap();
            assert_eq!(seen, (1..=20).collect::<Vec<u64>>(), "{wake:?}: a reader asleep for every frame missed one");
        }
        let counts = writer.wake_counts();
        // Every publish found sleepers: one wake each, by one thread or the
        // other. The writer wakes them itself when its ringer is still busy
        // with the previous frame, and at the first (which starts the ringer).
        assert_eq!(counts.by_ringer + counts.by_writer, 20, "{wake:?}: not one wake per frame: {counts:?}");
        if wake == ReaderWake::Ringer && realtime {
            assert!(counts.by_ringer > 0, "the ringer woke no reader: {counts:?}");
        } else {
            assert_eq!(counts.by_ringer, 0, "{wake:?}: a ringer without being asked for: {counts:?}");
        }
        assert_eq!(counts.by_lookout, 0, "{wake:?}: a lookout without being asked for: {counts:?}");
        assert!(writer.last_published_ns() > 0);
        drop(writer);
    }
}

/// Waits until the readers have read the last frame and every thread in
/// `tids` (of this process), and every ringer thread of this process,
/// sleeps. After its read, a reader of these tests blocks only in the
/// doorbell's futex wait, which it enters after announcing itself to the
/// writer; a ringer sleeps once it has recorded its last wake as done (a
/// writer whose ringer is still busy wakes the readers itself).
fn wait_until_asleep(tids: &[i32], read_the_last_frame: impl Fn() -> bool) {
    let started = Instant::now();
    let state = |task: &std::path::Path| {
        let stat = std::fs::read_to_string(task.join("stat")).unwrap_or_default();
        stat.rsplit_once(") ").and_then(|(_, rest)| rest.chars().next())
    };
    let all_asleep = || {
        let readers =
            tids.iter().all(|tid| state(std::path::Path::new(&format!("/proc/self/task/{tid}"))) == Some('S'));
        let ringers = std::fs::read_dir("/proc/self/task").unwrap().flatten().all(|task| {
            let name = std::fs::read_to_string(task.path().join("comm")).unwrap_or_default();
            name.trim_end() != "skinware-ringer" || state(&task.path()) == Some('S')
        });
        read_the_last_frame() && readers && ringers
    };
    while !all_asleep() {
        assert!(started.elapsed() < Duration::from_secs(20), "the readers never went to sleep");
        // Sleeps, not spins: this thread may be real-time, and its ringer
        // runs at its priority.
        std::thread::sleep(Duration::from_micros(200));
    }
}

#[test]
fn as_soon_as_available_reader_times_out_and_can_be_stopped() {
    let dir = SegmentDir::new("asap-timeout");
    let _writer = Writer::create("skin", "layer", 8, b"", &dir.writer()).unwrap();
    let mut reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
    let started = Instant::now();
    let err = reader.wait_newer(Duration::from_millis(50)).unwrap_err();
    assert!(matches!(err, Error::Timeout { .. }), "{err}");
    assert!(started.elapsed() >= Duration::from_millis(50));

    let stop = Stop::new();
    reader.set_stop(&stop);
    let waiter = std::thread::spawn(move || reader.wait_newer(Duration::from_secs(3600)).map(|f| f.seq()));
    std::thread::sleep(Duration::from_millis(50));
    let stopped_at = Instant::now();
    stop.stop();
    let result = waiter.join().unwrap();
    assert!(matches!(result, Err(Error::Stopped { .. })), "{result:?}");
    assert!(stopped_at.elapsed() < Duration::from_secs(5));
}

#[test]
fn request_triggers_a_sporadic_acquisition() {
    let dir = SegmentDir::new("request");
    let mut writer = Writer::create("skin", "sporadic", 8, b"", &dir.writer()).unwrap();
    let stop = Stop::new();
    writer.set_stop(&stop);
    let acquisitions = std::thread::spawn(move || {
        let mut count = 0u16;
        writer
            .run_sporadic(|frame| {
                count += 1;
                frame.write_responses(0, &[count; 4])
            })
            .unwrap();
        count
    });
    let mut reader = Reader::open_with("skin", "sporadic", &dir.reader()).unwrap();
    assert_eq!(reader.writer_period(), None);
    for expected in 1..=3u16 {
        let frame = reader.request(Duration::from_secs(20)).unwrap();
        assert_eq!(frame.responses(), &[expected; 4]);
        assert_eq!(frame.seq(), u64::from(expected));
    }
    stop.stop();
    assert_eq!(acquisitions.join().unwrap(), 3, "each request should cause exactly one acquisition");
}

#[test]
fn request_on_a_periodic_writer_waits_for_its_next_frame() {
    let dir = SegmentDir::new("request-periodic");
    let options = WriterOptions { period: Some(Duration::from_millis(5)), ..dir.writer() };
    let mut writer = Writer::create("skin", "periodic", 8, b"", &options).unwrap();
    let stop = Stop::new();
    writer.set_stop(&stop);
    let running = std::thread::spawn(move || {
        let mut value = 0u16;
        writer
            .run_periodic(Ticker::new(Duration::from_millis(5)), |frame| {
                value += 1;
                frame.write_responses(0, &[value; 4])
            })
            .unwrap();
        writer.stats()
    });
    let mut reader = Reader::open_with("skin", "periodic", &dir.reader()).unwrap();
    let before = reader.published_seq();
    let frame = reader.request(Duration::from_secs(20)).unwrap();
    assert!(frame.seq() > before);
    let mut ticker = Ticker::new(Duration::from_millis(20));
    let mut last = 0;
    for _ in 0..5 {
        let frame = reader.next_periodic(&mut ticker).unwrap();
        assert!(frame.seq() >= last);
        last = frame.seq();
    }
    stop.stop();
    let stats = running.join().unwrap();
    // Published on its own period, whatever the reader did: at least up to
    // the last frame read (no count of frames per second: this machine may
    // run the writer late).
    assert!(stats.frames >= last && last > before, "{stats:?}");
    assert!(stats.write_ns_max >= stats.write_ns_min);
    assert_eq!(stats.write_histogram.iter().sum::<u64>(), stats.frames);
}

#[test]
fn periodic_writer_counts_overruns() {
    let dir = SegmentDir::new("overrun");
    let mut writer = Writer::create("skin", "slow", 8, b"", &dir.writer()).unwrap();
    let stop = Stop::new();
    writer.set_stop(&stop);
    let mut frames = 0;
    let stopper = stop.clone();
    writer
        .run_periodic(Ticker::new(Duration::from_millis(2)), |_frame| {
            frames += 1;
            if frames == 3 {
                std::thread::sleep(Duration::from_millis(10)); // a slow acquisition
            }
            if frames == 6 {
                stopper.stop();
            }
            Ok::<(), String>(())
        })
        .unwrap();
    let stats = writer.stats();
    assert!(stats.overruns >= 1, "{stats:?}");
    assert!(stats.missed_periods >= 3, "{stats:?}");
}

#[test]
fn failed_acquisition_marks_the_channel_faulted_until_it_recovers() {
    let dir = SegmentDir::new("faulted");
    let mut writer = Writer::create("skin", "flaky", 8, b"", &dir.writer()).unwrap();
    let reader = Reader::open_with("skin", "flaky", &dir.reader()).unwrap();
    let stop = Stop::new();
    writer.set_stop(&stop);
    let stopper = stop.clone();
    let mut calls = 0;
    let mut states = Vec::new();
    writer
        .run_periodic(Ticker::new(Duration::from_millis(1)), |_frame| {
            calls += 1;
            states.push(reader.writer_state());
            match calls {
                2 | 3 => Err("cable pulled"),
                5 => {
                    stopper.stop();
                    Ok(())
                }
                _ => Ok(()),
            }
        })
        .unwrap();
    // The state seen during call n reflects calls before it.
    assert_eq!(
        states,
        [WriterState::Running, WriterState::Running, WriterState::Faulted, WriterState::Faulted, WriterState::Running]
    );
    assert_eq!(writer.stats().faults, 2);
    assert_eq!(writer.last_seq(), 3, "failed acquisitions must not publish");
}

#[test]
fn liveness_paused_and_gone() {
    let dir = SegmentDir::new("liveness");
    let writer = Writer::create("skin", "layer", 8, b"", &dir.writer()).unwrap();
    let reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
    assert_eq!(reader.writer_state(), WriterState::Running);
    writer.set_state(WriterState::Paused);
    assert_eq!(reader.writer_state(), WriterState::Paused);
    drop(writer);
    assert_eq!(reader.writer_state(), WriterState::Gone);
    assert!(dir.files().is_empty(), "the writer left {:?}", dir.files());
}

#[test]
fn readers_follow_a_successor_with_a_new_sequence() {
    let dir = SegmentDir::new("revival");
    let keep = WriterOptions { unlink_on_drop: false, ..dir.writer() };
    let mut first = Writer::create("skin", "layer", 8, b"topology", &keep).unwrap();
    let mut reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
    for value in 1..=4 {
        publish(&mut first, value);
    }
    assert_eq!(reader.latest().unwrap().seq(), 4);
    drop(first);
    assert_eq!(reader.writer_state(), WriterState::Gone);

    let mut second = Writer::create("skin", "layer", 8, b"topology", &dir.writer()).unwrap();
    assert!(second.revived());
    publish(&mut second, 50);
    let frame = reader.wait_newer(Duration::from_secs(5)).unwrap();
    assert_eq!(frame.seq(), 1, "a successor's channel is new memory: its sequence starts at 1");
    assert_eq!(frame.responses(), &[50; 4]);
    assert_eq!(reader.writer_state(), WriterState::Running);
    assert_eq!(reader.writer_generation(), 2);
}

/// Set in the child process of the revival-order test: the directory its writer uses.
const REVIVAL_CHILD_DIR: &str = "SKINWARE_TEST_REVIVAL_CHILD_DIR";

#[test]
fn a_reviving_writer_is_never_seen_running_before_it_owns_the_header() {
    if let Some(path) = std::env::var_os(REVIVAL_CHILD_DIR) {
        // The child: a writer that is SIGKILLed, so its header still says "running".
        let options = WriterOptions { dir: Some(path.into()), unlink_on_drop: false, ..WriterOptions::default() };
        let mut writer = Writer::create("skin", "layer", 8, b"topology", &options).unwrap();
        publish(&mut writer, 1);
        std::thread::sleep(Duration::from_secs(60));
        return;
    }
    let dir = SegmentDir::new("revival-order");
    let reader_options = dir.reader();
    for round in 0..40 {
        let mut child = std::process::Command::new(std::env::current_exe().unwrap())
            .args([
                "--exact",
                "exchange::a_reviving_writer_is_never_seen_running_before_it_owns_the_header",
                "--nocapture",
            ])
            .env(REVIVAL_CHILD_DIR, &dir.path)
            .stdout(std::process::Stdio::null())
            .spawn()
            .unwrap();
        let started = Instant::now();
        let mut reader = loop {
            match Reader::open_with("skin", "layer", &reader_options) {
                Ok(reader) if reader.writer_state() == WriterState::Running && reader.writer_pid() == child.id() => {
                    break reader;
                }
                _ => {
                    assert!(started.elapsed() < Duration::from_secs(20), "the child writer never came up");
                    std::thread::sleep(Duration::from_millis(1));
                }
            }
        };
        let dead_generation = reader.writer_generation();
        child.kill().unwrap();
        child.wait().unwrap();
        assert_eq!(reader.writer_state(), WriterState::Gone);
        let options = dir.writer();
        let reviver = std::thread::spawn(move || Writer::create("skin", "layer", 8, b"topology", &options).unwrap());
        // Watch the succession as closely as a reader can: once the writer is
        // seen alive, the header must already be the new writer's.
        loop {
            reader.follow_recreated();
            if reader.writer_state() == WriterState::Running {
                assert_eq!(
                    (reader.writer_pid(), reader.writer_generation()),
                    (std::process::id(), dead_generation + 1),
                    "round {round}: seen running with the killed writer's header"
                );
                break;
            }
            std::hint::spin_loop();
        }
        let revived = reviver.join().unwrap();
        assert!(revived.revived());
        drop(revived); // unlinks: the next round's child creates the channel afresh
    }
}

/// Starts this test binary as a writer process (the child of the revival
/// test) on `dir`, and waits until it has published its first frame.
// The caller kills and waits for the child it is given.
#[allow(clippy::zombie_processes)]
fn start_child_writer(dir: &SegmentDir) -> (std::process::Child, Reader) {
    let mut child = std::process::Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "exchange::a_reviving_writer_is_never_seen_running_before_it_owns_the_header", "--nocapture"])
        .env(REVIVAL_CHILD_DIR, &dir.path)
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let started = Instant::now();
    loop {
        if let Ok(mut reader) = Reader::open_with("skin", "layer", &dir.reader())
            && reader.writer_pid() == child.id()
            && reader.latest().is_ok()
        {
            return (child, reader);
        }
        if started.elapsed() > Duration::from_secs(20) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("the child writer never came up");
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

#[test]
fn a_reader_waiting_when_its_writer_is_killed_gets_writer_gone_within_its_timeout() {
    let dir = SegmentDir::new("gone-in-time");
    for mode in ["as soon as available", "on request"] {
        let (mut child, mut reader) = start_child_writer(&dir);
        let timeout = Duration::from_millis(400);
        let waiter = std::thread::spawn(move || {
            let started = Instant::now();
            let result = match mode {
                "on request" => reader.request(timeout).map(|f| f.seq()),
                _ => reader.wait_newer(timeout).map(|f| f.seq()),
            };
            (result, started.elapsed())
        });
        std::thread::sleep(Duration::from_millis(100));
        child.kill().unwrap();
        child.wait().unwrap();
        let (result, waited) = waiter.join().unwrap();
        let err = result.expect_err("no frame can come from a killed writer");
        assert!(matches!(err, Error::WriterGone { .. }), "{mode}: {err}");
        // Once, not again: a generous bound, since this machine's scheduling is not real-time.
        assert!(waited < timeout * 2 + Duration::from_secs(1), "{mode}: returned after {waited:?}");
        assert_eq!(skinware::remove_stale_channels(&dir.path, false).unwrap().len(), 1);
    }
}

#[test]
fn a_request_made_while_the_writer_is_gone_is_answered_by_its_successor() {
    let dir = SegmentDir::new("request-revival");
    let options = WriterOptions { unlink_on_drop: false, ..dir.writer() };
    let mut first = Writer::create("skin", "layer", 8, b"topology", &options).unwrap();
    publish(&mut first, 1);
    let mut reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
    drop(first);
    let asker = std::thread::spawn(move || reader.request(Duration::from_secs(10)).map(|f| f.responses()[0]));
    std::thread::sleep(Duration::from_millis(100)); // the request is made while no writer runs
    let mut second = Writer::create("skin", "layer", 8, b"topology", &options).unwrap();
    assert!(second.revived());
    // The waiting reader follows the new channel and asks it again.
    assert!(
        second.wait_request(Duration::from_secs(2)).unwrap(),
        "the new writer did not get the request made while the channel had none"
    );
    publish(&mut second, 2);
    assert_eq!(asker.join().unwrap().unwrap(), 2, "the answer is the successor's frame");
}

#[test]
fn readers_follow_a_re_created_channel() {
    let dir = SegmentDir::new("recreated");
    let mut first = Writer::create("skin", "layer", 8, b"v1", &dir.writer()).unwrap();
    let mut reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
    for value in 1..=3 {
        publish(&mut first, value);
    }
    assert_eq!(reader.latest().unwrap().seq(), 3);
    drop(first); // a clean stop removes the channel
    assert!(!reader.follow_recreated(), "nothing to follow yet");

    // A new writer (another topology description, same frame size) re-creates it.
    let mut second = Writer::create("skin", "layer", 8, b"v2", &dir.writer()).unwrap();
    assert!(!second.revived());
    publish(&mut second, 40);
    let frame = reader.wait_newer(Duration::from_millis(50)).expect("the reader follows on its own after a timeout");
    assert_eq!((frame.seq(), frame.responses()), (1, &[40u16; 4][..]));
    assert_eq!(reader.description(), b"v2");
    assert_eq!(reader.writer_state(), WriterState::Running);
}

/// The open files of this process whose target contains `name`, with their
/// access mode (`O_ACCMODE` of the fdinfo flags: 0 read-only, 2 read-write).
fn open_modes(name: &str) -> Vec<u32> {
    let mut modes = Vec::new();
    for entry in std::fs::read_dir("/proc/self/fd").unwrap().flatten() {
        let Ok(target) = std::fs::read_link(entry.path()) else { continue };
        if !target.to_string_lossy().contains(name) {
            continue;
        }
        let info = std::fs::read_to_string(format!("/proc/self/fdinfo/{}", entry.file_name().to_string_lossy()));
        let flags = info.ok().and_then(|info| {
            info.lines().find_map(|l| l.strip_prefix("flags:").and_then(|f| u32::from_str_radix(f.trim(), 8).ok()))
        });
        if let Some(flags) = flags {
            modes.push(flags & 0o3);
        }
    }
    modes.sort();
    modes
}

#[test]
fn readers_map_frames_read_only() {
    let dir = SegmentDir::new("readonly");
    let writer = Writer::create("skin", "rolayer", 30_848 * 2, b"", &dir.writer()).unwrap();
    let reader = Reader::open_with("skin", "rolayer", &dir.reader()).unwrap();
    let maps = std::fs::read_to_string("/proc/self/maps").unwrap();
    let frames: Vec<&str> = maps.lines().filter(|line| line.contains("skinware:skin/rolayer:frames")).collect();
    let doorbells: Vec<&str> = maps.lines().filter(|line| line.contains("skinware:skin/rolayer:doorbell")).collect();
    let perms = |line: &&str| line.split_whitespace().nth(1).unwrap().to_owned();
    let size = |line: &str| {
        let (start, end) = line.split_whitespace().next().unwrap().split_once('-').unwrap();
        u64::from_str_radix(end, 16).unwrap() - u64::from_str_radix(start, 16).unwrap()
    };
    // The writer's read-write mapping of the frames and the reader's
    // read-only one; both doorbells read-write, one page each.
    let mut frame_perms: Vec<String> = frames.iter().map(perms).collect();
    frame_perms.sort();
    assert_eq!(frame_perms, ["r--s", "rw-s"], "{frames:#?}");
    assert!(frames.iter().all(|line| size(line) > 60_000), "the mappings must cover the frames");
    assert_eq!(doorbells.len(), 2, "{doorbells:#?}");
    assert!(doorbells.iter().all(|line| perms(line) == "rw-s" && size(line) == 4096), "{doorbells:#?}");
    // Open files: the writer's read-write descriptor (it holds the liveness
    // lock) and the reader's read-only one (the writer keeps a read-only one
    // to hand over).
    assert_eq!(open_modes("skinware:skin/rolayer:frames"), [0, 0, 2]);
    drop(reader);
    drop(writer);
}

#[test]
fn stale_channels_are_listed_and_removed() {
    let dir = SegmentDir::new("clean");
    let keep = WriterOptions { unlink_on_drop: false, ..dir.writer() };
    drop(Writer::create("dead", "layer", 8, b"", &keep).unwrap());
    let _alive = Writer::create("live", "layer", 8, b"", &dir.writer()).unwrap();
    std::fs::write(dir.segment("junk", "layer"), b"not a channel at all").unwrap();

    let listed = skinware::list_channels(&dir.path).unwrap();
    let summary: Vec<(String, WriterState, bool)> =
        listed.iter().map(|c| (c.skin.clone(), c.state, c.problem.is_some())).collect();
    assert_eq!(
        summary,
        [
            ("dead".to_string(), WriterState::Gone, false),
            ("junk".to_string(), WriterState::Gone, true),
            ("live".to_string(), WriterState::Running, false)
        ]
    );

    let removed = skinware::remove_stale_channels(&dir.path, false).unwrap();
    assert_eq!(removed, [dir.segment("dead", "layer")]);
    assert_eq!(dir.files(), [".skinware-lock.live.layer", "skinware.junk.layer", "skinware.live.layer"]);
    let removed = skinware::remove_stale_channels(&dir.path, true).unwrap();
    assert_eq!(removed, [dir.segment("junk", "layer")]);
    assert_eq!(
        dir.files(),
        [".skinware-lock.live.layer", "skinware.live.layer"],
        "a live writer's channel was removed"
    );
}

#[test]
fn description_is_published_to_readers() {
    let dir = SegmentDir::new("description");
    let description: Vec<u8> = (0..=255).cycle().take(5000).collect();
    let _writer = Writer::create("skin", "layer", 8, &description, &dir.writer()).unwrap();
    let reader = Reader::open_with("skin", "layer", &ReaderOptions { ..dir.reader() }).unwrap();
    assert_eq!(reader.description(), description);
}

#[test]
fn an_anticipating_reader_gets_every_frame_and_falls_back_to_the_futex_when_one_is_late() {
    let dir = SegmentDir::new("anticipate");
    let period = Duration::from_millis(5);
    let options = WriterOptions { period: Some(period), ..dir.writer() };
    let mut writer = Writer::create("skin", "layer", 8, b"", &options).unwrap();
    publish(&mut writer, 1);
    let reader_options = ReaderOptions { anticipate: Some(Duration::from_micros(300)), ..dir.reader() };
    let mut reader = Reader::open_with("skin", "layer", &reader_options).unwrap();
    assert_eq!(reader.latest().unwrap().seq(), 1);
    // The writer publishes a frame only once the reader has read the one
    // before: a loaded machine that runs the reader late then makes frames
    // late (which the reader must cope with), never skipped.
    let last_read = Arc::new(AtomicU64::new(1));
    let read_by_reader = last_read.clone();
    let writer_thread = std::thread::spawn(move || {
        let mut ticker = Ticker::new(period);
        let stop = Stop::new();
        for value in 2..=40u16 {
            ticker.wait(&stop);
            let started = Instant::now();
            while read_by_reader.load(Ordering::Acquire) < u64::from(value) - 1 {
                assert!(started.elapsed() < Duration::from_secs(20), "the reader never read frame {}", value - 1);
                std::thread::sleep(Duration::from_micros(100));
            }
            if value == 30 {
                // Late by many periods: the reader's spinning window passes.
                std::thread::sleep(Duration::from_millis(40));
            }
            publish(&mut writer, value);
        }
        writer
    });
    let mut seen = Vec::new();
    while seen.last() != Some(&40) {
        let frame = reader.wait_newer(Duration::from_secs(5)).unwrap();
        assert_eq!(frame.responses()[0] as u64, frame.seq());
        seen.push(frame.seq());
        last_read.store(frame.seq(), Ordering::Release);
    }
    let _writer = writer_thread.join().unwrap();
    // Every frame, in order, whether it came when anticipated, early, late
    // or (frame 30) so late that the reader went back to the futex.
    assert_eq!(seen, (2..=40).collect::<Vec<u64>>());
    assert_eq!(reader.stats().skipped, 0);
}

#[test]
fn a_cleaner_racing_revivals_never_leaves_a_writer_on_an_unlinked_segment() {
    let dir = SegmentDir::new("clean-revive");
    let path = dir.segment("skin", "layer");
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let cleaner = {
        let (path, stop) = (path.clone(), stop.clone());
        std::thread::spawn(move || {
            let mut removed = 0;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                if skinware::remove_channel_if_stale(&path).unwrap() {
                    removed += 1;
                }
            }
            removed
        })
    };
    let keep = WriterOptions { unlink_on_drop: false, ..dir.writer() };
    let mut revived = 0;
    for value in 1..=300u16 {
        let mut writer = match Writer::create("skin", "layer", 8, b"topology", &keep) {
            Ok(writer) => writer,
            // The cleaner holds the segment's locks for a moment: try again.
            Err(Error::Busy { .. }) => continue,
            Err(e) => panic!("{e}"),
        };
        revived += usize::from(writer.revived());
        publish(&mut writer, value);
        // The writer must own the segment at the channel's path: a new reader finds it alive.
        let mut reader = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
        assert_eq!(reader.writer_state(), WriterState::Running);
        assert_eq!(reader.latest().unwrap().responses()[0], value, "the writer publishes into another segment");
        drop(writer);
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let removed = cleaner.join().unwrap();
    println!("{revived} revivals, {removed} removals");
}
