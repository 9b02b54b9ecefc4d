"""Fuzz of the LIBRARY: every estimator of ``radioloc.estimators.ESTIMATORS`` and the public
model constructors, with degenerate inputs (see ``library_harness``). Each call must end in
a toolkit error naming the field at fault, or a finite result (right where the answer is
known). Profile: RADIOLOC_FUZZ_PROFILE (fast in ``make test``, long in ``make fuzz``)."""

from __future__ import annotations

import contextlib
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fuzz_harness import FUZZ
from library_harness import (
    ARRAY_MODELS,
    CASES,
    MODELS,
    SETTING_VALUES,
    Case,
    Field,
    anchor_geometry,
    anchor_geometry3,
    classify_call,
    conditioning,
    invalid_setting,
    mutations,
    record,
)
from radioloc.estimators import LocalML, Multilateration, Ransac
from radioloc.models import LosNlosRange


def _run(case: Case, mutation) -> None:
    spec = case.fields[mutation.field]
    names = mutation.names or spec.names or (mutation.field,)
    outcome, detail = classify_call(lambda: case.solve(case.settings, case.args), names=names,
                                    invalid=mutation.invalid)
    record(outcome, detail, f"{case.name}: {mutation.description}")


@pytest.fixture(scope="module", autouse=True)
def _compiled():
    """Compile every kernel once before the timed cases (a first call compiles)."""
    for make in CASES.values():
        case = make()
        with contextlib.suppress(Exception):
            case.solve(case.settings, case.args)


@FUZZ
@given(data=st.data(), name=st.sampled_from(sorted(CASES)))
def test_fuzz_estimator_inputs(data, name):
    """One field of one estimator's valid problem mutated (NaN, inf, magnitudes, signs,
    shapes, empty, text, hostile settings)."""
    case, mutation = data.draw(mutations(CASES[name]()))
    _run(case, mutation)


def test_every_valid_case_is_a_correct_success():
    """The unmutated problems succeed (close to the truth where one is known)."""
    for name, make in CASES.items():
        case = make()
        outcome, detail = classify_call(lambda: case.solve(case.settings, case.args),
                                        truth=case.truth, tol_m=case.tol_m)
        assert outcome == "success", f"{name}: {outcome}: {detail}"


def _exact_ranges(anchors, truth):
    return np.linalg.norm(np.asarray(anchors) - truth, axis=-1)


@FUZZ
@given(g=anchor_geometry(), method=st.sampled_from(["gauss-newton", "levenberg-marquardt"]))
def test_fuzz_multilateration_geometry(g, method):
    """Exact ranges to general, collinear, duplicate or coincident anchors: the truth or a
    clean refusal, never a confident wrong answer (a mirror image, a local minimum)."""
    shape, anchors, truth = g
    r = _exact_ranges(anchors, truth)
    scale = max(1.0, float(r.max()))
    outcome, detail = classify_call(
        lambda: Multilateration(method=method, std_m=0.01).locate(r, anchors),
        names=("anchors", "ranges", "geometry", "collinear", "coincident"),
        truth=truth, tol_m=1e-3 * scale)
    record(outcome, detail, f"Multilateration {method}, {shape} anchors {anchors.tolist()}, "
                            f"truth {truth.tolist()} (conditioning "
                            f"{conditioning(anchors, truth):.2g})")


@FUZZ
@given(g=anchor_geometry3(), method=st.sampled_from(["gauss-newton", "levenberg-marquardt"]),
       std=st.sampled_from([None, 0.01]))
def test_fuzz_multilateration_geometry_3d(g, method, std):
    """3-D: exact ranges to general, coplanar, nearly coplanar or collinear anchors: the
    truth or a clean refusal."""
    shape, anchors, truth = g
    r = _exact_ranges(anchors, truth)
    scale = max(1.0, float(r.max()))
    outcome, detail = classify_call(
        lambda: Multilateration(method=method, std_m=std).locate(r, anchors),
        names=("anchors", "ranges", "geometry", "coplanar", "collinear", "coincident"),
        truth=truth, tol_m=1e-3 * scale)
    record(outcome, detail, f"Multilateration 3-D {method} std {std}, {shape} anchors "
                            f"{anchors.tolist()}, truth {truth.tolist()}")


@FUZZ
@given(g=anchor_geometry(n_min=4, n_max=6),
       which=st.sampled_from(["LocalML", "LocalML-derived", "Ransac"]))
