"""Scripted rig faults of the node emulator (``pendsim nodes --fault``): physics faults equal an
independent piecewise run of the solver, a mount turn shows in the swing angle and not in the
hinge gyro, a clock jump in the device times, over UDP in the recording; bad specs are refused."""

import math
import signal

import numpy as np
import pytest
from acquire_helpers import Pendsim, free_udp_ports

from pendsim_bridge.acquire.emulator import EmulatorSpec, fused_samples, plan, read_log
from pendsim_bridge.acquire.packets import GROUP_SLICES, ROW_FIELDS
from pendsim_bridge.acquire.rig_faults import parse_fault
from pendsim_bridge.cli import build_parser, main
from pendsim_bridge.commands.nodes import spec_from
from pendsim_bridge.io.recording import read_recording
from pendsim_bridge.run.record import RecordSpec
from pendsim_mj.engines import dispatch
from pendsim_mj.estimation.swing_frame import twist_angle
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import Bno055

GZ = ROW_FIELDS.index("gz")
RUN = RecordSpec(phi0_rad=(0.4, -0.2), duration_s=4.0, hold_s=0.5, imu=Bno055(noise=False))


def _spec(run: RecordSpec, *faults: str, seed: int = 0) -> EmulatorSpec:
    return EmulatorSpec(run, rig_faults=tuple(parse_fault(f) for f in faults), seed=seed)


def _sim_step(run: RecordSpec, t_s: np.ndarray) -> np.ndarray:
    """The 10 ms simulation row each sample instant (s since the start) reads (the latest at or
    before it), -1 while held."""
    return np.where(t_s >= run.hold_s, np.floor((t_s - run.hold_s) / run.dt_s + 1e-9), -1).astype(int)


def _piecewise_gyro(engine: str, run: RecordSpec, changed, fault_s: float) -> np.ndarray:
    """Independent: the solver with the rig's parameters up to the fault, then a new run with the
    changed ones from the state it reached; the gyro rows (n, 2, 3)."""
    k = round(fault_s / run.dt_s)
    before = dispatch.run(engine, run.params, run.phi0_rad, run.omega0_rad_s, k * run.dt_s, run.dt_s)
    after = dispatch.run(
        engine, changed, before.phi_rad[-1], before.omega_rad_s[-1], run.duration_s - k * run.dt_s, run.dt_s
    )
    return np.concatenate([before.imu_gyro_rad_s[:-1], after.imu_gyro_rad_s])


@pytest.mark.parametrize("engine", ["mujoco", "reference"])
@pytest.mark.parametrize(
    ("fault", "changed"),
    [
        ("stiffness:-5%@1.5", DEFAULT_PARAMS.with_overrides(c1_n_m=0.95 * DEFAULT_PARAMS.c1_n_m)),
        ("damping:m1*2@1.5", DEFAULT_PARAMS.with_overrides(b1_n_m_s=2 * DEFAULT_PARAMS.b1_n_m_s)),
        ("friction:m2=2e-3@1.5", DEFAULT_PARAMS.with_overrides(friction2_n_m=2e-3)),
    ],
)
def test_a_physics_fault_continues_from_the_state_at_the_fault_with_the_changed_rig(engine, fault, changed):
    run = RecordSpec(phi0_rad=(0.4, -0.2), duration_s=4.0, hold_s=0.5, imu=Bno055(noise=False), engine=engine)
    faulted, plain = plan(_spec(run, fault)), plan(_spec(run))
    # The reference engine's runs are computed on its compiled kernel; the check is the paper-faithful solver.
    expected = _piecewise_gyro(engine, run, changed, 1.5)
    for n, (stream, unfaulted) in enumerate(zip(faulted.streams, plain.streams, strict=True)):
        step = _sim_step(run, stream.t_s)
        after, before = step >= 150, (step >= 0) & (step < 150)
        np.testing.assert_allclose(stream.rows[after, GZ], expected[step[after], n, 2], rtol=0, atol=1e-9)
        np.testing.assert_array_equal(stream.rows[~after], unfaulted.rows[~after])  # the same run up to the fault
        assert np.any(before)
        if fault.startswith("stiffness") or n == int(fault.split(":m")[1][0]) - 1 or fault.startswith("damping"):
            assert np.max(np.abs(stream.rows[after, GZ] - unfaulted.rows[after, GZ])) > 1e-4  # it changed the motion


