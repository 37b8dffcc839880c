"""The README's Python example runs and its shape comments are true; its commands are the CI's."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()


def test_python_example_runs_and_shapes_match_the_comments():
    block = re.search(r"```python\n(.*?)```", README, re.S).group(1)
    namespace: dict = {}
    exec(compile(block, "README.md", "exec"), namespace)
    assert namespace["traj"].phi_rad.shape == (12001, 2)
    assert namespace["traj"].imu_accel_m_s2.shape == (12001, 2, 3)
    assert namespace["batch"].phi_rad.shape == (2, 1001, 2)
    assert namespace["ref"].phi_rad.shape == (2, 1001, 2)


def test_first_lines_give_the_two_setup_commands_and_ci_runs_the_test_one():
    first_block = re.search(r"```bash\n(.*?)```", README, re.S).group(1)
    commands = [line.split("#")[0].strip() for line in first_block.strip().splitlines()]
    assert commands == ["pip install -e . && pendsim demo", 'pip install -e ".[test]" && python -m pytest']
    ci = (ROOT / ".ci" / "run").read_text()
    assert commands[1] in ci
