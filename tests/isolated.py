"""Run a test body in a child Python process, so that a native crash cannot take the suite down.

Optional native back ends (Sionna RT's Dr.Jit/LLVM) can abort the interpreter; a test that
uses one calls :func:`run_isolated` with the dotted name of a function in a module of this
folder. The child's exit is checked: a failed assertion, an exception, a signal (abort,
segmentation fault) or a time-out becomes one failed test whose message carries the
child's last lines.
"""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
SRC = HERE.parent / "src"

_CHILD = """
import importlib, sys
sys.path[:0] = [{here!r}, {src!r}]
module, _, name = {target!r}.partition(":")
getattr(importlib.import_module(module), name)(*sys.argv[1:])
"""


def run_isolated(target: str, *args: str, timeout: float = 600.0, tail: int = 25) -> str:
    """Call ``module:function(*args)`` in a child process and fail the test if it fails.

    Parameters
    ----------
    target : str
        ``"module:function"``, the module found in ``tests/``.
    *args : str
        Arguments passed to the function (as strings).
    timeout : float, optional
        Seconds before the child is killed and the test fails.
    tail : int, optional
        How many of the child's last output lines the failure message shows.

    Returns
    -------
    str
        The child's standard output, when it succeeded.
    """
    code = _CHILD.format(here=str(HERE), src=str(SRC), target=target)
    try:
        res = subprocess.run([sys.executable, "-c", code, *map(str, args)],
                             capture_output=True, text=True, timeout=timeout,
                             stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired as exc:
        out = ((exc.stdout or b"") + (exc.stderr or b"")).decode(errors="replace")
        pytest.fail(f"{target} did not finish within {timeout:.0f} s; its last lines:\n"
                    + "\n".join(out.splitlines()[-tail:]), pytrace=False)
    if res.returncode != 0:
        how = (f"was killed by {signal.Signals(-res.returncode).name}" if res.returncode < 0
               else f"exited with code {res.returncode}")
        last = "\n".join((res.stdout + res.stderr).splitlines()[-tail:])
        pytest.fail(f"{target} {how}; its last lines:\n{last}", pytrace=False)
    return res.stdout
