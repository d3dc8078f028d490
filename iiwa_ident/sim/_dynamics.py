"""One robot cycle of the joint dynamics, built symbolically and compiled.

The continuous model (eqs (1)-(5) plus the switched-on effects) is written
once in casadi and integrated with ``substeps`` RK4 steps per cycle. The
cycle function is turned into C and compiled with the system C compiler
(cached on disk by a hash of the code); without a compiler the casadi
virtual machine runs the same function, only slower.

State ``x`` (per cycle, :data:`STATE`):
    theta_m [rad], z [Nm s] (integral state of eq (1)), theta_l [rad],
    omega_l [rad/s], standing [s] (how long the motor has stood still),
    held (1 while torque control is suppressed at standstill),
    theta_m_prev [rad] (motor position one substep earlier).
Input ``u`` (per cycle): the cycle's start time [s], then per substep the
rows of :data:`INPUTS`.
Output ``y`` (end of cycle, :data:`OUTPUTS`).

Eq (1) is realised as ``Jc theta_m' = (bc/K) e + z``, ``z' = tau - tau_s g'``
with ``e = tau - tau_s``, ``g(theta_m) = theta_m - f(theta_m)`` and ``tau_s``
the torque-sensor reading the internal loop regulates. Without effects this
is exactly eq (1) (``g' = 1``); with the ripple the motor feels the joint
torque through the transmission's instantaneous ratio ``g'`` (eq (5)).
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any, NamedTuple

import casadi as ca
import numpy as np

from iiwa_ident.sim._plant import Plant

__all__ = ["STATE", "INPUTS", "OUTPUTS", "CycleModel", "output_function", "cache_dir"]

log = logging.getLogger(__name__)

STATE = ("theta_m", "z", "theta_l", "omega_l", "standing", "held", "theta_m_prev")
INPUTS = ("tau_cmd", "q_cmd", "position_mode", "ext_tau", "ext_pos", "ext_vel", "ext_k", "ext_d")
OUTPUTS = ("theta_m", "tau_j", "tau_s", "theta_l", "omega_l", "omega_m", "tau_ext", "tau_applied", "held", "tau_model")
_BASE = ("Jc", "bc", "K", "Jl", "t_still", "tau_still", "v_still", "kp", "kd", "cycle_s")
_CODE_VERSION = "2"


def cache_dir() -> Path:
    """Folder of compiled simulators (``IIWA_IDENT_CACHE`` or ``~/.cache/iiwa-ident``)."""
    root = os.environ.get("IIWA_IDENT_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "iiwa-ident")
    return Path(root)


def _parameter_vector(plant: Plant) -> np.ndarray:
    d, i = plant.dynamics, plant.internal
    base = [d["Jc"], d["bc"], d["K"], d["Jl"], i["standstill_time_s"], i["standstill_torque_nm"],
            i["standstill_velocity_rad_s"], i["position_kp"], i["position_kd"], plant.cycle_s]
    return np.concatenate([np.asarray(base, float), *[e.vector() for e in plant.effects]])


def _n_params(plant: Plant) -> int:
    return len(_BASE) + sum(size for e in plant.effects for _, size in e.layout())


def _effect_params(plant: Plant, p: ca.SX) -> list[tuple]:
    """Each effect with its slice of the parameter vector ``p``, by parameter name."""
    offset = len(_BASE)
    out = []
    for e in plant.effects:
        Pe = {}
        for name, size in e.layout():
            Pe[name] = p[offset] if size == 1 else p[offset:offset + size]
            offset += size
        out.append((e, Pe))
    return out


class _Torques(NamedTuple):
    """The joint torque [Nm] of eq (1), as the sensor reports it [Nm], and the deflection's slope [-]."""

    tau_j: Any
    tau_s: Any
    df: Any


