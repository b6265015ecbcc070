"""Reading and writing from Python against a skin written from Python: every
reader mode, dtypes and shapes, read-only arrays, and errors on bad input."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

import skinware
from conftest import drive_in_thread, start_driver, wait_for


@pytest.fixture
def layer(skin):
    """A 72-sensor layer at 200 Hz written in this process; frame k holds k everywhere."""
    topology = skinware.Topology.uniform("pressure", 2, 3, 12, rate_hz=200)
    writer = skinware.Writer(skin, "pressure", topology)
    finish = drive_in_thread(writer)
    yield skin, writer
    finish()


def whole(frame) -> bool:
    """Every response of a frame of this writer is the same number."""
    values = frame.responses
    return bool((values == values[0]).all())


def test_latest_is_a_read_only_uint16_copy_with_metadata(layer):
    skin, writer = layer
    with skinware.Reader(skin, "pressure") as reader:
        frame = wait_for(lambda: _latest_or_none(reader), what="a first frame")
        assert isinstance(frame.responses, np.ndarray)
        assert frame.responses.dtype == np.uint16
        assert frame.responses.shape == (72,)
        assert len(frame) == 72 and len(reader) == 72
        assert not frame.responses.flags.writeable
        with pytest.raises(ValueError):
            frame.responses[0] = 1
        assert frame.seq >= 1 and frame.acquired_ns > 0 and frame.published_ns >= frame.acquired_ns
        assert frame.status == skinware.Status.OK and not frame.faulted
        assert whole(frame) and frame.responses[0] == frame.seq % 65536
        assert np.asarray(frame) is frame.responses
        assert np.asarray(frame, dtype=np.float32).dtype == np.float32
        # A frame is a copy: later reads do not change it.
        before = frame.responses.copy()
        reader.wait_newer(1.0)
        assert (frame.responses == before).all()
        assert reader.state == "running"
        assert reader.period == pytest.approx(1 / 200)
        assert reader.writer_pid > 0 and reader.generation == 1


def _latest_or_none(reader):
    try:
        return reader.latest()
    except skinware.NoFrameYet:
        return None


def test_wait_newer_returns_each_newer_frame(layer):
    skin, _ = layer
    reader = skinware.Reader(skin, "pressure")
    seqs = [reader.wait_newer(1.0).seq for _ in range(20)]
    assert seqs == sorted(seqs) and len(set(seqs)) == 20
    frame = reader.wait_newer(1.0)
    assert whole(frame) and frame.fresh
    reader.close()


def test_periodic_yields_the_newest_frame_on_a_fixed_grid(layer):
    skin, _ = layer
    reader = skinware.Reader(skin, "pressure")
    reader.wait_newer(1.0)
    started = time.monotonic()
    frames = [frame for _, frame in zip(range(10), reader.periodic(50))]
    elapsed = time.monotonic() - started
    assert len(frames) == 10
    assert all(whole(f) for f in frames)
    assert [f.seq for f in frames] == sorted(f.seq for f in frames)
    # 10 ticks at 50 Hz, the first at once: about 0.18 s (loose: a shared CI machine).
    assert 0.1 < elapsed < 2.0
    reader.close()


def test_frames_iterates_as_soon_as_available_and_ends_when_closed(layer):
    skin, _ = layer
    reader = skinware.Reader(skin, "pressure")
    seqs = []
    for frame in reader:
        seqs.append(frame.seq)
        if len(seqs) == 15:
            reader.close()
    assert len(seqs) == 15 and seqs == sorted(set(seqs))
    with pytest.raises(skinware.ReaderClosed):
        reader.latest()


def test_read_into_reuses_the_callers_array(layer):
    skin, _ = layer
    reader = skinware.Reader(skin, "pressure")
    out = np.zeros(72, np.uint16)
    for mode in ("newer", "latest", "request"):
        frame = reader.read_into(out, mode=mode, timeout=1.0)
        assert frame.responses is out
        assert (out == frame.seq % 65536).all()
    reader.close()


def test_a_sporadic_writer_answers_requests(skin):
    topology = skinware.Topology.uniform("touch", 1, 1, 4)
    writer = skinware.Writer(skin, "touch", topology)
    answered = []

    def answer():
        while writer.wait_request(timeout=2.0):
            answered.append(writer.publish(np.full(4, 7 + len(answered), np.uint16)))

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    reader = skinware.Reader(skin, "touch")
    assert reader.period is None
    first = reader.request(timeout=2.0)
    second = reader.request(timeout=2.0)
    assert second.seq > first.seq
    assert first.responses.tolist() == [7] * 4
    writer.close()
    thread.join(5)
    reader.close()


def test_timeout_and_writer_gone(skin):
    topology = skinware.Topology.uniform("quiet", 1, 1, 4)
    writer = skinware.Writer(skin, "quiet", topology)
    reader = skinware.Reader(skin, "quiet")
    writer.publish(np.zeros(4, np.uint16))
    reader.latest()
    started = time.monotonic()
    with pytest.raises(skinware.Timeout) as timeout:
        reader.wait_newer(0.3)
    assert isinstance(timeout.value, TimeoutError)
    assert time.monotonic() - started >= 0.29
    assert "quiet" in str(timeout.value)
    writer.close()
    with pytest.raises(skinware.WriterGone):
        reader.wait_newer(0.3)
    assert reader.state == "gone"
    # The last frame stays readable.
    assert reader.latest().seq == 1


def test_layers_and_channels_list_the_skin(layer):
    skin, _ = layer
    listed = skinware.layers(skin)
    assert [c.name for c in listed] == ["pressure"]
    info = listed[0]
    assert info.kind == "layer" and info.state == "running" and info.sensors == 72
    assert info.writer_pid > 0 and info.generation == 1 and info.problem is None
    assert skin in skinware.skins()
    assert skinware.services(skin) == []
    assert skinware.layer(skin, "pressure").name == "pressure"


def test_topology_round_trips_through_the_channel(skin):
    topology = skinware.Topology(
        "hand", [(1, 10, [100, 101, 102]), (1, 11, [110, 111]), (2, 20, [200])], sensor_type="temperature", rate_hz=25
    )
    with skinware.Writer(skin, "hand", topology):
        with skinware.Reader(skin, "hand") as reader:
            seen = reader.topology
    assert seen == topology
    assert seen.uids.tolist() == [100, 101, 102, 110, 111, 200]
    assert seen.module_ids.tolist() == [10, 10, 10, 11, 11, 20]
    assert seen.patch_ids.tolist() == [1, 1, 1, 1, 1, 2]
    assert seen.modules == [(10, 1, 0, 3), (11, 1, 3, 5), (20, 2, 5, 6)]
    assert seen.patches == [1, 2]
    assert seen.index_of(110) == 3 and seen.index_of(999) is None
    assert seen.sensor_type == "temperature" and seen.rate_hz == 25
    assert not seen.uids.flags.writeable


def test_a_python_service_is_read_by_type(skin):
    dtype = np.dtype([("force", "<f4"), ("touched", "u1"), ("pad", "u1", (3,))])
    with skinware.ServiceWriter(skin, "grip", dtype, ("lab.grip", 2), labels=["thumb", "index"], rate_hz=100) as service:
        records = service.empty()
        records["force"] = [1.5, 0.25]
        records["touched"] = [1, 0]
        service.publish(records)
        reader = skinware.ServiceReader(skin, "grip", dtype, ("lab.grip", 2))
        frame = reader.latest()
        assert reader.labels == ["thumb", "index"]
        assert reader.schema == ("lab.grip", 2) and reader.rate_hz == 100
        assert frame.records.dtype == dtype and frame.records.shape == (2,)
        assert not frame.records.flags.writeable
        assert frame.records["force"].tolist() == [1.5, 0.25]
        assert skinware.services(skin)[0].name == "grip"
        with pytest.raises(skinware.SchemaMismatch, match="lab.grip"):
            skinware.ServiceReader(skin, "grip", dtype, ("lab.grip", 1))
        with pytest.raises(skinware.SchemaMismatch, match="bytes"):
            skinware.ServiceReader(skin, "grip", np.dtype([("force", "<f8"), ("n", "<u4")]), ("lab.grip", 2))
        with pytest.raises(skinware.SchemaMismatch, match="service"):
            skinware.Reader(skin, "grip")
        with pytest.raises(skinware.InvalidArgument, match="dtype"):
            service.publish(np.zeros(2, np.float32))
        with pytest.raises(skinware.InvalidArgument, match="2 records"):
            service.publish(np.zeros(3, dtype))
        reader.close()


def test_a_sporadic_python_service_answers_requests(skin):
    dtype = np.dtype([("count", "<u4")])
    service = skinware.ServiceWriter(skin, "counter", dtype, ("lab.counter", 1), records=1)

    def answer():
        n = 0
        while service.wait_request(timeout=2.0):
            n += 1
            service.publish(np.array([(n,)], dtype))

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    reader = skinware.ServiceReader(skin, "counter", dtype, ("lab.counter", 1))
    assert reader.request(2.0).records["count"].tolist() == [1]
    assert reader.request(2.0).records["count"].tolist() == [2]
    service.close()
    thread.join(5)


@pytest.mark.parametrize(
    "make, error, words",
    [
        (lambda s: skinware.Reader(s, "no-such-layer"), skinware.ChannelMissing, "does not exist"),
        (lambda s: skinware.Reader("bad/skin", "x"), skinware.InvalidArgument, "invalid skin name"),
        (lambda s: skinware.Reader(s, ""), skinware.InvalidArgument, "invalid channel name"),
        (lambda s: skinware.Topology.uniform("x", 0, 1, 1), skinware.InvalidArgument, "at least one"),
        (lambda s: skinware.Topology("x", [(0, 1, [5]), (0, 2, [5])]), skinware.InvalidArgument, "uid 5"),
        (lambda s: skinware.Topology("x", [(0, 1, [1])], rate_hz=-1), skinware.InvalidArgument, "rate"),
        (lambda s: skinware.Geometry.open(s), skinware.GeometryError, "geometry"),
        (lambda s: skinware.ServiceWriter(s, "x", "u1", ("s", 1)), skinware.InvalidArgument, "labels"),
        (lambda s: skinware.ServiceWriter(s, "x", "u1", ("s", 1), labels=["two words"]), skinware.InvalidArgument, "one word"),
        (lambda s: skinware.ServiceWriter(s, "x", "u1", ("s" * 40, 1), records=1), skinware.InvalidArgument, "32 bytes"),
        (lambda s: skinware.ServiceWriter(s, "x", "<u8", ("s", 1), records=2**62), skinware.InvalidArgument, "do not fit"),
    ],
)
def test_bad_input_raises_a_typed_error_that_says_what_to_do(skin, make, error, words):
    with pytest.raises(error, match=words):
        make(skin)


def test_bad_arguments_to_reads_and_writes(layer):
    skin, writer = layer
    reader = skinware.Reader(skin, "pressure")
    reader.wait_newer(1.0)
    for bad in (np.zeros(72, np.float32), np.zeros(71, np.uint16), np.zeros((72, 1), np.uint16), np.zeros(144, np.uint16)[::2], [0] * 72):
        with pytest.raises(skinware.InvalidArgument, match="read_into"):
            reader.read_into(bad)
    readonly = np.zeros(72, np.uint16)
    readonly.flags.writeable = False
    with pytest.raises(skinware.InvalidArgument):
        reader.read_into(readonly)
    with pytest.raises(skinware.InvalidArgument, match="mode"):
        reader.read_into(np.zeros(72, np.uint16), mode="soon")
    for timeout in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="timeout"):
            reader.wait_newer(timeout)
    for hz in (0, -5, float("nan"), 2e6):
        with pytest.raises(skinware.InvalidArgument, match="Hz"):
            reader.periodic(hz)
    with pytest.raises(skinware.InvalidArgument, match="uint16"):
        writer.publish(np.zeros(72, np.int64))
    with pytest.raises(skinware.InvalidArgument, match="72 sensors"):
        writer.publish(np.zeros(70, np.uint16))
    with pytest.raises(skinware.InvalidArgument, match="uint16"):
        writer.publish([0] * 72)
    with pytest.raises(skinware.InvalidArgument, match="state"):
        writer.state = "sleeping"
    with pytest.raises(skinware.ChannelBusy, match="live writer"):
        skinware.Writer(skin, "pressure", writer.topology)
    with pytest.raises(skinware.SchemaMismatch, match="it is a layer"):
        skinware.ServiceReader(skin, "pressure", "u1", ("x", 1))
    reader.close()
    with pytest.raises(skinware.ReaderClosed):
        reader.wait_newer(0.1)
    with pytest.raises(skinware.ReaderClosed):
        reader.published_seq


def test_a_strided_view_publishes_what_it_shows(skin):
    topology = skinware.Topology.uniform("strided", 1, 1, 4)
    with skinware.Writer(skin, "strided", topology) as writer:
        values = np.arange(8, dtype=np.uint16)[::2]
        writer.publish(values, status=skinware.Status.PARTIAL, acquired_ns=12345)
        frame = skinware.Reader(skin, "strided").latest()
    assert frame.responses.tolist() == [0, 2, 4, 6]
    assert frame.status == skinware.Status.PARTIAL and frame.acquired_ns == 12345


def test_a_reader_sees_a_faulted_python_driver_and_its_recovery(skin):
    topology = skinware.Topology.uniform("flaky", 1, 1, 12)
    with skinware.Writer(skin, "flaky", topology, rate_hz=100) as writer:
        reader = skinware.Reader(skin, "flaky")
        writer.publish(np.ones(12, np.uint16))
        assert reader.latest().status == skinware.Status.OK
        writer.state = "faulted"
        writer.publish(np.zeros(12, np.uint16), status=skinware.Status.FAULT)
        frame = reader.latest()
        assert reader.state == "faulted" and frame.faulted
        assert [c.state for c in skinware.layers(skin)] == ["faulted"]
        writer.state = "running"
        writer.publish(np.full(12, 2, np.uint16))
        assert reader.state == "running" and not reader.latest().faulted
        reader.close()


def test_driver_in_another_process_killed_and_restarted_is_followed(skin):
    driver = start_driver(skin, "pressure", sensors=24, hz=200)
    reader = skinware.Reader(skin, "pressure")
    assert whole(reader.wait_newer(2.0))
    driver.kill()
    with pytest.raises(skinware.WriterGone):
        for _ in range(10):  # frames published before the kill come first
            reader.wait_newer(0.3)
    assert reader.state == "gone"
    driver = start_driver(skin, "pressure", sensors=24, hz=200)
    try:
        # The same reader, not re-attached, reads the new writer's frames.
        frame = reader.wait_newer(2.0)
        assert reader.generation == 2 and reader.state == "running"
        assert whole(frame)
        assert frame.seq < 1000  # numbered afresh by the new writer
    finally:
        code, _, err = driver.stop()
        assert code == 0, err
    reader.close()


def test_a_channel_recreated_with_another_layout_raises_layout_changed(skin):
    driver = start_driver(skin, "pressure", sensors=24, hz=200)
    reader = skinware.Reader(skin, "pressure")
    reader.wait_newer(2.0)
    driver.kill()
    bigger = start_driver(skin, "pressure", sensors=48, hz=200)
    try:
        with pytest.raises(skinware.LayoutChanged, match="48 sensors"):
            for _ in range(10):  # frames published before the kill come first
                reader.wait_newer(1.0)
        with pytest.raises(skinware.LayoutChanged):
            reader.latest()
        # A new reader reads the new layout.
        assert skinware.Reader(skin, "pressure").wait_newer(2.0).responses.shape == (48,)
    finally:
        bigger.kill()


def test_same_size_but_another_topology_is_a_layout_change(skin):
    first = skinware.Topology("pad", [(0, 0, [1, 2, 3, 4])], rate_hz=100)
    second = skinware.Topology("pad", [(0, 0, [5, 6, 7, 8])], rate_hz=100)
    from conftest import PythonProcess

    code = """
