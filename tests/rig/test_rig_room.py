"""The rig room as a whole: its facade exports the parameters, drives and model builder; the
parameters and drives come without MuJoCo, the model's names bring it when first used."""

import subprocess
import sys

import pendsim_mj
import pendsim_mj.rig as rig
from pendsim_mj.rig import drives, model, params


def test_the_facade_gives_the_defining_modules_objects():
    assert rig.RigParams is params.RigParams and rig.DEFAULT_PARAMS is params.DEFAULT_PARAMS
    assert rig.Drive is drives.Drive and rig.Sine is drives.Sine and rig.Target is drives.Target
    assert rig.build_model is model.build_model and rig.PLANAR is model.PLANAR and rig.Clamp is model.Clamp


def test_the_package_top_exports_the_same_rig():
    for name in ("RigParams", "DEFAULT_PARAMS", "Drive", "Sine", "SteppedSine", "Chirp", "TimeSeries", "build_model"):
        assert getattr(pendsim_mj, name) is getattr(rig, name), name


def test_parameters_and_drives_need_no_mujoco_and_the_model_brings_it():
    code = (
        "import sys\n"
        "from pendsim_mj.rig import DEFAULT_PARAMS, Drive, Sine\n"
        "Drive(torque_m1=Sine(0.003, 0.87)); DEFAULT_PARAMS.with_overrides(c1_n_m=7.0)\n"
        "assert 'mujoco' not in sys.modules and 'pendsim_mj.rig.model' not in sys.modules\n"
        "from pendsim_mj.rig import build_model\n"
        "assert 'mujoco' in sys.modules\n"
        "print(build_model().nq)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "2"  # the planar rig: phi1, phi2


def test_a_driven_model_has_the_drive_s_actuators():
    m = rig.build_model(rig.DEFAULT_PARAMS, drive_targets=(rig.Target.TORQUE_M1,))
    assert m.nu == 1 and m.opt.timestep == 0.01
