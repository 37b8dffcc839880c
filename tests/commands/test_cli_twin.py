"""pendsim twin on a replayed recording: what a newcomer types, the twin's estimate against the
simulation's own truth (the recording's /joint_states, read with the mcap library), the twin's
recording read back by pendsim's commands, and bad input refused before anything is written."""

from __future__ import annotations

import dataclasses
import json
import math
import re

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from pendsim_bridge.acquire.twin.summary import event_line
from pendsim_bridge.cli import main
from pendsim_bridge.io import twin_topics

HOLD_S = 1.0


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A 14 s release from 30 deg held for 1 s, as `pendsim record` writes it."""
    path = tmp_path_factory.mktemp("twin") / "run.mcap"
    args = ["record", "-o", str(path), "--duration-s", "14", "--hold-s", str(HOLD_S), "--ideal-timing"]
    assert main(args) == 0
    return path


@pytest.fixture(scope="module")
def replayed(recording, tmp_path_factory):
    out = tmp_path_factory.mktemp("twin_out") / "twin.mcap"
    assert main(["twin", "--replay", str(recording), "--speed", "0", "-o", str(out)]) == 0
    return out


def _messages(path, topic):
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [(m.log_time, msg) for _, _, m, msg in reader.iter_decoded_messages(topics=[topic])]


def test_the_twin_tracks_the_simulation_within_half_a_degree_after_two_seconds(recording, replayed):
    truth = _messages(recording, "/joint_states")
    t_truth = np.array([t for t, _ in truth], dtype=float)
    phi_truth = np.array([m.position for _, m in truth])
    est = _messages(replayed, twin_topics.ESTIMATE_TOPIC)
    assert est[0][1].layout.dim[0].label == ",".join(twin_topics.ESTIMATE_COLUMNS)
    values = np.array([m.data for _, m in est])
    t = values[:, twin_topics.ESTIMATE_COLUMNS.index("t_value_s")]  # s on the recording's clock
    phi = values[:, [twin_topics.ESTIMATE_COLUMNS.index(n) for n in ("phi1_rad", "phi2_rad")]]
    t_truth = (t_truth - t_truth[0]) * 1e-9  # /joint_states starts with the recording (the hold)
    late = t > HOLD_S + 2.0
    assert late.sum() > 1500
    for k in range(2):
        true_phi = np.interp(t[late], t_truth, phi_truth[:, k])
        assert np.max(np.degrees(np.abs(phi[late, k] - true_phi))) < 0.5
    # the estimate starts after the release (its first swing teaches each node's frame), not while
    # the pendulum is held at 30 deg
    assert HOLD_S < t[0] < HOLD_S + 2.0


def test_a_recording_whose_log_times_are_arrivals_is_replayed_on_its_stamps(tmp_path):
    """``pendsim record`` with a transport latency logs each sample at its arrival: a node's log
    times tie and cross (the recorder's clock), M2's clock drifts 30 ppm. The replay takes each
    node's stamps through the clock fitted to its log times, as validate does, and tracks the
    simulation within half a degree."""
    rec = tmp_path / "late.mcap"
    args = ["record", "-o", str(rec), "--duration-s", "9", "--hold-s", str(HOLD_S), "--latency-s", "0.005",
            "--clock-drift-ppm", "30", "--packet-loss", "0.02"]  # fmt: skip
    assert main(args) == 0
    out = tmp_path / "twin.mcap"
    assert main(["twin", "--replay", str(rec), "--speed", "0", "-o", str(out)]) == 0
    truth = _messages(rec, "/joint_states")
    t_truth = (np.array([t for t, _ in truth], dtype=float) - truth[0][0]) * 1e-9
    phi_truth = np.array([m.position for _, m in truth])
    values = np.array([m.data for _, m in _messages(out, twin_topics.ESTIMATE_TOPIC)])
    t = values[:, twin_topics.ESTIMATE_COLUMNS.index("t_value_s")]
    late = t > HOLD_S + 2.0
    assert late.sum() > 800
    for k, name in enumerate(("phi1_rad", "phi2_rad")):
        error = values[late, twin_topics.ESTIMATE_COLUMNS.index(name)] - np.interp(t[late], t_truth, phi_truth[:, k])
        assert np.max(np.degrees(np.abs(error))) < 0.5


def test_a_driven_recording_is_replayed_with_its_torques_and_its_replay_again_gives_the_same(tmp_path):
    """A motor's sine torque on M1 (``record --torque1-n-m``): the twin holds the recorded drive at
    the middle of each interval it predicts over (held at the samples' own instants it left a
    mean NIS of 3.2 and false alarms), its forecasts carry it on (without it, 16-66 % within 3
    sigma), and its recording keeps ``/drive``, so a replay of it gives the same estimates."""
    rec = tmp_path / "driven.mcap"
    assert main(["record", "-o", str(rec), "--duration-s", "12", "--torque1-n-m", "sine:0.003,0.87"]) == 0
    out, again = tmp_path / "twin.mcap", tmp_path / "again.mcap"
    assert main(["twin", "--replay", str(rec), "--speed", "0", "-o", str(out)]) == 0
    with open(out, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}[twin_topics.TWIN_RESULT_METADATA]
    assert json.loads(meta["alarms"]) == []
    assert max(json.loads(meta["nis_mean"])) < 2.5
    # the forecasts carry the recorded drive over their horizon and hold within their band
    forecast = json.loads(meta["forecast"])
    scored = [(n, w) for n, w in zip(forecast["count"], forecast["within_3_sigma"], strict=True) if n]
    assert scored and all(w >= 0.9 for _, w in scored), forecast
    assert len(_messages(out, "/drive")) == len(_messages(rec, "/drive"))
    assert main(["twin", "--replay", str(out), "--speed", "0", "-o", str(again)]) == 0
    a = np.array([m.data for _, m in _messages(out, twin_topics.ESTIMATE_TOPIC)])
    b = np.array([m.data for _, m in _messages(again, twin_topics.ESTIMATE_TOPIC)])
    assert a.shape == b.shape and np.array_equal(a, b)


def test_health_checks_are_held_while_the_model_does_not_fit_and_the_summary_says_so(tmp_path, capsys):
    """Gyros whose bias wanders 100 times the BNO055's (``--gyro-bias-instability-rad-s 0.003``):
    the twin does not model a gyro bias, and the NIS of both nodes runs to 15-20. The parameters
    then absorb what the model does not explain (with M2's chip fusing on a clock 50 ppm fast,
    before the twin followed that drift, dry friction at M2 and the springs alarmed on this
    healthy rig); the health checks are held while a node's recent NIS exceeds 20, the events say
    so and the summary warns."""
    rec = tmp_path / "bias.mcap"
    assert main(["record", "-o", str(rec), "--duration-s", "100", "--gyro-bias-instability-rad-s", "0.003",
                 "--heading-deg", "60", "--mount-misalignment-deg", "10", "--packet-loss", "0.05"]) == 0  # fmt: skip
    capsys.readouterr()
    out = tmp_path / "twin.mcap"
    assert main(["twin", "--replay", str(rec), "--speed", "0", "-o", str(out)]) == 0
    captured = capsys.readouterr()
    said = captured.out
    with open(out, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}[twin_topics.TWIN_RESULT_METADATA]
    assert json.loads(meta["alarms"]) == []
    events = [what for _, what in json.loads(meta["events"])]
    assert any(e.startswith("health checks held: the model does not fit the data") for e in events)
    assert json.loads(meta["nis_mean"])[1] > 3.0 and "warning: the model does not fit the data" in said
    # the summary says which clock its times are on, and names exactly the channels that are not white
    lines = said.splitlines()
    summary = next(i for i, line in enumerate(lines) if line.startswith("twin: end of the recording after"))
    assert "(times below: s on the twin's clock, from its start)" in lines[summary]
    # the events were said as the replay went, on standard error (as a live twin says them)
    said_on_the_way = captured.err.splitlines()
    assert any(line.startswith("twin: health checks held: the model does not fit") for line in said_on_the_way)
    named = [
        f"m{k + 1} {name}"
        for key, names in (("whiteness_p", ("angle", "rate")),
                           ("accel_whiteness_p", ("accelerometer tangential", "accelerometer normal")))
        for k, node in enumerate(json.loads(meta[key]))
        for name, p in zip(names, node, strict=True)
        if p is not None and p <= 0.01
    ]  # fmt: skip
    note = [line for line in said.splitlines() if line.startswith("note: not white")]
    assert "m2 angle" in named and len(note) == 1
    assert note[0].split(": ")[2] == ", ".join(named)


def test_a_healthy_replay_raises_no_alarm_and_its_forecasts_hold(recording, replayed):
    with open(replayed, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    result = meta[twin_topics.TWIN_RESULT_METADATA]
    assert json.loads(result["alarms"]) == []
    forecast = json.loads(result["forecast"])
    scored = [w for w, n in zip(forecast["within_3_sigma"], forecast["count"], strict=True) if n]
    assert scored and min(scored) > 0.9
    assert meta[twin_topics.TWIN_METADATA]["source"].startswith("replay of")


def test_the_twins_recording_is_a_recording_pendsims_commands_read(replayed, tmp_path):
    assert main(["inspect", str(replayed)]) == 0
    again = tmp_path / "again.mcap"
    assert main(["twin", "--replay", str(replayed), "--speed", "0", "-o", str(again)]) == 0  # the twin's own file
    a = [m.data for _, m in _messages(replayed, twin_topics.ESTIMATE_TOPIC)]
    b = [m.data for _, m in _messages(again, twin_topics.ESTIMATE_TOPIC)]
    assert len(a) == len(b) and np.array_equal(np.array(a), np.array(b))


def test_parameters_and_diagnostics_are_written_once_a_second(replayed):
    params = _messages(replayed, twin_topics.PARAMETERS_TOPIC)
    diagnostics = _messages(replayed, "/diagnostics")
    assert 10 <= len(params) <= 14 and len(diagnostics) >= 10
    names = {s.name for s in diagnostics[-1][1].status}
    assert "pendsim twin: coupling_sin_n_m" in names and "pendsim twin: estimator" in names
    assert all(s.level == 0 for s in diagnostics[-1][1].status)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--speed", "2"], "--speed is for --replay"),
        (["--node", "m3=5601"], "m3"),
        (["--node", "m1=5701"], "give --node for each (e.g. --node m1=5701 --node m2=5702), or neither"),
        (["--track", "springs"], "allowed: all, none"),
        (["--threshold-sigma", "1"], "--threshold-sigma"),
    ],
)
def test_bad_options_are_one_line_and_exit_2(args, message, tmp_path, capsys):
    out = tmp_path / "twin.mcap"
    assert main(["twin", "-o", str(out), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pendsim: error:") and "\n" not in err and message in err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def _stating(src, dst, rig: dict[str, float]) -> None:
    """A copy of a recording whose stated rig (``pendsim/rig_parameters``) has these values, as
    ``pendsim acquire`` states the rig it is given, whatever the rig swinging is (the mcap library's
    own writer: every message, metadata record and attachment copied; the edited record without
    pendsim's CRC of its values, which would refuse it)."""
    from mcap.writer import Writer

    with open(src, "rb") as f, open(dst, "wb") as g:
        reader = make_reader(f)
        writer = Writer(g)
        writer.start(profile=reader.get_header().profile, library="the test")
        schemas: dict[int, int] = {0: 0}
        channels: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[channel.schema_id], channel.metadata
                )
            writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time)
        for record in reader.iter_metadata():
            values = dict(record.metadata)
            if record.name == "pendsim/rig_parameters":  # edited: pendsim's own CRC of the values dropped
                values = {k: v for k, v in values.items() if k != "pendsim.crc32"} | {
                    k: repr(v) for k, v in rig.items()
                }
            writer.add_metadata(record.name, values)
        for attachment in reader.iter_attachments():
            writer.add_attachment(attachment.create_time, attachment.log_time, attachment.name,
                                  attachment.media_type, attachment.data)  # fmt: skip
        writer.finish()


