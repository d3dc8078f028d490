"""Subcommands ``chirp``, ``simulate`` and ``plant``: run experiments and inspect plants."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import typer

from iiwa_ident.cli._app import app, check_joint, fail, plant_option
from iiwa_ident.cli._progress import progress
from iiwa_ident.errors import IiwaIdentError

if TYPE_CHECKING:
    from iiwa_ident.excite import Experiment
    from iiwa_ident.robot import RobotInterface

__all__ = ["chirp_cmd", "simulate_cmd", "plant_cmd", "run_on_target"]

_PlantOpt = Annotated[Optional[Path], plant_option()]
_SeedOpt = Annotated[int, typer.Option("--seed", help="Seed of the sensor noise.")]
_OutOpt = Annotated[Path, typer.Option("--out", help="Dataset file to write (HDF5).")]
_RateOpt = Annotated[float, typer.Option("--rate", help="Recording rate [Hz]: 1000 or a divisor of it (e.g. 200).")]


def _floats(text: str, option: str) -> list[float]:
    try:
        values = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise IiwaIdentError(f"{option} expects comma-separated numbers, got {text!r}") from None
    if not values:
        raise IiwaIdentError(f"{option} expects at least one number")
    return values


def _robot_target(experiment: Experiment, robot: Optional[str], port: int, robot_model: str,
                  joint: int) -> RobotInterface:
    """The FRI robot the experiment runs on (``--target robot``)."""
    from iiwa_ident.fri import FriRobot, parse_host_port

    if not robot:
        raise IiwaIdentError("--target robot needs --robot HOST (the robot controller's address)")
    host, port = parse_host_port(robot, port, "--robot")
    return FriRobot(host, joint, robot_model, port=port, mode=experiment.mode)


def run_on_target(experiment: Experiment, target: str, plant: Optional[Path], seed: int, rate: float,
                  out: Path, q0: float = 0.0, robot: Optional[str] = None, port: int = 30200,
                  robot_model: str = "iiwa14", joint: Optional[int] = None, robot_name: Optional[str] = None) -> None:
    """Run ``experiment`` on the simulated joint or on a robot over FRI, write the dataset, print its summary.

    ``joint``: on the robot the joint under test (default 1); on the simulated joint, the plant's (refused if
    another is asked for)."""
    from iiwa_ident.datasets import dataset_info, format_info, set_robot_name, write_dataset
    from iiwa_ident.excite import record
    from iiwa_ident.sim import SimulatedJoint, default_plant, load_plant

    check_joint(joint)
    if target == "sim":
        the_plant = load_plant(plant) if plant else default_plant()
        if joint is not None and joint != the_plant.joint:
            raise IiwaIdentError(f"--joint {joint}: the simulated plant is joint {the_plant.joint} (another joint: "
                                 "--plant with a plant file of it, see 'iiwa-ident plant --write-default')")
        target_robot: RobotInterface = SimulatedJoint(the_plant, seed=seed, q0=q0)
    elif target == "robot":
        if plant is not None:
            raise IiwaIdentError("--plant only applies to --target sim")
        target_robot = _robot_target(experiment, robot, port, robot_model, 1 if joint is None else joint)
    else:
        raise IiwaIdentError(f"--target {target}: expected 'sim' or 'robot'")
    cycle = target_robot.sample_time_s
    every = 1.0 / rate / cycle if rate > 0 else 0.0
    if rate <= 0 or abs(every - round(every)) > 1e-9 or round(every) < 1:
        raise IiwaIdentError(f"--rate {rate:g}: must divide the robot's {1 / cycle:g} Hz cycle rate")
    where = "simulated" if target == "sim" else "on the robot"
    with progress(f"{experiment.name} ({experiment.duration_s:.0f} s {where})") as shown:
        ds = record(target_robot, experiment, record_every=int(round(every)), progress=shown.advance)
    set_robot_name(ds, robot_name)
    path = write_dataset(out, ds)
    typer.echo(format_info(dataset_info(ds)))
    if "stopped_reason" in ds.experiment_attrs:
        typer.echo(f"warning: stopped early: {ds.experiment_attrs['stopped_reason']}", err=True)
    typer.echo(f"wrote {path}")


_RobotOpt = Annotated[Optional[str], typer.Option("--robot", help="--target robot: robot controller HOST[:PORT].")]
_PortOpt = Annotated[int, typer.Option("--port", help="--target robot: local FRI UDP port.")]
_RobotModelOpt = Annotated[str, typer.Option("--robot-model", help="--target robot: iiwa7 | iiwa14.")]
_JointOpt = Annotated[Optional[int], typer.Option("--joint", help="Joint under test, 1-7 (--target robot: "
                                                   "default 1; --target sim: the plant's).")]
_RobotNameOpt = Annotated[Optional[str], typer.Option("--robot-name", help="Name of the robot (kept in the dataset; "
                                                                           "a fleet's key).")]


@app.command("chirp")
def chirp_cmd(
    out: _OutOpt,
    target: Annotated[str, typer.Option("--target", help="'sim' (simulated joint) or 'robot' (FRI).")] = "sim",
    plant: _PlantOpt = None,
    f0: Annotated[float, typer.Option("--f0", help="Start frequency [Hz].")] = 0.5,
    f1: Annotated[float, typer.Option("--f1", help="End frequency [Hz].")] = 200.0,
    duration: Annotated[float, typer.Option("--duration", help="Sweep duration [s].")] = 30.0,
    amplitude: Annotated[float, typer.Option("--amplitude", help="Sweep amplitude [Nm].")] = 10.0,
    bias: Annotated[float, typer.Option("--bias", help="Constant torque keeping clear of the 1 Nm standstill threshold [Nm].")] = 3.0,
    hold: Annotated[float, typer.Option("--hold", help="Weak position-hold stiffness against drift [Nm/rad].")] = 30.0,
    seed: _SeedOpt = 0,
    rate: _RateOpt = 1000.0,
    robot: _RobotOpt = None,
    port: _PortOpt = 30200,
    robot_model: _RobotModelOpt = "iiwa14",
    joint: _JointOpt = None,
    robot_name: _RobotNameOpt = None,
) -> None:
    """Record an exponential chirp (torque-commanded) as a dataset.

    On the robot the same program runs over FRI (robot side: JOINT_IMPEDANCE
    control mode, TORQUE client command mode, 1 ms send period).

    Examples:
      iiwa-ident chirp --target sim --duration 30 --out chirp.h5
      iiwa-ident chirp --target robot --robot 192.170.10.2 --joint 1 --duration 30 --out chirp.h5
    """
    from iiwa_ident.excite import Chirp

    try:
        run_on_target(Chirp(f0, f1, duration, amplitude, bias, hold), target, plant, seed, rate, out,
                      robot=robot, port=port, robot_model=robot_model, joint=joint, robot_name=robot_name)
    except IiwaIdentError as err:
        raise fail(str(err)) from None


@app.command("simulate")
def simulate_cmd(
    experiment: Annotated[str, typer.Argument(help="multisine | constant_velocity | quasi_static | hand_guided | "
                                              "step | sine")],
    out: _OutOpt,
    plant: _PlantOpt = None,
    seed: _SeedOpt = 0,
    rate: _RateOpt = 1000.0,
    velocity: Annotated[str, typer.Option("--velocity", help="constant_velocity: speeds [rad/s], comma-separated; quasi_static: agent speed.")] = "",
    range_: Annotated[Optional[float], typer.Option("--range", help="Travel [rad].")] = None,
    repeats: Annotated[int, typer.Option("--repeats", help="constant_velocity: back-and-forth passes per speed.")] = 1,
    mode: Annotated[str, typer.Option("--mode", help="constant_velocity: 'torque' (client tracking) or 'position'.")] = "torque",
    torque: Annotated[str, typer.Option("--torque", help="quasi_static: commanded loads [Nm], comma-separated.")] = "2,5,10",
    duration: Annotated[Optional[float], typer.Option("--duration", help="hand_guided, sine: duration [s].")] = None,
    kappa: Annotated[float, typer.Option("--kappa", help="hand_guided: command kappa * F/T torque.")] = 0.0,
    amplitude: Annotated[Optional[float], typer.Option("--amplitude", help="step, sine: amplitude; multisine: "
                                                   "peak [Nm].")] = None,
    frequency: Annotated[float, typer.Option("--frequency", help="sine: frequency [Hz].")] = 0.25,
    period: Annotated[Optional[float], typer.Option("--period", help="step: square-wave period (default 1); "
                                                    "multisine: period (default 2) [s].")] = None,
    band: Annotated[str, typer.Option("--band", help="multisine: F_LO,F_HI of the excited odd lines [Hz].")] = "1,100",
    periods: Annotated[int, typer.Option("--periods", help="multisine: steady-state periods per realisation "
                                         "(one more is run first for the transient).")] = 2,
    realisations: Annotated[int, typer.Option("--realisations", help="multisine: realisations with new random "
                                              "phases.")] = 4,
    bias: Annotated[float, typer.Option("--bias", help="multisine: constant torque [Nm].")] = 3.0,
    phase_seed: Annotated[int, typer.Option("--phase-seed", help="multisine: seed of the random phases.")] = 0,
    transient_periods: Annotated[Optional[int], typer.Option("--transient-periods", help="multisine: periods run "
                                                             "first in each realisation and left out (default: "
                                                             "4 s worth).")] = None,
    cycles: Annotated[int, typer.Option("--cycles", help="step: number of periods.")] = 3,
    q0: Annotated[float, typer.Option("--q0", help="Initial joint position [rad].")] = 0.0,
    target: Annotated[str, typer.Option("--target", help="'sim' (simulated joint) or 'robot' (FRI).")] = "sim",
    robot: _RobotOpt = None,
    port: _PortOpt = 30200,
    robot_model: _RobotModelOpt = "iiwa14",
    joint: _JointOpt = None,
    robot_name: _RobotNameOpt = None,
) -> None:
    """Run one of the other experiments on the simulated joint (or on the robot, --target robot).

    Examples:
      iiwa-ident simulate multisine --band 1,100 --period 2 --periods 2 --realisations 4 --out ms.h5
      iiwa-ident simulate constant_velocity --velocity 0.3,0.6,1.2 --out cv.h5
      iiwa-ident simulate constant_velocity --mode position --rate 200 --out cv200.h5
      iiwa-ident simulate quasi_static --torque 2,5,10 --out qs.h5
      iiwa-ident simulate hand_guided --duration 20 --out hand.h5
      iiwa-ident simulate sine --amplitude 15 --frequency 25 --duration 4 --out sine.h5
      iiwa-ident simulate constant_velocity --target robot --robot 192.170.10.2 --out cv.h5
    """
    from iiwa_ident.excite import Multisine

    try:
        if experiment == "multisine":
            lo_hi = _floats(band, "--band")
            if len(lo_hi) != 2:
                raise IiwaIdentError(f"--band expects F_LO,F_HI, got {band!r}")
            exp: Experiment = Multisine(lo_hi[0], lo_hi[1], 2.0 if period is None else period, periods,
                                        realisations, 10.0 if amplitude is None else amplitude, bias,
                                        seed=phase_seed, transient_periods=transient_periods)
        else:
            exp = _experiment(experiment, velocity, range_, repeats, mode, torque, duration, kappa, amplitude,
                              frequency, 1.0 if period is None else period, cycles)
        run_on_target(exp, target, plant, seed, rate, out, q0=q0, robot=robot, port=port,
                      robot_model=robot_model, joint=joint, robot_name=robot_name)
    except IiwaIdentError as err:
        raise fail(str(err)) from None


def _experiment(name, velocity, range_, repeats, mode, torque, duration, kappa, amplitude, frequency, period,
                cycles) -> Experiment:
    from iiwa_ident.excite import ConstantVelocity, HandGuided, QuasiStatic, SineTorque, StepTorque

    opt = {} if range_ is None else {"range_rad": range_}
    if name == "constant_velocity":
        speeds = _floats(velocity, "--velocity") if velocity else [0.3, 0.6, 1.2]
        return ConstantVelocity(speeds, repeats=repeats, mode=mode, **opt)
    if name == "quasi_static":
        if velocity:
            opt["velocity_rad_s"] = _floats(velocity, "--velocity")[0]
        return QuasiStatic(_floats(torque, "--torque"), **opt)
    if name == "hand_guided":
        return HandGuided(duration_s=duration or 20.0, kappa=kappa, **opt)
    if name == "step":
        return StepTorque(amplitude_nm=10.0 if amplitude is None else amplitude, period_s=period, cycles=cycles)
    if name == "sine":
        return SineTorque(amplitude_nm=5.0 if amplitude is None else amplitude, frequency_hz=frequency,
                          duration_s=duration or 8.0)
    if name == "chirp":
        raise IiwaIdentError("use 'iiwa-ident chirp' for the chirp experiment")
    raise IiwaIdentError(f"unknown experiment {name!r} (multisine, constant_velocity, quasi_static, hand_guided, "
                         "step, sine)")


@app.command("plant")
def plant_cmd(
    file: Annotated[Optional[Path], typer.Argument(help="Plant TOML file to check and show.")] = None,
    effects: Annotated[bool, typer.Option("--effects", help="List the effects a plant file can switch on.")] = False,
    write_default: Annotated[Optional[Path], typer.Option("--write-default", help="Write the default plant to this file.")] = None,
) -> None:
    """Check a plant file, list effects, or write the default plant as a starting point.

    Examples:
      iiwa-ident plant --write-default my_plant.toml
      iiwa-ident plant my_plant.toml
      iiwa-ident plant --effects
    """
    from iiwa_ident.sim import EFFECTS, default_plant, load_plant

    try:
        if effects:
            for name, cls in EFFECTS.items():
                typer.echo(f"{name}: {cls.summary}")
                for p in cls.params:
                    typer.echo(f"    {p.name} = {p.default:g} [{p.unit}]  {p.doc}")
                if name == "transmission_ripple":
                    typer.echo("    harmonics = [[amplitude_rad, phase_rad], ...]  or  lut = [f_0, ..., f_N-1] [rad]")
            return
        if write_default:
            from importlib import resources

            from iiwa_ident._toml import write_atomic

            write_atomic(write_default, resources.files("iiwa_ident").joinpath("data/default_plant.toml").read_text())
            typer.echo(f"wrote {write_default}")
            return
        plant = load_plant(file) if file else default_plant()
        d = plant.dynamics
        typer.echo(f"{plant.robot_model} joint {plant.joint}: Jc={d['Jc']:g} kg m^2, bc={d['bc']:g} Nm s/rad, "
                   f"K={d['K']:g} Nm/rad, Jl={d['Jl']:g} kg m^2, Td={d['Td'] * 1e3:g} ms")
        typer.echo("effects: " + (", ".join(e.name for e in plant.effects) or "none"))
    except IiwaIdentError as err:
        raise fail(str(err)) from None

