"""The live twin's views: the Foxglove server checked with a real client of its WebSocket protocol
(``websockets``, the protocol's binary frames decoded here, the alarms' protobuf decoded from the
schema the server advertised), and the Rerun view read back with Rerun's own reader. Made-up twin
outputs (twin_data.py); every value compared with what the view was given."""

import asyncio
import base64
import collections
import json
import os
import socket
import struct
import threading
import time

import mujoco
import numpy as np
import pytest
import rerun as rr
from twin_data import NODES, START_UTC_NS, feed, twin_run
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

from pendsim_bridge.errors import ProcessError
from pendsim_bridge.report.twin_foxglove import TwinFoxgloveView
from pendsim_bridge.report.twin_rerun import TwinRerunView
from pendsim_bridge.report.twin_views import NIS_LIMIT_95, TwinView, TwinViews
from pendsim_mj.rig.model import exact_mjcf

SUBPROTOCOLS = ["foxglove.websocket.v1", "foxglove.sdk.v1"]  # what a current Foxglove app or Lichtblick offers


@pytest.fixture(scope="module")
def mjcf():
    return exact_mjcf()


@pytest.fixture(scope="module")
def run():
    return twin_run(3.0)


def _listening(port: int) -> list[str]:
    """Local addresses (hex, /proc/net/tcp) listening on a TCP port."""
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(table) as f:
            for line in f.readlines()[1:]:
                fields = line.split()
                if fields[3] == "0A" and int(fields[1].split(":")[1], 16) == port:
                    found.append(fields[1].split(":")[0])
    return found


def _utc_ns(t_s: float) -> int:
    return START_UTC_NS + round(t_s * 1e9)


def _pendulum_xyzw(phi: float) -> list[float]:
    """A swing by phi about the hinge axis, world -y (models/pendulums.xml), as x, y, z, w."""
    return [0.0, -np.sin(phi / 2), 0.0, np.cos(phi / 2)]


def _fields(data: bytes) -> list[tuple[int, int | bytes]]:
    """The (field number, value) pairs of a protobuf message (wire format: varints and
    length-delimited fields; fixed-width ones, which these messages use only as doubles, as bytes)."""

    def varint(i: int) -> tuple[int, int]:
        value = shift = 0
        while True:
            byte = data[i]
            value |= (byte & 0x7F) << shift
            i, shift = i + 1, shift + 7
            if byte < 0x80:
                return value, i

    out, i = [], 0
    while i < len(data):
        key, i = varint(i)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, i = varint(i)
        elif wire == 2:
            n, i = varint(i)
            value, i = data[i : i + n], i + n
        elif wire == 1:
            value, i = data[i : i + 8], i + 8
        else:
            assert wire == 5, wire
            value, i = data[i : i + 4], i + 4
        out.append((number, value))
    return out


def _decode(schema_b64: str, type_name: str, payload: bytes) -> dict:
    """A protobuf message decoded by the FileDescriptorSet the server advertised: field names and
    nested message types from the descriptors (descriptor.proto: FileDescriptorSet.file = 1,
    FileDescriptorProto.package = 2 and .message_type = 4, DescriptorProto.name = 1 and .field = 2,
    FieldDescriptorProto.name = 1, .number = 3, .label = 4, .type = 5, .type_name = 6)."""
    messages = {}
    for _, file in _fields(base64.b64decode(schema_b64)):
        package = next(v.decode() for n, v in _fields(file) if n == 2)
        for _, message in (f for f in _fields(file) if f[0] == 4):
            fields = dict(_fields(message))
            layout = {}
            for _, field in (f for f in _fields(message) if f[0] == 2):
                spec = dict(_fields(field))
                layout[spec[3]] = (spec[1].decode(), spec[5], spec.get(6, b"").decode().lstrip("."), spec[4] == 3)
            messages[f"{package}.{fields[1].decode()}"] = layout

    def decode(name: str, data: bytes) -> dict:
        out: dict = {}
        for number, value in _fields(data):
            field, kind, nested, repeated = messages[name][number]
            if kind == 11:  # a message
                value = decode(nested, value)
            elif kind == 9:  # a string
                value = value.decode()
            elif kind == 1:  # a double
                value = struct.unpack("<d", value)[0]
            if repeated:
                out.setdefault(field, []).append(value)
            else:
                out[field] = value
        return out

    return decode(type_name, payload)


