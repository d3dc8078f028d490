"""Subcommand ``run``: execute a deployed controller config over FRI (or on the simulated joint)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import typer

from iiwa_ident._defaults import DEFAULT_PORT, LOOPS, TASKS, TAU_EXT_SOURCES
from iiwa_ident.cli._app import app, fail, json_option, plant_option, write_json
from iiwa_ident.errors import IiwaIdentError

if TYPE_CHECKING:
    from iiwa_ident.runtime import RunReport

__all__ = ["run_cmd", "format_report", "make_sensor"]


def make_sensor(tau_ext: str, ft: Optional[str], lever: Optional[float], counts_per_force: float,
                counts_per_torque: float, fault_cycles: int):
    """The F/T sensor of ``--tau-ext ft`` from the ``--ft*`` options (None for the other sources)."""
    from iiwa_ident.fri import parse_host_port
    from iiwa_ident.netft import RDT_PORT, Calibration, JointAxisProjection, NetFtSensor

    if tau_ext not in TAU_EXT_SOURCES:
        raise IiwaIdentError(f"--tau-ext {tau_ext!r}: expected one of {', '.join(TAU_EXT_SOURCES)}")
    if tau_ext != "ft":
        if ft is not None:
            raise IiwaIdentError("--ft is read only with --tau-ext ft")
        return None
    if ft is None:
        raise IiwaIdentError("--tau-ext ft needs the sensor's address: --ft HOST[:PORT]")
    host, port = parse_host_port(ft, RDT_PORT, "--ft")
    projection = JointAxisProjection.from_lever_arm(lever) if lever is not None else None
    return NetFtSensor(host, projection, port, Calibration(counts_per_force, counts_per_torque), fault_cycles)


# The ``--ft*`` options of the commands that read an F/T sensor (run, kappa).
FtHostOpt = Annotated[Optional[str], typer.Option("--ft", help="--tau-ext ft: the Net F/T's HOST[:PORT] (RDT, "
                                                  "port 49152).")]
FtLeverOpt = Annotated[Optional[float], typer.Option("--ft-lever", help="--tau-ext ft: the sensor's lever arm about "
                                                     "the joint's axis [m] (default: the flange's geometry from the "
                                                     "description at the arm's pose).")]
FtCpfOpt = Annotated[float, typer.Option("--ft-counts-per-force", help="--tau-ext ft: the sensor's counts per N.")]
FtCptOpt = Annotated[float, typer.Option("--ft-counts-per-torque", help="--tau-ext ft: the sensor's counts per Nm.")]
FtFaultOpt = Annotated[int, typer.Option("--ft-fault-cycles", help="--tau-ext ft: cycles in a row without a good "
                                         "record that ramp the loop down and end the run.")]


def format_report(report: RunReport) -> str:
    """Human-readable summary of a run, several lines."""
    lines = [f"ran {report.cycles} cycles ({report.duration_s:.3f} s); ended: {report.stop_reason or 'duration'}"]
    c = report.compute_us
    if c:
        lines.append(f"compute per cycle (receive to send): median {c['median']:.1f} us, p99 {c['p99']:.1f} us, "
                     f"p99.9 {c['p99_9']:.1f} us, max {c['max']:.1f} us")
    for t, text in report.watchdog_events:
        lines.append(f"watchdog at {t:.3f} s: {text}")
    if report.connection:
        lines.append("datagrams: " + ", ".join(f"{k} {v}" for k, v in report.connection.items()))
    if report.first_answer_s is not None:
        lines.append(f"first answer to the robot {report.first_answer_s * 1e3:.0f} ms after listening")
    if report.log and not Path(report.log).exists():
        # The log writer keeps no file that no dataset reader would accept (fewer than two rows).
        lines.append(f"log: {report.logged} row(s), too few for a dataset: no file written at {report.log}")
    else:
        lines.append(f"log: {report.logged} rows in {report.log}" +
                     (f", {report.lost_log_rows} rows LOST" if report.lost_log_rows else ""))
    return "\n".join(lines)


@app.command("run")
def run_cmd(
    config: Annotated[Path, typer.Option("--config", help="Controller config TOML (from 'iiwa-ident deploy').")],
    log: Annotated[Path, typer.Option("--log", help="Run log to write (dataset format v1, every cycle).")],
    robot: Annotated[Optional[str], typer.Option("--robot", help="Robot controller HOST[:PORT] (FRI).")] = None,
    port: Annotated[int, typer.Option("--port", help="Local FRI UDP port.")] = DEFAULT_PORT,
    target: Annotated[str, typer.Option("--target", help="'robot' (FRI) or 'sim' (the simulated joint, "
                                        "simulated time).")] = "robot",
    plant: Annotated[Optional[Path], plant_option("--target sim: ")] = None,
    task: Annotated[str, typer.Option("--task", help=f"Reference task: {' | '.join(TASKS)}.")] = "zero",
    duration: Annotated[float, typer.Option("--duration", help="Run length [s].")] = 10.0,
    amplitude: Annotated[float, typer.Option("--amplitude", help="constant, step, sine, chirp: amplitude; "
                                             "multisine: peak [Nm].")] = 5.0,
    frequency: Annotated[float, typer.Option("--frequency", help="sine: frequency; chirp: start "
                                             "frequency; multisine: lowest line [Hz].")] = 0.25,
    period: Annotated[float, typer.Option("--period", help="step: square-wave period; multisine: period [s].")] = 2.0,
    f1: Annotated[float, typer.Option("--f1", help="chirp: end frequency; multisine: highest line [Hz].")] = 50.0,
    sweep: Annotated[float, typer.Option("--sweep", help="chirp: sweep duration [s].")] = 20.0,
    kappa: Annotated[float, typer.Option("--kappa", help="kappa: tau_r = kappa * tau_ext.")] = 1.0,
    watchdog_cycles: Annotated[int, typer.Option("--watchdog-cycles", help="Lost or late cycles in a row that "
                                                 "ramp the additive torque to zero.")] = 3,
    ramp_ms: Annotated[float, typer.Option("--ramp-ms", help="Ramp time of the watchdog and of the final "
                                           "stop [ms].")] = 20.0,
    connect_timeout: Annotated[float, typer.Option("--connect-timeout", help="Wait this long for the robot "
                                                   "to start commanding [s].")] = 60.0,
    silence: Annotated[float, typer.Option("--silence-limit", help="End the run when the robot has sent nothing for "
                                           "this long [s]; shorter gaps trip the watchdog and the run goes "
                                           "on.")] = 1.0,
    realtime: Annotated[bool, typer.Option("--realtime/--no-realtime", help="--target robot: pin the loop to "
                                           "one CPU, SCHED_FIFO and locked memory where permitted (one line "
                                           "says what was set).")] = True,
    cpu: Annotated[Optional[int], typer.Option("--cpu", help="--realtime: CPU to pin the loop to (default: the "
                                               "highest one allowed).")] = None,
    seed: Annotated[int, typer.Option("--seed", help="--target sim: seed of the sensor noise.")] = 0,
    tau_ext: Annotated[str, typer.Option("--tau-ext", help="The external torque of the kappa task: "
                                         f"{' | '.join(TAU_EXT_SOURCES)} (the runtime's eq (14), KUKA's "
                                         "estimate, a Net F/T).")] = "estimate",
    loop: Annotated[str, typer.Option("--loop", help=f"{' | '.join(LOOPS)}: the deployed controller, or "
                                      "the reference sent as the torque command (the robot's own "
                                      "loop).")] = "additive",
    ft: FtHostOpt = None,
    ft_lever: FtLeverOpt = None,
    ft_cpf: FtCpfOpt = 1e6,
    ft_cpt: FtCptOpt = 1e6,
    ft_fault: FtFaultOpt = 20,
    json_out: Annotated[Optional[Path], json_option("the run report")] = None,
) -> None:
    """Execute a deployed controller at 1 kHz: eq (9) correction, spatial filter, improved observer,
    additive controller, task reference and limits, every cycle, with a watchdog and a log.

    The robot side must run its FRI application with JOINT_IMPEDANCE control mode (zero stiffness),
    client command mode TORQUE and a 1 ms send period; the runtime refuses any other setting.
    Ctrl-C (SIGINT) or SIGTERM ramps the additive torque out and closes the log. Over FRI the loop
    runs pinned to one CPU, under SCHED_FIFO and with its memory locked where the user has the rights
    (--no-realtime: none of that); one line says what was set and, if not permitted, how to grant it.

    Examples:
      iiwa-ident run --config controller.toml --robot 192.170.10.2 --task zero --duration 30 --log run.h5
      iiwa-ident run --config controller.toml --robot 127.0.0.1 --task sine --amplitude 15 --frequency 25 --log sine.h5
      iiwa-ident run --config controller.toml --robot 192.170.10.2 --task kappa --kappa 3 --log kappa.h5
      iiwa-ident run --config controller.toml --robot 192.170.10.2 --task kappa --kappa 3 --tau-ext ft
        --ft 192.168.1.1 --log kappa.h5
      iiwa-ident run --config controller.toml --target sim --task step --amplitude 10 --log step.h5
      iiwa-ident run --config controller.toml --target sim --task multisine --amplitude 5 --frequency 1 --f1 40 --period 2 --log ms.h5
    """
    from iiwa_ident.deploy import read_config
    from iiwa_ident.fri import FriRobot, parse_host_port
    from iiwa_ident.robot import RobotInterface
    from iiwa_ident.runtime import Watchdog, make_task, run_controller
    from iiwa_ident.sim import SimulatedJoint, default_plant, load_plant

    try:
        cfg = read_config(config)
        the_task = make_task(task, amplitude, frequency, period, f1, sweep, kappa, cfg.sample_time_s)
        if not ramp_ms >= 0:
            raise IiwaIdentError("--ramp-ms must not be negative")
        if not 0 < silence < float("inf"):
            raise IiwaIdentError(f"--silence-limit must be a positive number of seconds, got {silence!r}")
        watchdog = Watchdog(cfg.sample_time_s, watchdog_cycles, ramp_ms * 1e-3)
        if loop not in LOOPS:
            raise IiwaIdentError(f"--loop {loop!r}: expected one of {', '.join(LOOPS)}")
        sensor = make_sensor(tau_ext, ft, ft_lever, ft_cpf, ft_cpt, ft_fault)
        if sensor is not None and target != "robot":
            raise IiwaIdentError("--tau-ext ft reads a sensor over the network: run against the emulator "
                                 "('iiwa-ident emulate --ft-port PORT') with --target robot")
        the_robot: RobotInterface
        if target == "robot":
            if not robot:
                raise IiwaIdentError("--robot HOST is required with --target robot")
            host, the_port = parse_host_port(robot, port, "--robot")
            the_robot = FriRobot(host, cfg.joint, cfg.robot_model, port=the_port, mode="torque",
                                 connect_timeout_s=connect_timeout, message_timeout_s=silence)
            typer.echo(f"listening on UDP port {the_port} for {host}; waiting for the robot to start commanding")
        elif target == "sim":
            if robot:
                raise IiwaIdentError("--robot only applies to --target robot")
            the_plant = load_plant(plant) if plant else default_plant()
            if (the_plant.robot_model, the_plant.joint) != (cfg.robot_model, cfg.joint):
                raise IiwaIdentError(f"the plant is {the_plant.robot_model} A{the_plant.joint}, the config "
                                     f"{cfg.robot_model} A{cfg.joint}")
            the_robot = SimulatedJoint(the_plant, seed=seed)
        else:
            raise IiwaIdentError(f"--target {target}: expected 'robot' or 'sim'")
        report = run_controller(cfg, the_robot, the_task, duration, log, watchdog=watchdog,
                                progress=typer.echo, realtime=realtime and target == "robot", cpu=cpu,
                                tau_ext=tau_ext, sensor=sensor, loop=loop)
        typer.echo(format_report(report))
        if json_out is not None:
            write_json(json_out, report.as_dict())
    except IiwaIdentError as err:
        raise fail(str(err)) from None
    if report.ended_early:
        # The log and the report are written: a script still learns that the run did not go its course.
        raise fail(f"the run ended after {report.duration_s:.3f} s of {duration:g} s: {report.stop_reason}", code=1)
