"""The validation layer at the library boundary: every public estimator and model refuses
complex, bool and object inputs naming the argument (never drops an imaginary part or reads
True as 1), refuses settings beyond their bound, and readers name the right line."""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "fuzz"))

from library_harness import ARRAY_MODELS, CASES, MODELS

from radioloc.core.errors import ConfigError, InputError, RadiolocError
from radioloc.core.textfile import read_json_object
from radioloc.core.validation import (
    as_float_array,
    check_dtype,
    check_int,
    check_positive,
    check_real,
    check_shapes,
)
from radioloc.estimators import GridFilter, GridGeometry, LocalML, Ransac
from radioloc.io.logs import read_measurements
from radioloc.models import LogDistanceGaussian, LosNlosRange, TrapezoidModel

DTYPES = {
    "complex": lambda a: a + 0j,
    "bool": lambda a: a > np.median(a),
    "object": lambda a: a.astype(object),
}


def _refused(fn, names) -> str:
    """``fn()`` raises a toolkit error naming one of ``names``, with no warning on the way."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(RadiolocError) as info:
            fn()
    msg = str(info.value)
    assert any(n in msg for n in names), msg
    return msg


def _array_fields():
    for name, make in sorted(CASES.items()):
        case = make()
        for field, spec in sorted(case.fields.items()):
            if not spec.setting and np.asarray(case.args[field]).size > 1:
                yield name, field


@pytest.mark.parametrize("kind", sorted(DTYPES))
@pytest.mark.parametrize("name,field", list(_array_fields()))
def test_every_estimator_refuses_complex_bool_object_arrays(name, field, kind):
    case = CASES[name]()
    args = dict(case.args)
    args[field] = DTYPES[kind](np.asarray(args[field], dtype=float))
    msg = _refused(lambda: case.solve(case.settings, args), case.fields[field].names or (field,))
    assert kind in msg


@pytest.mark.parametrize("name", sorted(CASES))
def test_every_estimator_refuses_complex_and_bool_settings(name):
    case = CASES[name]()
    settings = [f for f, spec in case.fields.items() if spec.setting and f in case.settings]
    for field in settings:
        for value in (np.complex128(2.0), complex(1, 1), np.bool_(True)):
            s = dict(case.settings, **{field: value})
            _refused(lambda s=s: case.solve(s, case.args), (field,))


@pytest.mark.parametrize("name", sorted(MODELS))
def test_every_model_refuses_complex_settings(name):
    ctor, fields, values, check = MODELS[name]
    for field in fields:
        kw = dict(values, **{field: np.complex128(2.0)})
        _refused(lambda kw=kw: check(ctor(**kw)), (field,))


@pytest.mark.parametrize("name", sorted(ARRAY_MODELS))
@pytest.mark.parametrize("kind", sorted(DTYPES))
def test_array_models_refuse_dtypes_and_name_shape_errors(name, kind):
    ctor, fields, make, check = ARRAY_MODELS[name]
    for field in fields:
        kw = make()
        kw[field] = DTYPES[kind](np.asarray(kw[field], dtype=float))
        _refused(lambda kw=kw: check(ctor(**kw)), (field,))
        kw = make()
        kw[field] = np.asarray(kw[field])[:-1]
        _refused(lambda kw=kw: check(ctor(**kw)), tuple(fields))


def test_helpers_name_the_argument():
    with pytest.raises(InputError, match="ranges: expected real numbers, got complex"):
        as_float_array(np.ones(3) + 1j, "ranges")
    with pytest.raises(InputError, match="mask: expected real numbers, got bool"):
        check_dtype(np.ones(3) > 0, "mask")
    with pytest.raises(InputError, match="w: expected real numbers, got object"):
        as_float_array([1.0, None], "w")
    with pytest.raises(InputError, match="x: expected an array of numbers"):
        as_float_array([[1.0, 2.0], [3.0]], "x")
    assert check_dtype([1, 2], "n").dtype.kind == "i"
    with pytest.raises(InputError, match=r"a \(shape \(3,\)\) and b \(shape \(4,\)\)"):
        check_shapes("a", (3,), "b", (4,))
    assert check_shapes("a", (3, 1), "b", (4,)) == (3, 4)
    for bad in (np.complex128(1.0), 1j, np.bool_(False)):
        with pytest.raises(ConfigError, match="std_m"):
            check_positive(bad, "std_m")
        with pytest.raises(ConfigError, match="bias_m"):
            check_real(bad, "bias_m")
        with pytest.raises(ConfigError, match="count"):
            check_int(bad, "count")


def test_length_settings_are_bounded():
    geom = GridGeometry.centred(8, 8, 1.0, centre=(0.0, 0.0))
    with pytest.raises(ConfigError, match="blur_m: 1e\\+30 is outside"):
        GridFilter(geom, LogDistanceGaussian(a=60.0, n=2.0, s=2.0, d_ref_m=0.1), blur_m=1e30)
    with pytest.raises(ConfigError, match="los_std_m"):
        LosNlosRange(los_std_m=1e30)
    assert LosNlosRange(los_std_m=1e3).los_std_m == 1e3


@pytest.mark.parametrize("make", [
    lambda: LocalML(LosNlosRange(0.02, 5.0, 0.9), radius_m=40.0),
    lambda: Ransac(threshold_m=0.5, radius_m=40.0)])
def test_snapshot_baselines_refuse_all_nan_ranges(make):
    centres = np.array([[[0.0, 0.0], [30.0, 0.0], [0.0, 20.0]]] * 2)
    with pytest.raises(InputError, match="ranges: no finite range"):
        make().locate(np.full((2, 3), np.nan), centres)


@pytest.mark.parametrize("content,words", [
    (b"null", "got null"), (b'"a string"', "got str"), (b"[" * 100000 + b"]" * 100000, "nested"),
    (b'{"mu": {"a": 1}, "tau": [1], "sigma": [1]}', "mu: expected real numbers"),
    (b'{"mu": [1,\n2,\n\xff]}', "line 3: not UTF-8"),
    (b'{"mu": [1,\n2,\n}', "line 3: not valid JSON")])
def test_trapezoid_model_file_errors_are_toolkit_errors(tmp_path, content, words):
    p = tmp_path / "model.json"
    p.write_bytes(content)
    with pytest.raises(InputError, match=words):
        TrapezoidModel.load(p)


def test_text_files_utf16_bom_and_the_line_of_a_bad_byte(tmp_path):
    text = "time,node,peer,kind,value\r\n0,t,A,range,1\r\n1,t,A,range,2\r\n"
    p = tmp_path / "m.csv"
    for encoding in ("utf-16", "utf-8-sig", "utf-8"):
        p.write_bytes(text.encode(encoding))
        assert read_measurements(p)["value"].tolist() == [1.0, 2.0]
    p.write_bytes(("time,node,peer,kind,value\n" + "0,t,A,range,1\n" * 5000).encode()
                  + "1,t\xe9,A,range,2\n".encode("latin-1"))
    with pytest.raises(InputError, match="line 5002: not UTF-8 text \\(byte 0xe9"):
        read_measurements(p)
    q = tmp_path / "c.json"
    q.write_text(json.dumps({"a": 1}))
    assert read_json_object(q, "calibration") == {"a": 1}


# ---- the generic models' boundary: named shape errors, no silent complex/bool -----------

def _generic_models():
    from radioloc.models import (
        BearingModel,
        LogDistanceGaussian,
        PseudorangeModel,
        RangeModel,
        RssModel,
    )
    return {"range": RangeModel(std_m=0.1), "aoa": BearingModel(std_rad=0.05),
            "pseudorange": PseudorangeModel(std_m=1.0),
            "rss": RssModel(LogDistanceGaussian(a=60.0, n=2.0, s=2.0, d_ref_m=0.1))}


@pytest.mark.parametrize("kind", ["range", "aoa", "pseudorange", "rss"])
def test_generic_model_logpdf_names_shape_mismatches(kind):
    from radioloc.core.errors import InputError
    from radioloc.models.measurement import Context

    model = _generic_models()[kind]
    ctx = Context(points=np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 20.0], [30.0, 20.0]]))
    state = {"position": np.array([[7.0, 12.0], [8.0, 11.0], [1.0, 1.0]]),
             "clock_offset": np.zeros(3)}
    assert model.logpdf(np.ones(4), state, ctx).shape == (3, 4)        # rows broadcast
    with pytest.raises(InputError, match=r"z \(shape \(3,\)\)"):
        model.logpdf(np.ones(3), state, ctx)
    with pytest.raises(InputError, match=r"z \(shape \(2, 4\)\)"):
        model.logpdf(np.ones((2, 4)), state, ctx)
    with pytest.raises(InputError, match="state"):
        model.logpdf(np.ones(4), np.array([7.0, 12.0]), ctx)
    with pytest.raises(InputError, match=r"state\['position'\]"):
        model.logpdf(np.ones(4), {**state, "position": np.ones(7)}, ctx)
    if kind == "pseudorange":
        with pytest.raises(InputError, match="clock_offset"):
            model.logpdf(np.ones(4), {"position": state["position"]}, ctx)
    with pytest.raises(InputError, match="z: expected real numbers"):
        model.logpdf(np.ones(4) + 0j, state, ctx)


@pytest.mark.parametrize("call", ["gaussian", "los_nlos", "by_state", "logd_lik", "logd_lp",
                                  "trapezoid"])
def test_range_and_rss_densities_name_shape_mismatches(call):
    from radioloc.core.errors import InputError
    from radioloc.models import (
        GaussianRange,
        LogDistanceGaussian,
        LosNlosRange,
        TrapezoidModel,
    )

    trap = TrapezoidModel(mu=np.linspace(40.0, 0.5, 101), tau=np.full(101, 1.0),
                          sigma=np.full(101, 2.0), count=np.full(101, 100.0))
    logd = LogDistanceGaussian(a=60.0, n=2.0, s=2.0, d_ref_m=0.1)
    fn = {"gaussian": GaussianRange(0.1).logpdf, "los_nlos": LosNlosRange(0.1, 1.0, 0.5).logpdf,
          "by_state": LosNlosRange(0.1, 1.0, 0.5).logpdf_by_state,
          "logd_lik": logd.likelihood, "logd_lp": logd.logpdf, "trapezoid": trap.likelihood}[call]
    assert np.shape(fn(np.ones(3), np.ones((2, 1)))) in ((2, 3), (2, 3, 2))
    with pytest.raises(InputError, match="do not broadcast"):
        fn(np.ones(3), np.ones(4))
    if call in ("gaussian", "los_nlos", "by_state"):
        with pytest.raises(InputError, match="measured: expected real numbers"):
            fn(np.ones(3) + 0j, np.ones(3))


@pytest.mark.parametrize("field", ["points", "reference", "std", "height_m", "obs_std"])
@pytest.mark.parametrize("bad", ["complex", "bool"])
def test_context_and_observation_refuse_complex_and_bool(field, bad):
    from radioloc.core.errors import RadiolocError
    from radioloc.models import RangeModel
    from radioloc.models.measurement import Context, Observation

    pts = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 20.0]])
    good = {"points": pts, "reference": pts[::-1].copy(), "std": np.full(3, 0.1),
            "height_m": 1.0}
    value = {"points": pts, "reference": pts, "std": np.full(3, 0.1), "height_m": 1.0,
             "obs_std": np.full(3, 0.1)}[field]
    value = (np.asarray(value) + 0j) if bad == "complex" else (np.asarray(value) > 0.5)
    name = "std" if field == "obs_std" else field
    with pytest.raises(RadiolocError, match=name):
        if field == "obs_std":
            Observation(RangeModel(std_m=0.1), np.ones(3), Context(**good), std=value)
        else:
            Context(**{**good, field: value[()] if field == "height_m" else value})


def test_measurements_table_refuses_a_non_frame():
    from radioloc.core.errors import InputError
    from radioloc.io.measurements import Measurements

    with pytest.raises(InputError, match="measurements: expected a DataFrame"):
        Measurements([[0.0, "a", "A1", "range", 1.0]])


def test_a_range_below_a_large_bias_names_the_bias_argument():
    from radioloc.core.validation import check_ranges

    with pytest.raises(InputError, match=r"range_bias_m 1e\+12 m .*is range_bias_m right\?"):
        check_ranges(np.array([9.8, 3.0]), "ranges", 0.1, bias_m=1e12, bias_name="range_bias_m")
    with pytest.raises(InputError, match=r"^ranges: range -1 at index \(1,\) .* below 0\)$"):
        check_ranges(np.array([9.8, -1.0]), "ranges", 0.1)


def test_an_infinite_measurement_is_named_by_its_observation_and_index():
    from radioloc.estimators.batch_smoother import BatchSmoother
    from radioloc.estimators.least_squares import LeastSquares
    from radioloc.models.measurement import Context, Observation
    from radioloc.models.motion import WhiteAccelerationCV
    from radioloc.models.ranging import RangeModel

    pts = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 20.0], [30.0, 20.0]])
    z = np.array([[np.inf, 20.0, 15.0, 25.0]] * 3)
    obs = Observation(RangeModel(std_m=0.1), z, Context(points=pts))
    with pytest.raises(InputError, match=r"^observations\[0\]\.z: .*\(0, 0\)"):
        LeastSquares().locate(obs)
    with pytest.raises(InputError, match=r"^observations\[0\]\.z: .*\(0, 0\)"):
        BatchSmoother(WhiteAccelerationCV(dim=2, q=0.1)).run(obs, np.arange(3.0),
                                                            prior_mean=np.zeros(4),
                                                            prior_cov=np.eye(4))


def test_the_particle_filter_names_an_infinite_measurement():
    from radioloc.estimators.particle_filter import ParticleFilter
    from radioloc.models.measurement import Context, Observation
    from radioloc.models.motion import WhiteAccelerationCV
    from radioloc.models.ranging import RangeModel

    pts = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 20.0], [30.0, 20.0]])
    z = np.array([[np.inf, 20.0, 15.0, 25.0]] * 3)
    obs = Observation(RangeModel(std_m=0.1), z, Context(points=pts))
    with pytest.raises(InputError, match=r"^observations\[0\]\.z: .*\(0, 0\)"):
        ParticleFilter(WhiteAccelerationCV(dim=2, q=0.1), n_particles=50, seed=1).run(
            obs, np.arange(3.0), prior_mean=np.zeros(4), prior_cov=np.eye(4))