@pytest.fixture(scope="module")
def stiffer(tmp_path_factory):
    """A rig whose springs 1-2 and 1-3 are 6 % stiffer than the paper's (14 s, `pendsim record`),
    whose recording states the paper's rig, as `pendsim acquire` of an uncalibrated rig does."""
    folder = tmp_path_factory.mktemp("stiffer")
    true = folder / "true.mcap"
    args = ["record", "-o", str(true), "--duration-s", "14", "--hold-s", str(HOLD_S), "--ideal-timing"]
    assert main([*args, "--set", "c1_n_m=6.543"]) == 0
    _stating(true, folder / "run.mcap", {"c1_n_m": 6.173})
    return folder / "run.mcap"


def _rig_and_result(path):
    from pendsim_bridge.io.recording import read_recording

    rec = read_recording(path, topics=())
    return rec.params(), rec.metadata[twin_topics.TWIN_RESULT_METADATA]


def test_a_rig_calibrated_from_a_recording_is_given_to_replay_it(stiffer, tmp_path, capsys):
    """The twin replays a recording on the rig the recording states (as validate does). Where that
    is not the rig that swung (its springs 6 % stiffer), the spring coupling is found 6 % off its
    reference from the first checks on: alarmed, saying it may have been so from the start (a
    rig unlike its stated parameters looks the same) and pointing to calibrate. The rig `pendsim
    calibrate` finds from that recording, given with --params-file, raises nothing and fits (mean
    NIS about 2, the chi^2 with 2 degrees of freedom), and the twin says how it differs from the
    stated one."""
    stated = tmp_path / "stated.mcap"
    assert main(["twin", "--replay", str(stiffer), "--speed", "0", "-o", str(stated)]) == 0
    out = capsys.readouterr().out
    assert "differs" not in out
    rig, result = _rig_and_result(stated)
    (alarm,) = json.loads(result["alarms"])
    assert rig.c1_n_m == 6.173 and alarm["parameter"] == "coupling_sin_n_m" and alarm["from_start"]
    assert alarm["value"] / alarm["reference"] - 1 == pytest.approx(0.06, abs=0.01)
    # ... and in the springs' own stiffness, as the rig's parameters give it (the rig's: 6.543 N/m)
    springs = re.search(r"the springs' c1_n_m ([0-9.]+) -> ([0-9.]+) N/m", alarm["text"])
    assert springs is not None, alarm["text"]
    assert float(springs[1]) == pytest.approx(6.173, rel=1e-3) and float(springs[2]) == pytest.approx(6.543, rel=0.01)
    assert "it may have been so from the start" in alarm["text"] and "'pendsim calibrate'" in alarm["text"]
    assert main(["calibrate", str(stiffer), "-o", str(tmp_path / "cal")]) == 0
    calibrated = json.loads((tmp_path / "cal" / "params.json").read_text())
    assert "pendsim twin -o twin.mcap --params-file" in capsys.readouterr().out
    given = tmp_path / "given.mcap"
    args = ["twin", "--replay", str(stiffer), "--speed", "0", "-o", str(given)]
    assert main([*args, "--params-file", str(tmp_path / "cal" / "params.json")]) == 0
    said = capsys.readouterr()
    assert f"twin: the rig given differs from the one {stiffer.name} states (c1_n_m 6.173 -> " in said.err
    assert "warning: the model does not fit" not in said.out
    rig, result = _rig_and_result(given)
    assert rig.c1_n_m == pytest.approx(calibrated["c1_n_m"]) and json.loads(result["alarms"]) == []
    assert max(json.loads(result["nis_mean"])) < 2.5