class _Effects:
    """The plant's effects on symbolic quantities: each hook summed (or chained) over the plant's effects."""

    def __init__(self, effect_params: list, P: dict) -> None:
        self.effect_params, self.P = effect_params, P

    def deflection(self, theta_m):
        """The transmission's deflection f(theta_m) [rad] and its slope [-]."""
        f, df = 0, 0
        for e, Pe in self.effect_params:
            out = e.deflection(theta_m, Pe)
            if out is not None:
                f, df = f + out[0], df + out[1]
        return f, df

    def sensor(self, tau, t):
        for e, Pe in self.effect_params:
            tau = e.sensor(tau, t, Pe)
        return tau

    def link_torque(self, theta_l, omega_l):
        total = 0
        for e, Pe in self.effect_params:
            out = e.link_torque(theta_l, omega_l, Pe)
            if out is not None:
                total = total + out
        return total

    def model_torque(self, theta_m):
        total = 0
        for e, Pe in self.effect_params:
            out = e.robot_model_torque(theta_m, Pe)
            if out is not None:
                total = total + out
        return total

    def torques(self, s, t) -> _Torques:
        f, df = self.deflection(s[0])
        tau_j = self.P["K"] * (s[0] - f - s[2])
        return _Torques(tau_j, self.sensor(tau_j, t), df)

    def rhs(self, s, t, tau, free, ext):
        """The state's derivative and the external torque [Nm] at ``s``, time ``t``, motor torque ``tau``."""
        Jc, bc, K, Jl = self.P["Jc"], self.P["bc"], self.P["K"], self.P["Jl"]
        ext_tau, ext_pos, ext_vel, ext_k, ext_d = ext
        tau_j, tau_s, df = self.torques(s, t)
        e = tau - tau_s
        dtheta_m = free * ((bc / K) * e + s[1]) / Jc
        dz = free * (tau - tau_s * (1 - df))
        tau_ext = ext_tau + ext_k * (ext_pos - s[2]) + ext_d * (ext_vel - s[3])
        domega_l = (tau_j + tau_ext + self.link_torque(s[2], s[3])) / Jl
        return ca.vertcat(dtheta_m, dz, s[3], domega_l), tau_ext


def _build(plant: Plant) -> ca.Function:
    """The symbolic cycle function ``F(x, u, p) -> (x_next, y)``."""
    M = plant.substeps
    nin = len(INPUTS)
    x = ca.SX.sym("x", len(STATE))
    u = ca.SX.sym("u", 1 + nin * M)
    p = ca.SX.sym("p", _n_params(plant))
    P = {name: p[k] for k, name in enumerate(_BASE)}
    fx = _Effects(_effect_params(plant, p), P)
    h = P["cycle_s"] / M

    s = x[0:4]
    standing_s, held, theta_prev = x[4], x[5], x[6]
    t0 = u[0]
    for j in range(M):
        row = u[1 + j * nin:1 + (j + 1) * nin]
        tau_cmd, q_cmd, pos_mode = row[0], row[1], row[2]
        ext = tuple(row[3 + k] for k in range(5))
        t = t0 + j * h
        omega_est = (s[0] - theta_prev) / h
        comp = -fx.model_torque(s[0])  # the robot's own gravity compensation
        # The client's command arrives already through the feasibility filter's slew limit (applied
        # per cycle by the caller); the position controller is the robot's own, at the internal rate.
        tau_f = ca.if_else(pos_mode > 0.5, P["kp"] * (q_cmd - s[0]) - P["kd"] * omega_est, tau_cmd)
        # Torque control is suppressed from standstill while command and sensed load stay below the
        # threshold (section II.A): standstill means the motor has not moved for t_still; position
        # mode never is.
        tau_s_now = fx.torques(s, t).tau_s
        small = ca.logic_and(ca.fabs(tau_f) < P["tau_still"], ca.fabs(tau_s_now - comp) < P["tau_still"])
        standing_s = ca.if_else(ca.fabs(omega_est) < P["v_still"], standing_s + h, 0)
        standing = standing_s >= P["t_still"]
        held = ca.if_else(pos_mode > 0.5, 0, ca.if_else(held > 0.5, small, ca.logic_and(small, standing)))
        free = 1 - held
        tau = free * (tau_f + comp)
        theta_prev = s[0]
        k1, _ = fx.rhs(s, t, tau, free, ext)
        k2, _ = fx.rhs(s + h / 2 * k1, t + h / 2, tau, free, ext)
        k3, _ = fx.rhs(s + h / 2 * k2, t + h / 2, tau, free, ext)
        k4, _ = fx.rhs(s + h * k3, t + h, tau, free, ext)
        s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    t_end = t0 + M * h
    deriv, tau_ext = fx.rhs(s, t_end, tau, free, ext)
    tau_j, tau_s, _ = fx.torques(s, t_end)
    x_next = ca.vertcat(s, standing_s, held, theta_prev)
    y = ca.vertcat(s[0], tau_j, tau_s, s[2], s[3], deriv[0], tau_ext, tau, held, fx.model_torque(s[0]))
    return ca.Function("iiwa_cycle", [x, u, p], [x_next, y])