import sys, numpy as np, skinware
uids = [int(u) for u in sys.argv[2].split(",")]
t = skinware.Topology("pad", [(0, 0, uids)], rate_hz=100)
with skinware.Writer(sys.argv[1], "pad", t) as w:
    print("ready", flush=True)
    for _ in w.ticks():
        w.publish(np.zeros(4, np.uint16))
"""
    with PythonProcess(code, skin, "1,2,3,4") as one:
        assert one.process.stdout.readline().strip() == "ready"
        reader = skinware.Reader(skin, "pad")
        assert reader.topology == first
        reader.wait_newer(2.0)
    with PythonProcess(code, skin, "5,6,7,8") as two:
        assert two.process.stdout.readline().strip() == "ready"
        assert skinware.Reader(skin, "pad").topology == second
        with pytest.raises(skinware.LayoutChanged, match="other sensor uids"):
            for _ in range(50):
                reader.wait_newer(1.0)


RESTARTABLE = """
import sys, numpy as np, skinware
uids = [int(u) for u in sys.argv[2].split(",")]
t = skinware.Topology("pad", [(0, 0, uids)], rate_hz=100)
with skinware.Writer(sys.argv[1], "pad", t) as w:
    print("ready", flush=True)
    for k, _ in zip(range(int(sys.argv[3])), w.ticks()):
        w.publish(np.full(4, k, np.uint16))