async def _session(view: TwinFoxgloveView, run) -> tuple[dict, dict, dict[str, list[tuple[int, bytes]]]]:
    """Connect, read serverInfo and advertise, subscribe to every channel, feed the view, and
    collect the binary messageData frames per topic (subscription id -> topic)."""
    async with connect(f"ws://127.0.0.1:{view.port}", subprotocols=SUBPROTOCOLS) as ws:
        assert ws.subprotocol == "foxglove.sdk.v1"
        info = json.loads(await ws.recv())
        advertise = json.loads(await ws.recv())
        assert info["op"] == "serverInfo" and advertise["op"] == "advertise"
        channels = {c["topic"]: c for c in advertise["channels"]}
        subscriptions = {100 + k: topic for k, topic in enumerate(sorted(channels))}
        await ws.send(json.dumps({
            "op": "subscribe",
            "subscriptions": [{"id": s, "channelId": channels[t]["id"]} for s, t in subscriptions.items()],
        }))  # fmt: skip
        deadline = time.monotonic() + 10
        while not (all(c.has_sinks() for c in view.channels.values()) and view.tf.has_sinks()):
            assert time.monotonic() < deadline, "the server did not take the subscriptions"
            await asyncio.sleep(0.01)
        feed(view, run)
        expected = 2 * len(run.estimates) + len(run.forecasts) + len(run.checks) + len(run.alarms)
        expected += len(run.diagnostics)
        frames: dict[str, list[tuple[int, bytes]]] = collections.defaultdict(list)
        received = 0
        while received < expected:
            frame = await asyncio.wait_for(ws.recv(), 10)
            assert isinstance(frame, bytes)
            if frame[0] != 1:  # 2: time
                continue
            subscription, log_time = struct.unpack_from("<IQ", frame, 1)
            topic = subscriptions[subscription]
            frames[topic].append((log_time, frame[13:]))
            received += topic != "/tf"
        return info, channels, frames


