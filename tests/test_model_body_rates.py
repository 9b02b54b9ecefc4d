"""Body-frame odometry models (speed, yaw rate) and the white-jerk motion model."""

from __future__ import annotations

import numpy as np
import pytest

from radioloc.core.errors import ConfigError
from radioloc.models.body_rates import SpeedModel, VerticalSpeedModel, YawRateModel
from radioloc.models.measurement import Context, StateLayout, numerical_jacobian
from radioloc.models.motion import WhiteJerkCA

CTX3 = Context(points=np.zeros((1, 3)))
CTX2 = Context(points=np.zeros((1, 2)))


def circle_state(radius: float, speed: float, angle: float, centre=(0.0, 0.0, 0.0),
                 up=np.array([0.0, 0.0, 1.0])) -> dict:
    """A point turning counter-clockwise (seen from ``up``) on a horizontal circle."""
    e1 = np.cross(up, [1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.cross(up, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    c, s = np.cos(angle), np.sin(angle)
    w = speed / radius
    return {"position": np.asarray(centre) + radius * (c * e1 + s * e2),
            "velocity": speed * (-s * e1 + c * e2),
            "acceleration": -speed * w * (c * e1 + s * e2)}


def test_yaw_rate_of_a_circle_is_speed_over_radius_in_any_frame():
    local = circle_state(25.0, 10.0, 0.7)
    assert YawRateModel(std_rps=0.01).predict(local, CTX3)[0] == pytest.approx(0.4)
    # the same turn in ECEF near Berlin: "up" from the Earth's centre
    centre = np.array([3785108.0, 899901.5, 5037234.5])
    ecef = circle_state(25.0, 10.0, 2.1, centre, centre / np.linalg.norm(centre))
    got = YawRateModel(std_rps=0.01, geocentric=True).predict(ecef, CTX3)[0]
    assert got == pytest.approx(0.4, rel=1e-6)
    clockwise = dict(local, velocity=-local["velocity"])
    assert YawRateModel(std_rps=0.01).predict(clockwise, CTX3)[0] == pytest.approx(-0.4)


def test_speed_ignores_the_vertical_which_vertical_speed_reads():
    state = {"position": np.zeros(3), "velocity": np.array([3.0, 4.0, 12.0])}
    assert SpeedModel(std_mps=0.1).predict(state, CTX3)[0] == pytest.approx(5.0)
    assert VerticalSpeedModel(std_mps=0.1).predict(state, CTX3)[0] == pytest.approx(12.0)
    p = np.array([3785108.0, 899901.5, 5037234.5])           # ECEF: "up" from the centre
    climb = {"position": p, "velocity": 2.0 * p / np.linalg.norm(p) + [1.0, -1.0, 0.0]}
    got = VerticalSpeedModel(std_mps=0.1, geocentric=True).predict(climb, CTX3)[0]
    assert got == pytest.approx(2.0 + (p[0] - p[1]) / np.linalg.norm(p))


@pytest.mark.parametrize("model", [SpeedModel(std_mps=0.1), YawRateModel(std_rps=0.01),
                                   VerticalSpeedModel(std_mps=0.1)])
@pytest.mark.parametrize("dim", [2, 3])
def test_jacobians_equal_finite_differences(model, dim):
    if dim == 2 and model.kind == "vertical_speed":
        pytest.skip("a 2-D state has no vertical")
    layout = StateLayout(dim=dim, order=2).with_model(model)
    rng = np.random.default_rng(4)
    x = layout.join({"position": rng.normal(size=(5, dim)),
                     "velocity": rng.normal(size=(5, dim)) * 4 + 3,
                     "acceleration": rng.normal(size=(5, dim))})
    ctx = CTX2 if dim == 2 else CTX3
    _, H = layout.measure(model, x, ctx)
    numeric = numerical_jacobian(model, layout.split(x), ctx)
    for name in ("velocity", "acceleration"):
        if name in model.reads:
            np.testing.assert_allclose(H[..., layout.slices[name]], numeric[name], atol=1e-6)


def test_yaw_rate_is_missing_when_standing_still():
    state = {"position": np.zeros(2), "velocity": np.array([0.1, 0.0]),
             "acceleration": np.array([0.0, 1.0])}
    model = YawRateModel(std_rps=0.01)
    assert np.isnan(model.predict(state, CTX2)).all()
    assert model.logpdf(np.array([0.3]), state, CTX2).tolist() == [0.0]


def test_white_jerk_noise_does_not_depend_on_how_an_interval_is_split():
    motion = WhiteJerkCA(q=2.0, dim=2)
    F1, Q1 = motion.F(0.3), motion.Q(0.3)
    two_steps = motion.F(0.7) @ Q1 @ motion.F(0.7).T + motion.Q(0.7)
    np.testing.assert_allclose(two_steps, motion.Q(1.0), atol=1e-12)
    np.testing.assert_allclose(motion.F(0.7) @ F1, motion.F(1.0), atol=1e-12)
    assert np.linalg.eigvalsh(motion.Q(0.2)).min() > 0          # full rank
    with pytest.raises(ConfigError):
        WhiteJerkCA(q=-1.0)


def test_body_rates_are_declared_kinds_refused_beyond_their_limits_and_motions(tmp_path):
    """speed, vertical_speed and yaw_rate come from the registry (self-measured, their own
    sigma options); a log row beyond a kind's limit is refused naming the line; a yaw rate
    with a motion without acceleration is refused naming motion=ca."""
    from radioloc.core.kinds import kind
    from radioloc.io.logs import read_measurements
    from radioloc.models.measurement import check_motion
    from radioloc.models.motion import WhiteAccelerationCV

    for name, option in (("speed", "speed_std_mps"), ("vertical_speed", "vertical_speed_std_mps"),
                         ("yaw_rate", "yaw_rate_std_rps")):
        k = kind(name)
        assert k.self_measured and k.sigma_option == option and k.build(0.2).kind == name
    log = tmp_path / "m.csv"
    log.write_text("time,node,peer,kind,value\n0,car,odo,speed,12\n1,car,odo,speed,2000\n")
    with pytest.raises(ValueError, match=r"line 3.*speed 2000 m/s is beyond the limit of 1000"):
        read_measurements(log)
    with pytest.raises(ConfigError, match="motion=ca"):
        check_motion(YawRateModel(std_rps=0.01), WhiteAccelerationCV(1.0, 2))