def test_a_recording_of_the_spatial_model_is_refused_before_the_rigs_are_compared(tmp_path, capsys):
    rec = tmp_path / "spatial.mcap"
    assert main(["record", "-o", str(rec), "--duration-s", "3", "--model", "spatial"]) == 0
    capsys.readouterr()
    out = tmp_path / "t.mcap"
    assert main(["twin", "--replay", str(rec), "-o", str(out), "--set", "plane_offset_m=0.05"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pendsim: error:") and "spatial model" in err and "\n" not in err
    assert not out.exists()


def test_a_file_that_is_no_recording_is_refused(tmp_path, capsys):
    bogus = tmp_path / "x.mcap"
    bogus.write_bytes(b"not an mcap at all")
    assert main(["twin", "--replay", str(bogus), "-o", str(tmp_path / "t.mcap")]) == 2
    assert "not an MCAP file" in capsys.readouterr().err
    assert math.isfinite(1.0)


def test_the_live_views_see_the_twins_estimates_and_end_with_it(recording, replayed, tmp_path):
    """--rerun writes the twin's estimates (the same as its recording's) to an .rrd file, fed from
    the views' own thread; --foxglove serves while it runs and its port is free after."""
    import socket
    import threading

    import rerun as rr

    rrd = tmp_path / "twin.rrd"
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    args = ["twin", "--replay", str(recording), "--speed", "0", "-o", str(tmp_path / "t.mcap"), "--rerun", str(rrd)]
    assert main([*args, "--foxglove", str(port)]) == 0
    rows = {}
    for chunk in rr.chunk.RrdReader(str(rrd)).stream():
        if not chunk.is_static:
            rows[str(chunk.entity_path)] = rows.get(str(chunk.entity_path), 0) + chunk.num_rows
    estimates = len(_messages(replayed, twin_topics.ESTIMATE_TOPIC))
    m1, m2 = rows.get("/twin/m1/angle", 0), rows.get("/twin/m2/angle", 0)
    assert m1 + m2 == estimates  # every estimate reached the view, none twice
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))  # the Foxglove server has let go of its port
    assert not [t for t in threading.enumerate() if t.name == "pendsim-twin-views"]