_WRAPPER = r"""
/* Plain entry points for ctypes: one cycle, and n cycles in a row. */
static casadi_real iiwa_w[{sz_w}];
static casadi_int iiwa_iw[{sz_iw} + 1];

int iiwa_step(const double* x, const double* u, const double* p, double* x_next, double* y) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  arg[0] = x; arg[1] = u; arg[2] = p;
  res[0] = x_next; res[1] = y;
  return iiwa_cycle(arg, res, iiwa_iw, iiwa_w, 0);
}}

int iiwa_run(long n, const double* x0, const double* U, const double* p, double* X, double* Y) {{
  const double* x = x0;
  for (long k = 0; k < n; ++k) {{
    if (iiwa_step(x, U + k * {nu}, p, X + k * {nx}, Y + k * {ny})) return 1;
    x = X + k * {nx};
  }}
  return 0;
}}
"""


class _Compiled:
    """ctypes handle on a compiled cycle function."""

    def __init__(self, lib_path: Path, nx: int, nu: int, ny: int) -> None:
        self.lib = ctypes.CDLL(str(lib_path))
        # Raw addresses (array.ctypes.data) are the cheapest way through ctypes, which matters at 1 kHz.
        self.lib.iiwa_step.argtypes = [ctypes.c_void_p] * 5
        self.lib.iiwa_run.argtypes = [ctypes.c_long] + [ctypes.c_void_p] * 5
        self.nx, self.nu, self.ny = nx, nu, ny


def _compile(fn: ca.Function) -> _Compiled | None:
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if not cc:
        return None
    with tempfile.TemporaryDirectory() as tmp:
        cwd = os.getcwd()
        try:
            os.chdir(tmp)
            gen = ca.CodeGenerator("iiwa_cycle.c", {"with_header": False})
            gen.add(fn)
            gen.generate()
            code = Path("iiwa_cycle.c").read_text()
        finally:
            os.chdir(cwd)
    code += _WRAPPER.format(sz_w=max(fn.sz_w(), 1), sz_iw=fn.sz_iw(), sz_arg=fn.sz_arg(), sz_res=fn.sz_res(),
                            nu=fn.size1_in(1), nx=fn.size1_in(0), ny=fn.size1_out(1))
    digest = hashlib.sha256((_CODE_VERSION + code).encode()).hexdigest()[:20]
    folder = cache_dir()
    lib = folder / f"sim-{digest}.so"
    if not lib.exists():
        try:
            folder.mkdir(parents=True, exist_ok=True)
            src = folder / f"sim-{digest}.{os.getpid()}.c"
            src.write_text(code)
            tmp_lib = folder / f"sim-{digest}.{os.getpid()}.so"
            subprocess.run([cc, "-O2", "-fPIC", "-shared", str(src), "-o", str(tmp_lib), "-lm"],
                           check=True, capture_output=True, timeout=300)
            os.replace(tmp_lib, lib)  # atomic: a concurrent process sees all or nothing
            src.unlink(missing_ok=True)
        except (OSError, subprocess.SubprocessError) as err:
            log.warning("compiling the simulator failed (%s); using the slower casadi VM", err)
            return None
    return _Compiled(lib, fn.size1_in(0), fn.size1_in(1), fn.size1_out(1))


# One build per structure (substeps, effect structure) for the life of the process.
_BUILT: dict[tuple, tuple[ca.Function, _Compiled | None]] = {}