def test_doubled_damping_makes_the_free_decay_as_fast_as_the_solver_with_doubled_b1():
    run = RecordSpec(phi0_rad=(0.3, 0.3), duration_s=12.0, hold_s=0.0, imu=Bno055(noise=False), engine="reference")
    gyro = {f: plan(_spec(run, *f)).streams[0] for f in [(), ("damping:m1*2@1",)]}
    ref = {
        "b1": _piecewise_gyro("reference", run, DEFAULT_PARAMS.with_overrides(b1_n_m_s=2 * DEFAULT_PARAMS.b1_n_m_s), 1),
        "none": _piecewise_gyro("reference", run, DEFAULT_PARAMS, 1),
        "b2": _piecewise_gyro("reference", run, DEFAULT_PARAMS.with_overrides(b2_n_m_s=2 * DEFAULT_PARAMS.b2_n_m_s), 1),
    }

    def decay(t_s: np.ndarray, omega: np.ndarray) -> float:
        """RMS of M1's rate over the last 2 s against that over the 2 s after the fault."""
        late, early = t_s >= run.duration_s - 2, (t_s >= 1) & (t_s < 3)
        return float(np.sqrt(np.mean(omega[late] ** 2) / np.mean(omega[early] ** 2)))

    t_s = gyro[()].t_s  # the node's sample instants; each reads the latest 10 ms row
    step = _sim_step(run, t_s)
    expected = {k: decay(t_s, g[step, 0, 2]) for k, g in ref.items()}
    got = {f: decay(s.t_s, s.rows[:, GZ]) for f, s in gyro.items()}
    assert got[("damping:m1*2@1",)] == pytest.approx(expected["b1"], rel=1e-9)
    assert got[()] == pytest.approx(expected["none"], rel=1e-9)
    # The solver's own numbers: doubling b1 decays faster by several per cent, and unlike doubling b2
    assert expected["b1"] < 0.97 * expected["none"] and abs(expected["b1"] - expected["b2"]) > 0.01
    assert got[("damping:m1*2@1",)] < 0.97 * got[()]


def test_a_mount_turn_adds_its_angle_to_the_swing_and_leaves_the_hinge_gyro():
    faulted, plain = plan(_spec(RUN, "mount:m1=3deg@1.2")), plan(_spec(RUN))
    for n in (0, 1):
        f, p = faulted.streams[n].rows, plain.streams[n].rows
        quat = GROUP_SLICES["quat"]
        rest = p[0, quat]  # held still: the rest orientation
        swing = [twist_angle(r[:, quat], rest, np.array([0.0, 0.0, 1.0])) for r in (f, p)]
        after = faulted.streams[n].t_s >= RUN.hold_s + 1.2
        turned = math.radians(3.0) if n == 0 else 0.0
        np.testing.assert_allclose(swing[0][after] - swing[1][after], turned, atol=1e-9)
        np.testing.assert_array_equal(f[~after], p[~after])
        np.testing.assert_array_equal(f[:, GZ], p[:, GZ])  # the turn is about the hinge axis
        # The accelerometer's axes turn with the node: a' = R_z(theta)^T a
        c, s = math.cos(turned), math.sin(turned)
        ax, ay = p[after, ROW_FIELDS.index("ax")], p[after, ROW_FIELDS.index("ay")]
        np.testing.assert_allclose(f[after, ROW_FIELDS.index("ax")], c * ax + s * ay, atol=1e-9)
        np.testing.assert_allclose(f[after, ROW_FIELDS.index("ay")], -s * ax + c * ay, atol=1e-9)