def test_fuzz_link_estimators_geometry(g, which):
    """LocalML (with a radius, and with its derived search square) and Ransac with exact
    ranges to degenerate anchor sets: the truth (within their search resolution) or a
    clean refusal."""
    shape, anchors, truth = g
    r = _exact_ranges(anchors, truth)
    radius = float(np.max(np.linalg.norm(anchors - anchors.mean(0), axis=-1))) + 2 * float(
        np.max(r)) + 1.0
    if which.startswith("LocalML"):
        est = LocalML(LosNlosRange(0.02, 5.0, 0.9), on_degenerate="raise",
                      radius_m=radius if which == "LocalML" else None)
        tol = 0.05 * max(1.0, radius / 20)
    else:
        est = Ransac(threshold_m=0.5, radius_m=radius, on_degenerate="raise")
        # a mirror closer than 2 thresholds is within Ransac's resolution and not refused
        tol = max(1.0, 1e-3 * float(np.max(r)))
    outcome, detail = classify_call(
        lambda: est.locate(r, anchors),
        names=("centres", "ranges", "geometry", "collinear", "coincident", "anchors"),
        truth=truth, tol_m=tol)
    record(outcome, detail, f"{which}, {shape} anchors {anchors.tolist()}, truth "
                            f"{truth.tolist()} (conditioning {conditioning(anchors, truth):.2g})")


@FUZZ
@given(g=anchor_geometry(n_min=4, n_max=6),
       which=st.sampled_from(["LocalML", "LocalML-derived", "Ransac"]))
def test_fuzz_link_estimators_flag_ambiguity(g, which):
    """With the default ``on_degenerate="flag"``, a fix far from the truth of exact ranges
    must carry ``diagnostics["degenerate"]``: never an unflagged wrong answer."""
    shape, anchors, truth = g
    r = _exact_ranges(anchors, truth)
    radius = float(np.max(np.linalg.norm(anchors - anchors.mean(0), axis=-1))) + 2 * float(
        np.max(r)) + 1.0
    if which.startswith("LocalML"):
        est = LocalML(LosNlosRange(0.02, 5.0, 0.9),
                      radius_m=radius if which == "LocalML" else None)
        tol = 0.05 * max(1.0, radius / 20)
    else:
        # a mirror closer than 2 thresholds is within Ransac's resolution and not flagged
        est, tol = Ransac(threshold_m=0.5, radius_m=radius), max(1.0, 1e-3 * float(np.max(r)))
    res = {}

    def solve():
        res["e"] = est.locate(r, anchors)
        return res["e"]
    outcome, detail = classify_call(solve, names=("centres", "ranges"), truth=truth, tol_m=tol)
    if outcome == "wrong answer" and bool(res["e"].diagnostics["degenerate"]):
        outcome = "success"          # flagged as ambiguous: not a confident answer
    record(outcome, detail, f"{which} (flag), {shape} anchors {anchors.tolist()}, truth "
                            f"{truth.tolist()}")


@FUZZ
@given(name=st.sampled_from(sorted(MODELS)), data=st.data())
def test_fuzz_model_constructors(name, data):
    """Scalar parameters of the public model constructors: hostile values are refused
    naming the parameter; accepted ones give finite model outputs."""
    ctor, fields, valid, probe = MODELS[name]
    kwargs = dict(valid)
    pname = data.draw(st.sampled_from(sorted(fields)))
    value = data.draw(st.sampled_from(SETTING_VALUES))
    kwargs[pname] = value
    spec = fields[pname]
    invalid = invalid_setting(spec, value)
    outcome, detail = classify_call(lambda: probe(ctor(**kwargs)), names=(pname,),
                                    invalid=invalid)
    record(outcome, detail, f"{name}({kwargs})")


@FUZZ
@given(name=st.sampled_from(sorted(ARRAY_MODELS)), data=st.data())
def test_fuzz_array_model_constructors(name, data):
    """Array parameters of TrapezoidModel and DiagMixture.create mutated like the
    estimators' inputs."""
    ctor, fields, make, probe = ARRAY_MODELS[name]
    base = Case(name, {}, make(), fields, lambda s, a: probe(ctor(**a)))
    case, mutation = data.draw(mutations(base))
    _run(case, mutation)


def test_setting_values_cover_the_hostile_classes():
    vals = SETTING_VALUES
    assert any(isinstance(v, float) and math.isnan(v) for v in vals)
    assert math.inf in vals and -math.inf in vals and 10**12 in vals
    assert invalid_setting(Field(neg_ok=False), -1.0) and not invalid_setting(Field(), 2.0)
