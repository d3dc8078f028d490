"""What the joint model predicts for a measured dataset, and the residual channels.

Two predictions of the measured joint torque ``tau_J`` are formed, each
giving one *residual channel* (measured minus predicted, [Nm]):

``link`` (every dataset)
    The link-side equation (2)-(3), ``tau_J = J_l theta_l'' - tau_ext``,
    with ``theta_l`` the external link reference ``q_l_ref`` when measured,
    else eq (9) ``theta_l = q_m - f(q_m mod rho) - tau_J / K`` with the
    model's ripple table, and ``tau_ext`` the F/T reference (zero in free
    motion, whatever the F/T reads there: its noise alone, which a scale
    beside a refit of J_l would otherwise fit; zero too when not measured and
    the experiment has no contact). Differentiating a quantised
    position twice needs a low-pass: ``tau_J``, ``theta_l`` and ``tau_ext``
    all pass the same zero-phase Butterworth filter (cut-off :data:`LINK_CUTOFF_HZ`,
    at most 0.2 of the sample rate), so the equation holds filtered as it
    holds raw. This channel is the error of a model-based external-torque
    estimate: it sees friction, gravity-like loads, a sensor offset or
    scale, slow time-periodic disturbances and (through eq (9)) a wrong
    deflection at low speed.
``command`` (torque-commanded datasets)
    Eqs (1)-(4) driven by the measured command: with the loop input
    ``u = tau_c(t - T_d) - tau_s`` and link-side torques ``d`` (external and
    effects), ``tau_J = G_c tau_c(t - T_d) - G_d d + S delta_J + G_r r`` and the
    sensor reading adds ``(1 - G_c) delta_s``, where ``G_c`` is eq (4)
    without its delay, ``G_d = J_c K / den``, ``S = J_c J_l s^2 / den``,
    ``G_r = K J_l / den`` and ``den = J_c J_l s^2 + J_l b_c s + (J_c + J_l) K``;
    with a ripple table, ``delta_J = -K f(q_m)`` and the reaction
    ``r = tau_J f'(q_m)`` on the motor side (the transmission's ratio ``1 - f'``),
    both from the measured signals as in the fit. The external torque in
    ``d`` is the F/T reference through the link channel's low-pass (its
    noise, passed by ``G_d``, is not a torque the loop saw). The transfer
    functions are discretised exactly (zero-order hold) at the dataset's
    rate; the delay is realised with linear interpolation between samples.
    This channel sees delay errors, sensor scale, the transmission ripple
    at any speed and fast disturbances.

A candidate effect injects signals at one of the physical points below;
:func:`channel_columns` maps an injection onto both channels, so an effect
never needs to know the channels' equations:

``link``        a torque acting on the link [Nm] (friction, loads)
``sensor``      an additive error of the torque reading the internal loop regulates [Nm]
``logged``      an additive error of the logged torque reading only [Nm]
``deflection``  an added transmission deflection f(theta_m) [rad], eq (5)
``reaction``    its reaction on the motor side, tau_J f'(theta_m) [Nm] (the command channel only)
``command``     a torque added to the internal loop's target [Nm] (the robot's own compensation)
``command_raw`` a change of the command channel's prediction itself [Nm] (the model's own parameters)
``link_raw``    a change of the link channel's prediction itself [Nm] (the model's own parameters)
``reading_scale`` the torque reading ``phi`` (a relative reading error): the command channel
                sees ``(1 - G_c) phi``, the link channel the model's own link-side torque
                prediction instead of ``phi`` (the measured torque holds whatever the model
                misses, gravity included, which a scale must not claim)
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import signal
from scipy.linalg import expm

from iiwa_ident.datasets import Dataset
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.model import JointModel, polynomials, sample_means
from iiwa_ident.sim import INJECTIONS as EFFECT_POINTS
from iiwa_ident.sim import TorqueLogFilter

__all__ = ["LINK_CUTOFF_HZ", "MIN_DURATION_S", "CHANNELS", "INJECTIONS", "Context", "build_context", "channel_columns", "logged_change",
           "command_prediction", "predict_channel"]

#: Cut-off of the zero-phase low-pass of the link channel [Hz].
LINK_CUTOFF_HZ = 20.0
#: Residual channels, in report order.
CHANNELS = ("link", "command")
#: Injection points an effect may use.
INJECTIONS = (*EFFECT_POINTS, "command_raw", "link_raw")  # the effects' points and the model's own changes

#: Shortest dataset diagnosed [s]: what the channels' edges leave must still hold a few held-out folds (a run a
#: safety stop ended within its first second still counts).
MIN_DURATION_S = 0.5

_EDGE_S = 0.15  # filter and derivative edge effects of the link channel [s]
_SETTLE_S = 0.3  # start-up transient of the command channel (robot released from standstill) [s]
_CONTACT = ("hand_guided", "quasi_static")  # experiments where someone pushes the link
#: Experiments in which nothing touches the link (a ``free`` log may hold a push).
_FREE_MOTION = ("chirp", "multisine", "constant_velocity", "step", "sine")


@dataclass(kw_only=True)
class Context:
    """One dataset seen through the model (all arrays per sample, SI units).

    Attributes
    ----------
    index : int
        Position of the dataset in the diagnosed list.
    name : str
        File name (or ``dataset <index>``).
    experiment : str
        The dataset's experiment.
    dt : float
        Sample period [s].
    t, q_m, tau : numpy.ndarray
        Time [s], motor position [rad], measured joint torque [Nm].
    theta_l, omega_l : numpy.ndarray
        Low-passed link position [rad] and velocity [rad/s].
    omega_fast : numpy.ndarray
        Link velocity with a wide-band low-pass (0.3 of the sample rate) [rad/s],
        for effects that are nonlinear in the velocity (friction switches with
        the fast oscillations the link channel's filter removes).
    tau_ext : numpy.ndarray
        External torque used [Nm] (measured, or zero).
    link_from_eq9 : bool
        Whether theta_l comes from eq (9) (no external link reference).
    tau_c : numpy.ndarray or None
        Torque command [Nm] (torque-commanded datasets).
    params : dict
        Model parameters Jc, bc, K, Jl, Td used.
    masks : dict of str to numpy.ndarray
        Samples of each available channel.
    measured, predicted, residual : dict of str to numpy.ndarray
        Per channel: what is compared, the model's prediction, their difference [Nm].
    with_effects : dict of str to numpy.ndarray
        Per channel, the prediction with the model's own extra effects (its gravity, friction, ...) [Nm]: the
        model's estimate of the whole torque (what a filter before the log acts on).
    log_filter : TorqueLogFilter or None
        A filter before the log the model carries or the diagnosis named: every effect's change of the logged
        torque passes it (:func:`channel_columns`).
    effects_filtered : bool
        Whether the model's own effects in :attr:`with_effects` reached the log through :attr:`log_filter` (the
        model carries the filter); the filter's own column is then ``F(p) - p`` of the prediction alone.
    """

    index: int
    name: str
    experiment: str
    dt: float
    t: np.ndarray
    q_m: np.ndarray
    tau: np.ndarray
    theta_l: np.ndarray
    omega_l: np.ndarray
    omega_fast: np.ndarray
    tau_ext: np.ndarray
    link_from_eq9: bool
    tau_c: np.ndarray | None
    params: dict[str, float]
    cutoff_hz: float
    #: The model's ripple deflection f(q_m mod rho) [rad] (None without a table).
    f0: np.ndarray | None = None
    #: The ripple's reaction on the motor side ``tau_J f'(q_m)`` [Nm] (None without a table).
    reaction: np.ndarray | None = None
    masks: dict[str, np.ndarray] = field(default_factory=dict)
    measured: dict[str, np.ndarray] = field(default_factory=dict)
    predicted: dict[str, np.ndarray] = field(default_factory=dict)
    residual: dict[str, np.ndarray] = field(default_factory=dict)
    with_effects: dict[str, np.ndarray] = field(default_factory=dict)
    log_filter: TorqueLogFilter | None = None
    effects_filtered: bool = False
    #: What candidates compute from the measured signals alone, by key (a diagnosis prepares them many times).
    memo: dict = field(default_factory=dict)
    _sos: np.ndarray | None = None
    _tf: dict = field(default_factory=dict)

    @property
    def channels(self) -> list[str]:
        """Channels available for this dataset."""
        return [c for c in CHANNELS if c in self.masks]

    def lowpass(self, x: np.ndarray) -> np.ndarray:
        """The link channel's zero-phase low-pass of ``x``: :func:`scipy.signal.sosfiltfilt` with its default
        odd extension, the filter's steady state computed once (a diagnosis low-passes tens of thousands of
        columns)."""
        sos = self._sos
        if sos is None:
            raise ValueError(f"{self.name}: no link channel to low-pass")
        if "lowpass_zi" not in self.memo:
            edge = 3 * (2 * len(sos) + 1 - min(int((sos[:, 2] == 0).sum()), int((sos[:, 5] == 0).sum())))
            self.memo["lowpass_zi"] = (signal.sosfilt_zi(sos), edge)
        zi, edge = self.memo["lowpass_zi"]
        x = np.asarray(x, float)
        if len(x) <= edge:
            return signal.sosfiltfilt(sos, x)  # (which says why it cannot)
        ext = np.concatenate([2 * x[0] - x[edge:0:-1], x, 2 * x[-1] - x[-2:-edge - 2:-1]])
        y = signal.sosfilt(sos, ext, zi=zi * ext[0])[0]
        y = signal.sosfilt(sos, y[::-1], zi=zi * y[-1])[0]
        return y[::-1][edge:-edge]

    def ddt(self, x: np.ndarray) -> np.ndarray:
        """Time derivative by central differences [unit/s]."""
        return np.gradient(x, self.dt)

    def tf(self, name: str, x: np.ndarray, steady: bool = True, params: dict[str, float] | None = None
           ) -> np.ndarray:
        """Apply the discretised transfer function ``name`` (Gc, Gd, S, 1-Gc) to ``x``.

        ``steady`` starts the filter in the steady state of ``x[0]`` (signals
        that existed before the recording); otherwise it starts at rest.
        ``params``: other eq (4) parameters than the model's.
        """
        b, a = (self._tf if params is None else _transfer_functions(params, self.dt))[name]
        zi = _steady_state(tuple(b), tuple(a)) * x[0] if steady else np.zeros(max(len(a), len(b)) - 1)
        return signal.lfilter(b, a, x, zi=zi)[0]


def _discrete_all(nums: dict[str, np.ndarray], den: np.ndarray, dt: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each ``nums[name] / den`` sampled with a zero-order hold at ``dt`` [s], as ``(b, a)``.

    The transfer functions share their denominator, so they share the controllable canonical form's ``A, B``
    and its discretisation: one matrix exponential and one characteristic polynomial for all of them (what
    :func:`scipy.signal.cont2discrete` computes for each, by the same formulas: ``tf2ss``, ``expm``,
    ``ss2tf``).
    """
    den = np.asarray(den, float)
    n = len(den) - 1
    A = np.zeros((n, n))
    A[0, :] = -den[1:] / den[0]
    A[1:, :-1] = np.eye(n - 1)
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A * dt
    M[0, n] = dt
    E = expm(M)
    Ad, Bd = E[:n, :n], E[:n, n:]
    a = np.poly(Ad).real
    out = {}
    for name, num in nums.items():
        num = np.asarray(num, float) / den[0]
        num = np.concatenate([np.zeros(n + 1 - len(num)), num])
        D, C = num[0], num[1:] - num[0] * den[1:] / den[0]
        b = np.poly(Ad - Bd @ C[None, :]).real + (D - 1.0) * a
        out[name] = (b / a[0], a / a[0])
    return out