def test_a_mount_turn_keeps_the_noise_draws():
    run = RecordSpec(phi0_rad=(0.4, -0.2), duration_s=2.0, hold_s=0.5, imu=Bno055(seed=4))
    faulted = fused_samples(run, _spec(run, "mount:m2=-2deg@1").played_faults())
    plain = fused_samples(run)
    np.testing.assert_array_equal(faulted.gyro_rad_s[:, 1, 2], plain.gyro_rad_s[:, 1, 2])  # the same draws
    np.testing.assert_array_equal(faulted.quat_wxyz[:, 0], plain.quat_wxyz[:, 0])


def test_a_clock_jump_shows_in_the_device_times_only():
    spec = _spec(RUN, "clock:m2=+0.5@1", "clock:m1=-0.25s@2.004")
    faulted, plain = plan(spec), plan(_spec(RUN))
    for stream, unfaulted, (jump_s, at_s) in zip(
        faulted.streams, plain.streams, [(-0.25, 2.004), (0.5, 1.0)], strict=True
    ):
        steps = np.diff(stream.device_time_us)
        first = int(np.argmax(stream.t_s >= RUN.hold_s + at_s))  # the first sample at or after the jump
        assert steps[first - 1] == 12500 + round(jump_s * 1e6)
        assert np.all(np.delete(steps, first - 1) == 12500)
        np.testing.assert_array_equal(stream.t_s, unfaulted.t_s)  # the node samples when it did
        np.testing.assert_array_equal(stream.rows, unfaulted.rows)
        np.testing.assert_array_equal(stream.seq, unfaulted.seq)


def test_a_drawn_time_follows_the_seed_within_its_window_and_a_ramp_reaches_its_value():
    times = {seed: _spec(RUN, "clock:m1=1@1~3", seed=seed).played_faults()[0].start_s for seed in (0, 0, 1)}
    assert len(times) == 2 and all(1 <= t <= 3 for t in times.values())
    (ramp,) = _spec(RUN, "stiffness:c2*0.5@1..3.004").played_faults()
    assert (ramp.before, ramp.after, ramp.start_s, ramp.end_s) == pytest.approx((6.562, 3.281, 1.0, 3.0))


