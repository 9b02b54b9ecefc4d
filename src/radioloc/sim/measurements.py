"""Measurement draws for any measurement model over a batch of trajectories.

- :func:`observe`: ``model.sample`` at every step of a batch of state trajectories, as an
  :class:`~radioloc.models.measurement.Observation`;
- :func:`clock_trajectory`: a receiver clock (offset, drift) evolving by a
  :class:`~radioloc.models.clock.ClockModel`;
- :func:`simulate_tdoa`: time differences drawn from first principles: one independent
  arrival-time error per anchor, differenced against the reference (so the rows' correlation
  comes from the differencing, not from the model's ``noise_cov``), with the drift of a tag
  clock over the anchors' transmission slots;
- :func:`simulate_aoa`: azimuth (and, in 3-D, elevation) observations at the anchors.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.constants import SPEED_OF_LIGHT_M_PER_S
from radioloc.core.errors import InputError
from radioloc.core.validation import as_float_array, check_positive
from radioloc.models.bearing import BearingModel
from radioloc.models.clock import ClockModel
from radioloc.models.measurement import Context, MeasurementModel, Observation, StateLayout
from radioloc.models.ranging import range_geometry
from radioloc.models.tdoa import TdoaModel

__all__ = ["observe", "clock_trajectory", "simulate_tdoa", "simulate_aoa", "SPEED_OF_LIGHT_M_PER_S"]


def observe(model: MeasurementModel, states: np.ndarray, context: Context,
            rng: np.random.Generator, layout: StateLayout | None = None) -> Observation:
    """Noisy measurements of ``model`` along a batch of trajectories.

    Parameters
    ----------
    model : MeasurementModel
    states : ndarray, shape (..., T, n)
        States laid out by ``layout`` (or positions ``(..., T, D)`` when ``layout`` is None
        and the model reads only the position).
    context : Context
        The rows' reference points: static ``(m, P)``, or moving ``(..., T, m, P)`` with
        the states' batch axes (as :meth:`Observation.at` slices them).
    rng : numpy.random.Generator
    layout : StateLayout, optional

    Returns
    -------
    Observation
        ``z`` of shape ``(..., T, m)``.
    """
    x = as_float_array(states, "states", min_ndim=2)
    if layout is None:
        if tuple(model.reads) != ("position",):
            raise InputError(f"layout: {type(model).__name__} reads {', '.join(model.reads)}; "
                             "give the StateLayout of the states")
        if x.shape[-1] not in (2, 3):
            raise InputError(f"states: positions must have 2 or 3 coordinates, got {x.shape[-1]}")
        layout = StateLayout(dim=x.shape[-1])
    layout.check(model)
    z = model.sample(layout.split(x), context, rng)
    return Observation(model=model, z=z, context=context)


def clock_trajectory(clock: ClockModel, steps: int, dt: float, rng: np.random.Generator,
                     initial: np.ndarray | None = None, batch_shape: tuple[int, ...] = ()) -> np.ndarray:
    """A receiver clock evolving by ``clock`` over ``steps`` steps of ``dt`` seconds.

    Parameters
    ----------
    clock : ClockModel
    steps : int
        T (>= 1); the first step is ``initial``.
    dt : float
        Seconds between steps.
    rng : numpy.random.Generator
    initial : ndarray, shape (..., terms), optional
        Clock state at the first step (zero by default).
    batch_shape : tuple of int
        Leading batch axes when ``initial`` is not given.

    Returns
    -------
    ndarray, shape (..., T, terms)
        Offset (m) and, with two terms, drift (m/s).
    """
    if int(steps) != steps or steps < 1:
        raise InputError(f"steps: must be a whole number >= 1, got {steps!r}")
    check_positive(dt, "dt", allow_zero=True)
    x = np.zeros(tuple(batch_shape) + (clock.terms,)) if initial is None else \
        as_float_array(initial, "initial", last_dim=clock.terms)
    out = [x]
    for _ in range(int(steps) - 1):
        x = clock.sample(x, dt, rng)
        out.append(x)
    return np.stack(out, axis=-2)


def simulate_tdoa(positions: np.ndarray, anchors: np.ndarray, rng: np.random.Generator, *,
                  std_m: float, reference: int = 0, slot_s: np.ndarray | None = None,
                  drift_m_per_s: np.ndarray | None = None) -> Observation:
    """Time differences of arrival against one reference anchor, drawn from independent
    arrival times.

    Each anchor's arrival time (in metres) is ``d_a + e_a``, ``e_a ~ N(0, std_m^2)``
    independent; a row is the difference to the reference's. With ``slot_s`` the anchors
    transmit in turn, anchor ``i`` ``tau_i = slot_s[i] - slot_s[reference]`` seconds after
    the reference, and the tag's clock, running fast by ``drift / c``, measures the time
    between the two arrivals as ``(1 + drift / c)`` times the true one; the known interval is
    then subtracted: ``z_i = (1 + drift / c)(d_i - d_ref + c tau_i) - c tau_i + e_i - e_ref``.

    Parameters
    ----------
    positions : ndarray, shape (..., T, D) or (..., D)
        Tag positions.
    anchors : ndarray, shape (A, D)
        Anchor positions.
    rng : numpy.random.Generator
    std_m : float
        Standard deviation of one arrival time, metres.
    reference : int
        Row of the reference anchor in ``anchors``.
    slot_s : ndarray, shape (A,), optional
        Transmission time of each anchor within a frame, seconds.
    drift_m_per_s : ndarray, shape (..., T) or (...), optional
        The tag clock's drift at each step (needs ``slot_s``).

    Returns
    -------
    Observation
        A :class:`~radioloc.models.tdoa.TdoaModel` with rows for every anchor but the
        reference (``Context.index``, ``reference_index`` set).
    """
    x = as_float_array(positions, "positions", min_ndim=1, last_dim=(2, 3))
    a = as_float_array(anchors, "anchors", ndim=2, last_dim=x.shape[-1])
    A = a.shape[0]
    if int(reference) != reference or not 0 <= reference < A:
        raise InputError(f"reference: must be an anchor row 0..{A - 1}, got {reference!r}")
    others = np.array([k for k in range(A) if k != reference])
    if drift_m_per_s is not None and slot_s is None:
        raise InputError("slot_s: a clock drift only shows in TDoA rows of anchors that "
                         "transmit at different times; give their slot times")
    d, _ = range_geometry(x, a)
    arrival = d + check_positive(std_m, "std_m") * rng.standard_normal(d.shape)
    z = arrival[..., others] - arrival[..., [reference]]
    if slot_s is not None:
        slots = as_float_array(slot_s, "slot_s", ndim=1)
        if slots.shape != (A,):
            raise InputError(f"slot_s: expected {A} slot times (one per anchor), got "
                             f"{slots.shape[0]}")
        tau = slots[others] - slots[reference]
        if drift_m_per_s is not None:
            drift = as_float_array(drift_m_per_s, "drift_m_per_s")[..., None]
            true = d[..., others] - d[..., [reference]] + SPEED_OF_LIGHT_M_PER_S * tau
            z = z + drift / SPEED_OF_LIGHT_M_PER_S * true
    else:
        slots = None
    m = A - 1
    ctx = Context(points=a[others], index=others, reference=np.broadcast_to(a[reference], (m, a.shape[1])),
                  reference_index=np.full(m, int(reference)))
    return Observation(model=TdoaModel(std_m=std_m, slot_s=slots), z=z, context=ctx)


def simulate_aoa(positions: np.ndarray, anchors: np.ndarray, rng: np.random.Generator, *,
                 std_rad: float, orientation_rad: float | np.ndarray = 0.0) -> list[Observation]:
    """Angles of arrival at every anchor: the azimuth, and in 3-D the elevation too.

    Parameters
    ----------
    positions : ndarray, shape (..., T, D) or (..., D)
    anchors : ndarray, shape (A, D)
    rng : numpy.random.Generator
    std_rad : float
        Standard deviation of each angle, radians.
    orientation_rad : float or ndarray, shape (A,)
        Yaw of each anchor's frame.

    Returns
    -------
    list of Observation
        ``[azimuth]`` in 2-D, ``[azimuth, elevation]`` in 3-D (``Context.index`` set).
    """
    x = as_float_array(positions, "positions", min_ndim=1, last_dim=(2, 3))
    a = as_float_array(anchors, "anchors", ndim=2, last_dim=x.shape[-1])
    ctx = Context(points=a, index=np.arange(a.shape[0]))
    parts = ["azimuth"] + (["elevation"] if x.shape[-1] == 3 else [])
    out = []
    for component in parts:
        model = BearingModel(std_rad=std_rad, component=component, orientation_rad=orientation_rad)
        out.append(Observation(model=model, z=model.sample({"position": x}, ctx, rng), context=ctx))
    return out