def test_a_foxglove_client_receives_every_record_as_given_with_its_utc_log_time(run, mjcf):
    view = TwinFoxgloveView(START_UTC_NS, NODES, mjcf_xml=mjcf, port=0)
    try:
        assert isinstance(view, TwinView) and view.url == f"ws://127.0.0.1:{view.port}"
        assert _listening(view.port) == ["0100007F"]  # loopback only
        info, channels, frames = asyncio.run(_session(view, run))
    finally:
        view.close()
    assert info["name"] == "pendsim twin" and "time" in info["capabilities"]
    assert set(channels) == {
        "/twin/estimate", "/twin/innovation", "/twin/forecast", "/twin/parameters", "/twin/alarms", "/diagnostics",
        "/tf",
    }  # fmt: skip
    assert channels["/diagnostics"]["schemaName"] == "diagnostic_msgs/msg/DiagnosticArray"
    assert (channels["/twin/alarms"]["schemaName"], channels["/twin/alarms"]["encoding"]) == (
        "foxglove.Log",
        "protobuf",
    )
    est = run.estimates
    rows = np.arange(len(est))

    # /twin/estimate and /twin/innovation: one message per sample, in order
    estimate = [(t, json.loads(p)) for t, p in frames["/twin/estimate"]]
    assert [t for t, _ in estimate] == [_utc_ns(x) for x in est.t_s]
    got = {key: np.array([m[key] for _, m in estimate]) for key in estimate[0][1] if key not in ("state", "sigma")}
    np.testing.assert_array_equal(got["t_s"], est.t_s)
    assert got["node"].tolist() == [NODES[k] for k in est.node]
    np.testing.assert_array_equal(got["measured_angle_rad"], est.measured[:, 0])
    np.testing.assert_array_equal(got["rate_rad_s"], est.state[rows, 2 + est.node])
    np.testing.assert_allclose(got["angle_upper_rad"], est.state[rows, est.node] + 3 * est.sigma[rows, est.node])
    assert np.array([list(m["state"].values()) for _, m in estimate]).tolist() == est.state.tolist()
    innovation = [json.loads(p) for _, p in frames["/twin/innovation"]]
    np.testing.assert_array_equal([m["rate_rad_s"] for m in innovation], est.innovation[:, 1])
    np.testing.assert_allclose([m["angle_lower_rad"] for m in innovation], -3 * est.innovation_sigma[:, 0])
    np.testing.assert_array_equal([m["nis"] for m in innovation], est.nis)
    assert {m["nis_limit_95"] for m in innovation} == {NIS_LIMIT_95}
    assert pytest.approx(5.9915, abs=1e-4) == NIS_LIMIT_95  # chi^2(2) at 95 %: -2 ln 0.05

    # /twin/forecast and /twin/parameters: once a second; NaN (no baseline yet) arrives as null
    (made, forecast), (t_first, first) = run.forecasts[-1], frames["/twin/forecast"][-1]
    message = json.loads(first)
    assert t_first == _utc_ns(made) and message["made_at_s"] == made
    np.testing.assert_array_equal(message["mean"]["phi2_rad"], forecast.mean[:, 1])
    np.testing.assert_array_equal(message["sigma"]["omega1_rad_s"], forecast.sigma[:, 2])
    parameters = [json.loads(p) for _, p in frames["/twin/parameters"]]
    assert [p["t_s"] for p in parameters] == [c.t_s for c in run.checks]
    assert parameters[0]["parameters"][0]["reference"] is None and parameters[0]["parameters"][0]["z"] is None
    last = {p["name"]: p for p in parameters[-1]["parameters"]}
    assert last["b1_n_m_s"]["value"] == run.checks[-1].value[0]
    assert last["b1_n_m_s"]["z"] == pytest.approx(run.checks[-1].z[0])

    # /twin/alarms: a foxglove.Log at WARNING with the alarm's text and instant
    ((t_alarm, payload),) = frames["/twin/alarms"]
    log = _decode(channels["/twin/alarms"]["schema"], "foxglove.Log", payload)
    alarm = run.alarms[0]
    assert t_alarm == _utc_ns(alarm.t_s) and log["level"] == 3  # WARNING
    assert log["message"] == alarm.describe(START_UTC_NS)  # with its times of day
    assert log["timestamp"]["seconds"] * 10**9 + log["timestamp"]["nanos"] == _utc_ns(alarm.t_s)

    # /diagnostics: the DiagnosticArray's fields
    diagnostics = [json.loads(p) for _, p in frames["/diagnostics"]]
    assert len(diagnostics) == len(run.diagnostics)
    status = diagnostics[-1]["status"][0]
    given = run.diagnostics[-1][1][0]
    assert (status["level"], status["name"], status["message"]) == (given.level, given.name, given.message)
    assert status["values"] == [{"key": k, "value": v} for k, v in given.values]
    stamp = diagnostics[-1]["header"]["stamp"]
    assert stamp["sec"] * 10**9 + stamp["nsec"] == _utc_ns(run.diagnostics[-1][0])

    # /tf: each pendulum's frame posed from the latest estimate of each send
    assert frames["/tf"][-1][0] == _utc_ns(est.t_s[-1])


def test_the_pendulum_frames_turn_by_the_estimated_angles(mjcf):
    run = twin_run(0.1)
    view = TwinFoxgloveView(START_UTC_NS, NODES, mjcf_xml=mjcf, port=0)

    async def session():
        async with connect(f"ws://127.0.0.1:{view.port}", subprotocols=SUBPROTOCOLS) as ws:
            await ws.recv()
            channels = {c["topic"]: c for c in json.loads(await ws.recv())["channels"]}
            await ws.send(
                json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": channels["/tf"]["id"]}]})
            )
            while not view.tf.has_sinks():
                await asyncio.sleep(0.01)
            view.add_estimates(run.batches[0])
            view.send()
            while (frame := await asyncio.wait_for(ws.recv(), 10))[0] != 1:
                pass
            return channels["/tf"]["schema"], frame[13:]

    try:
        schema, payload = asyncio.run(session())
    finally:
        view.close()
    tf = _decode(schema, "foxglove.FrameTransforms", payload)
    state = run.batches[0].state[-1]
    assert len(tf["transforms"]) == 2
    for k, transform in enumerate(tf["transforms"]):
        assert (transform["parent_frame_id"], transform["child_frame_id"]) == ("world", NODES[k])
        r = transform["rotation"]
        xyzw = [r.get(axis, 0.0) for axis in "xyzw"]  # proto3 leaves zeros out
        np.testing.assert_allclose(xyzw, _pendulum_xyzw(state[k]), atol=1e-15)
        assert transform["timestamp"]["seconds"] * 10**9 + transform["timestamp"]["nanos"] == _utc_ns(
            run.batches[0].t_s[-1]
        )