def test_nodes_plays_the_faults_over_udp_into_the_recording(tmp_path):
    """pendsim nodes --fault, pendsim acquire, loopback UDP: the recording holds M1 turned by 3 deg
    and M2's device clock jumping 0.503 s; the log header and the summary say what was played."""
    p1, p2 = free_udp_ports(2)
    ports = ["--node", f"m1={p1}", "--node", f"m2={p2}"]
    acquire = Pendsim(["acquire", "-o", "run.mcap", *ports], cwd=tmp_path)
    nodes = None
    faults = ["--fault", "mount:m1=3deg@1", "--fault", "clock:m2=+0.503@1.5"]
    try:
        acquire.wait_for("listening:")
        args = ["nodes", *ports, "--duration-s", "3.5", "--hold-s", "1", "--no-noise", *faults, "--log", "sent.jsonl"]
        nodes = Pendsim(args, cwd=tmp_path)
        assert nodes.finish() == 0, nodes.err
        acquire.signal(signal.SIGTERM)
        assert acquire.finish() == 0, acquire.err
    finally:
        if nodes is not None:
            nodes.kill()
        acquire.kill()
    out = "\n".join(nodes.out)
    assert (
        "rig faults played (s after the release): mount m1 turns +3 deg (to +3 deg) at 1 s; clock m2 jumps +0.503 s"
        in out
    )
    header, _ = read_log(tmp_path / "sent.jsonl")
    mount, clock = header["rig_faults"]
    assert (mount["kind"], mount["node"], mount["after"], mount["start_s"]) == ("mount", "m1", 3.0, 1.0)
    assert (clock["quantity"], clock["node"], clock["after"], clock["start_s"]) == ("clock_s", "m2", 0.503, 1.5)
    rec = read_recording(tmp_path / "run.mcap")
    m1, m2 = rec.imu["m1"], rec.imu["m2"]
    # M1: each recorded sample is one the faulted plan sent (the nearest: the binary format rounds
    # quaternions to 2^-14); its swing angle about the hinge is the unfaulted one plus 3 deg from 1 s
    # after the release on.
    options = ["nodes", *ports, "--duration-s", "3.5", "--hold-s", "1", "--no-noise"]
    sent = plan(spec_from(build_parser().parse_args([*options, *faults]))).streams[0]
    unfaulted = plan(spec_from(build_parser().parse_args(options))).streams[0]
    quat = GROUP_SLICES["quat"]
    k = np.argmin(np.linalg.norm(m1.quat_wxyz[:, None, :] - sent.rows[None, :, quat], axis=2), axis=1)
    assert np.max(np.abs(m1.quat_wxyz - sent.rows[k, quat])) < 1e-4
    z = np.array([0.0, 0.0, 1.0])
    turn = twist_angle(m1.quat_wxyz, sent.rows[0, quat], z) - twist_angle(
        unfaulted.rows[k, quat], sent.rows[0, quat], z
    )
    after = sent.t_s[k] >= 1.0 + 1.0
    assert after.sum() > 50 and (~after).sum() > 50
    np.testing.assert_allclose(turn[after], math.radians(3.0), atol=3e-4)
    np.testing.assert_allclose(turn[~after], 0.0, atol=3e-4)
    # M2: one step of its stamps is 0.503 s longer (whole periods between the others, if any were lost)
    steps = np.diff(m2.stamp_ns) % 12_500_000
    assert np.count_nonzero(steps == 3_000_000) == 1 and np.count_nonzero(steps) == 1


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--fault", "stiffness-5%@1"], "expected KIND:TARGETCHANGE@WHEN; forms: stiffness:[c1|c2]CHANGE"),
        (["--fault", "wobble:m1*2@1"], "unknown kind 'wobble'; allowed: stiffness, damping, friction, mount, clock"),
        (["--fault", "damping:m3*2@1"], "unknown target 'm3' for damping; allowed: m1, m2"),
        (["--fault", "stiffness:m1*2@1"], "unknown target 'm1' for stiffness; allowed: c1, c2"),
        (["--fault", "damping:m1*200@1"], "a factor must be in (0, 100], got 200"),
        (["--fault", "stiffness:-150%@1"], "a change must be in (-100, +1000] %"),
        (["--fault", "mount:m1=200deg@1"], "within +-180 deg"),
        (["--fault", "mount:m1=3@1"], "expected mount:m1|m2=ANGLEdeg"),
        (["--fault", "mount:m1=3deg@1..2"], "a ramp (@T..T2) is for stiffness, damping and friction"),
        (["--fault", "clock:m2=0@1"], "the clock change must be nonzero"),
        (["--fault", "damping:m1*2"], "no time: end with @T, @T..T2 or @T~T2"),
        (["--fault", "damping:m1*2@-1"], "a time must be a number of s >= 0 after the release"),
        (["--fault", "damping:m1*2@3..1"], "need T2 > T"),
        (["--fault", "stiffness:-5%@30"], "30 s is past the run's end (8 s after the release)"),
        (["--fault", "stiffness:-5%@1..9"], "9 s is past the run's end"),
        (["--fault", "damping:m1*2@2", "--fault", "damping:m1=1e-3@2"], "overlaps"),
        (["--fault", "stiffness:-5%@1..5", "--fault", "stiffness:c1*2@3"], "must not overlap in time"),
        (["--fault", "clock:m1=1@1~4", "--fault", "clock:m1=1@3"], "must not overlap in time"),
        (["--fault", "friction:m1*2@1"], "friction1_n_m is 0 before the fault; give the value (=VALUE)"),
        (["--fault", "stiffness:c1=2e6@1"], "c1_n_m must be"),
        (["--node", "m1=5601", "--fault", "clock:m2=1@1"], "node m2 is not sent to"),
        (["--fault", "clock:m2=-700@1", "--clock-offset-s", "m2=100"], "the node's clock would read"),
        (["--motor", "--fault", "clock:m2=1@1"], "--fault is for the precomputed run"),
    ],
)
def test_a_bad_fault_is_one_line_exit_2(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    assert main(["nodes", "--duration-s", "10", *args]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("pendsim: error: ") and message in err[0], err
    assert list(tmp_path.iterdir()) == []