def test_the_summary_gives_the_models_value_and_says_when_a_parameter_is_where_no_rig_can_be():
    from pendsim_bridge.acquire.twin.pipeline import TwinResult
    from pendsim_bridge.acquire.twin.summary import summary_text
    from pendsim_mj.twin.session import ForecastScore, TwinSummary

    summary = TwinSummary(
        samples=(800, 800), started_s=1.0, nis_mean=(2.0, 2.0), whiteness_p=((0.5, 0.5), (0.5, 0.5)),
        forecast=ForecastScore((), (), (), ()), alarms=(), monitored_from_s=2.0,
        parameters={"friction1_n_m": (-5e-6, 1e-5), "friction2_n_m": (-5e-5, 1e-5), "b1_n_m_s": (7e-4, 1e-5),
                    "offset_m1_rad": (-1e-3, 1e-5), "offset_accel_m2_rad_s2": (1e-5, 1e-4)},
        stated={"friction1_n_m": 0.0, "friction2_n_m": 0.0, "b1_n_m_s": 6.953e-4},
    )  # fmt: skip
    text = summary_text(TwinResult(None, 10.0, "end", summary, (), (0.0, 0.0), 0))
    rows = {line.split()[0]: line for line in text.splitlines() if line.startswith("  ")}
    assert rows["friction1_n_m"].endswith("(below 0, but 0 is within 2 sigma: none found)")
    assert rows["friction2_n_m"].endswith(
        "(below 0 beyond 2 sigma, which a rig cannot have: the model misses something)"
    )
    assert "below 0" not in rows["offset_m1_rad"] and "below 0" not in rows["b1_n_m_s"]
    assert rows["b1_n_m_s"].endswith("N m s/rad (the model's rig: 0.0006953)")  # what the estimate is against
    assert "the model's rig" not in rows["offset_m1_rad"]
    # the values line up under the longest name
    assert len({line.index(line.split()[1]) for line in rows.values()}) == 1


