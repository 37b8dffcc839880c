"""The Gymnasium environments of the rig (pendsim_mj.control.environment, .vector_env, .tasks):
Gymnasium's own checker, seeding, the two engines against each other, controllers of the control
room as policies, the vector environment against Gymnasium's SyncVectorEnv over the single one,
autoreset, node observations and bad options."""

from __future__ import annotations

import math
import subprocess
import sys
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import pendsim_mj.control as control
from pendsim_mj.control import (
    ENV_ID,
    LQR,
    BeatingSuppressor,
    CoupledPendulumsEnv,
    CoupledPendulumsVectorEnv,
    EnergyRegulator,
    decay_time_s,
)
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import Bno055
from pendsim_mj.sensors.imperfections import Imperfections

ALL_CHANNELS = ("torque_m1", "torque_m2", "support_x")


def _episode(env, policy, *, seed=0, options=None, steps=None):
    """(t_s (n+1,), info["mode_amplitudes_rad"] (n+1, 2), the return, the states (n+1, 4))."""
    obs, info = env.reset(seed=seed, options=options)
    t, amps, states, total = [0.0], [info["mode_amplitudes_rad"]], [info["state"]], 0.0
    for _ in range(steps or env.config.nstep):
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        t.append(info["t_s"])
        amps.append(info["mode_amplitudes_rad"])
        states.append(info["state"])
        total += reward
        if terminated or truncated:
            break
    return np.array(t), np.array(amps), total, np.array(states)


def _zero(obs):
    return np.zeros(2)


@pytest.mark.parametrize("engine", ["fast", "mujoco"])
@pytest.mark.parametrize("observation", ["state", "nodes"])
def test_gymnasium_s_checker_passes_without_a_warning(engine, observation):
    env = gymnasium.make(ENV_ID, engine=engine, observation=observation, render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the checker reports its doubts as warnings
        check_env(env.unwrapped)  # with the spec: also render modes and close
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (240, 240, 3) and frame.dtype == np.uint8 and np.any(frame != 255)


@pytest.mark.parametrize("task", control.TASKS)
def test_every_task_passes_the_checker_with_every_channel(task):
    env = gymnasium.make(ENV_ID, task=task, actions=ALL_CHANNELS)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped, skip_render_check=True)
    assert env.action_space.high.tolist() == [0.05, 0.05, 1.0]  # N m, N m, m/s^2
    width = 6 if task == "tongue" else 4  # the tongue's drive phase
    assert env.observation_space.shape == (width,)


