"""Shared helpers of the reliability tests (one-line errors, fake locate methods)."""

from __future__ import annotations

from typer.testing import CliRunner

from radioloc.cli import app

runner = CliRunner()


def invoke(args, **kw):
    """Run ``radioloc ARGS`` in-process; exceptions are caught by the CLI boundary."""
    return runner.invoke(app, [str(a) for a in args], **kw)


def locate(meas, anchors, method, *opts):
    """Run ``radioloc locate MEAS --anchors ANCHORS --method METHOD -o OPT ...``."""
    args = ["locate", meas, "--anchors", anchors, "--method", method]
    for o in opts:
        args += ["-o", o]
    return invoke(args)


def lines(res) -> list[str]:
    return [ln for ln in res.output.splitlines() if ln.strip()]


def assert_one_line_error(res, code: int = 2, prefix: str = "error:") -> str:
    """The command failed with one line ``prefix ...`` and exit ``code``; returns the line."""
    out = lines(res)
    assert res.exit_code == code, (res.exit_code, res.output, res.exception)
    assert len(out) == 1 and out[0].startswith(prefix), res.output
    assert "Traceback" not in res.output
    return out[0]
