"""Ctrl-C or SIGTERM (a real signal to a separate `radioloc reproduce` process) at several
points of a run leaves ``OUT/<id>`` holding the previous complete run, a new complete run (when the
signal arrives after the swap) or nothing: never a mixed or partial folder.

The child process registers a small fake experiment and pauses at named points (during a
block, after the figure, half-way through ``results.csv``, inside ``summary.json``, just
before and just after the folder swap), announcing each on standard error; the test sends
SIGINT when the announced point is reached and inspects the folder afterwards.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pandas as pd
import pytest

pytestmark = pytest.mark.skipif(os.name != "posix", reason="SIGINT to a child needs POSIX")

EXP = "fake-interrupt"

CHILD = textwrap.dedent(r'''
    import os, sys, time, dataclasses
    import pandas as pd
    import radioloc.core.atomic as atomic
    import radioloc.experiments.base as exp_base
    import radioloc.experiments as experiments
    from radioloc.experiments.base import Claim, Experiment, Metric, Summary

    # only the fake experiment is registered: importing every experiment module (what
    # `reproduce` does to write the index) costs about 2 s per child and is not under test
    experiments.discover = lambda: None

    PAUSE = os.environ.get("PAUSE_AT", "")

    def point(name):
        sys.stderr.write(f"AT {name}\n"); sys.stderr.flush()
        if name == PAUSE:
            time.sleep(60)          # the test interrupts here

    @dataclasses.dataclass
    class Config:
        runs: int = 4
        block_size: int = 2

    class Fake(Experiment):
        id = "fake-interrupt"
        paper = "-"
        description = "fake experiment for the interrupt test"

        def config(self, full):
            return Config()

        def run_block(self, config, runs, rng):
            point("block")
            return pd.DataFrame({"run": runs, "error_m": rng.random(len(runs))})

        def summarize(self, config, results, out_dir):
            (out_dir / "fig.png").write_bytes(b"png " + str(len(results)).encode())
            point("figure")
            return Summary([Metric("mean error", float(results.error_m.mean()), unit="m")],
                           [Claim("it runs", True)], [])

    exp_base._REGISTRY[Fake.id] = Fake()

    real_to_csv = pd.DataFrame.to_csv
    def to_csv(self, f=None, **kw):
        if f is not None and hasattr(f, "write") and list(self.columns) == ["run", "error_m"]:
            f.write("run,error_m\n"); f.flush()
            point("results.csv")
            text = real_to_csv(self, None, **kw)
            f.write(text.split("\n", 1)[1])
            return None
        return real_to_csv(self, f, **kw)
    pd.DataFrame.to_csv = to_csv

    real_write_text = atomic.atomic_write_text
    def write_text(path, text):
        if str(path).endswith("summary.json"):
            with atomic.atomic_open(path, "w") as fh:
                fh.write(text[: len(text) // 2]); fh.flush()
                point("summary.json")
                fh.write(text[len(text) // 2:])
            return path
        return real_write_text(path, text)
    import radioloc.experiments.runner as runner
    runner.atomic_write_text = write_text

    real_exchange = atomic._exchange
    def exchange(a, b):
        point("before swap")
        done = real_exchange(a, b)
        point("after swap")
        return done
    atomic._exchange = exchange
    real_replace = atomic.os.replace
    def replace(a, b):
        moving_run = os.path.basename(str(b)) == "fake-interrupt"
        if moving_run:
            point("before swap")
        real_replace(a, b)
        if moving_run:
            point("after swap")
    atomic.os.replace = replace

    from radioloc.cli import app
    sys.argv = ["radioloc", "reproduce", "fake-interrupt", "--out", sys.argv[1],
                "--seed", sys.argv[2]]
    app()
''')

POINTS = ["block", "figure", "results.csv", "summary.json", "before swap", "after swap"]


def _child(tmp_path: Path, out: Path, seed: int, pause: str | None):
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    env = {**os.environ, "PAUSE_AT": pause or "",
           "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src")}
    return subprocess.Popen([sys.executable, str(script), str(out), str(seed)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _snapshot(folder: Path) -> dict[str, bytes]:
    if not folder.exists():
        return {}
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def _complete(folder: Path) -> bool:
    if not all((folder / n).is_file() for n in ("summary.json", "results.csv", "fig.png")):
        return False
    s = json.loads((folder / "summary.json").read_text())
    r = pd.read_csv(folder / "results.csv")
    return len(r) == s["runs"] and (folder / "fig.png").exists() and \
        sorted(p.name for p in folder.iterdir()) == ["fig.png", "results.csv", "summary.json"]


def _run_to_end(tmp_path, out, seed):
    proc = _child(tmp_path, out, seed, None)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err


CASES = ([("SIGINT", pause) for pause in POINTS]
         + [("SIGTERM", pause) for pause in ("block", "results.csv", "summary.json")])


@pytest.mark.parametrize("previous", [True, False], ids=["after-a-run", "first-run"])
@pytest.mark.parametrize("signame, pause", CASES)
def test_a_signal_leaves_previous_run_new_run_or_nothing(tmp_path, signame, pause, previous):
    out = tmp_path / "out"
    folder = out / EXP
    if previous:
        _run_to_end(tmp_path, out, 1)
        assert _complete(folder)
    before = _snapshot(folder)
    proc = _child(tmp_path, out, 2, pause)
    seen = []
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        seen.append(line.strip())
        if line.strip() == f"AT {pause}":
            proc.send_signal(getattr(signal, signame))
            break
    else:  # pragma: no cover
        proc.kill()
        pytest.fail(f"the child did not reach {pause!r}: {seen}")
    assert f"AT {pause}" in seen, f"the child ended before {pause!r}: {seen}"
    _, err = proc.communicate(timeout=300)
    code, word = (130, "interrupted") if signame == "SIGINT" else (143, "terminated")
    assert proc.returncode == code, (proc.returncode, err)
    assert [ln for ln in err.splitlines() if ln.strip()] == [word], err
    after = _snapshot(folder)
    if after and after != before:
        assert _complete(folder), f"interrupted at {pause!r}: a partial folder {sorted(after)}"
        assert pause == "after swap", f"a new run appeared although interrupted at {pause!r}"
    elif not after:
        assert not previous or pause in ("before swap", "after swap"), \
            f"the previous run vanished (interrupted at {pause!r})"
    staging = out / ".radioloc-staging"
    assert not staging.exists() or not any(staging.iterdir()), \
        f"staging leftovers after the interrupt at {pause!r}: {list(staging.iterdir())}"
    # the next run completes and leaves one complete folder, nothing else
    _run_to_end(tmp_path, out, 3)
    assert _complete(folder) and sorted(p.name for p in out.iterdir()) == [EXP]