@functools.lru_cache(maxsize=256)
def _steady_state(b: tuple[float, ...], a: tuple[float, ...]) -> np.ndarray:
    """:func:`scipy.signal.lfilter_zi` of ``(b, a)`` (cached: a parameter search filters with few of them)."""
    return signal.lfilter_zi(b, a)


def _transfer_functions(p: dict[str, float], dt: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    return _transfer_functions_of(float(p["Jc"]), float(p["bc"]), float(p["K"]), float(p["Jl"]), float(dt))


@functools.lru_cache(maxsize=64)
def _transfer_functions_of(Jc: float, bc: float, K: float, Jl: float, dt: float
                           ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    # Cached: a parameter search predicts every channel of every dataset at the same parameters.
    p = (Jc, bc, K, Jl, 0.0)
    gc, den = polynomials(p, "motor")
    return _discrete_all({
        "Gc": gc,
        "Gd": -polynomials(p, "link")[0],  # the channel subtracts G_d d
        # S = Jc Jl s^2 / den = 1 + (S - 1) per unit of tau_J's own deflection: the direct path and the strictly
        # proper rest, -(Jl bc s + (Jc + Jl) K) / den.
        "S-1": -np.asarray(den[1:], float),
        "1-Gc": np.polysub(den, gc),
        "R": polynomials(p, "reaction")[0],
    }, den, dt)


def command_prediction(ctx: Context, Td: float, params: dict[str, float] | None = None) -> np.ndarray:
    """``G_c tau_c(t - T_d)`` [Nm]: eq (4) driven by the measured command, from rest.

    The delay is ``Td`` [s], realised as whole samples plus a linear
    interpolation for the fraction; ``params``: other Jc, bc, K, Jl than the model's.
    """
    if ctx.tau_c is None:
        raise ValueError(f"{ctx.name}: no commanded torque tau_c to predict from")
    n = max(Td, 0.0) / ctx.dt
    k = int(math.floor(n))
    frac = n - k
    padded = np.concatenate([np.zeros(k + 1), ctx.tau_c])
    m = len(ctx.tau_c)
    u = (1 - frac) * padded[1:m + 1] + frac * padded[0:m]
    return ctx.tf("Gc", u, steady=False, params=params)


def ripple_response(ctx: Context, f: np.ndarray, reaction: np.ndarray | None = None,
                    params: dict[str, float] | None = None) -> np.ndarray:
    """``tau_J`` [Nm] from a transmission deflection ``f`` [rad] (``delta_J = -K f``) and its reaction on the
    motor side [Nm], both per sample.

    Both are functions of the motion, not commands held over a sample: the dynamics see each interval's mean
    (:func:`~iiwa_ident.model.sample_means`, as the fit does); held instead, a 25 Hz ripple lags by half a
    sample (4.5 degrees at 1 kHz), which left 0.035 Nm RMS on the default joint's chirp. The deflection's
    direct path (the sensor reads ``-K f`` at once) takes the sample itself.
    """
    K = (ctx.params if params is None else params)["K"]
    out = -K * (f + ctx.tf("S-1", sample_means(f), params=params))
    if reaction is not None:
        out = out + ctx.tf("R", sample_means(reaction), params=params)
    return out


def _tau_ext_lowpassed(ctx: Context) -> np.ndarray:
    """The external torque through the link channel's low-pass, once per context (both channels use it)."""
    if "tau_ext_lp" not in ctx.memo:
        ctx.memo["tau_ext_lp"] = ctx.lowpass(ctx.tau_ext)
    return ctx.memo["tau_ext_lp"]


def predict_channel(ctx: Context, channel: str, params: dict[str, float] | None = None) -> np.ndarray:
    """The model's prediction of a residual channel [Nm] (module docstring), at the model's parameters or others.

    ``params``: Jc, bc, K, Jl, Td [SI] in place of the model's (the ripple table and the
    measured signals stay); this is how a wrong parameter of eq (4) shows in each channel.
    """
    p = ctx.params if params is None else params
    if channel == "link":
        # Linear in Jl and in 1/K: the three signals once per context (a parameter search asks for thousands).
        if "link_terms" not in ctx.memo:
            ctx.memo["link_terms"] = (ctx.ddt(ctx.ddt(ctx.theta_l)), ctx.ddt(ctx.ddt(ctx.lowpass(ctx.tau))),
                                      _tau_ext_lowpassed(ctx))
        acc_l, acc_tau, tau_ext = ctx.memo["link_terms"]
        if ctx.link_from_eq9 and params is not None and p["K"] != ctx.params["K"]:
            # eq (9) with another K moves the link by tau_J (1/K_model - 1/K).
            acc_l = acc_l + acc_tau * (1.0 / ctx.params["K"] - 1.0 / p["K"])
        return p["Jl"] * acc_l - tau_ext
    if channel == "command":
        tfp = None if params is None else p
        # The F/T reference through the link channel's low-pass: its noise above a push's band, passed by Gd,
        # is what a refit of the loop's parameters would fit (it shrinks Gd where only that noise is).
        pred = command_prediction(ctx, p["Td"], tfp) - ctx.tf("Gd", _tau_ext_lowpassed(ctx), params=tfp)
        if ctx.f0 is not None:
            pred = pred + ripple_response(ctx, ctx.f0, ctx.reaction, tfp)
        return pred
    raise ValueError(f"unknown channel {channel!r}")


def build_context(dataset: Dataset, model: JointModel, index: int = 0,
                  cutoff_hz: float = LINK_CUTOFF_HZ) -> Context:
    """Predict ``dataset`` with ``model`` and form the baseline residual channels.

    Parameters
    ----------
    dataset : Dataset
        Any experiment of format v1 (torque-commanded or position-controlled, 200 Hz to 1 kHz).
    model : JointModel
        The model; its ripple table and extra effects are part of the prediction
        only through :mod:`iiwa_ident.diagnose._candidates` (known effects are
        added by :func:`iiwa_ident.diagnose.diagnose`).
    index : int
        Position in the diagnosed list.
    cutoff_hz : float
        Link-channel low-pass cut-off [Hz] (limited to 0.2 of the sample rate).

    Returns
    -------
    Context
    """
    t = np.asarray(dataset["t"], float)
    name = str(dataset.path.name) if dataset.path else f"dataset {index}"
    if len(t) < 2 or t[-1] - t[0] < MIN_DURATION_S:
        raise IiwaIdentError(f"{name}: {len(t)} samples over {t[-1] - t[0] if len(t) else 0.0:.3g} s: too short to "
                             f"diagnose (at least {MIN_DURATION_S:g} s: the link channel drops {_EDGE_S:g} s at each "
                             f"end and the command channel its first {_SETTLE_S:g} s)")
    dt = float(np.median(np.diff(t)))
    p = {k: model.value(k) for k in ("Jc", "bc", "K", "Jl", "Td")}
    fc = min(cutoff_hz, 0.2 / dt)
    sos = signal.butter(2, fc, fs=1.0 / dt, output="sos")
    q_m = np.asarray(dataset["q_m"], float)
    tau = np.asarray(dataset["tau_j"], float)
    has_ext = dataset.has("tau_ext_ref")
    contact = dataset.experiment in _CONTACT
    # In free motion the external torque is zero: a reference sensor's reading there is its own noise, which a
    # column built on the prediction (a scale beside a refit of Jl) would fit in the residual it also enters.
    free_motion = dataset.experiment in _FREE_MOTION
    tau_ext = np.asarray(dataset["tau_ext_ref"], float) if has_ext and not free_motion else np.zeros_like(t)
    f0 = model.ripple(q_m) if model.ripple is not None else np.zeros_like(q_m)
    from_eq9 = not dataset.has("q_l_ref")
    theta_raw = q_m - f0 - tau / p["K"] if from_eq9 else np.asarray(dataset["q_l_ref"], float)
    tau_c = np.asarray(dataset["tau_c"], float) if dataset.has("tau_c") else None
    ctx = Context(index=index, name=name, experiment=dataset.experiment, dt=dt, t=t, q_m=q_m, tau=tau,
                  theta_l=np.zeros_like(t), omega_l=np.zeros_like(t), omega_fast=np.zeros_like(t), tau_ext=tau_ext,
                  link_from_eq9=from_eq9, tau_c=tau_c, params=p, cutoff_hz=fc,
                  f0=f0 if model.ripple is not None else None,
                  reaction=tau * model.ripple.slope(q_m) if model.ripple is not None else None, _sos=sos,
                  _tf=_transfer_functions(p, dt))
    ctx.theta_l = ctx.lowpass(theta_raw)
    ctx.omega_l = ctx.ddt(ctx.theta_l)
    wide = signal.butter(2, 0.3 / dt, fs=1.0 / dt, output="sos")
    ctx.omega_fast = ctx.ddt(signal.sosfiltfilt(wide, theta_raw))
    usable = not contact or has_ext  # an unmeasured push makes both equations unusable
    n = len(t)
    if usable and n * dt > 4 * _EDGE_S:
        mask = (t - t[0] > _EDGE_S) & (t[-1] - t > _EDGE_S)
        ctx.masks["link"] = mask
        ctx.measured["link"] = ctx.lowpass(tau)
        ctx.predicted["link"] = predict_channel(ctx, "link")
    if usable and tau_c is not None and n * dt > 2 * _SETTLE_S:
        ctx.masks["command"] = t - t[0] > _SETTLE_S
        ctx.measured["command"] = tau
        ctx.predicted["command"] = predict_channel(ctx, "command")
    for c in ctx.masks:
        ctx.residual[c] = ctx.measured[c] - ctx.predicted[c]
    return ctx


def channel_columns(ctx: Context, injection: str, phi: np.ndarray) -> dict[str, np.ndarray]:
    """What an injected signal ``phi`` adds to each residual channel of ``ctx``.

    Parameters
    ----------
    ctx : Context
    injection : str
        One of :data:`INJECTIONS` (see the module docstring).
    phi : numpy.ndarray
        The injected signal per sample (unit of the injection point).

    Returns
    -------
    dict of str to numpy.ndarray
        Residual change per available channel [Nm] (absent: no change).
    """
    if injection not in INJECTIONS:
        raise ValueError(f"unknown injection point {injection!r}")
    # The same signal meets a context many times (each selection round, each filter the diagnosis tries): its
    # columns before the filter once, the most recently used kept within _COLUMN_CACHE_BYTES.
    phi = np.asarray(phi, float)
    key = (injection, *_fingerprint(ctx, phi))
    cache = ctx.memo.setdefault("channel_columns", {})
    out = cache.pop(key, None)
    if out is None:
        out = _columns_before_the_log(ctx, injection, phi)
        for v in out.values():
            v.flags.writeable = False
        while cache and sum(a.nbytes for c in cache.values() for a in c.values()) > _COLUMN_CACHE_BYTES:
            del cache[next(iter(cache))]  # the least recently used
    cache[key] = out
    if ctx.log_filter is not None and injection not in _AFTER_THE_LOG_FILTER:
        # The logged torque is the filtered one: so is every change an effect makes to it; and eq (9) takes the
        # link from the logged reading, which the filter moves by what it takes from the change (as the
        # filter's own column has it).
        return {ch: logged_change(ctx, ch, v) for ch, v in out.items()}
    return dict(out)


def _fingerprint(ctx: Context, x: np.ndarray) -> tuple[float, ...]:
    """A signal's identity for the context's caches: its length and three projections on fixed random weights
    (two different signals share them only by a coincidence of measure zero; a digest of the bytes costs ten
    times more)."""
    w = ctx.memo.get("fingerprint_weights")
    if w is None or w.shape[1] != len(x):
        w = ctx.memo["fingerprint_weights"] = np.random.default_rng(len(x)).standard_normal((3, len(x)))
    return (float(len(x)), *map(float, w @ x))


#: Bytes of columns a context keeps (:func:`channel_columns`).
_COLUMN_CACHE_BYTES = 32 * 2**20


def _columns_before_the_log(ctx: Context, injection: str, phi: np.ndarray) -> dict[str, np.ndarray]:
    """:func:`channel_columns` without a filter before the log."""
    p = ctx.params
    out: dict[str, np.ndarray] = {}
    if "link" in ctx.masks:
        if injection == "link":
            # tau_J = Jl theta_l'' - tau_ext - d: an unmodelled link torque d appears as -d.
            out["link"] = -ctx.lowpass(phi)
        elif injection in ("sensor", "logged"):
            lp = ctx.lowpass(phi)
            col = lp
            if ctx.link_from_eq9:  # eq (9) uses the reading: theta_l errs by -phi/K
                col = lp + p["Jl"] / p["K"] * ctx.ddt(ctx.ddt(lp))
            out["link"] = col
        elif injection == "reading_scale":
            col = ctx.predicted["link"]
            if ctx.link_from_eq9:
                col = col + p["Jl"] / p["K"] * ctx.ddt(ctx.ddt(ctx.lowpass(phi)))
            out["link"] = col
        elif injection == "deflection" and ctx.link_from_eq9:
            # eq (9) without the deflection places the link at theta_l + f: Jl f'' too much predicted.
            out["link"] = -p["Jl"] * ctx.ddt(ctx.ddt(ctx.lowpass(phi)))
    if "command" in ctx.masks:
        if injection == "link":
            out["command"] = -ctx.tf("Gd", phi)
        elif injection in ("sensor", "reading_scale"):
            out["command"] = ctx.tf("1-Gc", phi)  # the loop drives the true torque away by what it senses
        elif injection == "logged":
            out["command"] = phi
        elif injection == "deflection":
            out["command"] = ripple_response(ctx, phi)
        elif injection == "reaction":
            out["command"] = ctx.tf("R", sample_means(phi))
        elif injection == "command":
            out["command"] = ctx.tf("Gc", phi)
        elif injection == "command_raw":
            out["command"] = phi
    if injection == "link_raw" and "link" in ctx.masks:
        out["link"] = phi
    return {ch: v.copy() if v is phi else v for ch, v in out.items()}  # (the cache freezes what it keeps)


def logged_change(ctx: Context, channel: str, v: np.ndarray, log_filter: TorqueLogFilter | None = None
                  ) -> np.ndarray:
    """A change ``v`` [Nm] of a residual channel of the torque as the log shows it: through the filter before the
    log (``log_filter``, by default the context's; none: ``v``), and on the link channel from eq (9) the link
    that the filter moves with it."""
    log_filter = ctx.log_filter if log_filter is None else log_filter
    if log_filter is None:
        return v
    if channel == "link" and ctx.link_from_eq9 and len(v):
        return v + _eq9_change(ctx, log_filter, np.asarray(v, float))
    return log_filter.apply(v, ctx.dt)


#: Damping ratio given the link's resonance ``sqrt(K/Jl)`` in eq (9)'s correction for a filter before the log
#: (:func:`logged_change`): the correction divides by ``1 + P (1 - F)``, which an undamped link makes almost zero
#: near its resonance. A regularisation, not a fitted figure: on the real joint 2's run (a 2.3 Hz filter, a
#: 9.5 Hz link) a linear fit leaves 0.29, 0.28 and 0.31 Nm at 0.05, 0.2 and 0.5.
EQ9_LINK_DAMPING = 0.2


def _eq9_change(ctx: Context, log_filter: TorqueLogFilter, v: np.ndarray) -> np.ndarray:
    """What a filter ``F`` before the log changes in the link channel's torque ``v`` [Nm] where eq (9) takes the
    link from the logged torque.

    The log shows ``F tau``; eq (9) places the link at ``q_m - F tau / K``, ``(1 - F) tau / K`` from where it is,
    so the model's torque is ``v = (1 + P (1 - F)) tau`` with ``P = (Jl s^2 + 2 zeta sqrt(K Jl) s) / K``, and the
    log differs from it by ``(F - 1)(1 + P) / (1 + P (1 - F)) v``. To first order in ``P (1 - F)`` this is
    ``(F - 1) v + Jl/K ((F - 1) v)''``, which fails above the link's resonance, where ``P (1 - F)`` exceeds one
    (joint 2's ripple line at 15 Hz: 2.6 times). Applied in the frequency domain (the division has no stable
    causal form), from rest at ``v[0]``; the derivatives are :meth:`Context.ddt`'s central differences.
    """
    n = len(v)
    size = 1 << (2 * n + 64).bit_length()
    key = (size, tuple(sorted(log_filter.to_dict().items())))
    # The selection asks for the same column through the same filter in every round: the last ones kept.
    done = ctx.memo.setdefault("eq9_changes", {})
    seen = (key, *_fingerprint(ctx, v))
    if seen in done:
        return done[seen]
    responses = ctx.memo.setdefault("eq9_responses", {})
    H = responses.pop(key, None)
    if H is None:
        f = np.fft.rfftfreq(size, ctx.dt)
        F = log_filter.frequency_response(f, ctx.dt)
        d1 = 1j * np.sin(2.0 * np.pi * f * ctx.dt) / ctx.dt
        tau = math.sqrt(ctx.params["Jl"] / ctx.params["K"])
        P = tau ** 2 * d1 ** 2 + 2.0 * EQ9_LINK_DAMPING * tau * d1
        H = (F - 1.0) * (1.0 + P) / (1.0 + P * (1.0 - F))
        if len(responses) >= 8:  # a search tries many filters, each a few times in a row
            del responses[next(iter(responses))]
    responses[key] = H
    taper = ("eq9_taper", size, n)
    if taper not in ctx.memo:
        # Held, then tapered to rest, so that the circular transform's wrap does not step.
        tail = size - n
        ctx.memo[taper] = 0.5 * (1.0 + np.cos(np.pi * np.arange(1, tail + 1) / tail))
    x = np.empty(size)
    x[:n] = v - v[0]
    x[n:] = x[n - 1] * ctx.memo[taper]
    out = np.fft.irfft(np.fft.rfft(x) * H, size)[:n]
    out.flags.writeable = False
    if len(done) * n * 8 >= _COLUMN_CACHE_BYTES // 2:
        del done[next(iter(done))]
    done[seen] = out
    return out


#: Injection points a filter before the log does not act on: the log itself, and the raw columns (already what
#: the log shows: the filter's own, a refit's prediction, which filters itself).
_AFTER_THE_LOG_FILTER = ("logged", "command_raw", "link_raw")