def test_a_client_offering_only_the_old_subprotocol_name_is_refused(mjcf):
    """foxglove-sdk 0.30 speaks ``foxglove.sdk.v1`` (the same protocol, renamed): an app that offers
    only ``foxglove.websocket.v1`` (Foxglove Studio before the rename, Lichtblick before 1.22)
    cannot connect. docs/twin.md says so."""
    view = TwinFoxgloveView(START_UTC_NS, NODES, port=0)

    async def old_client():
        async with connect(f"ws://127.0.0.1:{view.port}", subprotocols=["foxglove.websocket.v1"]):
            pass

    try:
        with pytest.raises(InvalidStatus):
            asyncio.run(old_client())
    finally:
        view.close()


def test_a_port_in_use_is_one_error_naming_it():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(ProcessError, match=f"port {port} on 127.0.0.1 is in use") as error:
            TwinFoxgloveView(START_UTC_NS, NODES, port=port)
    assert "\n" not in str(error.value)
    with pytest.raises(ProcessError, match="must be an IP address"):
        TwinFoxgloveView(START_UTC_NS, NODES, bind="localhost")


def _threads() -> int:
    return len(os.listdir("/proc/self/task"))


def test_close_stops_the_server_and_leaves_nothing_running(run):
    python_threads = set(threading.enumerate())
    counts = []
    for _ in range(2):  # the SDK's runtime threads are shared, started once: none more per view
        view = TwinFoxgloveView(START_UTC_NS, NODES, port=0)

        async def connected_until_closed(view=view):
            async with connect(f"ws://127.0.0.1:{view.port}", subprotocols=SUBPROTOCOLS) as ws:
                await ws.recv()
                view.add_estimates(run.batches[0])
                view.close()
                view.close()  # idempotent
                with pytest.raises(ConnectionClosed):
                    while True:
                        await asyncio.wait_for(ws.recv(), 10)

        asyncio.run(connected_until_closed())
        assert not _listening(view.port)
        counts.append(_threads())
    assert counts[1] == counts[0]
    assert set(threading.enumerate()) == python_threads


def _rrd_rows(path):
    """entity -> (times s, values (n, k)) of the Scalars; entity -> rows; entity -> static rows."""
    series, rows, static = {}, collections.Counter(), collections.Counter()
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        entity = str(chunk.entity_path)
        (static if chunk.is_static else rows)[entity] += chunk.num_rows
        if chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        if "Scalars:scalars" in batch.schema.names:
            t = batch.column("time").cast("int64").to_numpy() * 1e-9
            v = np.array(batch.column("Scalars:scalars").to_pylist())
            old_t, old_v = series.get(entity, (np.zeros(0), np.zeros((0, v.shape[1]))))
            series[entity] = (np.concatenate([old_t, t]), np.concatenate([old_v, v]))
    return series, rows, static


