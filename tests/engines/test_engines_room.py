"""The engines room: its facade loads no engine, every exported name resolves, and every entry of
``ENGINES`` has the ``Engine`` protocol's signature (mypy checks the table statically too)."""

import inspect
import subprocess
import sys
import typing

import pytest

import pendsim_mj.engines
from pendsim_mj.engines import ENGINES, Engine, dispatch, fast_planar, reference
from pendsim_mj.engines.protocol import EngineName
from pendsim_mj.engines.simulation import simulate_batch
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.params import DEFAULT_PARAMS


def test_importing_the_room_loads_neither_mujoco_nor_numba():
    code = (
        "import sys; import pendsim_mj.engines as e; "
        "print(sorted(m for m in ('mujoco', 'numba') if m in sys.modules)); "
        "e.Trajectory; e.ENGINES; e.Engine; e.run_batch; e.solve; "  # the light names stay light
        "print(sorted(m for m in ('mujoco', 'numba') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.splitlines() == ["[]", "[]"]


def test_every_exported_name_resolves():
    for name in pendsim_mj.engines.__all__:
        assert getattr(pendsim_mj.engines, name) is not None, name
    assert pendsim_mj.engines.simulate_batch is simulate_batch
    assert pendsim_mj.engines.solve_batch is reference.solve_batch
    assert set(pendsim_mj.engines.__all__) <= set(dir(pendsim_mj.engines))
    with pytest.raises(AttributeError, match="has no attribute 'simulat'"):
        _ = pendsim_mj.engines.simulat


def test_engines_are_the_command_line_names_and_the_real_entry_points():
    assert tuple(ENGINES) == typing.get_args(EngineName) == dispatch.ENGINE_NAMES == ("mujoco", "reference", "fast")
    assert ENGINES["mujoco"] is simulate_batch
    assert ENGINES["reference"] is reference.solve_batch
    assert ENGINES["fast"] is fast_planar.solve_batch
    assert "fast" in ENGINES and "spatial" not in ENGINES and len(ENGINES) == 3
    with pytest.raises(KeyError):
        ENGINES["spatial"]


def _protocol_parameters():
    params = list(inspect.signature(Engine.__call__).parameters.values())[1:]  # without self
    hints = typing.get_type_hints(Engine.__call__)
    return params, hints


@pytest.mark.parametrize("name", dispatch.ENGINE_NAMES)
def test_each_engine_has_the_protocols_parameters_and_defaults(name):
    params, hints = _protocol_parameters()
    engine = ENGINES[name]
    own = inspect.signature(engine).parameters
    engine_hints = typing.get_type_hints(engine)
    for p in params:
        assert p.name in own, f"{name}: no parameter {p.name}"
        q = own[p.name]
        assert q.kind == p.kind, f"{name}: {p.name} is {q.kind}, the protocol's is {p.kind}"
        assert q.default is not inspect.Parameter.empty, f"{name}: {p.name} has no default"
        assert engine_hints[p.name] == hints[p.name], f"{name}: {p.name} is {engine_hints[p.name]}"
    positional = [q.name for q in own.values() if q.kind is inspect.Parameter.POSITIONAL_OR_KEYWORD]
    assert positional == [p.name for p in params if p.kind is inspect.Parameter.POSITIONAL_OR_KEYWORD]
    for q in own.values():  # anything more: keyword-only, with a default
        if q.name not in hints:
            assert q.kind is inspect.Parameter.KEYWORD_ONLY and q.default is not inspect.Parameter.empty, q.name
    assert engine_hints["return"] == hints["return"]


def test_the_engines_share_their_defaults():
    params, _ = _protocol_parameters()
    defaults = {
        name: {p.name: inspect.signature(ENGINES[name]).parameters[p.name].default for p in params} for name in ENGINES
    }
    assert defaults["mujoco"] == defaults["reference"] == defaults["fast"]
    assert defaults["fast"]["params"] == DEFAULT_PARAMS and defaults["fast"]["drive"] is None


@pytest.mark.parametrize(
    ("engine", "spatial", "message"),
    [
        ("nope", False, "unknown engine 'nope'; allowed: mujoco, reference, fast"),
        ("reference", True, "the spatial model runs in MuJoCo only; the reference is planar"),
        ("fast", True, "the spatial model runs in MuJoCo only; the fast engine is planar"),
    ],
)
def test_the_dispatcher_names_a_bad_engine(engine, spatial, message):
    for call in (dispatch.run_batch, dispatch.run_blocks):
        with pytest.raises(ParameterError) as err:
            call(engine, DEFAULT_PARAMS, (0.3, 0.0), (0.0, 0.0), 0.1, spatial=spatial)
        assert str(err.value) == message
