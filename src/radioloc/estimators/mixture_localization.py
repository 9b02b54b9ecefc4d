"""Localization and tracking with Gaussian-mixture signal-strength models (paper 004, Sects. 3.2, 4).

- :class:`MixtureLocalizer` (snapshot): each received base station's model
  ``D^(k)(x, y, m)`` (eq. (1)) is conditioned on its measured ``m^(k)`` in closed form
  (:meth:`DiagMixture.condition`), and the ``N_r`` position densities are multiplied and
  renormalised, eq. (2); after each product the result is reduced to ``max_components``
  (:func:`radioloc.models.mixture.reduce`). Base stations not received (NaN) are left out.
- :class:`MixtureTracker` (recursive): per time step, prediction by convolution with the
  uniform disk of radius ``v_max * dt`` of a :class:`~radioloc.models.motion.UniformDisk`
  motion model, re-approximated as a mixture (:func:`uniform_ball`), then the filter step
  (product of the prediction with the measurement density of eq. (2)), reduction, and the
  mixture mean and covariance as the per-step estimate. ``v_max = 0`` skips the prediction
  (the static user of Sect. 5). A step where no base station is received is a prediction.
  With a :class:`~radioloc.models.motion.BoundedSpeedCV` motion the state is (position,
  velocity) and each component is predicted at constant velocity (ours, not the paper's).
  ``reduction="progressive"`` re-approximates by the Progressive Bayes ISD homotopy.

Both return the posterior mixture with the estimate: diagnostics ``mixture_weights``
``(..., K)``, ``mixture_means`` and ``mixture_variances`` ``(..., K, D)`` (unused slots have
weight 0), read back with :func:`posterior_mixture`; ``measurements_used`` is the number of
base stations received.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.arrays import kernel_array
from radioloc.core.backend import DEFAULT_BACKEND, check_backend
from radioloc.core.errors import ConfigError, InputError, RadiolocError
from radioloc.core.results import Estimate, Track, track_from_steps
from radioloc.core.validation import (MAX_COMPONENTS, POSITIVE_FLOOR, as_float_array,
                                      check_covariance, check_int, check_memory,
                                      refuse_infinite)
from radioloc.estimators.base import RecursiveEstimator, SnapshotEstimator, Tags
from radioloc.estimators.observation_rows import (common_steps, flatten_step, log_likelihood_at,
                                                  observation_list, unflatten_estimate)
from radioloc.estimators.progressive_update import progressive_update
from radioloc.models.fingerprint_mixture import FingerprintMixture, place_moments, place_weights
from radioloc.models.mixture import (REDUCTIONS, DiagMixture, check_reduction, compact,
                                     convolve, linear_predict, merge_groups, outer,
                                     pad_components, product, product_on, reduce, select,
                                     uniform_ball)
from radioloc.models.mixture_compiled import product_batch
from radioloc.models.measurement import Observation
from radioloc.models.mixture_rss import MixtureRssModel
from radioloc.models.motion import BoundedSpeedCV, UniformDisk, WhiteAccelerationCV

__all__ = ["MixtureLocalizer", "MixtureTracker", "MixtureState", "posterior_mixture",
           "TRACKER_REDUCTIONS"]

#: reductions of :class:`MixtureTracker` (the first is the default)
TRACKER_REDUCTIONS = ("continuous",) + REDUCTIONS

#: diagnostics keys holding the posterior mixture
MIXTURE_KEYS = ("mixture_weights", "mixture_means", "mixture_variances")


def _check_models(models: object) -> DiagMixture:
    if not isinstance(models, DiagMixture):
        raise InputError(f"models: expected a DiagMixture, got {type(models).__name__}")
    if not models.batch_shape:
        raise InputError("models: needs a base-station axis (batch shape (..., S))")
    if models.dim < 2:
        raise InputError(f"models: dimension {models.dim}, expected position coordinates and m")
    for name in ("weights", "means", "variances"):
        arr = np.asarray(getattr(models, name))
        if not np.all(np.isfinite(arr)):
            idx = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
            raise InputError(f"models: non-finite {name} at index {idx}")
    if np.any(models.variances <= 0):
        raise InputError("models: variances must be > 0")
    if np.any(models.weights < 0) or np.any(models.weights.sum(-1) <= 0):
        raise InputError("models: weights must be >= 0 with a positive total per station")
    return models


def _check_max_components(k: object) -> int:
    try:
        return check_int(k, "max_components", minimum=1, maximum=MAX_COMPONENTS)
    except RadiolocError as exc:          # this module's settings errors are InputErrors
        raise InputError(str(exc)) from None


def _with_mixture(mix: DiagMixture, k: int) -> dict[str, np.ndarray]:
    mix = pad_components(mix, k)
    return {"mixture_weights": mix.weights, "mixture_means": mix.means,
            "mixture_variances": mix.variances}


def posterior_mixture(result: Estimate) -> DiagMixture:
    """The posterior mixture carried by an estimate of :class:`MixtureLocalizer` or
    :class:`MixtureTracker` (``track.at(t)`` for a step of a track).

    Parameters
    ----------
    result : Estimate
        An estimate whose diagnostics hold ``mixture_weights``, ``mixture_means`` and
        ``mixture_variances``.

    Returns
    -------
    DiagMixture
        Batch shape ``result.batch_shape``, dimension ``result.dim``.
    """
    missing = [k for k in MIXTURE_KEYS if k not in result.diagnostics]
    if missing:
        raise InputError(f"result: no posterior mixture in its diagnostics ({', '.join(missing)})")
    d = result.diagnostics
    return DiagMixture(np.asarray(d["mixture_weights"]), np.asarray(d["mixture_means"]),
                       np.asarray(d["mixture_variances"]))


class MixtureLocalizer(SnapshotEstimator):
    """One-shot localization by the product of conditioned station models, eq. (2).

    Two kinds of models:

    - a :class:`~radioloc.models.mixture.DiagMixture` per base station (paper 004 as
      written): each received station's ``D^(k)(x, y, m)`` (eq. (1)) is conditioned on its
      measurement, the ``N_r`` densities are multiplied (eq. (2)) and reduced to
      ``max_components`` after each product; stations not received (NaN) are left out.
      Defined by the composition of :meth:`DiagMixture.condition`, :func:`product` and
      :func:`reduce` (``backend="numpy"``); one compiled kernel over the rows by default
      (``radioloc.models.mixture_compiled.product_batch``, West/Runnalls only).
    - a :class:`~radioloc.models.fingerprint_mixture.FingerprintMixture` (WiFi scale:
      place components shared by all access points, "not detected" an explicit outcome;
      NaN = not detected): the place weights of every scan come from one matrix product,
      the zone (e.g. building, then floor) is the one of largest posterior mass
      (:func:`~radioloc.models.fingerprint_mixture.zone_posterior`), and the estimate is
      the mean and covariance of the posterior mixture restricted to that zone.

    Parameters
    ----------
    models : DiagMixture or FingerprintMixture
        Per-station models, batch shape ``(..., S)`` (extra leading axes broadcast against
        the measurements), dimension ``D + 1``: the position coordinates ``(x[, y])`` then
        the signal strength ``m`` (eq. (1)); or a fingerprint model.
    max_components : int
        Bound on the components of every position density (after each product); with a
        fingerprint model, the number of heaviest place components reported in the
        diagnostics.
    reduction : str
        ``"runnalls"`` (West/Runnalls greedy merging, one compiled kernel) or
        ``"progressive"`` (the Progressive Bayes ISD homotopy,
        :func:`radioloc.models.mixture.reduce`); station models only.
    temperature : float
        Fingerprint models only: ``T >= 1`` tempering the product over access points
        (place weights ``∝ exp(log L / T)``); 1 = the plain product.
    top_places : int, optional
        Fingerprint models only: keep the ``M`` heaviest places of the chosen zone
        (:func:`~radioloc.models.fingerprint_mixture.place_weights`); None = all.
    backend : str
        ``"numba"`` (default: the compiled kernels) or ``"numpy"`` (the definition).

    Raises
    ------
    InputError
        Naming ``models``, ``max_components``, ``reduction`` or ``temperature`` when they
        are not valid.

    Notes
    -----
    The densities are axis-aligned: a :class:`~radioloc.models.mixture.DiagMixture` holds
    per-axis variances, and a moment-matched merge keeps the diagonal of the merged
    covariance (the x-y term is dropped). A rotation of the scene is therefore exact only
    where it maps the models onto themselves (multiples of 90 degrees, the variances
    swapped at a quarter turn); any other rotation changes the reduced product, and moves
    the estimate the more, the fewer components are kept (on a 1.5 m calibration grid with
    0.35 m^2 variances, 0.7 rad moved it 0.14 m with 8 components, 5e-4 m with 30).
    """

    name = "mixture"

    def __init__(self, models: DiagMixture | FingerprintMixture, max_components: int = 16,
                 reduction: str = "runnalls", temperature: float = 1.0,
                 top_places: int | None = None, backend: str = DEFAULT_BACKEND) -> None:
        self.backend = check_backend(backend)
        if top_places is not None:
            if isinstance(top_places, bool) or not isinstance(top_places, (int, np.integer)) \
                    or top_places < 1:
                raise InputError(f"top_places: must be an integer >= 1 or None, got "
                                 f"{top_places!r}")
            if not isinstance(models, FingerprintMixture):
                raise InputError("top_places: applies to fingerprint models only")
        self.top_places = None if top_places is None else int(top_places)
        if isinstance(models, FingerprintMixture):
            self.models = models
        else:
            self.models = _check_models(models)
        self.max_components = _check_max_components(max_components)
        self.reduction = check_reduction(reduction)
        t = temperature
        if isinstance(t, bool) or not isinstance(t, (int, float, np.floating)) \
                or not np.isfinite(t) or t < 1:
            raise InputError(f"temperature: must be a finite number >= 1, got {t!r}")
        if t != 1 and not isinstance(models, FingerprintMixture):
            raise InputError("temperature: applies to fingerprint models only")
        self.temperature = float(t)

    @property
    def fingerprint(self) -> bool:
        """Whether the models are a :class:`FingerprintMixture`."""
        return isinstance(self.models, FingerprintMixture)

    @property
    def n_stations(self) -> int:
        """Number of base stations S."""
        if self.fingerprint:
            return self.models.n_stations
        return self.models.batch_shape[-1]

    @property
    def dim(self) -> int:
        """Position coordinates D."""
        return self.models.dim if self.fingerprint else self.models.dim - 1

    def _check_rss(self, rss: object, name: str = "rss", min_ndim: int = 1) -> np.ndarray:
        m = as_float_array(rss, name, min_ndim=min_ndim, allow_nan=True)
        if m.shape[-1] != self.n_stations:
            raise InputError(f"{name}: {m.shape[-1]} base station columns, the models have "
                             f"{self.n_stations}")
        if np.any(np.isinf(m)):
            idx = tuple(int(i) for i in np.argwhere(np.isinf(m))[0])
            raise InputError(f"{name}: infinite signal strength at index {idx}")
        return m

    def _require_stations(self, what: str) -> None:
        if self.fingerprint:
            raise InputError(f"{what}: needs per-station DiagMixture models (this localizer "
                             "holds a FingerprintMixture; use locate)")

    def density_and_mask(self, rss: np.ndarray, models: DiagMixture | None = None
                         ) -> tuple[DiagMixture, np.ndarray]:
        """Position density of eq. (2) for every row, rows with no station included.

        Parameters
        ----------
        rss : ndarray, shape (..., S)
            Signal strengths, NaN = not received (already validated).
        models : DiagMixture, optional
            The station models broadcast against ``rss`` (default: this localizer's).

        Returns
        -------
        density : DiagMixture
            Batch shape ``rss.shape[:-1]`` (broadcast with the models' leading axes); where
            no station is received it is a meaningless placeholder.
        received : ndarray of bool, shape (...)
            True where at least one station was received.
        """
        self._require_stations("density_and_mask")
        models = self.models if models is None else models
        try:
            shape = np.broadcast_shapes(models.batch_shape[:-1], rss.shape[:-1])
        except ValueError:
            raise InputError(f"rss: batch shape {rss.shape[:-1]} does not broadcast with the "
                             f"models' {models.batch_shape[:-1]}") from None
        s, k, d1 = models.batch_shape[-1], models.n_components, models.dim
        kmax = self.max_components
        # min(kmax, k ** s) without forming k ** s (it overflows for hundreds of stations)
        k_eff = float(kmax) if k > 1 and s * np.log(k) >= np.log(kmax) else float(k) ** s
        check_memory(32.0 * np.prod(shape, dtype=float) * k_eff * k_eff * (2 * d1 - 1),
                     "max_components", "the products of the position mixtures")
        got = np.broadcast_to(np.isfinite(rss), shape + (s,))
        order = _station_order(np.broadcast_to(rss, shape + (s,)))
        if self.reduction == "runnalls" and self.backend == "numba":
            ow, om, ov, ok = product_batch(
                kernel_array(np.broadcast_to(models.weights, shape + (s, k)).reshape(-1, s, k)),
                *(kernel_array(np.broadcast_to(a, shape + (s, k, d1)).reshape(-1, s, k, d1))
                  for a in (models.means, models.variances)),
                kernel_array(np.broadcast_to(rss, shape + (s,)).reshape(-1, s)),
                kernel_array(order.reshape(-1, s), np.int64), kmax)
            if not np.all(ok):
                raise InputError("weights: a mixture lost all its mass (disjoint densities)")
            post = compact(DiagMixture(ow, om, ov))
            kk = post.n_components
            post = DiagMixture(post.weights.reshape(shape + (kk,)),
                               post.means.reshape(shape + (kk, d1 - 1)),
                               post.variances.reshape(shape + (kk, d1 - 1)))
            return post, got.any(-1)
        # the definition: condition, reduce each station, multiply and reduce (eq. (2))
        cond = models.condition(d1 - 1, np.where(np.isfinite(rss), rss, 0.0),
                                valid=np.isfinite(rss))
        cw = np.broadcast_to(cond.weights, shape + cond.weights.shape[-2:])
        cm = np.broadcast_to(cond.means, shape + cond.means.shape[-3:])
        cv = np.broadcast_to(cond.variances, shape + cond.variances.shape[-3:])
        post = have = None
        for p in range(s):
            st = order[..., p]
            ck = DiagMixture(
                np.take_along_axis(cw, st[..., None, None], -2)[..., 0, :],
                np.take_along_axis(cm, st[..., None, None, None], -3)[..., 0, :, :],
                np.take_along_axis(cv, st[..., None, None, None], -3)[..., 0, :, :])
            ck = reduce(ck, kmax, self.reduction, self.backend)
            gk = np.take_along_axis(got, st[..., None], -1)[..., 0]
            if post is None:
                post, have = ck, gk
                continue
            both = reduce(product(post, ck), kmax, self.reduction, self.backend)
            post = select(gk & have, both, select(gk, ck, post))
            have = have | gk
        return post, have

    def density(self, rss: object) -> DiagMixture:
        """Position density ``D(x, y | m)`` of eq. (2) for a batch of measurement vectors.

        Parameters
        ----------
        rss : array_like, shape (..., S)
            Measured signal strengths; NaN = base station not received.

        Returns
        -------
        DiagMixture
            Batch shape ``rss.shape[:-1]``, dimension D.

        Raises
        ------
        InputError
            If a row has no received base station, or on a shape mismatch.
        """
        self._require_stations("density")
        m = self._check_rss(rss)
        post, have = self.density_and_mask(m)
        if not np.all(have):
            bad = tuple(int(i) for i in np.argwhere(~np.broadcast_to(have, post.batch_shape))[0])
            raise InputError(f"rss: row {bad} has no received base station")
        return post

    def locate(self, rss: object) -> Estimate:
        """Locate every measurement vector of a batch (eq. (2)).

        Parameters
        ----------
        rss : array_like, shape (..., S)
            Measured signal strengths in dBm; NaN = base station not received (skipped)
            with station models, not detected (an outcome) with a fingerprint model.

        Returns
        -------
        Estimate
            ``position`` ``(..., D)`` = the mixture mean, ``covariance`` ``(..., D, D)`` =
            the mixture covariance; diagnostics ``measurements_used`` and the posterior
            mixture (:func:`posterior_mixture`). With a fingerprint model: the zone-restricted
            posterior (its ``max_components`` heaviest places, renormalised, in the
            diagnostics), ``stations_ignored`` (detected access points the model dropped)
            and ``zone`` ``(..., L)`` (the chosen label of each zone level).

        Raises
        ------
        InputError
            If a row has no received base station (station models), or on a shape mismatch.
        """
        m = self._check_rss(rss)
        if self.fingerprint:
            return self._locate_places(m)
        post = self.density(m)
        mean, cov = post.moments()
        used = np.broadcast_to(np.isfinite(m).sum(-1), post.batch_shape)
        return Estimate(mean, cov, None, {"measurements_used": used,
                                          **_with_mixture(post, self.max_components)})

    def _locate_places(self, m: np.ndarray) -> Estimate:
        fm: FingerprintMixture = self.models
        lead = m.shape[:-1]
        flat = m.reshape(-1, m.shape[-1])
        w, chosen = place_weights(fm, fm.loglik(flat), self.temperature, self.top_places)
        pos, pvar = fm.positions, fm.position_variances
        mean, cov = place_moments(fm, w)
        det = np.isfinite(flat)
        top = min(self.max_components, fm.n_places)
        idx = np.argpartition(-w, top - 1, axis=1)[:, :top]
        tw = np.take_along_axis(w, idx, 1)
        order = np.argsort(-tw, axis=1, kind="stable")
        idx, tw = np.take_along_axis(idx, order, 1), np.take_along_axis(tw, order, 1)
        mix = DiagMixture(tw / tw.sum(1, keepdims=True), pos[idx], pvar[idx])
        diag = {"measurements_used": (det & fm.active).sum(-1).reshape(lead),
                "stations_ignored": (det & ~fm.active).sum(-1).reshape(lead),
                **{k: v.reshape(lead + v.shape[1:]) for k, v in
                   _with_mixture(mix, self.max_components).items()}}
        if fm.zones.shape[1]:
            diag["zone"] = chosen.reshape(lead + chosen.shape[1:])
        return Estimate(mean.reshape(lead + (fm.dim,)), cov.reshape(lead + (fm.dim, fm.dim)),
                        None, diag)


@dataclass(frozen=True)
class MixtureState:
    """State of :class:`MixtureTracker` for a batch of runs.

    Attributes
    ----------
    mixture : DiagMixture
        Current density of the tracker's state, batch shape ``(...)``: the position, or
        (with a :class:`~radioloc.models.motion.BoundedSpeedCV` motion) the position then
        the velocity.
    informed : ndarray of bool, shape (...)
        False until a first base station is received (and no prior was given): the
        density is then the calibration area (flat prior), replaced at the first
        measurement.
    used : ndarray of int, shape (...)
        Base stations received at the last step.
    time : float
        Time of the last step, seconds.
    """

    mixture: DiagMixture
    informed: np.ndarray
    used: np.ndarray
    time: float = 0.0


class MixtureTracker(RecursiveEstimator):
    """Recursive Bayesian tracking with mixture densities (Sect. 4, Fig. 7).

    Observations: :meth:`run` also takes
    :class:`~radioloc.models.measurement.Observation` inputs with a prior (``prior_mean``,
    ``prior_cov`` or a mixture), the form of the generic estimators (``tags``: any model
    with a ``logpdf`` of the position). Observations of a
    :class:`~radioloc.models.mixture_rss.MixtureRssModel` (the calibration mixtures as a
    measurement model, rows the stations) take the paper's filter step, the exact product
    with the measurement density of eq. (2). Other models (ranges, time differences,
    bearings, path-loss RSS, ...) take a Gaussian-sum filter step: each predicted
    component is multiplied by the likelihood and moment-matched by a progressive update
    on Gauss-Hermite nodes (ours; :meth:`run_observations`).

    Parameters
    ----------
    models : DiagMixture, optional
        Per-base-station calibration models, batch shape ``(..., S)``, dimension ``D + 1``
        (as for :class:`MixtureLocalizer`); None: given by the observations' model.
    motion : UniformDisk, BoundedSpeedCV or WhiteAccelerationCV
        ``UniformDisk`` (the paper's model): the next position is uniform in the disk of
        radius ``v_max * dt`` (paper: ``v_max`` = 1.5 m/s); ``v_max = 0`` is a static user
        (no prediction); the state is the position. ``BoundedSpeedCV`` (ours, a velocity
        that persists): the state is (position, velocity), each component predicted by the
        constant-velocity transition with white acceleration (kept axis-aligned:
        :func:`radioloc.models.mixture.linear_predict`); before the first measurement the
        velocity is uniform in the ball of radius ``v_max`` (:func:`uniform_ball`).
        ``WhiteAccelerationCV``: the same transition, with the velocity from a prior on
        the whole state (no ``v_max``).
    max_components : int
        Bound on the components of every density.
    reduction : str
        How the filter step and the prediction are re-approximated:

        - ``"continuous"`` (default): a fixed-structure reduction, continuous in the
          inputs. The prediction convolves every component with the disk mixture and keeps
          all the cells (no reduction); the filter step multiplies this prediction by the
          measurement density of eq. (2) and merges, for every component of the
          measurement density, its products with all the predicted components into one,
          moment-matched (:func:`radioloc.models.mixture.merge_groups`); a step with no
          station received merges each component's disk cells (the moment-matched
          convolution). The posterior then has as many components as the measurement
          density (at most ``max_components``), placed by the data and weighted and
          narrowed by the prior. No cost is compared, so the estimate is a continuous
          function of the time steps and of the prior, exactly independent of the order of
          the components, and rotates and translates with the scene. The measurement
          density itself (the product over the stations, reduced after each factor by
          West/Runnalls; the stations by decreasing reading) depends only on the readings
          and the models, not on time.
        - ``"runnalls"``: West/Runnalls greedy merging of every product and prediction
          (the re-approximation as in Sect. 4); the greedy choice jumps where two merges
          are about as cheap, so the track can move by metres when a time step changes by a
          millisecond.
        - ``"progressive"``: the Progressive Bayes ISD homotopy of the paper's reference
          [3] for every re-approximation (started from West/Runnalls, so not continuous
          either).
    backend : str
        ``"numba"`` (default) or ``"numpy"``: the West/Runnalls reduction and the
        measurement density by their compiled kernels or by their NumPy definitions.

    Raises
    ------
    InputError
        Naming ``models``, ``motion``, ``max_components`` or ``reduction`` when they are
        not valid.

    Notes
    -----
    The densities are axis-aligned (per-axis variances; merges drop the x-y covariance,
    see :class:`MixtureLocalizer`) and the disk mixture has 60-degree symmetry, so a
    rotation of the scene rotates the estimate exactly only by a half turn; any other moves
    it by a fraction of a component's spread (0.04-0.20 m for 0.7 rad with 0.35 m^2
    components and 8 components kept). "Rotates with the scene" in ``reduction`` means
    under those symmetries.
    """

    name = "mixture-tracker"
    tags = Tags(kinds=None, uses="logpdf", dims=(1, 2), recursive=True,
                generic=True, reads=("position",))

    def __init__(self, models: DiagMixture | None = None,
                 motion: UniformDisk | BoundedSpeedCV | WhiteAccelerationCV | None = None,
                 max_components: int = 16, reduction: str = "continuous",
                 backend: str = DEFAULT_BACKEND) -> None:
        self.backend = check_backend(backend)
        self.models = None if models is None else _check_models(models)
        self.max_components = _check_max_components(max_components)
        if not isinstance(reduction, str) or reduction not in TRACKER_REDUCTIONS:
            raise InputError(f"reduction: must be one of {', '.join(TRACKER_REDUCTIONS)}, "
                             f"got {reduction!r}")
        self.reduction = reduction
        self.continuous = reduction == "continuous"
        #: the reduction of the fixed densities (measurement density, calibration area,
        #: a prior with too many components): West/Runnalls for the continuous tracker
        self.base_reduction = "runnalls" if self.continuous else reduction
        if not isinstance(motion, (UniformDisk, WhiteAccelerationCV)):
            raise InputError(f"motion: expected radioloc.models.motion.UniformDisk, "
                             f"BoundedSpeedCV or WhiteAccelerationCV, got {type(motion).__name__}")
        if self.models is not None and motion.dim != self.models.dim - 1:
            raise InputError(f"motion: dim {motion.dim} differs from the models' position "
                             f"dimension {self.models.dim - 1}")
        if motion.dim > 2 and (isinstance(motion, WhiteAccelerationCV)
                               or motion.v_max_m_per_s > 0):
            raise InputError(f"motion: the tracker supports 1 or 2 position coordinates "
                             f"(1-D, 2-D), got dim {motion.dim}")
        self.motion = motion
        self.velocity = isinstance(motion, WhiteAccelerationCV)
        self._localizer = None if models is None else MixtureLocalizer(
            models, max_components, self.base_reduction, backend=self.backend)

    @property
    def dim(self) -> int:
        """Position coordinates D."""
        return self.motion.dim

    @property
    def state_dim(self) -> int:
        """Coordinates of the tracked state: D, or 2 D with velocity."""
        return 2 * self.dim if self.velocity else self.dim

    def _reduce(self, mix: DiagMixture) -> DiagMixture:
        return reduce(mix, self.max_components, self.base_reduction, self.backend)

    def _with_velocity(self, pos: DiagMixture) -> DiagMixture:
        """A position density extended by the velocity prior (uniform in the ball v_max);
        continuous tracker: each position component with the moment-matched ball."""
        if not self.velocity:
            return pos
        if not isinstance(self.motion, BoundedSpeedCV):
            raise InputError(f"prior: {type(self.motion).__name__} gives no velocity prior "
                             "(no v_max): give a prior on the whole state (prior_mean, "
                             "prior_cov with the velocity, or a DiagMixture of dimension "
                             f"{self.state_dim})")
        joint = outer(pos, uniform_ball(self.motion.v_max_m_per_s, self.dim))
        if self.continuous:
            return merge_groups(joint, pos.n_components, "outer")
        return self._reduce(joint)

    def calibration_area(self) -> DiagMixture:
        """The flat-prior stand-in: the position marginal of all station models pooled.

        Returns
        -------
        DiagMixture
            Batch shape ``models.batch_shape[:-1]``, at most ``max_components`` components.
        """
        self._require_models("a flat prior (the calibration area)")
        marg = self.models.marginal(list(range(self.dim)))
        s, k = marg.batch_shape[-1], marg.n_components
        lead = marg.batch_shape[:-1]
        w = marg.weights / marg.weights.sum(-1, keepdims=True) / s
        pooled = DiagMixture(w.reshape(lead + (s * k,)),
                             marg.means.reshape(lead + (s * k, self.dim)),
                             marg.variances.reshape(lead + (s * k, self.dim)))
        return self._reduce(pooled)

    def init(self, prior: DiagMixture | None = None, batch_shape: tuple[int, ...] | None = None,
             time: float = 0.0) -> MixtureState:
        """The state before the first measurement.

        Parameters
        ----------
        prior : DiagMixture, optional
            Prior density of the position (dimension D; with velocity it is extended by
            the velocity prior) or of the whole state (dimension :attr:`state_dim`).
            Default: none (a flat prior: the first step with a received station starts
            from its measurement density alone; until then the estimate is the
            calibration area).
        batch_shape : tuple of int, optional
            Batch axes of the runs (default: the models' leading axes, or the prior's).
        time : float
            Time of the state, seconds.

        Returns
        -------
        MixtureState
            The initial state.
        """
        if prior is None:
            mix = self._with_velocity(self.calibration_area())
            informed = False
        else:
            if not isinstance(prior, DiagMixture) or prior.dim not in (self.dim, self.state_dim):
                raise InputError(f"prior: expected a DiagMixture of dimension {self.dim}"
                                 + (f" or {self.state_dim}" if self.velocity else ""))
            mix = self._reduce(prior) if prior.dim == self.state_dim else \
                self._with_velocity(self._reduce(prior))
            informed = True
        shape = mix.batch_shape if batch_shape is None else tuple(batch_shape)
        try:
            shape = np.broadcast_shapes(shape, mix.batch_shape)
        except ValueError:
            raise InputError(f"batch_shape: {shape} does not broadcast with "
                             f"{mix.batch_shape}") from None
        mix = DiagMixture(np.broadcast_to(mix.weights, shape + mix.weights.shape[-1:]),
                          np.broadcast_to(mix.means, shape + mix.means.shape[-2:]),
                          np.broadcast_to(mix.variances, shape + mix.variances.shape[-2:]))
        return MixtureState(mix, np.full(shape, informed), np.zeros(shape, int), float(time))

    def _predict(self, mix: DiagMixture, dt: float) -> DiagMixture:
        if self.velocity:
            if dt <= 0:
                return mix
            return linear_predict(mix, self.motion.F(dt), self.motion.Q(dt))
        r = float(self.motion.radius(dt))
        if r <= 0:
            return mix
        return self._reduce(convolve(mix, uniform_ball(r, self.dim)))

    def _update_continuous(self, state: MixtureState, meas: DiagMixture, received: np.ndarray,
                           used: np.ndarray, dt: float) -> MixtureState:
        """The filter step of ``reduction="continuous"`` (see the class docstring)."""
        informed = np.broadcast_to(state.informed, meas.batch_shape)
        received = np.broadcast_to(received, meas.batch_shape)
        prior = state.mixture
        kp = prior.n_components
        if self.velocity:
            cells = linear_predict(prior, self.motion.F(dt), self.motion.Q(dt)) if dt > 0 \
                else prior
            merged = cells
        else:
            r = float(self.motion.radius(dt))
            if r > 0:
                cells = convolve(prior, uniform_ball(r, self.dim))
                merged = merge_groups(cells, kp, "outer")
            else:
                cells = merged = prior
        if np.any(informed):
            pred = select(informed, cells, prior)
            if self.velocity:
                prod = product_on(pred, meas, list(range(self.dim)))
            else:
                prod = product(pred, meas)
            filtered = merge_groups(prod, pred.n_components, "inner")
            kept = select(informed, merged, prior)
        else:
            filtered, kept = meas, prior
        if np.any(received & ~informed):
            post = select(received & informed, filtered,
                          select(received, self._with_velocity(meas), kept))
        else:
            post = select(received, filtered, kept)
        return MixtureState(compact(post), informed | received,
                            np.broadcast_to(used, meas.batch_shape), state.time + dt)

    def _update(self, state: MixtureState, meas: DiagMixture, received: np.ndarray,
                used: np.ndarray, dt: float) -> MixtureState:
        if self.continuous:
            return self._update_continuous(state, meas, received, used, dt)
        informed = np.broadcast_to(state.informed, meas.batch_shape)
        received = np.broadcast_to(received, meas.batch_shape)
        prior = state.mixture
        if np.any(informed):
            prior = select(informed, self._predict(prior, dt), prior)
        if self.velocity:
            filtered = self._reduce(product_on(prior, meas, list(range(self.dim))))
            first = self._with_velocity(meas)
        else:
            filtered = self._reduce(product(prior, meas))
            first = meas
        post = select(received & informed, filtered, select(received, first, prior))
        return MixtureState(self._reduce(post), informed | received,
                            np.broadcast_to(used, meas.batch_shape), state.time + dt)

    def _check_dt(self, dt: object) -> float:
        d = as_float_array(dt, "dt")
        if d.ndim != 0 or d < 0:
            raise InputError(f"dt: must be one finite time step >= 0 s, got {dt!r}")
        return float(d)

    def step(self, state: MixtureState, rss_t: object, dt: float) -> MixtureState:
        """Prediction over ``dt`` and filter step with one measurement vector per run.

        Parameters
        ----------
        state : MixtureState
            The state at the previous step (not modified).
        rss_t : array_like, shape (..., S)
            Signal strengths of this step, NaN = not received; a run with no station
            received is only predicted.
        dt : float
            Time since the previous step, seconds (>= 0).

        Returns
        -------
        MixtureState
            The new state.
        """
        m = self._require_models("step")._check_rss(rss_t, "rss_t")
        dt = self._check_dt(dt)
        meas, received = self._localizer.density_and_mask(m)
        used = np.isfinite(m).sum(-1)
        return self._update(state, meas, received, used, dt)

    def estimate(self, state: MixtureState) -> Estimate:
        """Mixture mean and covariance of the position of a state.

        Parameters
        ----------
        state : MixtureState
            A tracker state.

        Returns
        -------
        Estimate
            ``position`` ``(..., D)``, ``covariance`` ``(..., D, D)``, ``time``;
            diagnostics ``measurements_used`` and the posterior mixture of the state
            (dimension :attr:`state_dim`, padded to ``max_components`` slots;
            :func:`posterior_mixture`).
        """
        mean, cov = state.mixture.marginal(list(range(self.dim))).moments()
        return Estimate(mean, cov, state.time, {
            "measurements_used": np.asarray(state.used),
            **_with_mixture(state.mixture, self.max_components)})

    def _require_models(self, where: str) -> MixtureLocalizer:
        if self._localizer is None:
            raise InputError(f"models: {where} needs the tracker's station models (give "
                             "models, or observations of a MixtureRssModel)")
        return self._localizer

    def run(self, rss: object, time: object = None, prior: DiagMixture | None = None, *,
            prior_mean=None, prior_cov=None) -> Track:
        """Track every run of a batch through a series of measurement vectors.

        ``run(observations, time, *, prior_mean, prior_cov)`` is the form of the generic
        estimators (:meth:`run_observations`).

        Parameters
        ----------
        rss : array_like, shape (..., T, S), or Observation
            Signal strengths per step, NaN = not received (a step with no station received
            is a prediction only); or an observation of a
            :class:`~radioloc.models.mixture_rss.MixtureRssModel`.
        time : array_like, shape (T,)
            Step times in seconds, non-decreasing (the first step is not predicted).
        prior : DiagMixture, optional
            Prior density (see :meth:`init`).
        prior_mean, prior_cov : array_like, optional
            A Gaussian prior on the tracker's state instead (observations only).

        Returns
        -------
        Track
            ``position`` ``(..., T, D)``, ``covariance`` ``(..., T, D, D)``, ``time``;
            per-step diagnostics as in :meth:`estimate`.
        """
        if isinstance(rss, Observation) or (isinstance(rss, (list, tuple)) and rss
                                            and isinstance(rss[0], Observation)):
            return self.run_observations(rss, time, prior_mean=prior_mean, prior_cov=prior_cov,
                                         prior=prior)
        if prior_mean is not None or prior_cov is not None:
            raise InputError("prior_mean: taken with observations; with readings give prior "
                             "(a DiagMixture)")
        if time is None:
            raise InputError("time: give the step times of the readings")
        m = self._require_models("run")._check_rss(rss, min_ndim=2)
        t = as_float_array(time, "time", ndim=1)
        if t.shape[0] != m.shape[-2]:
            raise InputError(f"time: {t.shape[0]} steps, rss has {m.shape[-2]}")
        dts = np.diff(t, prepend=t[0])
        if np.any(dts < 0):
            i = int(np.flatnonzero(dts < 0)[0])
            raise InputError(f"time: decreases at step {i} ({t[i - 1]} -> {t[i]})")
        # the measurement densities of all steps at once: a time axis in the models
        mod = self.models
        tm = DiagMixture(mod.weights[..., None, :, :], mod.means[..., None, :, :, :],
                         mod.variances[..., None, :, :, :])
        meas, received = self._localizer.density_and_mask(m, tm)
        used = np.isfinite(m).sum(-1)
        batch = meas.batch_shape[:-1]
        state = self.init(prior, batch, float(t[0]))
        steps = []
        for i in range(t.size):
            mi = DiagMixture(meas.weights[..., i, :], meas.means[..., i, :, :],
                             meas.variances[..., i, :, :])
            state = self._update(state, mi, received[..., i], used[..., i], float(dts[i]))
            steps.append(self.estimate(state))
        return track_from_steps(steps, t)


    def run_observations(self, observations, time=None, *, prior_mean=None,
                         prior_cov=None, prior: DiagMixture | None = None) -> Track:
        """Track through observations of any model with a log-likelihood of the position.

        - One observation of a :class:`~radioloc.models.mixture_rss.MixtureRssModel`
          (paper 004's calibration mixtures as a measurement model): its rows are stations
          (``context.index``), its mixtures the tracker's station models, and the filter
          that of :meth:`run` on the readings placed in their station columns (the exact
          product of eq. (2)).
        - Any other models (ranges, time differences, bearings, signal strength, ...,
          several at once): each step predicts every component (as the continuous
          reduction does: the disk cells of a component merged back into one, or the
          constant-velocity transition) and multiplies it by the rows' likelihood through
          the models' ``logpdf``, re-approximated per component by a progressive Gaussian
          update on Gauss-Hermite nodes
          (:func:`~radioloc.estimators.progressive_update.progressive_update`). The number
          of components is that of the prior. A run whose rows have zero likelihood on
          every node keeps its prediction for that step (``measurements_used`` 0).

        Parameters
        ----------
        observations : Observation or sequence of Observation
            ``z`` ``(..., T, m)`` each, the same ``T``; NaN = not received.
        time : array_like, shape (T,), optional
            Step times, seconds (default ``0..T-1``).
        prior_mean, prior_cov : array_like, optional
            Gaussian prior on the state (``(..., n)``, ``(n, n)`` or ``(..., n, n)``,
            ``n`` = :attr:`state_dim`): one component with the diagonal of ``prior_cov``
            (the mixture is axis-aligned). Without it, a mixture tracker's calibration area
            (and, with velocity, the ball of ``BoundedSpeedCV``); other models need a prior.
        prior : DiagMixture, optional
            A mixture prior instead (as for :meth:`init`; not with a
            :class:`~radioloc.models.mixture_rss.MixtureRssModel`).

        Returns
        -------
        Track
            ``position`` ``(..., T, D)``, ``covariance`` ``(..., T, D, D)``, ``time``;
            diagnostics as in :meth:`estimate`.
        """
        obs = observation_list(observations)
        for i, o in enumerate(obs):
            self.tags.require(o.model, f"observations[{i}].model", type(self).__name__)
        if len(obs) != 1 or not isinstance(obs[0].model, MixtureRssModel):
            return self._run_models(obs, time, prior_mean, prior_cov, prior)
        if prior is not None:
            raise InputError("prior: with observations of a MixtureRssModel give prior_mean "
                             "and prior_cov")
        o = obs[0]
        model: MixtureRssModel = o.model
        if model.dim != self.dim:
            raise InputError(f"observations[0].model: {model.dim}-D positions, the motion "
                             f"model's are {self.dim}-D")
        z = refuse_infinite(o.z, "observations[0].z")
        if z.ndim < 2:
            raise InputError(f"observations[0].z: expected shape (..., T, m), got {z.shape}")
        idx = o.context.index
        if idx is None or np.any((idx < 0) | (idx >= model.n_stations)) \
                or np.unique(idx).size != idx.size:
            raise InputError("observations[0].context.index: give each row's station, once "
                             f"each, among the model's {model.n_stations}")
        rss = np.full(z.shape[:-1] + (model.n_stations,), np.nan)
        rss[..., idx] = z
        t = np.arange(z.shape[-2], dtype=float) if time is None else time
        prior = self._gaussian_prior(prior_mean, prior_cov)
        tracker = self if self.models is model.models else MixtureTracker(
            model.models, self.motion, self.max_components, self.reduction, self.backend)
        return tracker.run(rss, t, prior)

    def _prior_moments(self, prior_mean, prior_cov) -> tuple[np.ndarray, np.ndarray] | None:
        """A Gaussian prior on the state, checked: ``(mean (..., n), cov (..., n, n))``, or
        None when neither is given."""
        if prior_mean is None and prior_cov is None:
            return None
        if prior_mean is None or prior_cov is None:
            raise InputError("prior_mean: give both prior_mean and prior_cov")
        n = self.state_dim
        mean = as_float_array(prior_mean, "prior_mean", min_ndim=1)
        cov = as_float_array(prior_cov, "prior_cov", min_ndim=2)
        if mean.shape[-1] != n or cov.shape[-2:] != (n, n):
            raise InputError(f"prior_mean: expected shape (..., {n}) and prior_cov "
                             f"(..., {n}, {n}) (the tracker's state), got {mean.shape} "
                             f"and {cov.shape}")
        check_covariance(cov, "prior_cov", min_variance=POSITIVE_FLOOR)
        return mean, cov

    def _gaussian_prior(self, prior_mean, prior_cov) -> DiagMixture | None:
        """One axis-aligned component from a Gaussian prior on the state (None without)."""
        moments = self._prior_moments(prior_mean, prior_cov)
        if moments is None:
            return None
        mean, cov = moments
        var = np.diagonal(cov, axis1=-2, axis2=-1)
        shape = np.broadcast_shapes(mean.shape, var.shape)
        return DiagMixture(np.ones(shape[:-1] + (1,)),
                           np.broadcast_to(mean, shape)[..., None, :],
                           np.broadcast_to(var, shape)[..., None, :])

    def _predict_full(self, means: np.ndarray, covs: np.ndarray, dt: float):
        """Prediction of full-covariance components: the constant-velocity transition,
        or the uniform disk of radius ``r`` moment-matched (covariance
        ``r^2 / (D + 2)`` per axis added)."""
        if dt <= 0:
            return means, covs
        if self.velocity:
            F, Q = self.motion.F(dt), self.motion.Q(dt)
            return means @ F.T, F @ covs @ F.T + Q
        r = float(self.motion.radius(dt))
        return means, covs + (r * r / (self.dim + 2)) * np.eye(self.dim)

    def _run_models(self, obs: list[Observation], time, prior_mean, prior_cov,
                    prior: DiagMixture | None) -> Track:
        """The generic form of :meth:`run_observations` (its docstring): a Gaussian-sum
        filter whose components keep full covariances."""
        for i, o in enumerate(obs):
            dim = o.context.position_dim
            if dim != self.dim:
                raise ConfigError(f"observations[{i}].context.points: {dim}-D points, the "
                                  f"tracker holds {self.dim}-D positions")
        T = common_steps(obs)
        t = np.arange(T, dtype=float) if time is None else as_float_array(time, "time", ndim=1)
        if t.shape != (T,):
            raise InputError(f"time: expected {T} steps, got shape {t.shape}")
        if np.any(np.diff(t) < 0):
            i = int(np.flatnonzero(np.diff(t) < 0)[0]) + 1
            raise InputError(f"time: decreases at step {i} ({t[i - 1]} -> {t[i]})")
        n = self.state_dim
        moments = self._prior_moments(prior_mean, prior_cov)
        if moments is not None:
            if prior is not None:
                raise InputError("prior: give a DiagMixture prior or prior_mean and "
                                 "prior_cov, not both")
            mean, cov = moments
            w0, m0, P0 = np.ones(mean.shape[:-1] + (1,)), mean[..., None, :], cov[..., None, :, :]
        elif prior is not None:
            start = self.init(prior).mixture
            w0, m0 = start.weights, start.means
            P0 = start.variances[..., None] * np.eye(n)
        else:
            raise InputError(f"prior_mean: {type(obs[0].model).__name__} gives no calibration "
                             "area to start from; give prior_mean and prior_cov (or prior)")
        shapes = [o.z.shape[:-2] for o in obs] + [o.at(0)[1].points.shape[:-2] for o in obs]
        try:
            batch = np.broadcast_shapes(*shapes, w0.shape[:-1], P0.shape[:-3])
        except ValueError:
            raise InputError(f"observations: batch shapes {shapes} do not broadcast with the "
                             f"prior's {w0.shape[:-1]}") from None
        B = int(np.prod(batch, dtype=np.int64))
        k = w0.shape[-1]
        check_memory(8.0 * B * k * 5**self.dim * max(o.context.rows for o in obs) * 4,
                     "observations", "the mixture tracker's update")

        def flat(a, tail):
            return np.broadcast_to(a, batch + a.shape[a.ndim - tail:]).reshape(
                (B,) + a.shape[a.ndim - tail:])
        w, m, P = flat(w0, 1), flat(m0, 2), flat(P0, 3)
        out = []
        for step in range(T):
            if step:
                m, P = self._predict_full(m, P, float(t[step] - t[step - 1]))
            rows = [flatten_step(*o.at(step), batch) for o in obs]
            heard = sum(np.isfinite(z).sum(-1) for z, _ in rows)

            models_rows = [(o.model, z, ctx) for o, (z, ctx) in zip(obs, rows)]

            def loglik(x, rows=models_rows, step=step):
                return log_likelihood_at(rows, x, f" at step {step}")
            w1, m1, P1, explained = progressive_update(w, m, P, loglik, self.dim)
            used = np.where(explained, heard, 0)
            on = used > 0
            w = np.where(on[:, None], w1, w)
            m = np.where(on[:, None, None], m1, m)
            P = np.where(on[:, None, None, None], P1, P)
            out.append(unflatten_estimate(self._estimate_full(w, m, P, used, float(t[step])),
                                          batch))
        return track_from_steps(out, t)

    def _estimate_full(self, w, m, P, used, time) -> Estimate:
        """Mixture mean and covariance of the position of full-covariance components; the
        diagnostics' mixture holds their per-axis variances."""
        d = self.dim
        mean = np.einsum("bk,bki->bi", w, m[..., :d])
        dm = m[..., :d] - mean[:, None]
        cov = np.einsum("bk,bkij->bij", w, P[..., :d, :d] + dm[..., :, None] * dm[..., None, :])
        mix = DiagMixture(w, m, np.diagonal(P, axis1=-2, axis2=-1))
        return Estimate(mean, cov, time, {"measurements_used": np.asarray(used),
                                          **_with_mixture(mix, max(self.max_components,
                                                                   w.shape[-1]))})


def _station_order(rss: np.ndarray) -> np.ndarray:
    """The order in which the stations of each row enter the product of eq. (2): received
    stations by decreasing signal strength, then the stations not received; equal readings
    keep their column order.

    The product is reduced after each factor, so its result depends on this order; taking
    it from the readings (not from the column order) makes a permutation of the stations
    (models and columns together) change nothing, as long as the received readings differ.

    Parameters
    ----------
    rss : ndarray, shape (..., S)
        Signal strengths, NaN = not received.

    Returns
    -------
    ndarray of int, shape (..., S)
        Column indices in product order.
    """
    key = np.where(np.isfinite(rss), -rss, np.inf)
    return np.ascontiguousarray(np.argsort(key, axis=-1, kind="stable"))