def test_the_rerun_view_records_every_stream_with_its_bands(run, mjcf, tmp_path):
    rrd = tmp_path / "twin.rrd"
    view = TwinRerunView(START_UTC_NS, NODES, mjcf, rrd=rrd)
    assert isinstance(view, TwinView)
    feed(view, run)
    view.close()
    view.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["twin.rrd"]  # published, nothing partial left
    series, rows, static = _rrd_rows(rrd)
    est = run.estimates
    for k, node in enumerate(NODES):
        mine = est.node == k
        t, angle = series[f"/twin/{node}/angle"]
        np.testing.assert_allclose(t, est.t_s[mine], atol=1e-9)
        s = 3 * est.sigma[mine, k]
        expected = np.stack(
            [est.measured[mine, 0], est.state[mine, k], est.state[mine, k] + s, est.state[mine, k] - s], 1
        )
        np.testing.assert_allclose(angle, expected, rtol=1e-12)
        _, rate = series[f"/twin/{node}/rate"]
        np.testing.assert_array_equal(rate[:, 1], est.state[mine, 2 + k])
        _, innovation = series[f"/twin/{node}/innovation/rate"]
        np.testing.assert_allclose(innovation[:, 2], -3 * est.innovation_sigma[mine, 1])
        _, nis = series[f"/twin/{node}/nis"]
        np.testing.assert_array_equal(nis[:, 0], est.nis[mine])
        # predicted against measured: each forecast's stretch until the next one was made
        t, predicted = series[f"/twin/{node}/prediction/forecast"]
        stretches = [
            (f.t_s[f.t_s < until], f.mean[f.t_s < until, k])
            for (_, f), until in zip(
                run.forecasts, [m for m, _ in run.forecasts[1:]] + [est.t_s[-1] + 1e-9], strict=True
            )
        ]
        np.testing.assert_allclose(t, np.concatenate([s[0] for s in stretches]), atol=1e-9)
        np.testing.assert_array_equal(predicted[:, 0], np.concatenate([s[1] for s in stretches]))
    # the rig posed at every sample, its geometry once
    assert rows["/rig/m1"] == rows["/rig/m2"] == len(est)
    assert static["/rig/m1/geoms"] == static["/rig/frame/geoms"] == 1
    model = mujoco.MjModel.from_xml_string(mjcf)
    for k, body in enumerate(("m1", "m2")):  # each body turned about the hinge by its swing angle
        quats, positions = [], []
        for chunk in rr.chunk.RrdReader(str(rrd)).stream():
            if str(chunk.entity_path) == f"/rig/{body}" and not chunk.is_static:
                batch = chunk.to_record_batch()
                quats += [q[0] for q in batch.column("Transform3D:quaternion").to_pylist()]
                positions += [p[0] for p in batch.column("Transform3D:translation").to_pylist()]
        xyzw = np.array(quats)
        np.testing.assert_allclose(np.linalg.norm(xyzw[:, :3], axis=1), np.abs(np.sin(est.state[:, k] / 2)), atol=1e-6)
        np.testing.assert_allclose(positions, np.repeat(model.body(body).pos[None], len(est), axis=0), atol=1e-6)
    # parameters with their references; z-scores; the latest forecast ahead; alarms and health
    t, b1 = series["/twin/parameters/b1_n_m_s"]
    np.testing.assert_array_equal(t, [c.t_s for c in run.checks])
    np.testing.assert_array_equal(b1[1:, 3], [c.reference[0] for c in run.checks[1:]])
    assert np.isnan(b1[0, 3])
    assert rows["/twin/forecast/m1"] == len(run.forecasts)
    texts = {}
    for chunk in rr.chunk.RrdReader(str(rrd)).stream():
        if str(chunk.entity_path) in ("/twin/alarms", "/twin/diagnostics") and not chunk.is_static:
            batch = chunk.to_record_batch()
            texts.setdefault(str(chunk.entity_path), []).extend(
                zip(batch.column("TextLog:level").to_pylist(), batch.column("TextLog:text").to_pylist(), strict=True)
            )
    assert texts["/twin/alarms"] == [(["WARN"], [run.alarms[0].describe(START_UTC_NS)])]
    # a status is logged when it changes: b1 ok, then changing at 2 s; node m1 ok once
    assert [text[0] for _, text in texts["/twin/diagnostics"]] == [
        "twin: b1_n_m_s: ok",
        "twin: node m1: ok",
        "twin: b1_n_m_s: changing",
    ]


def test_one_failing_view_does_not_keep_the_others_open(run, mjcf, tmp_path):
    class Failing:
        def __getattr__(self, name):
            def fail(*args):
                raise RuntimeError("broken view")

            return fail

    fox = TwinFoxgloveView(START_UTC_NS, NODES, port=0)
    views = TwinViews([Failing(), fox])
    with pytest.raises(RuntimeError, match="broken view"):
        views.close()
    assert fox.closed and not _listening(fox.port)


def _free_port_pair() -> int:
    for _ in range(50):
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port + 1))
            except OSError:
                continue
        return port
    raise RuntimeError("no two adjacent free ports")


def test_the_served_rerun_viewer_listens_on_loopback_only_and_ends_with_the_view(run, mjcf):
    port = _free_port_pair()
    view = TwinRerunView(START_UTC_NS, NODES, mjcf, serve=("127.0.0.1", port))
    try:
        assert view.url is not None and view.url.startswith(f"http://127.0.0.1:{port}/?url=")
        for p in (port, port + 1):
            assert _listening(p) == ["0100007F"], p
        view.add_estimates(run.batches[0])
        view.send()
    finally:
        view.close()
    assert not _listening(port) and not _listening(port + 1)
