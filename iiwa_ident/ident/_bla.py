"""The best linear approximation (BLA) from multisine data, its noise and its nonlinear distortion.

The robust method of Pintelon and Schoukens (*System Identification: A
Frequency Domain Approach*, 2nd ed., Wiley 2012, section 3.7; Schoukens,
Pintelon and Rolain, *Mastering System Identification in 100 Exercises*,
Wiley 2012, exercise 4.9) on ``M`` realisations of ``P`` steady-state periods
of a random-phase multisine (:class:`~iiwa_ident.excite.Multisine`):

1. per realisation ``m``, the spectra of input ``U`` and outputs ``Y`` at the
   excited lines, averaged over its periods, and
   ``G_m = mean_p Y / mean_p U`` (the ratio of averages: with the measured
   input in the denominator, a feedback through the hold does not bias it);
2. the noise variance of ``G_m`` from the period-to-period variation of the
   residual ``Y_p - G_m U_p``: ``sum_p |e_p|^2 / ((P - 1) P |mean U|^2)``;
3. the BLA ``G = mean_m G_m``, its **total** variance from the realisations,
   ``sum_m |G_m - G|^2 / (M (M - 1))`` (noise plus the stochastic nonlinear
   distortions, which change with the random phases), and its **noise**
   variance ``sum_m var_n(G_m) / M^2``; the difference is the variance of the
   nonlinear distortions (clipped at zero; the two are estimated with
   ``M - 1`` and ``M (P - 1)`` degrees of freedom, so at a single line the
   difference is noisy).

Variances are of the complex ``G`` (``E|G - E G|^2``), per output and line.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from iiwa_ident.datasets import Dataset
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.ident._frf import levy_fit

__all__ = ["BestLinearApproximation", "best_linear_approximation", "bla_from_arrays", "BlaFit", "fit_bla",
           "sampled_response", "LINK_TERMS", "SMOOTH_LINES"]


@dataclass(kw_only=True)
class BestLinearApproximation:
    """The BLA of ``tau_c`` to the outputs at the excited lines.

    Attributes
    ----------
    f_hz : numpy.ndarray
        Excited frequencies [Hz].
    lines : numpy.ndarray
        Their line numbers ``k`` (``f = k / period``).
    outputs : tuple of str
        The outputs, in the order of the first axis of the arrays below.
    G : numpy.ndarray
        BLA per output and line (complex; [Nm/Nm] for ``tau_j``, [rad/Nm] for ``q_m``).
    var_total : numpy.ndarray
        Variance of ``G`` from the realisations (noise and nonlinear distortions).
    var_noise : numpy.ndarray
        Variance of ``G`` due to the noise alone, from the periods.
    realisations, periods : int
        M and P.
    """

    f_hz: np.ndarray
    lines: np.ndarray
    outputs: tuple[str, ...]
    G: np.ndarray
    var_total: np.ndarray
    var_noise: np.ndarray
    realisations: int
    periods: int

    @property
    def var_nonlinear(self) -> np.ndarray:
        """Variance of ``G`` due to the stochastic nonlinear distortions (total less noise, at least 0)."""
        return np.maximum(self.var_total - self.var_noise, 0.0)

    def bands(self, edges_hz: np.ndarray) -> list[dict[str, Any]]:
        """Per output and band: mean total, noise and nonlinear variance relative to ``|G|^2`` [-].

        ``edges_hz`` are the band edges; a band without lines is left out.
        """
        out = []
        for i, name in enumerate(self.outputs):
            for lo, hi in zip(edges_hz[:-1], edges_hz[1:]):
                m = (self.f_hz >= lo) & (self.f_hz < hi)
                if not m.any():
                    continue
                g2 = np.abs(self.G[i, m]) ** 2
                out.append({"output": name, "lo_hz": float(lo), "hi_hz": float(hi), "lines": int(m.sum()),
                            "total_rel": float(np.mean(self.var_total[i, m] / g2)),
                            "noise_rel": float(np.mean(self.var_noise[i, m] / g2)),
                            "nonlinear_rel": float(np.mean(self.var_nonlinear[i, m] / g2))})
        return out


def bla_from_arrays(u: np.ndarray, y: np.ndarray, lines: np.ndarray, period_s: float,
                    outputs: tuple[str, ...] = ("y",)) -> BestLinearApproximation:
    """The BLA from steady-state periods already cut out.

    Parameters
    ----------
    u : numpy.ndarray
        Input, shape (M, P, N): realisations, periods, samples per period.
    y : numpy.ndarray
        Outputs, shape (n_outputs, M, P, N).
    lines : array of int
        Excited line numbers.
    period_s : float
        Period [s].
    outputs : tuple of str
        Names of the outputs.
    """
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    M, P, N = u.shape
    if M < 2 or P < 2:
        raise IiwaIdentError(f"best linear approximation: need at least 2 realisations and 2 periods, got {M} and {P}")
    lines = np.asarray(lines, int)
    U = np.fft.rfft(u, axis=-1)[..., lines]  # (M, P, F)
    Y = np.fft.rfft(y, axis=-1)[..., lines]  # (n, M, P, F)
    Ubar = U.mean(axis=1)  # (M, F)
    if np.any(np.abs(Ubar) == 0):
        raise IiwaIdentError("best linear approximation: an excited line carries no input")
    Ybar = Y.mean(axis=2)  # (n, M, F)
    Gm = Ybar / Ubar  # (n, M, F)
    e = Y - Gm[:, :, None, :] * U[None]  # residual per period (its mean over periods is 0)
    var_gm = np.sum(np.abs(e) ** 2, axis=2) / ((P - 1) * P * np.abs(Ubar) ** 2)  # (n, M, F)
    G = Gm.mean(axis=1)
    var_total = np.sum(np.abs(Gm - G[:, None, :]) ** 2, axis=1) / (M * (M - 1))
    var_noise = var_gm.sum(axis=1) / M**2
    return BestLinearApproximation(f_hz=lines / period_s, lines=lines, outputs=tuple(outputs), G=G,
                                   var_total=var_total, var_noise=var_noise, realisations=M, periods=P)


def best_linear_approximation(ds: Dataset, outputs: tuple[str, ...] = ("tau_j", "q_m")) -> BestLinearApproximation:
    """The BLA of a multisine dataset, ``tau_c`` to ``outputs`` (default ``tau_j`` and ``q_m``).

    The design (period, periods, transient periods, realisations, excited
    lines) is read from the dataset's ``/experiment`` attributes; the
    transient period of each realisation is left out.

    Raises
    ------
    IiwaIdentError
        Not a multisine, no torque command, a design the record does not
        match (stopped early, another rate); the message names the file.
    """
    label = str(ds.path) if ds.path is not None else "the dataset"
    if ds.experiment != "multisine":
        raise IiwaIdentError(f"{label}: a {ds.experiment} dataset, not a multisine")
    a = ds.experiment_attrs
    missing = [k for k in ("period_s", "periods", "realisations", "excited_lines") if k not in a]
    if missing:
        raise IiwaIdentError(f"{label}: the multisine design lacks {', '.join(missing)}")
    if not ds.has("tau_c"):
        raise IiwaIdentError(f"{label}: no torque command (tau_c)")
    if "stopped_reason" in a:
        raise IiwaIdentError(f"{label}: the multisine stopped early ({a['stopped_reason']})")
    N = int(round(float(a["period_s"]) * ds.sample_rate_hz))
    if abs(N / ds.sample_rate_hz - float(a["period_s"])) > 1e-9 * float(a["period_s"]):
        raise IiwaIdentError(f"{label}: recorded at {ds.sample_rate_hz:g} Hz, not a whole number of samples per "
                             f"{a['period_s']:g} s period")
    M, P = int(a["realisations"]), int(a["periods"])
    skip = int(a.get("transient_periods", 1))
    lead = int(round(float(a.get("lead_in_s", 0.0)) * ds.sample_rate_hz))
    if ds.n_samples != lead + M * (P + skip) * N:
        raise IiwaIdentError(f"{label}: {ds.n_samples} samples, the design needs {lead} + {M} x {P + skip} x {N}")
    lines = np.asarray(a["excited_lines"], int)
    if lines.max() >= N / 2:
        raise IiwaIdentError(f"{label}: excited lines beyond the Nyquist frequency of the recording")

    def cut(x: np.ndarray) -> np.ndarray:
        return np.asarray(x, float)[lead:].reshape(M, P + skip, N)[:, skip:, :]

    y = np.stack([cut(ds[name]) for name in outputs])
    return bla_from_arrays(cut(ds["tau_c"]), y, lines, float(a["period_s"]), outputs)


# --------------------------------------------------------------------------
# eq (4) fitted to the BLA

#: Warn when the weighted residual per degree of freedom exceeds this [-].
CHI2_WARN = 2.0
#: Warn when the nonlinear distortions' variance of tau_j's BLA in a band exceeds this share of |G|^2 [-]
#: (a 3 % standard deviation of G).
NONLINEAR_WARN_REL = 1e-3

#: Neighbouring lines whose relative variances are averaged into each line's weight: a variance from
#: M - 1 realisations alone is too noisy to weight by (lines that happen to scatter little would dominate).
SMOOTH_LINES = 7


@dataclass(kw_only=True)
class BlaFit:
    """Eq (4) with delay fitted to a best linear approximation.

    Attributes
    ----------
    parameters, std : dict of str to float
        ``Jc`` [kg m^2], ``bc`` [Nm s/rad], ``K`` [Nm/rad], ``Jl`` [kg m^2], ``Td`` [s] and their
        standard deviations: from the Jacobian weighted by the BLA's total variance (noise and
        nonlinear distortions), widened by ``sqrt(chi2_dof)`` when the model misses the BLA by more
        than that variance explains.
    covariance : numpy.ndarray
        Covariance in that order [SI units squared].
    chi2_dof : float
        Weighted residual sum of squares per degree of freedom (about 1 when eq (4) explains the BLA
        within its variance).
    std_method : str
        How the std was computed.
    blas : list of BestLinearApproximation
        The data fitted, one per dataset.
    labels : list of str
        The datasets' files.
    """

    parameters: dict[str, float]
    std: dict[str, float]
    covariance: np.ndarray
    chi2_dof: float
    blas: list[BestLinearApproximation]
    labels: list[str]
    std_method: str = ("inverse Fisher information of the BLA weighted by its total variance (noise and nonlinear "
                       "distortions, robust method), times sqrt(chi2/dof) when above 1")
    method: str = "bla"
    #: The link terms (:data:`LINK_TERMS`) fitted alongside: name -> (value, std) [SI].
    link: dict[str, tuple[float, float]] = field(default_factory=dict)

    def variance_bands(self) -> list[dict[str, Any]]:
        """Per dataset, output and octave band: the BLA's total, noise and nonlinear variance relative to |G|^2."""
        out = []
        for label, bla in zip(self.labels, self.blas):
            lo, hi = float(bla.f_hz.min()), float(bla.f_hz.max())
            edges = lo * 2.0 ** np.arange(0, math.ceil(math.log2(hi / lo)) + 1.0)
            edges[-1] = max(edges[-1], hi) * (1 + 1e-9)
            out += [{"dataset": label, **row} for row in bla.bands(edges)]
        return out

    def warnings(self) -> list[str]:
        """What a user should know before trusting the result."""
        out = []
        if self.chi2_dof > CHI2_WARN:
            out.append(f"eq (4) misses the BLA by more than its variance explains (chi2/dof {self.chi2_dof:.2g}): "
                       "effects the model lacks; the std is widened by sqrt(chi2/dof) but may not cover them")
        for b in self.variance_bands():
            if b["output"] == "tau_j" and b["nonlinear_rel"] > NONLINEAR_WARN_REL:
                where = f"{b['dataset']}: " if len(self.labels) > 1 else ""
                out.append(f"{where}the joint is not linear in {b['lo_hz']:.3g}-{b['hi_hz']:.3g} Hz: the nonlinear "
                           f"distortions' variance is {b['nonlinear_rel']:.2g} of |G|^2 (noise "
                           f"{b['noise_rel']:.2g})")
        return out

    def to_json(self) -> dict:
        """The ``--json`` document (SI units, ``Td`` in s)."""
        from iiwa_ident.model import PARAMETER_NAMES, PARAMETER_UNITS

        std = np.sqrt(np.diag(self.covariance))
        corr = self.covariance / np.outer(std, std)
        return {"parameters": {k: {"value": self.parameters[k], "std": self.std[k], "unit": PARAMETER_UNITS[k]}
                               for k in PARAMETER_NAMES},
                "correlation": {"names": list(PARAMETER_NAMES), "matrix": corr.tolist()},
                "method": self.method, "std_method": self.std_method, "chi2_dof": self.chi2_dof,
                "link_terms": {k: {"value": v, "std": sd} for k, (v, sd) in self.link.items()},
                "variance_bands": self.variance_bands(), "warnings": self.warnings(),
                "design": [{"dataset": label, "realisations": b.realisations, "periods": b.periods,
                            "lines": int(len(b.f_hz)), "f_lo_hz": float(b.f_hz.min()), "f_hi_hz": float(b.f_hz.max())}
                           for label, b in zip(self.labels, self.blas)]}