def test_the_twins_result_is_json_that_every_parser_reads(replayed):
    """Every JSON field of the twin's result metadata parses with NaN and Infinity refused (as
    JavaScript's JSON.parse, and so Foxglove, refuses them): an alarm's evidence where none was
    weighed, or a parameter not estimated, is null."""
    from pendsim_bridge.acquire.twin.pipeline import _strict_json
    from pendsim_mj.twin.health import Alarm

    def refuse(constant: str) -> None:
        raise ValueError(f"not JSON: {constant}")

    out = replayed
    with open(out, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}[twin_topics.TWIN_RESULT_METADATA]
    for text in meta.values():
        if text[:1] in "[{":
            json.loads(text, parse_constant=refuse)
    went_on = Alarm("b1_n_m_s", "damping at M1's hinge", 32.0, 10.0, 7e-4, 1.1e-3, 4e-5, follows_s=17.0)
    (read,) = json.loads(_strict_json([dataclasses.asdict(went_on)]), parse_constant=refuse)
    assert read["evidence"] is None and read["value"] == 1.1e-3 and read["follows_s"] == 17.0


def test_a_live_twin_says_its_sessions_events_in_words_with_their_time_of_day():
    start = 1_790_000_000_000_000_000  # 2026-09-21 14:13:20 UTC
    assert event_line(2.0, "held", start) == (
        "twin: the rig is held still: the estimate waits for its release (at 2.0 s, 14:13:22 UTC)"
    )
    assert event_line(61.5, "touched", start).startswith("twin: touched: the rig stopped moving as its model does")
    assert event_line(3.25, "m2 angle jumped by +3.00 deg", start) == (
        "twin: m2 angle jumped by +3.00 deg (at 3.2 s, 14:13:23 UTC)"
    )
    assert event_line(9.0, "m1: its clock jumped by +0.500 s; its timeline restarted", start) is None  # said when seen


