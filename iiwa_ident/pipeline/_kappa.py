"""The outer loop's gain margin measured live through FRI, for both controllers, beside its prediction.

:func:`run_kappa_sweep` runs :class:`~iiwa_ident.runtime.KappaSweep` (``tau_r = kappa tau_ext`` with
kappa raised stepwise until the run itself shows an instability, then ramped down) through the FRI
runtime, first for the built-in loop (the reference sent as the torque command), then for the deployed
additive controller, with the external torque from the chosen source (``ft``: a Net F/T over RDT;
``estimate``: the runtime's eq (14); ``fri``: KUKA's estimate). On the simulated target each run has an
emulator of its own in lockstep, with a hand holding the arm (slowly drifting, as a person's hand does
while the loop is raised) and, for ``ft``, the emulated Net F/T; two runs give the same figures. On the
robot a person holds the arm, and the sweep refuses to start unless told so.

Beside each live margin stands the linear prediction for the same loop
(:func:`~iiwa_ident.design.deployed_margin`): the design's model with the hand's impedance, the
source's dynamics (the F/T sensor's filter and rate; the observer of eq (13) with its gain), FRI's
delay, and the spatial filter at the speeds the run passed through (its least margin over them).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from iiwa_ident.datasets import read_dataset
from iiwa_ident.deploy import ControllerConfig
from iiwa_ident.design import (
    AdditiveDesign,
    DeployedLoop,
    DesignRecord,
    HumanArm,
    deployed_margin,
    filter_period,
)
from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.netft import JointAxisProjection, NetFtSensor, NetFtSettings
from iiwa_ident.pipeline._session import LOCKSTEP_GUARD_S, LateFriRobot, free_udp_port
from iiwa_ident.runtime import KappaSweep, RunReport, SweepSettings, Watchdog, run_controller
from iiwa_ident.sim import Plant, default_plant

__all__ = ["HoldingHand", "run_kappa_sweep", "speeds_of_run", "prediction_error_pct", "rate_limited_pct",
           "RATE_LIMITED_PCT", "CONTROLLERS"]

#: The loops swept, in order.
CONTROLLERS = ("builtin", "additive")


@dataclass(frozen=True)
class HoldingHand:
    """The emulator's hand while the gain is raised: an arm impedance to a slowly drifting hand.

    Attributes
    ----------
    stiffness_nm_rad, damping_nms_rad : float
        Arm impedance about the joint's axis [Nm/rad], [Nm s/rad].
    peak_speed_rad_s, range_rad : float
        The hand's drift: peak speed [rad/s] and largest excursion [rad].
    """

    stiffness_nm_rad: float = 300.0
    damping_nms_rad: float = 40.0
    peak_speed_rad_s: float = 0.05
    range_rad: float = 0.05

    def arm(self) -> HumanArm:
        return HumanArm(self.stiffness_nm_rad, self.damping_nms_rad)


def speeds_of_run(path: Path, upto_s: float | None = None, quantile: float = 0.95, cutoff_hz: float = 20.0) -> float:
    """The joint speed a run's log stays below ``quantile`` of the time [rad/s] (the spatial filter's
    smoothing: a first-order low-pass at ``cutoff_hz`` of the position's difference), up to ``upto_s``."""
    ds = read_dataset(path)
    t = np.asarray(ds["t"], float)
    q = np.asarray(ds["q_m"], float)
    if len(t) < 3:
        return 0.0
    dt = float(np.median(np.diff(t)))
    v = np.diff(q) / dt
    a = 1.0 - math.exp(-2.0 * math.pi * cutoff_hz * dt)
    from scipy.signal import lfilter
    vs = lfilter([a], [1.0, a - 1.0], v)
    if upto_s is not None:
        vs = vs[: max(1, int((upto_s - t[0]) / dt))]
    return float(np.quantile(np.abs(vs), quantile))