def test_the_registration_works_from_a_fresh_interpreter_by_module_prefix():
    code = (
        "import sys, gymnasium\n"
        "assert 'pendsim_mj.control' not in sys.modules\n"
        "env = gymnasium.make('pendsim_mj.control:pendsim/CoupledPendulums-v0', task='hold')\n"
        "vec = gymnasium.make_vec('pendsim/CoupledPendulums-v0', num_envs=3)\n"
        "print(type(env.unwrapped).__name__, type(vec).__name__, vec.num_envs)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["CoupledPendulumsEnv", "CoupledPendulumsVectorEnv", "3"]


def test_the_same_seed_gives_the_same_episode_and_another_seed_another():
    def run(seed):
        env = CoupledPendulumsEnv(observation="nodes", actions=ALL_CHANNELS)  # noisy nodes: two streams
        env.action_space.seed(seed)
        obs, _ = env.reset(seed=seed)
        out = [obs]
        for _ in range(60):
            out.append(env.step(env.action_space.sample())[0])
        return np.array(out)

    first, again, other = run(3), run(3), run(4)
    np.testing.assert_array_equal(first, again)
    assert np.max(np.abs(first - other)) > 1e-3


def test_the_fast_engine_and_mujoco_give_the_same_states_for_the_same_actions():
    # every drive the environment applies: both motors and the support (actions), the pivot (tongue)
    rng = np.random.default_rng(7)
    actions = rng.uniform(-1, 1, (300, 3)) * [0.05, 0.05, 1.0]
    states = {}
    for engine in ("fast", "mujoco"):
        env = CoupledPendulumsEnv(engine=engine, task="tongue", actions=ALL_CHANNELS, tongue_level_m_s2=2.0)
        _, info = env.reset(options={"phi0_rad": (0.4, -0.2), "omega0_rad_s": (0.5, 0.0)})
        states[engine] = [info["state"]] + [env.step(a)[4]["state"] for a in actions]
    fast, mujoco = np.array(states["fast"]), np.array(states["mujoco"])
    assert np.max(np.abs(fast - mujoco)) < 1e-9
    assert np.ptp(fast[:, 0]) > 0.5  # the run moved


def test_lqr_as_a_policy_damps_both_modes_ten_times_faster_than_no_action():
    env = CoupledPendulumsEnv(task="damp", episode_s=5.0)
    release = {"phi0_rad": (0.05, -0.03)}  # 3 deg: linear, so the amplitudes are clean envelopes
    lqr = LQR(DEFAULT_PARAMS)
    t, amps_lqr, return_lqr, _ = _episode(env, lambda obs: lqr(obs), options=release)
    t0, amps_free, return_free, _ = _episode(env, _zero, options=release)
    # without action each amplitude decays at the documented default damping: to 20 % in 120 s
    free_rate = np.log(amps_free[0] / amps_free[-1]) / t0[-1]
    np.testing.assert_allclose(free_rate, math.log(5.0) / 120.0, rtol=0.05)
    lqr_rate = 1.0 / np.array([decay_time_s(t, amps_lqr[:, i]) for i in range(2)])  # 1/e time
    assert np.all(lqr_rate >= 10 * free_rate), (lqr_rate, free_rate)
    assert return_lqr > 10 * return_free  # both negative: LQR's cost is a tenth or less


def test_the_tongue_task_grows_a_free_swing_and_lqr_holds_it_down():
    env = CoupledPendulumsEnv(task="tongue")
    lqr = LQR(DEFAULT_PARAMS)
    _, free, _, _ = _episode(env, _zero, seed=1)
    _, held, _, _ = _episode(env, lambda obs: lqr(obs[:4]), seed=1)
    mode = env.task.tongue_mode - 1
    assert env.task.drive_level_m_s2 == pytest.approx(10 * env.task.tip_level_m_s2)
    assert free[-1, mode] > 5 * free[0, mode]  # inside the tongue: rest is unstable
    assert held[-1, mode] < 0.01 * held[0, mode]


def test_the_controllers_built_for_a_task_earn_more_than_no_action():
    pairs = [
        ("hold", EnergyRegulator(DEFAULT_PARAMS, target_amplitudes_rad=(math.radians(10.0), 0.0))),
        ("still-m2", BeatingSuppressor(DEFAULT_PARAMS)),
    ]
    for task, controller in pairs:
        env = CoupledPendulumsEnv(task=task, episode_s=10.0)
        _, _, earned, _ = _episode(env, lambda obs, c=controller: c(obs), seed=2)
        _, _, free, _ = _episode(env, _zero, seed=2)
        assert earned > free + 0.2 * abs(free), (task, earned, free)


def _compare_with_sync(options, nenv, nstep, rng):
    """Our vector env against Gymnasium's SyncVectorEnv over the single env: every returned array."""
    sync = gymnasium.make_vec(ENV_ID, num_envs=nenv, vectorization_mode="sync", **options)
    ours = gymnasium.make_vec(ENV_ID, num_envs=nenv, threads=2, full_info=True, **options)
    assert isinstance(ours, CoupledPendulumsVectorEnv) and ours.threads == 2
    assert ours.metadata["autoreset_mode"] == sync.metadata["autoreset_mode"]
    first, mine = sync.reset(seed=11), ours.reset(seed=11)
    np.testing.assert_allclose(mine[0], first[0], rtol=0, atol=1e-12)
    limits = ours.single_action_space.high
    ends = 0
    for _ in range(nstep):
        actions = rng.uniform(-1.2, 1.2, (nenv, len(limits))) * limits  # some beyond the limits
        theirs, mine = sync.step(actions), ours.step(actions)
        assert ours.observation_space.contains(mine[0])
        for a, b in zip(mine[:4], theirs[:4], strict=True):
            np.testing.assert_allclose(np.asarray(a, float), np.asarray(b, float), rtol=0, atol=1e-12)
        for key in ("state", "mode_amplitudes_rad", "energy_j", "t_s"):
            np.testing.assert_allclose(mine[4][key], theirs[4][key], rtol=0, atol=1e-12)
        ends += int(np.sum(mine[3]))
    return ends


def test_the_vector_env_s_members_are_single_envs_through_autoresets():
    options = {"task": "still-m2", "episode_s": 0.4, "actions": ALL_CHANNELS}
    ends = _compare_with_sync(options, 4, 130, np.random.default_rng(0))
    assert ends == 4 * 3  # three truncations per member, each followed by an autoreset


def test_the_vector_env_s_nodes_are_the_single_env_s_without_noise():
    options = {"task": "tongue", "observation": "nodes", "nodes": Bno055(noise=False), "episode_s": 0.3}
    _compare_with_sync(options, 3, 40, np.random.default_rng(1))


def test_autoreset_starts_a_new_episode_on_the_step_after_the_end():
    env = CoupledPendulumsVectorEnv(5, episode_s=0.05)  # 5 steps
    obs, _ = env.reset(seed=0)
    for _ in range(5):
        obs, reward, terminated, truncated, info = env.step(np.zeros((5, 2)))
    assert truncated.all() and not terminated.any() and np.all(info["t_s"] == pytest.approx(0.05))
    ended = obs
    obs, reward, terminated, truncated, info = env.step(np.full((5, 2), 0.05))  # ignored
    assert np.all(reward == 0) and not truncated.any() and np.all(info["t_s"] == 0)
    assert np.all(obs[:, 2:] == 0) and np.all(np.abs(obs[:, :2] - ended[:, :2]) > 0)  # released at rest, anew
    assert np.all(np.abs(obs[:, :2]) <= math.radians(30))
    obs2, reward, *_ = env.step(np.zeros((5, 2)))
    assert np.all(reward < 0) and np.all(obs2[:, 2:] != 0)  # the new episode runs


def test_over_the_top_terminates():
    env = CoupledPendulumsEnv()
    env.reset(options={"phi0_rad": (3.13, 0.0), "omega0_rad_s": (3.0, 0.0)})
    _, _, terminated, truncated, info = env.step(np.zeros(2))
    assert terminated and not truncated and info["state"][0] > math.pi


def test_the_vector_env_s_node_noise_and_timing_are_the_node_model_s():
    # at rest every reading is noise: the gyro's is the sensor model's (spec: 0.00127 rad/s about z)
    vec = CoupledPendulumsVectorEnv(4096, observation="nodes")
    vec.reset(seed=1, options={"phi0_rad": (0.0, 0.0)})
    rates = np.array([vec.step(np.zeros((4096, 2)))[0][:, 2:4] for _ in range(8)])
    assert np.std(rates) == pytest.approx(0.00127, rel=0.03)
    # latency and burst loss: the share of late samples and the mean age as the single env's NodeObserver
    nodes = Bno055(imperfections=Imperfections(latency_s=0.02, packet_loss=0.2, loss_burst_samples=3.0))
    options = {"observation": "nodes", "nodes": nodes, "episode_s": 2.0}
    single = CoupledPendulumsEnv(**options)
    ages = []
    for seed in range(3):
        single.reset(seed=seed)
        ages += [single.step(np.zeros(2))[4]["age_s"] for _ in range(200)]
    vec = CoupledPendulumsVectorEnv(512, full_info=True, **options)
    vec.reset(seed=0)
    vec_ages = np.array([vec.step(np.zeros((512, 2)))[4]["age_s"] for _ in range(199)])
    single_ages = np.minimum(np.array(ages), 1.0)
    vec_ages = np.minimum(vec_ages, 1.0)
    assert np.mean(vec_ages) == pytest.approx(np.mean(single_ages), rel=0.1)
    assert np.mean(vec_ages > 0.05) == pytest.approx(np.mean(single_ages > 0.05), abs=0.03)
    assert 0.09 < np.mean(vec_ages > 0.05) < 0.14  # a loss or a late sample often enough to see


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"engine": "bullet"}, "unknown engine 'bullet'; allowed: mujoco, fast"),
        ({"task": "swing-up"}, "unknown task 'swing-up'; allowed: damp, hold, still-m2, no-beating, tongue"),
        ({"actions": ("pivot_z",)}, "actions must be distinct channels among torque_m1, torque_m2, support_x"),
        ({"observation": "camera"}, "unknown observation 'camera'; allowed: state, nodes"),
        ({"torque_limit": 0.1}, "unknown option(s) torque_limit; allowed:"),
        ({"episode_s": 0.015}, "episode_s must be whole control periods of 0.01 s"),
        ({"target_amplitudes_rad": (2.0, 0.0)}, "target_amplitudes_rad must be two numbers in [0, 1.5] rad"),
    ],
)
def test_bad_options_raise_naming_the_option(options, message):
    with pytest.raises(ParameterError) as caught:
        CoupledPendulumsEnv(**options)
    assert str(caught.value).startswith(message)