class CycleModel:
    """The compiled cycle function of a plant, with fast single and batch calls.

    Parameters
    ----------
    plant : Plant
        The plant; parameter values are inputs of the compiled code, so plants
        that differ only in values share one compiled function.
    compile : bool
        Compile to C (default) or use the casadi virtual machine.
    """

    def __init__(self, plant: Plant, compile: bool = True) -> None:
        key = (plant.substeps, tuple(e.structure() for e in plant.effects), compile)
        if key not in _BUILT:
            fn = _build(plant)
            _BUILT[key] = (fn, _compile(fn) if compile else None)
        self.function, self._compiled = _BUILT[key]
        self.p = np.ascontiguousarray(_parameter_vector(plant))
        self._p_addr = self.p.ctypes.data
        self.substeps = plant.substeps
        self.nx, self.nu, self.ny = len(STATE), self.function.size1_in(1), len(OUTPUTS)
        self._y = np.zeros(self.ny)
        self._mapped: dict[int, ca.Function] = {}

    @property
    def compiled(self) -> bool:
        """True when the C-compiled function is in use."""
        return self._compiled is not None

    def step(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Advance one cycle: returns ``(x_next, y)``."""
        if self._compiled is None:
            xn, y = self.function(x, u, self.p)
            return np.asarray(xn).ravel(), np.asarray(y).ravel()
        x = np.ascontiguousarray(x, float)
        u = np.ascontiguousarray(u, float)
        xn = np.empty(self.nx)
        y = np.empty(self.ny)
        self._compiled.lib.iiwa_step(x.ctypes.data, u.ctypes.data, self._p_addr, xn.ctypes.data, y.ctypes.data)
        return xn, y

    def run(self, x0: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Advance ``len(U)`` cycles; ``U`` is (n, nu). Returns states (n, nx) and outputs (n, ny)."""
        U = np.ascontiguousarray(U, float)
        n = U.shape[0]
        if self._compiled is None:
            chunk = 1000
            if chunk not in self._mapped:
                self._mapped[chunk] = self.function.mapaccum(chunk)
            X = np.empty((n, self.nx))
            Y = np.empty((n, self.ny))
            x = np.asarray(x0, float)
            for start in range(0, n, chunk):
                block = U[start:start + chunk]
                m = len(block)
                padded = np.vstack([block, np.repeat(block[-1:], chunk - m, axis=0)]) if m < chunk else block
                Xc, Yc = self._mapped[chunk](x, padded.T, self.p)
                X[start:start + m] = np.asarray(Xc).T[:m]
                Y[start:start + m] = np.asarray(Yc).T[:m]
                x = X[start + m - 1]
            return X, Y
        x0 = np.ascontiguousarray(x0, float)
        X = np.empty((n, self.nx))
        Y = np.empty((n, self.ny))
        if self._compiled.lib.iiwa_run(n, x0.ctypes.data, U.ctypes.data, self._p_addr, X.ctypes.data, Y.ctypes.data):
            raise RuntimeError("simulation step failed")
        return X, Y



def output_function(plant: Plant) -> ca.Function:
    """``g(theta_m, theta_l, t, p) -> (f, tau_j, tau_s, tau_model, tau_link)`` at one instant.

    Deflection [rad], true and sensed joint torque [Nm], the robot's model
    torque [Nm] and the torque the effects put on a link at rest [Nm], from
    the same effect hooks as the cycle function.
    """
    th_m, th_l, t = ca.SX.sym("theta_m"), ca.SX.sym("theta_l"), ca.SX.sym("t")
    p = ca.SX.sym("p", _n_params(plant))
    f, tau_model, tau_link, sensed = 0, 0, 0, []
    for e, Pe in _effect_params(plant, p):
        link = e.link_torque(th_l, 0.0, Pe)
        if link is not None:
            tau_link = tau_link + link
        out = e.deflection(th_m, Pe)
        if out is not None:
            f = f + out[0]
        model = e.robot_model_torque(th_m, Pe)
        if model is not None:
            tau_model = tau_model + model
        sensed.append((e, Pe))
    tau_j = p[_BASE.index("K")] * (th_m - f - th_l)
    tau_s = tau_j
    for e, Pe in sensed:
        tau_s = e.sensor(tau_s, t, Pe)
    return ca.Function("outputs", [th_m, th_l, t, p], [f, tau_j, tau_s, tau_model, tau_link])