def run_kappa_sweep(config: ControllerConfig, outdir: Path, *, record: DesignRecord | None, tau_ext: str = "ft",
                    target: str = "sim", plant: Plant | None = None, robot: tuple[str, int] | None = None,
                    ft: tuple[str, int] | None = None, ft_settings: NetFtSettings = NetFtSettings(),
                    ft_projection: JointAxisProjection | None = None,
                    settings: SweepSettings = SweepSettings(), hand: HoldingHand = HoldingHand(),
                    holding_the_arm: bool = False, lockstep: bool = True, seed: int = 21,
                    say: Callable[[str], None] = lambda _m: None) -> dict[str, Any]:
    """Measure the outer loop's live gain margin of both controllers and predict it (module docstring).

    Parameters
    ----------
    config : ControllerConfig
        The deployed additive controller (its limits and watchdog serve both loops).
    outdir : Path
        Folder of the run logs ``kappa_<controller>_<source>.h5``.
    record : DesignRecord or None
        The design the config was deployed from: its model makes the linear prediction (None: no
        prediction).
    tau_ext : str
        ``"ft"``, ``"estimate"`` or ``"fri"``.
    target : str
        ``"sim"`` (the emulator on loopback, running ``plant``) or ``"robot"`` (at ``robot`` = (host,
        local port), the F/T sensor at ``ft``).
    ft_settings : NetFtSettings
        The emulated sensor (sim target) and its filter in the prediction.
    ft_projection : JointAxisProjection, optional
        The sensor's geometry (default: the flange from the description at the pose FRI reports).
    settings : SweepSettings
        Kappa steps and the judgement of instability.
    hand : HoldingHand
        The emulator's hand (sim target); on the robot its arm impedance is the prediction's guess.
    holding_the_arm : bool
        Robot target: a person holds the arm (required).
    lockstep : bool
        Sim target: the emulator in lockstep (repeatable figures); both sweeps then run at once.
    seed : int
        The emulator's seed (noise, hand).
    say : callable
        Progress messages.

    Returns
    -------
    dict
        JSON-ready: ``tau_ext``, ``target``, ``clock``, ``settings``, ``hand``, per controller (``builtin``,
        ``additive``): ``live_limit``, ``unstable_at``, ``reason``, ``stop_reason``, ``steps``, ``file``,
        ``speed_p95_rad_s``, ``rate_limited_from`` (the first kappa whose command sat at the runtime's
        torque-rate limit in :data:`RATE_LIMITED_PCT` % of its cycles: from there the prediction, which has
        no rate limits, does not describe the loop), ``linear_limit``, ``linear_at_speed_rad_s``, ``linear_error_pct`` (outside
        the live bracket, :func:`prediction_error_pct`); ``ratio_live`` (of the live limits) and
        ``ratio_linear`` (additive / built-in; None where a figure is missing).
    """
    plant = plant or default_plant()
    _refuse_unsafe(target, tau_ext, plant, holding_the_arm, robot, ft)
    outdir.mkdir(parents=True, exist_ok=True)
    lockstep = lockstep and target == "sim"
    duration = settings.steps() * settings.hold_s + 1.0

    @contextmanager
    def robot_side() -> Iterator[tuple[tuple[str, int], tuple[str, int] | None]]:
        if target != "sim":
            yield robot, ft  # type: ignore[misc]  # _refuse_unsafe: the robot target comes with both
            return
        from iiwa_ident.emulator import EmulatorConfig, spawn_emulator

        port = free_udp_port()
        ft_port = free_udp_port() if tau_ext == "ft" else None
        cfg = EmulatorConfig(client=("127.0.0.1", port), plant=plant, seed=seed, lockstep=lockstep,
                             lockstep_guard_s=LOCKSTEP_GUARD_S, agent="hand", duration_s=duration + 1.0,
                             hand_peak_speed_rad_s=hand.peak_speed_rad_s, hand_range_rad=hand.range_rad,
                             hand_stiffness_nm_rad=hand.stiffness_nm_rad, hand_damping_nms_rad=hand.damping_nms_rad,
                             ft_port=ft_port, ft=ft_settings)
        with spawn_emulator(cfg) as emu:
            try:
                yield ("127.0.0.1", port), (("127.0.0.1", ft_port) if ft_port else None)
            finally:
                emu.stop()
                emu.join(30.0)

    def sweep(loop: str) -> dict[str, Any]:
        path = outdir / f"kappa_{loop}_{tau_ext}.h5"
        task = KappaSweep(settings, config.sample_time_s)
        with robot_side() as (fri_addr, ft_addr):
            fri = LateFriRobot(fri_addr[0], fri_addr[1], config.joint, config.robot_model, lockstep)
            sensor = None
            if tau_ext == "ft":
                sensor = NetFtSensor(ft_addr[0], ft_projection, ft_addr[1], ft_settings.calibration)  # type: ignore[index]  # set with the F/T source
            rep = run_controller(config, fri, task, duration, path, tau_ext=tau_ext,  # type: ignore[arg-type]  # a FriRobot once started
                                 sensor=sensor, loop=loop, watchdog=Watchdog(config.sample_time_s))
        row = _sweep_row(task, rep, path, config.limits.torque_rate_nm_s)
        say(f"  {loop} loop, tau_ext from {tau_ext}: stable up to kappa {_fmt(task.live_limit)}, unstable at "
            f"{_fmt(task.unstable_at)} ({task.reason or rep.stop_reason})")
        return row

    if lockstep:
        with ThreadPoolExecutor(max_workers=2) as pool:
            rows = dict(zip(CONTROLLERS, pool.map(sweep, CONTROLLERS)))
    else:
        rows = {loop: sweep(loop) for loop in CONTROLLERS}
    arm = hand.arm() if target == "sim" else (record.margins.arm if record is not None else HumanArm())
    for loop, row in rows.items():
        row["linear_limit"] = row["linear_at_speed_rad_s"] = None
        if record is not None:
            the_loop = DeployedLoop(source=tau_ext, ft_cutoff_hz=ft_settings.cutoff_hz, ft_rate_hz=ft_settings.rate_hz,
                                    KI=record.KI, filter=record.filter, ripple_period_rad=filter_period(record.ripple))
            _predict(row, record, record.design if loop == "additive" else None, arm, the_loop)
    b, a = rows["builtin"], rows["additive"]
    return {"tau_ext": tau_ext, "target": target, "clock": "lockstep" if lockstep else "realtime",
            "settings": {k: getattr(settings, k) for k in settings.__dataclass_fields__},
            "hand": {k: getattr(hand, k) for k in hand.__dataclass_fields__} if target == "sim" else "a person",
            "ft": ({"rate_hz": ft_settings.rate_hz, "cutoff_hz": ft_settings.cutoff_hz} if tau_ext == "ft" else None),
            "builtin": b, "additive": a,
            "ratio_live": _ratio(a["live_limit"], b["live_limit"]),
            "ratio_linear": _ratio(a["linear_limit"], b["linear_limit"])}