def _smoothed(var: np.ndarray, G: np.ndarray, width: int = SMOOTH_LINES) -> np.ndarray:
    """Variance per line from the mean relative variance of ``width`` neighbouring lines."""
    rel = var / np.maximum(np.abs(G) ** 2, 1e-300)
    kernel = np.ones(min(width, rel.shape[-1]))
    num = np.apply_along_axis(lambda r: np.convolve(r, kernel, mode="same"), -1, rel)
    den = np.convolve(np.ones(rel.shape[-1]), kernel, mode="same")
    return num / den * np.abs(G) ** 2


def _start(bla: BestLinearApproximation, T: float) -> dict[str, float]:
    """Start values from the BLA alone: delay by a grid on eq (4)'s rational fit, scale from q_m / tau_j."""
    f = bla.f_hz
    s = 2j * np.pi * f
    G0 = bla.G[0] / np.sinc(f * T) * np.exp(s * T / 2)  # undo the hold's half-sample lag and sinc gain
    best = None
    for td in np.arange(0.0, 0.05 + 1e-12, 0.1e-3):
        out = levy_fit(G0 * np.exp(s * td), s)
        if out is not None and (best is None or out[1] < best[0]):
            best = (out[1], td, out[0])
    if best is None:
        raise IiwaIdentError("the BLA of tau_c to tau_j does not look like eq (4) at any delay up to 50 ms")
    _, td, (a, b0, a0) = best
    # q_m / tau_j = 1/K - 1/(Jl w^2) on the lines where q_m stands out of its variance, weighted by it.
    R = bla.G[1] / bla.G[0]
    sigma_R = np.sqrt(bla.var_total[1] / 2.0) / np.abs(bla.G[0])
    use = np.abs(bla.G[1]) > 3.0 * np.sqrt(bla.var_total[1])
    if use.sum() < 2:
        raise IiwaIdentError("q_m does not stand out of its noise at 2 excited lines: cannot find the inertia "
                             "scale (Jl); a larger amplitude or more periods and realisations would")
    w = 2 * np.pi * f[use]
    M = np.column_stack([np.ones_like(w), -1.0 / w**2]) / sigma_R[use, None]
    (inv_K, inv_Jl), *_ = np.linalg.lstsq(M, R[use].real / sigma_R[use], rcond=None)
    if not inv_Jl > 0:
        raise IiwaIdentError("q_m does not follow the joint torque as a free link would: cannot find the inertia "
                             "scale (Jl)")
    Jl = 1.0 / inv_Jl
    Jc = Jl * (a0 / b0 - 1.0)
    return {"Jc": float(Jc), "bc": float(a * Jc), "K": float(b0 * Jc), "Jl": float(Jl), "Td": float(td)}