"""


def test_a_cleanly_restarted_writer_with_another_topology_is_a_layout_change(skin):
    from conftest import PythonProcess

    # The first writer stops cleanly (removing the channel's name), so its
    # successor starts again at generation 1: the reader must still notice.
    with PythonProcess(RESTARTABLE, skin, "1,2,3,4", "30") as one:
        assert one.process.stdout.readline().strip() == "ready"
        reader = skinware.Reader(skin, "pad")
        reader.wait_newer(2.0)
        assert one.process.wait(10) == 0
    with PythonProcess(RESTARTABLE, skin, "5,6,7,8", "100000") as two:
        assert two.process.stdout.readline().strip() == "ready"
        assert skinware.Reader(skin, "pad").generation == 1
        with pytest.raises(skinware.LayoutChanged, match="uids"):
            for _ in range(100):
                reader.wait_newer(1.0)


def test_a_cleanly_restarted_writer_with_the_same_topology_is_followed(skin):
    from conftest import PythonProcess

    with PythonProcess(RESTARTABLE, skin, "1,2,3,4", "30") as one:
        assert one.process.stdout.readline().strip() == "ready"
        reader = skinware.Reader(skin, "pad")
        reader.wait_newer(2.0)
        assert one.process.wait(10) == 0
    with PythonProcess(RESTARTABLE, skin, "1,2,3,4", "100000") as two:
        assert two.process.stdout.readline().strip() == "ready"
        seqs = [frame.seq for _, frame in zip(range(60), reader.frames(gone_timeout=5.0))]
        assert reader.state == "running" and seqs[-1] < 200


def test_iterators_raise_writer_gone_after_gone_timeout_and_ride_through_a_restart(skin):
    driver = start_driver(skin, "pressure", sensors=24, hz=200)
    reader = skinware.Reader(skin, "pressure")
    reader.wait_newer(2.0)
    frames = reader.frames(gone_timeout=3.0)
    next(frames)
    driver.kill()
    # A successor within the grace period: the iteration goes on.
    driver = start_driver(skin, "pressure", sensors=24, hz=200)
    for _, frame in zip(range(20), frames):
        assert whole(frame)
    driver.kill()
    started = time.monotonic()
    with pytest.raises(skinware.WriterGone, match="gone for 1.0 s"):
        for _ in reader.periodic(50, gone_timeout=1.0):
            pass
    assert 0.9 < time.monotonic() - started < 5.0
    with pytest.raises(skinware.WriterGone):
        for _ in reader.frames(gone_timeout=0.5):
            pass
    reader.close()


def test_closing_a_reader_ends_an_iteration_in_another_thread(layer):
    skin, _ = layer
    reader = skinware.Reader(skin, "pressure")
    seen = []
    ended = threading.Event()

    def iterate():
        for frame in reader.frames():
            seen.append(frame.seq)
        ended.set()

    thread = threading.Thread(target=iterate)
    thread.start()
    wait_for(lambda: len(seen) > 5, what="frames in the iterating thread")
    reader.close()
    thread.join(5)
    assert ended.is_set()


def test_an_unlabelled_service_has_one_record_each(skin):
    with skinware.ServiceWriter(skin, "many", "<u2", ("lab.many", 1), records=300, rate_hz=10) as service:
        service.publish(np.arange(300, dtype="<u2"))
        reader = skinware.ServiceReader(skin, "many", "<u2", ("lab.many", 1))
        assert len(reader) == 300 and reader.labels == []
        assert reader.latest().records.tolist() == list(range(300))
        reader.close()


def test_array_conversion_follows_numpys_copy_rules(layer):
    skin, _ = layer
    frame = skinware.Reader(skin, "pressure").wait_newer(1.0)
    assert np.asarray(frame) is frame.responses
    assert np.array(frame, copy=True) is not frame.responses
    with pytest.raises(ValueError, match="copy"):
        np.asarray(frame, dtype=np.float64, copy=False)