def _refuse_unsafe(target: str, tau_ext: str, plant: Plant, holding_the_arm: bool, robot: tuple[str, int] | None,
                   ft: tuple[str, int] | None) -> None:
    """Refuse a sweep that cannot run or must not: on the robot, nobody holding the arm."""
    if target not in ("sim", "robot"):
        raise IiwaIdentError(f"kappa sweep: target {target!r}, expected 'sim' or 'robot'")
    if target == "robot":
        if not holding_the_arm:
            raise IiwaIdentError("kappa sweep on the robot: the loop amplifies the torque a person applies and is "
                                 "driven until it oscillates; a person must hold the arm "
                                 "(--i-am-holding-the-arm)")
        if robot is None:
            raise IiwaIdentError("kappa sweep on the robot needs the robot's address")
        if tau_ext == "ft" and ft is None:
            raise IiwaIdentError("kappa sweep with the F/T source needs the sensor's address")
    if target == "sim" and tau_ext == "ft" and not plant.ft_sensor:
        raise IiwaIdentError("kappa sweep with the F/T source on the simulated joint needs a plant with "
                             "sensors.ft_sensor = true")


def _sweep_row(task: KappaSweep, rep: RunReport, path: Path, torque_rate_nm_s: float) -> dict[str, Any]:
    """One controller's sweep as measured: its judgement, its steps, its speeds and its rate-limited cycles."""
    t_end = (task.steps[-1]["t_start_s"] if task.reason else None)
    row: dict[str, Any] = {
        "live_limit": task.live_limit, "unstable_at": task.unstable_at, "reason": task.reason,
        "stop_reason": rep.stop_reason, "file": path.name, "watchdog_events": len(rep.watchdog_events),
        "steps": [{"kappa": s["kappa"], "t_start_s": s["t_start_s"], "stable": s["stable"],
                   "rms_max_nm": max(s["rms_nm"]) if s["rms_nm"] else None} for s in task.steps],
        "sensor": rep.sensor,
    }
    if task.reason == "" and not rep.stop_reason.startswith("kappa sweep"):
        row["reason"] = f"ended before a judgement: {rep.stop_reason}"
    row["speed_p95_rad_s"] = speeds_of_run(path, t_end)
    limited = rate_limited_pct(path, [st["t_start_s"] for st in task.steps], torque_rate_nm_s)
    for st, pct in zip(row["steps"], limited):
        st["rate_limited_pct"] = pct
    row["rate_limited_from"] = next((st["kappa"] for st in row["steps"]
                                     if st["rate_limited_pct"] >= RATE_LIMITED_PCT), None)
    return row