#: Link-side terms fitted with eq (4) to the BLA: a viscous damping ``bl`` [Nm s/rad] and a stiffness ``kl``
#: [Nm/rad] on the link, ``Jl theta_l'' = tau_j - bl theta_l' - kl theta_l``: the linear part of link friction
#: (Coulomb friction's describing function is a damping) and of a position-dependent load (its slope).
LINK_TERMS: tuple[str, ...] = ("bl", "kl")


def sampled_response(params: dict[str, float], f_hz: np.ndarray, sample_time_s: float) -> np.ndarray:
    """Exact sampled-data response of eqs (1)-(3) with link damping and stiffness, ZOH input, fractional delay.

    Parameters
    ----------
    params : dict
        ``Jc, bc, K, Jl`` [SI], ``Td`` [s], and optionally ``bl`` [Nm s/rad], ``kl`` [Nm/rad] (default 0).
    f_hz : numpy.ndarray
        Frequencies [Hz], not 0.
    sample_time_s : float
        T [s].

    Returns
    -------
    numpy.ndarray
        Shape (2, n), complex: ``tau_j / tau_c`` [Nm/Nm] and ``q_m / tau_c`` [rad/Nm]. With ``bl = kl = 0``
        it equals :meth:`~iiwa_ident.model.DiscreteModel.frequency_response`.
    """
    from iiwa_ident.model import delayed_hold, state_matrices

    Jc, bc, K, Jl, Td = (float(params[k]) for k in ("Jc", "bc", "K", "Jl", "Td"))
    T = float(sample_time_s)
    # The chirp fit's eqs (1)-(3), state (theta_m, z, theta_l, omega_l), with the link terms added to
    # Jl omega_l' = tau_j - bl omega_l - kl theta_l.
    A, B, C = state_matrices((Jc, bc, K, Jl, 0.0))
    A[3, 2] -= float(params.get("kl", 0.0)) / Jl
    A[3, 3] -= float(params.get("bl", 0.0)) / Jl
    Phi, Gamma0, Gamma1, d = delayed_hold(A, B, T, Td)
    zi = np.exp(-2j * np.pi * np.asarray(f_hz, float) * T)  # z^-1
    out = np.empty((2, len(zi)), complex)
    for n, w in enumerate(zi):
        x = np.linalg.solve(np.eye(4) / w - Phi, Gamma0 + Gamma1 * w)  # (z I - Phi)^-1 (Gamma0 + Gamma1 z^-1)
        out[:, n] = (C @ x) * w**d
    return out


