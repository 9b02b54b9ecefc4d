"""Unit slips of tdoa, pseudorange and angle values, refused at input by the bounds that hold
for any position (``tdoa_units``, ``pseudorange_units``, ``angle_units``): a correct noisy log
passes, each slip is refused with one line naming the kind and the likely unit, and
``no_check=NAME`` lets it through, in the library and through `radioloc locate`."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import InputError
from radioloc.core.plausibility import (check_angles, check_pseudoranges, check_tdoa,
                                        check_values, difference_ratio)
from radioloc.models.bearing import BearingModel
from radioloc.models.measurement import Context, Observation
from radioloc.models.pseudorange import PseudorangeModel
from radioloc.models.tdoa import TdoaModel
from reliability_helpers import assert_one_line_error, lines, locate

ANCHORS = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0], [10.0, -3.0],
                    [23.0, 7.0]])
NS = 1e9 / 299_792_458.0            # a distance in ns is this many times the one in metres


def _inside(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.c_[rng.uniform(2, 18, n), rng.uniform(2, 13, n)]


def _noisy_ranges(xy: np.ndarray, anchors=ANCHORS, seed: int = 1, nlos_rate: float = 0.3,
                  nlos_mean_m: float = 2.0) -> np.ndarray:
    """True ranges plus 0.3 m Gaussian noise and, on ``nlos_rate`` of them, an NLOS excess
    (exponential, mean ``nlos_mean_m``)."""
    rng = np.random.default_rng(seed)
    d = np.linalg.norm(xy[:, None] - anchors[None], axis=-1)
    nlos = (rng.random(d.shape) < nlos_rate) * rng.exponential(nlos_mean_m, d.shape)
    return d + 0.3 * rng.standard_normal(d.shape) + nlos


def _tdoa(xy, anchors=ANCHORS, seed=1):
    """Differences against anchor 0: values (T, M-1), anchors (M-1, 2), references."""
    r = _noisy_ranges(xy, anchors, seed)
    return r[:, 1:] - r[:, :1], anchors[1:], np.broadcast_to(anchors[0], anchors[1:].shape)


# ---- the array checks -------------------------------------------------------------------

def test_noisy_nlos_tdoa_passes_and_units_are_named():
    z, pts, ref = _tdoa(_inside(300))
    ratio, beyond, rows = difference_ratio(z, pts, ref)
    assert 0.1 < ratio < 0.8 and rows == z.size and beyond < 0.05 * rows   # bound holds
    check_tdoa(z, pts, ref)
    for k, unit in ((1e3, "mm"), (1e2, "cm")):
        with pytest.raises(InputError, match=rf"^tdoa: tdoa values in {unit}\? .*"
                                             r"no_check=tdoa_units"):
            check_tdoa(k * z, pts, ref)
        check_tdoa(k * z, pts, ref, skip={"tdoa_units"})
    # ns (3.34 x) breaks the bound over most rows only when the tag is outside the anchors
    far = _inside(300) + [60.0, 60.0]
    z_far, _, _ = _tdoa(far)
    check_tdoa(z_far, pts, ref)
    with pytest.raises(InputError, match=r"tdoa values in ns\?"):
        check_tdoa(NS * z_far, pts, ref)


def test_difference_ratio_is_unit_free_and_moves_with_the_scene():
    """Scaling values and anchors together, or moving and rotating the scene, leaves the
    statistic as it is (the anchor distances stay above the 1 m floor)."""
    z, pts, ref = _tdoa(_inside(100))
    base = difference_ratio(z, pts, ref)[0]
    assert difference_ratio(3 * z, 3 * pts, 3 * ref)[0] == pytest.approx(base)
    c, s = np.cos(0.7), np.sin(0.7)
    rot = np.array([[c, -s], [s, c]])
    assert difference_ratio(z, pts @ rot + 1e4, ref @ rot + 1e4)[0] == pytest.approx(base)
    assert difference_ratio(np.full(3, np.nan), pts[:3], ref[:3]) is None


def test_pseudoranges_with_a_large_clock_offset_pass_and_units_are_named():
    rng = np.random.default_rng(2)
    xy = _inside(200)
    offset = rng.normal(0.0, 3e4, (200, 1)) + 1e5          # the clock offset, metres
    rho = _noisy_ranges(xy) + offset
    rho[rng.random(rho.shape) < 0.1] = np.nan                 # a missing row now and then
    check_pseudoranges(rho, ANCHORS)
    for k, unit in ((1e3, "mm"), (1e2, "cm")):
        with pytest.raises(InputError, match=rf"pseudoranges in {unit}\? .*pairs of rows .*"
                                             r"no_check=pseudorange_units"):
            check_pseudoranges(k * rho, ANCHORS, where="pseudoranges")
        check_pseudoranges(k * rho, ANCHORS, skip={"pseudorange_units"})
    # km shrinks the differences: no bound tells it from a node equidistant from the anchors
    check_pseudoranges(rho / 1e3, ANCHORS)
    far = xy + [60.0, 60.0]
    with pytest.raises(InputError, match=r"pseudoranges in ns\?"):
        check_pseudoranges(NS * (_noisy_ranges(far) + offset), ANCHORS)


def test_angles_near_plus_minus_pi_pass_and_degrees_are_refused():
    rng = np.random.default_rng(3)
    near_pi = np.pi - np.abs(rng.normal(0, 0.3, 500))
    aoa = np.where(rng.random(500) < 0.5, near_pi, -near_pi) + rng.normal(0, 0.05, 500)
    check_angles(aoa)
    check_angles(np.mod(aoa, 2 * np.pi))                  # the [0, 2 pi) convention
    check_angles(aoa, "heading")
    with pytest.raises(InputError, match=r"^aoa: aoa values in degrees\? .*no_check=angle_units"):
        check_angles(np.degrees(aoa))
    check_angles(np.degrees(aoa), skip={"angle_units"})
    elevation = rng.uniform(0.05, 0.1, 200)               # 3-6 degrees: within 2 pi
    check_angles(elevation, "aoa_elevation")
    with pytest.raises(InputError, match=r"aoa_elevation values in degrees\?"):
        check_angles(np.degrees(elevation), "aoa_elevation")
    with pytest.raises(InputError, match=r"heading values not in radians\?"):
        check_angles(1e3 * aoa, "heading")                 # milliradians
    check_values("range", 1e3 * aoa)                       # no value bound of its own here


def test_observations_refuse_slipped_values_and_keep_their_no_check():
    """The library's Observation applies the same checks; a batch of runs (B, T, m) is one
    log; ``no_check`` lets the values through."""
    z, pts, ref = _tdoa(_inside(40))
    ctx = Context(points=pts, reference=ref)
    batch = np.stack([z, z[::-1]])                         # (2, T, m)
    Observation(TdoaModel(std_m=0.3), batch, ctx)
    with pytest.raises(InputError, match=r"z \(tdoa\): tdoa values in mm\?"):
        Observation(TdoaModel(std_m=0.3), 1e3 * batch, ctx)
    Observation(TdoaModel(std_m=0.3), 1e3 * batch, ctx, no_check={"tdoa_units"})
    rho = _noisy_ranges(_inside(40)) + 500.0
    with pytest.raises(InputError, match=r"z \(pseudorange\): pseudoranges in mm\?"):
        Observation(PseudorangeModel(std_m=1.0), 1e3 * rho, Context(points=ANCHORS))
    xy = _inside(40)
    bearings = np.arctan2(xy[:, None, 1] - ANCHORS[:, 1], xy[:, None, 0] - ANCHORS[:, 0])
    Observation(BearingModel(std_rad=0.05), bearings, Context(points=ANCHORS))
    with pytest.raises(InputError, match=r"z \(aoa\): aoa values in degrees\?"):
        Observation(BearingModel(std_rad=0.05), np.degrees(bearings), Context(points=ANCHORS))


# ---- through `radioloc locate` -----------------------------------------------------------

def _walk(n: int = 20) -> tuple[np.ndarray, np.ndarray]:
    t = 0.5 * np.arange(n)
    return t, np.c_[6.0 + 0.5 * t, 5.0 + 0.3 * t]


def _write(tmp_path, kind: str, scale: float = 1.0, nlos: tuple[float, float] = (0.1, 0.5)):
    """A tag walking among six anchors: tdoa rows against A0, pseudoranges with a 150 m
    clock offset, or bearings and elevations from 3-D anchors (elevations of 2-5 degrees,
    so that degrees stay below 2 pi); 0.3 m noise with an NLOS excess on ``nlos[0]`` of the
    ranges (mean ``nlos[1]`` m), 0.01 rad on the bearings."""
    t, xy = _walk()
    rng = np.random.default_rng(4)
    ids = [f"A{k}" for k in range(len(ANCHORS))]
    heights = np.array([0.40, 0.45, 0.35, 0.42, 0.38, 0.44])
    rows = ["time,node,peer,kind,value,reference"]
    for k, tk in enumerate(t):
        if kind in ("tdoa", "pseudorange"):
            r = _noisy_ranges(xy[k:k + 1], seed=k, nlos_rate=nlos[0], nlos_mean_m=nlos[1])[0]
            for a in range(1 if kind == "tdoa" else 0, len(ids)):
                v = r[a] - r[0] if kind == "tdoa" else r[a] + 150.0 + 2.0 * tk
                rows.append(f"{float(tk)!r},tag,{ids[a]},{kind},{float(scale * v)!r},"
                            + (ids[0] if kind == "tdoa" else ""))
        else:
            for a, (p, h) in enumerate(zip(ANCHORS, heights)):
                d = xy[k] - p
                az = np.arctan2(d[1], d[0]) + 0.01 * rng.standard_normal()
                el = np.arctan2(1.0 - h, np.hypot(*d)) + 0.002 * rng.standard_normal()
                rows.append(f"{float(tk)!r},tag,{ids[a]},aoa,{float(np.angle(np.exp(1j * az)))!r},")
                rows.append(f"{float(tk)!r},tag,{ids[a]},aoa_elevation,{float(scale * el)!r},")
    (tmp_path / "m.csv").write_text("\n".join(rows) + "\n")
    head = "id,x,y" + (",z" if kind == "aoa" else "")
    arows = [head] + [f"{i},{float(p[0])!r},{float(p[1])!r}"
                      + (f",{float(h)!r}" if kind == "aoa" else "")
                      for i, p, h in zip(ids, ANCHORS, heights)]
    (tmp_path / "a.csv").write_text("\n".join(arows) + "\n")
    return tmp_path / "m.csv", tmp_path / "a.csv"


SLIPS = {
    # kind: (factor, words in the message, check)
    "tdoa": (1e3, "tdoa values in mm?", "tdoa_units"),
    "pseudorange": (1e3, "pseudoranges in mm?", "pseudorange_units"),
    "aoa": (np.degrees(1.0), "aoa_elevation values in degrees?", "angle_units"),
}
OPTIONS = {"tdoa": ("tdoa_std_m=0.3",), "pseudorange": ("pseudorange_std_m=0.5",),
           "aoa": ("aoa_std_rad=0.01",)}


@pytest.mark.parametrize("method", ("lsq", "ekf-track"))
@pytest.mark.parametrize("kind", list(SLIPS))
def test_locate_refuses_each_slip_and_no_check_lets_it_through(tmp_path, kind, method):
    factor, words, check = SLIPS[kind]
    meas, anchors = _write(tmp_path, kind, scale=factor)
    line = assert_one_line_error(locate(meas, anchors, method, *OPTIONS[kind]))
    assert line.startswith("error: measurements: ") and words in line, line
    assert f"no_check={check}" in line, line
    res = locate(meas, anchors, method, *OPTIONS[kind], f"no_check={check}")
    assert f"no_check={check}" not in res.output, res.output


@pytest.mark.parametrize("method", ("lsq", "ekf-track"))
@pytest.mark.parametrize("kind", list(SLIPS))
def test_locate_passes_a_correct_noisy_log(tmp_path, kind, method):
    meas, anchors = _write(tmp_path, kind)
    res = locate(meas, anchors, method, *OPTIONS[kind])
    assert res.exit_code == 0, res.output
    body = [ln for ln in lines(res) if not ln.startswith("warning:")]
    xy = np.array([[float(v) for v in ln.split(",")[2:4]] for ln in body[1:]])
    err = np.linalg.norm(xy - _walk()[1], axis=1)
    assert np.median(err) < (3.0 if kind == "tdoa" else 1.5), err


def test_a_kind_within_its_bound_is_never_blamed_for_mm():
    """A tracker that only the tdoa values divided by 1000 satisfy: the slip search names mm
    when the log was not checked, and not when the tdoa values passed their bound (values
    in mm would have broken it); other slips of that kind are still tried."""
    from radioloc.locate.slips import likely_slip

    log = pd.DataFrame({"kind": ["tdoa", "tdoa", "range"], "value": [1.5, -2.0, 4.0]})

    def only_mm(m: pd.DataFrame) -> bool:
        return bool(np.allclose(m["value"], [1.5e-3, -2e-3, 4.0]))

    assert likely_slip(log, only_mm)[2] == "tdoa values in mm?"
    assert likely_slip(log, only_mm, bounded={"tdoa"}) is None
    assert likely_slip(log, lambda m: bool(m["value"].iloc[0] < 0),
                       bounded={"tdoa"})[1] == "negated"


def test_ekf_track_does_not_call_a_metre_log_with_nlos_mm(tmp_path):
    """0.3 m noise and an NLOS excess (mean 2 m) on 30 % of the ranges, tdoa_std_m=0.5: the
    track may diverge (a warning), but the log is not refused as tdoa in mm."""
    meas, anchors = _write(tmp_path, "tdoa", nlos=(0.3, 2.0))
    res = locate(meas, anchors, "ekf-track", "tdoa_std_m=0.5")
    assert "in mm?" not in res.output and res.exit_code == 0, res.output


def test_ekf_track_blames_the_noise_not_a_slip_when_looser_sigmas_fit(tmp_path):
    """Metre pseudoranges with an NLOS excess (mean 2 m on 30 % of the ranges) and
    pseudorange_std_m=0.5 diverge, but fit with the sigmas three times larger: a warning
    naming the noise option, not a refusal as pseudoranges in ns."""
    meas, anchors = _write(tmp_path, "pseudorange", nlos=(0.3, 2.0))
    res = locate(meas, anchors, "ekf-track", "pseudorange_std_m=0.5")
    assert res.exit_code == 0 and "in ns?" not in res.output, res.output
    assert "pseudorange_std_m=0.5" in res.output and "too small" in res.output, res.output


def test_the_value_checks_of_an_observation_do_not_load_pandas():
    """Observation runs the tdoa, pseudorange and angle checks on every construction; they
    need NumPy only, so a library user of the models does not pay for pandas."""
    import subprocess
    import sys
    from pathlib import Path

    code = ("import sys, numpy as np; "
            "from radioloc.models.measurement import Context, Observation; "
            "from radioloc.models.tdoa import TdoaModel; "
            "a = np.array([[0.0, 0], [20, 0], [20, 15]]); "
            "Observation(TdoaModel(std_m=0.1), np.array([[1.0, 2.0]]), "
            "Context(points=a[1:], reference=a[:2] * 0)); "
            "assert 'pandas' not in sys.modules, 'pandas loaded'")
    src = str(Path(__file__).resolve().parents[1] / "src")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={"PYTHONPATH": src, "PATH": "/usr/bin:/bin"}, timeout=60)
    assert res.returncode == 0, res.stderr
