"""Interrupts held back while code that would swallow them runs (bridge/signals.py), and the
CLI's clean stop on Ctrl-C at any moment, also while its commands' modules import."""

import os
import signal
import subprocess
import sys
import time

import pytest

from pendsim_bridge.signals import interrupts_deferred


@pytest.mark.parametrize("signum, raised", [(signal.SIGINT, KeyboardInterrupt), (signal.SIGTERM, OSError)])
def test_a_signal_inside_the_block_is_delivered_when_it_ends_not_before(signum, raised):
    seen = []

    def handler(s, frame):
        raise OSError(f"signal {s}")

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        with pytest.raises(raised), interrupts_deferred():
            os.kill(os.getpid(), signum)
            time.sleep(0.05)  # Python runs handlers between bytecodes: it would have by now
            seen.append("block finished")
        assert seen == ["block finished"]
        assert signal.getsignal(signal.SIGTERM) is handler  # the handlers before are back
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_without_a_signal_the_block_changes_nothing():
    before = signal.getsignal(signal.SIGINT)
    with interrupts_deferred():
        pass
    assert signal.getsignal(signal.SIGINT) is before


def test_ctrl_c_while_the_commands_import_stops_cleanly_with_exit_130():
    """SIGINT as the commands' modules begin to import (sent from inside the deferring block)."""
    script = (
        "import os, signal, sys\n"
        "from pendsim_bridge import cli\n"
        "import pendsim_bridge.signals as s\n"
        "real = s.interrupts_deferred\n"
        "def early():\n"
        "    block = real()\n"
        "    class Hook:\n"
        "        def __enter__(self):\n"
        "            block.__enter__(); os.kill(os.getpid(), signal.SIGINT)\n"
        "        def __exit__(self, *exc):\n"
        "            return block.__exit__(*exc)\n"
        "    return Hook()\n"
        "cli.interrupts_deferred = early\n"
        "sys.exit(cli.main(['allan', '--help']))\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 130, done.stderr
    assert done.stderr.strip() == "pendsim: interrupted"