def test_the_message_count_said_is_what_the_file_holds(recording, tmp_path, capsys):
    # it counted the samples and forgot the twin's own topics and /diagnostics (a new user's
    # live run said 8901 messages of a file holding 18 496)
    out = tmp_path / "again.mcap"
    assert main(["twin", "--replay", str(recording), "--speed", "0", "-o", str(out)]) == 0
    said = [line for line in capsys.readouterr().out.splitlines() if line.startswith(f"wrote {out} (")]
    with open(out, "rb") as f:
        stats = make_reader(f).get_summary().statistics
    assert said == [f"wrote {out} ({stats.message_count} messages)"]


def test_a_rig_the_model_cannot_follow_is_said_so_not_blamed_on_the_baseline(tmp_path, capsys):
    # a 3000 N/m spring recorded at 10 ms: the twin's model never tracks it for long (it is
    # "touched" again and again); the summary says the model does not fit, not "--baseline-s past
    # the end?", which was given to nothing
    rec = tmp_path / "stiff.mcap"
    assert main(["record", "-o", str(rec), "--set", "c1_n_m=3000", "--duration-s", "30", "--hold-s", "2"]) == 0
    capsys.readouterr()
    assert main(["twin", "--replay", str(rec), "--speed", "0", "-o", str(tmp_path / "twin.mcap")]) == 0
    said = capsys.readouterr().out
    health = [line for line in said.splitlines() if line.startswith("health: never checked")]
    assert len(health) == 1 and "touched" in health[0] and "does not fit this rig" in health[0], said
    assert "--baseline-s" not in said and "warning: the model does not fit the data" in said