def test_bad_resets_steps_and_vector_options_raise_clearly():
    env = CoupledPendulumsEnv()
    with pytest.raises(ParameterError, match="call reset"):
        env.step(np.zeros(2))
    with pytest.raises(ParameterError, match=r"unknown reset option\(s\) phi_rad; allowed: phi0_rad"):
        env.reset(options={"phi_rad": (0.1, 0.0)})
    with pytest.raises(ParameterError, match="phi0_rad must be two angles"):
        env.reset(options={"phi0_rad": (0.1, 0.0, 0.0)})
    with pytest.raises(ParameterError, match="target_amplitudes_rad is an option of the hold task only"):
        env.reset(options={"target_amplitudes_rad": (0.1, 0.0)})
    env.reset(seed=0)
    with pytest.raises(ParameterError, match=r"actions must have shape \(2,\)"):
        env.step(np.zeros(3))
    with pytest.raises(ParameterError, match="actions must be finite"):
        env.step(np.array([np.nan, 0.0]))
    with pytest.raises(ParameterError, match="runs on the fast engine only"):
        CoupledPendulumsVectorEnv(4, engine="mujoco")
    with pytest.raises(ParameterError, match="seed must be an integer >= 0 or 4 of them"):
        CoupledPendulumsVectorEnv(4).reset(seed=[1, 2])


def test_actions_beyond_the_limits_are_clipped_and_the_hold_target_is_an_option():
    env = CoupledPendulumsEnv(task="hold")
    env.reset(seed=0, options={"target_amplitudes_rad": (0.3, 0.0)})
    a = env.step(np.array([5.0, -5.0]))
    env.reset(seed=0, options={"target_amplitudes_rad": (0.3, 0.0)})
    b = env.step(np.array([0.05, -0.05]))
    np.testing.assert_array_equal(a[0], b[0])
    assert a[4]["targets_rad"].tolist() == [0.3, 0.0]
    off = (a[4]["task_amplitudes_rad"] - [0.3, 0.0]) / math.radians(10.0)
    assert a[1] == pytest.approx(-np.sum(off**2) - 0.1 * 1.0)  # full effort on both motors