def _predict(row: dict[str, Any], record: DesignRecord, design: AdditiveDesign | None, arm: HumanArm,
             loop: DeployedLoop) -> None:
    """Add the linear prediction of ``row``'s sweep: the deployed loop's margin over the run's speeds."""
    v_hi = row["speed_p95_rad_s"]
    speeds = [float(v) for v in np.linspace(0.0, v_hi, 6)] if v_hi > 0 else [0.0]
    m = deployed_margin(record.design.params, design, arm, loop, speeds)
    row["linear_limit"] = _num(m.kappa_max)
    row["linear_at_speed_rad_s"] = m.at_speed_rad_s
    row["linear_error_pct"] = prediction_error_pct(m.kappa_max, row["live_limit"], row["unstable_at"])


#: Share of a step's cycles at the runtime's torque-rate limit from which the linear prediction, which
#: has no rate limits, no longer describes the loop [%].
RATE_LIMITED_PCT = 1.0


def rate_limited_pct(path: Path, step_starts_s: list[float], torque_rate_nm_s: float) -> list[float]:
    """Per kappa step, the share of cycles whose command changed by the runtime's torque-rate limit [%]."""
    ds = read_dataset(path)
    t = np.asarray(ds["t"], float)
    t = t - t[0]
    change = np.abs(np.diff(np.asarray(ds["tau_c"], float)))
    at_limit = change >= torque_rate_nm_s * float(np.median(np.diff(t))) * (1.0 - 1e-6)
    edges = list(step_starts_s) + [math.inf]
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        sel = (t[1:] >= a) & (t[1:] < b)
        out.append(float(100.0 * np.mean(at_limit[sel])) if np.any(sel) else 0.0)
    return out


def prediction_error_pct(linear: float, live_limit: float | None, unstable_at: float | None) -> float | None:
    """How far a predicted margin lies outside the live bracket [%]: 0 between the last stable and the first
    unstable kappa of the sweep (the sweep cannot tell the margin more finely), else its distance from the
    nearer end, relative to that end (None without a live figure)."""
    if live_limit is None or not math.isfinite(linear):
        return None
    if linear < live_limit:
        return float(100.0 * (linear - live_limit) / live_limit)
    if unstable_at is not None and linear > unstable_at:
        return float(100.0 * (linear - unstable_at) / unstable_at)
    return 0.0


def _ratio(a: float | None, b: float | None) -> float | None:
    return float(a / b) if a is not None and b not in (None, 0) else None


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"