def fit_bla(blas: BestLinearApproximation | Sequence[BestLinearApproximation], sample_time_s: float | Sequence[float],
            initial: dict[str, float] | None = None, labels: Sequence[str] | None = None,
            link_terms: bool = True) -> BlaFit:
    """Fit the sampled eq (1)-(4) model (both outputs, ``tau_j`` and ``q_m``) to one or more BLAs.

    The residual of each output and line is ``(G - G_model) / sigma`` with
    ``sigma^2`` the BLA's total variance (smoothed over
    :data:`SMOOTH_LINES` neighbouring lines), real and imaginary parts
    separately; the model is :func:`sampled_response` (exact for periodic
    steady state), with the link terms :data:`LINK_TERMS` unless
    ``link_terms`` is False.

    Parameters
    ----------
    blas : BestLinearApproximation or sequence of them
        With outputs ``("tau_j", "q_m")``, of one joint.
    sample_time_s : float or sequence of float
        Sample time of each BLA's data [s].
    initial : dict, optional
        Start values (default: from the first BLA alone).
    labels : sequence of str, optional
        Names of the datasets, for the result.
    link_terms : bool
        Also fit :data:`LINK_TERMS` (link damping and stiffness), which take up
        the linear part of link friction and loads instead of letting it bias
        ``Jc, bc, K, Jl``.
    """
    from scipy.optimize import least_squares

    from iiwa_ident.model import PARAMETER_NAMES

    blas = [blas] if isinstance(blas, BestLinearApproximation) else list(blas)
    T_given = np.asarray(sample_time_s, dtype=float)
    Ts = [float(T_given)] * len(blas) if T_given.ndim == 0 else [float(t) for t in T_given]
    if not blas or len(Ts) != len(blas):
        raise IiwaIdentError("fit_bla needs one sample time per BLA, and at least one BLA")
    for bla in blas:
        if bla.outputs != ("tau_j", "q_m"):
            raise IiwaIdentError(f"eq (4) is fitted to the outputs tau_j and q_m, the BLA has "
                                 f"{', '.join(bla.outputs)}")
    p0 = initial or _start(blas[0], Ts[0])
    # Per real and imaginary part: half the complex variance each.
    weights = [np.sqrt(2.0 / np.maximum(_smoothed(b.var_total, b.G), 1e-300)) for b in blas]

    n_link = len(LINK_TERMS) if link_terms else 0

    def params(x: np.ndarray) -> dict[str, float]:
        out = {"Jc": math.exp(x[0]), "bc": math.exp(x[1]), "K": math.exp(x[2]), "Jl": math.exp(x[3]),
               "Td": float(x[4]) * 1e-3}
        for name, v in zip(LINK_TERMS[:n_link], x[5:]):
            out[name] = float(v)
        return out

    size = 2 * sum(b.G.size for b in blas)

    def residual(x: np.ndarray) -> np.ndarray:
        parts = []
        p = params(x)
        with np.errstate(all="ignore"):  # a trial step far out: no model there, a cost no step accepts
            for b, T, w in zip(blas, Ts, weights):
                e = (b.G - sampled_response(p, b.f_hz, T)) * w
                parts += [e.real.ravel(), e.imag.ravel()]
            r = np.concatenate(parts)
        return r if np.all(np.isfinite(r)) else np.full(size, 1e10)

    x0 = np.array([math.log(p0[k]) for k in PARAMETER_NAMES[:4]] + [p0["Td"] * 1e3] + [0.0] * n_link)
    lower = np.array([math.log(1e-4), math.log(1e-3), math.log(1.0), math.log(1e-4), 0.0] + [-np.inf] * n_link)
    upper = np.array([math.log(1e4), math.log(1e6), math.log(1e8), math.log(1e5), 50.0] + [np.inf] * n_link)
    sol = least_squares(residual, np.clip(x0, lower, upper), bounds=(lower, upper), x_scale="jac")
    r = sol.fun
    dof = max(len(r) - len(x0), 1)
    chi2_dof = float(r @ r / dof)
    J = sol.jac
    cov_x = np.linalg.pinv(J.T @ J) * max(chi2_dof, 1.0)
    p = params(sol.x)
    D = np.diag([p["Jc"], p["bc"], p["K"], p["Jl"], 1e-3] + [1.0] * n_link)  # d(SI)/dx
    cov_all = D @ cov_x @ D
    cov = cov_all[:5, :5]
    std = dict(zip(PARAMETER_NAMES, map(float, np.sqrt(np.diag(cov)))))
    link = {name: (p[name], float(math.sqrt(max(cov_all[5 + i, 5 + i], 0.0))))
            for i, name in enumerate(LINK_TERMS[:n_link])}
    names = list(labels) if labels is not None else [f"dataset {i + 1}" for i in range(len(blas))]
    return BlaFit(parameters={k: p[k] for k in PARAMETER_NAMES}, std=std, covariance=cov, chi2_dof=chi2_dof,
                  blas=blas, labels=names, link=link)
