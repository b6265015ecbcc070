"""Against `skin run` of the virtual skin with both services: layers, every
reader mode, the geometry as numpy arrays, and the services' typed readers."""

from __future__ import annotations

import numpy as np
import pytest

import skinware
from conftest import wait_for


def test_layers_are_listed_with_their_state(virtual_skin):
    layers = skinware.layers(virtual_skin)
    assert [c.name for c in layers] == ["body-0", "body-1"]
    assert all(c.state == "running" and c.kind == "layer" for c in layers)
    assert sum(c.sensors for c in layers) == 3000
    services = {c.name for c in skinware.services(virtual_skin)}
    assert services == {"contact", "contact-taxels", "motion"}


def test_every_reader_mode_on_a_layer(virtual_skin):
    with skinware.Reader(virtual_skin, "body-0") as reader:
        sensors = len(reader.topology)
        newer = reader.wait_newer(2.0)
        latest = reader.latest()
        periodic = [f for _, f in zip(range(3), reader.periodic(25))]
        requested = reader.request(2.0)
        out = np.empty(sensors, np.uint16)
        into = reader.read_into(out, mode="newer")
        for frame in (newer, latest, requested, into, *periodic):
            assert frame.responses.shape == (sensors,) and frame.responses.dtype == np.uint16
            assert frame.status == 0
        assert requested.seq > newer.seq
        assert reader.period == pytest.approx(1 / 50)
        assert reader.writer_stats["frames"] > 0


def test_geometry_as_numpy_arrays(virtual_skin):
    geometry = skinware.Geometry.open(virtual_skin)
    n = len(geometry)
    assert n == 3000 and geometry.layers == ["body-0", "body-1"]
    assert geometry.positions.shape == (n, 3) and geometry.positions.dtype == np.float32
    assert geometry.normals.shape == (n, 3)
    assert np.allclose(np.linalg.norm(geometry.normals, axis=1), 1.0, atol=1e-3)
    assert geometry.map.shape == (n, 2) and geometry.map.dtype == np.float32
    assert geometry.map_pieces.shape == (n,)
    assert geometry.radii.shape == (n,) and (geometry.radii > 0).all()
    assert geometry.link_of.shape == (n,) and geometry.link_of.max() < len(geometry.links)
    indptr, indices = geometry.neighbours
    assert indptr.shape == (n + 1,) and indptr[0] == 0 and indptr[-1] == len(indices)
    assert (np.diff(indptr.astype(np.int64)) >= 0).all() and (indices < n).all()
    # The graph is symmetric: j is a neighbour of i exactly when i is one of j.
    edges = {(i, int(j)) for i in range(n) for j in indices[indptr[i] : indptr[i + 1]]}
    assert all((j, i) in edges for i, j in edges)
    assert set(geometry.regions) == {"torso", "left_forearm"}
    torso = geometry.region("torso")
    assert torso.dtype == np.uint32 and len(torso) > 0 and (np.diff(torso.astype(np.int64)) > 0).all()
    link = geometry.links.index("torso")
    assert (geometry.link_of[torso] == link).all()
    covered = np.concatenate([geometry.subregions[s] for s in geometry.region_subregions["torso"]])
    assert sorted(covered.tolist()) == torso.tolist()
    start, end = geometry.layer_range("body-1")
    assert geometry.layer_starts.tolist() == [0, start, end] and end == n
    assert geometry.global_index("body-1", 0) == start
    assert geometry.locate(start)[:2] == ("body-1", 0)
    assert len(geometry.topology("body-0")) == start
    for array in (geometry.positions, geometry.normals, geometry.map, indptr, indices, torso):
        assert not array.flags.writeable
    with pytest.raises(skinware.InvalidArgument, match="no region"):
        geometry.region("tail")
    with pytest.raises(skinware.InvalidArgument, match="no layer"):
        geometry.layer_range("body-7")


def test_contact_service_as_a_structured_array(virtual_skin):
    geometry = skinware.Geometry.open(virtual_skin)
    with skinware.ContactReader(virtual_skin) as contacts:
        assert contacts.labels == ["torso", "left_forearm"]
        assert contacts.dtype == skinware.REGION_CONTACTS_DTYPE

        def touched():
            frame = contacts.wait_newer(2.0)
            return frame if (frame.records["count"] > 0).all() else None

        frame = wait_for(touched, timeout=20, what="a contact on both regions")
        assert frame.records.shape == (2,) and not frame.records.flags.writeable
        torso = frame.records[0]
        contact = torso["contacts"][0]
        assert contact["taxels"] > 0 and contact["total"] > 0
        assert int(contact["peak_sensor"]) in set(geometry.region("torso").tolist())
        assert np.isfinite(contact["centroid"]).all()


def test_motion_and_taxel_state_services(virtual_skin):
    with skinware.MotionReader(virtual_skin) as motion:
        assert motion.labels == ["torso", "left_forearm"]

        def moving():
            frame = motion.wait_newer(2.0)
            return frame if frame.records["flags"][1] & skinware.MotionFlags.CONTACT else None

        frame = wait_for(moving, timeout=20, what="the forearm contact in the motion service")
        assert frame.records.dtype == skinware.MOTION_DTYPE
    with skinware.TaxelStateReader(virtual_skin) as states:
        frame = states.wait_newer(2.0)
        assert frame.records.shape == (3000,) and frame.records.dtype == np.uint8
        assert set(np.unique(frame.records).tolist()) <= {int(s) for s in skinware.TaxelState}
    with pytest.raises(skinware.SchemaMismatch):
        skinware.ContactReader(virtual_skin, "motion")
    with pytest.raises(skinware.SchemaMismatch, match="layer"):
        skinware.MotionReader(virtual_skin, "body-0")


EXAMPLES = __import__("conftest").REPO / "examples" / "python"


def test_the_contact_logger_example_logs_contacts(virtual_skin):
    import subprocess
    import sys

    result = subprocess.run(
        [sys.executable, str(EXAMPLES / "contact_logger.py"), "--skin", virtual_skin, "--seconds", "1.5"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].startswith("time_s,seq,region,taxels")
    regions = {line.split(",")[2] for line in lines[1:]}
    assert regions == {"torso", "left_forearm"}, lines[:5]


def test_the_heatmap_example_draws_the_skin(virtual_skin, tmp_path):
    import subprocess
    import sys

    pytest.importorskip("matplotlib", reason="the heatmap example needs matplotlib")
    image = tmp_path / "skin.png"
    result = subprocess.run(
        [sys.executable, str(EXAMPLES / "heatmap.py"), "--skin", virtual_skin, "--frames", "10", "--save", str(image)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert image.stat().st_size > 10_000 and "after 10 frames" in result.stdout
