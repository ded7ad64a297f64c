"""Unit tests of node_common's teardown bound (no rclpy.init: the step is a plain call)."""

import subprocess
import sys
import time

from hri_core.node_common import bounded_teardown

HUNG = ("import time\n"
        "from hri_core.node_common import bounded_teardown\n"
        "bounded_teardown(lambda: time.sleep(30), 'node teardown', print, 3, timeout=0.3)\n"
        "print('returned')\n")


def test_a_hung_teardown_step_ends_the_process_with_its_code_and_a_line():
    started = time.monotonic()
    result = subprocess.run([sys.executable, '-c', HUNG], capture_output=True, text=True,
                            timeout=20)
    assert time.monotonic() - started < 10.0
    assert result.returncode == 3, result.stderr
    assert 'node teardown did not return within 0.3 s' in result.stdout
    assert 'returned' not in result.stdout


def test_a_teardown_step_that_returns_leaves_the_process_running():
    said = []
    bounded_teardown(lambda: time.sleep(0.05), 'rclpy shutdown', said.append, 0, timeout=1.0)
    time.sleep(1.2)  # past the timeout: the cancelled timer never fires
    assert said == []
