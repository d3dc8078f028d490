"""Subcommand ``emulate``: play the robot side of FRI over UDP with the simulated joint behind it."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import typer

from iiwa_ident._realtime import stop_signals
from iiwa_ident.cli._app import app, fail, json_option, parse_pose, plant_option, write_json
from iiwa_ident.errors import IiwaIdentError

if TYPE_CHECKING:
    from iiwa_ident.emulator import EmulatorConfig, EmulatorReport

__all__ = ["emulate_cmd", "format_summary"]


def _ms(x: float | None) -> str:
    return "-" if x is None else f"{x * 1e3:.3f} ms"


def format_summary(report: EmulatorReport) -> str:
    """Human-readable summary of an emulator run, several lines."""
    r = report
    lines = [
        "session: " + " -> ".join(s.name for s in r.state_sequence()),
        f"cycles: {r.cycles} ({r.skipped_cycles} skipped), overruns (> 0.5 ms late): {r.overruns}; "
        f"cycle start delay median {_ms(r.cycle_delay_median_s)}, p99 {_ms(r.cycle_delay_p99_s)}, "
        f"max {_ms(r.cycle_delay_max_s)}",
        f"monitoring sent: {r.monitoring_sent}; answers: {r.answers_received} received, {r.answers_invalid} invalid, "
        f"{r.answers_foreign} foreign, {r.answers_stale} stale, {r.late_answers} late; missed cycles: "
        f"{r.missed_cycles}",
        f"latency: median {_ms(r.latency_median_s)}, p99 {_ms(r.latency_p99_s)}, max {_ms(r.latency_max_s)}",
        "quality (cycles): " + ", ".join(f"{name} {n}" for name, n in r.quality.items()),
        f"session drops: {len(r.session_drops)}",
    ]
    lines += [f"  {t:8.3f} s  {reason}" for t, reason in r.session_drops]
    injected = {k: v for k, v in r.faults.items() if v}
    if injected:
        lines.append("faults injected: " + ", ".join(f"{k} {v}" for k, v in injected.items()))
    if r.send_errors:
        lines.append(f"send errors: {r.send_errors}")
    if r.lockstep:
        lines.append(f"lockstep (times are virtual): messages resent to a silent client {r.resent}, client taken "
                     f"for gone {r.client_gone} times, commanding messages left unsent after that {r.unsent}")
    if r.safety_stop:
        lines.append(f"SAFETY STOP at {r.safety_stop_t_s:.3f} s: {r.safety_stop}; the joint braked to rest and the "
                     "session ended")
    if r.stalled_cycles:
        lines.append(f"robot-side stalls: {r.stalled_cycles} cycles without a message")
    lines.append(f"commanding active: {r.commanding_s:.3f} s; wall time {r.wall_s:.3f} s; ended: {r.end_reason}")
    return "\n".join(lines)


def _check_probability(option: str, value: float) -> float:
    if not 0.0 <= value <= 1.0:
        raise IiwaIdentError(f"{option} {value:g}: must be a probability in [0, 1]")
    return value


def _check_positive(option: str, value: Optional[float]) -> None:
    if value is not None and not (math.isfinite(value) and value > 0):
        raise IiwaIdentError(f"{option} {value:g}: must be a positive number of seconds")


def _config(plant, client, bind, duration, mode, loss, jitter_ms, duplicate, reorder, corrupt, seed, agent,
            record, max_time, hand_speed, lockstep=False, stalls=(), pose=None, ft_port=None, ft_rate=1000.0,
            ft_cutoff=152.0, ft_lever=None, ft_noise=(0.0, 0.0), idle_timeout=None) -> EmulatorConfig:
    """The emulator settings from the options; every user error is an IiwaIdentError naming the option."""
    from iiwa_ident.emulator import AGENTS, DEFAULT_JOINT_POSITIONS, EmulatorConfig, Faults
    from iiwa_ident.fri import ClientCommandMode, ControlMode, parse_host_port
    from iiwa_ident.netft import NetFtSettings
    from iiwa_ident.sim import load_plant

    if mode not in ("torque", "position"):
        raise IiwaIdentError(f"--mode {mode!r}: must be 'torque' or 'position'")
    if agent is not None and agent not in AGENTS:
        raise IiwaIdentError(f"--agent {agent!r}: must be one of {', '.join(AGENTS)}")
    _check_positive("--duration", duration)
    _check_positive("--max-time", max_time)
    if idle_timeout is not None and not (math.isfinite(idle_timeout) and idle_timeout >= 0):
        raise IiwaIdentError(f"--idle-timeout {idle_timeout:g}: must be a number of seconds >= 0 (0: wait for "
                             "clients for ever)")
    if not (math.isfinite(hand_speed) and hand_speed > 0):
        raise IiwaIdentError(f"--hand-speed {hand_speed:g}: must be a positive speed [rad/s]")
    if not (math.isfinite(jitter_ms) and 0.0 <= jitter_ms <= 1000.0):
        raise IiwaIdentError(f"--jitter-ms {jitter_ms:g}: must be in [0, 1000] ms")
    faults = Faults(
        loss=_check_probability("--loss", loss), jitter_s=jitter_ms * 1e-3,
        duplicate=_check_probability("--duplicate", duplicate), reorder=_check_probability("--reorder", reorder),
        corrupt=_check_probability("--corrupt", corrupt), seed=seed)
    torque = mode == "torque"
    return EmulatorConfig(
        joint_positions=DEFAULT_JOINT_POSITIONS if pose is None else parse_pose(pose, "--pose"),
        client=parse_host_port(client, None, "--client"),
        bind=parse_host_port(bind, None, "--bind", allow_any_port=True),
        plant=load_plant(plant) if plant else None,
        seed=seed,
        control_mode=ControlMode.JOINT_IMPEDANCE if torque else ControlMode.POSITION,
        client_command_mode=ClientCommandMode.TORQUE if torque else ClientCommandMode.POSITION,
        duration_s=duration,
        faults=faults,
        agent=agent,
        hand_peak_speed_rad_s=hand_speed,
        record=record,
        max_wall_s=max_time,
        idle_timeout_s=idle_timeout or None,
        lockstep=lockstep,
        stalls=tuple(_stall(text) for text in stalls),
        ft_port=ft_port,
        ft=NetFtSettings(rate_hz=ft_rate, cutoff_hz=ft_cutoff if ft_cutoff else None, force_noise_n=ft_noise[0],
                         torque_noise_nm=ft_noise[1], seed=seed),
        ft_lever_m=ft_lever,
    )


def _stall(text: str) -> tuple[float, float]:
    """``"START:LENGTH"`` of ``--stall`` (seconds of commanding, milliseconds) -> (start, length) [s]."""
    start, sep, length = text.partition(":")
    try:
        a, b = float(start), float(length) * 1e-3
    except ValueError:
        a = b = float("nan")
    if not sep or not (math.isfinite(a) and a >= 0 and math.isfinite(b) and b > 0):
        raise IiwaIdentError(f"--stall {text!r}: expected START:LENGTH, seconds of commanding >= 0 and a positive "
                             "number of milliseconds (e.g. 2.0:30)")
    return a, b


@app.command("emulate")
def emulate_cmd(
    plant: Annotated[Optional[Path], plant_option()] = None,
    client: Annotated[str, typer.Option("--client", help="HOST:PORT the FRI client listens on.")] = "127.0.0.1:30200",
    bind: Annotated[str, typer.Option("--bind", help="HOST:PORT of the robot-side socket (port 0: any free "
                                      "port).")] = "127.0.0.1:0",
    duration: Annotated[Optional[float], typer.Option("--duration", help="Seconds of COMMANDING_ACTIVE, then close "
                                                      "the session and exit (default: until Ctrl-C).")] = None,
    mode: Annotated[str, typer.Option("--mode", help="'torque' (JOINT_IMPEDANCE, client command mode TORQUE) or "
                                      "'position' (POSITION, POSITION).")] = "torque",
    loss: Annotated[float, typer.Option("--loss", help="Drop probability per datagram, both directions.")] = 0.0,
    jitter_ms: Annotated[float, typer.Option("--jitter-ms", help="Extra delay of robot-to-client datagrams, "
                                             "uniform in [0, MS], in ms.")] = 0.0,
    duplicate: Annotated[float, typer.Option("--duplicate", help="Probability of sending a robot-to-client "
                                             "datagram twice.")] = 0.0,
    reorder: Annotated[float, typer.Option("--reorder", help="Probability of sending a robot-to-client datagram "
                                           "after the next one.")] = 0.0,
    corrupt: Annotated[float, typer.Option("--corrupt", help="Probability of flipping random bytes of a datagram, "
                                           "both directions.")] = 0.0,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the sensor noise, the faults and the hand.")] = 0,
    agent: Annotated[Optional[str], typer.Option("--agent", help="'hand': a human arm moves the link while "
                                                 "commanding is active.")] = None,
    hand_speed: Annotated[float, typer.Option("--hand-speed", help="--agent hand: peak hand speed, in "
                                              "rad/s.")] = 0.5,
    record: Annotated[Optional[Path], typer.Option("--record", help="Write the robot-side dataset (every "
                                                   "simulated signal and the plant truth) here.")] = None,
    max_time: Annotated[Optional[float], typer.Option("--max-time", help="Stop after this many seconds of wall "
                                                      "time, whatever the session state.")] = None,
    idle_timeout: Annotated[float, typer.Option("--idle-timeout", help="Once a client has been heard, end "
                                                "after this many seconds without an answer outside "
                                                "commanding (0: wait for clients for ever).")] = 10.0,
    json_out: Annotated[Optional[Path], json_option("the run report")] = None,
    lockstep: Annotated[bool, typer.Option("--lockstep", help="Wait for each answer, on a virtual clock: "
                                           "repeatable runs whatever the machine's load (no latency is "
                                           "measured).")] = False,
    stall: Annotated[Optional[list[str]], typer.Option("--stall", help="START:LENGTH: a robot-side stall "
                                                       "after START seconds of commanding, LENGTH ms without "
                                                       "a message (repeatable).")] = None,
    pose: Annotated[Optional[str], typer.Option("--pose", help="Start pose of the 7 joints, comma-separated "
                                                "degrees (default 0,30,0,-90,0,60,0).")] = None,
    ft_port: Annotated[Optional[int], typer.Option("--ft-port", help="Serve a Net F/T over RDT on this UDP port "
                                                   "(the joint's external torque as a hand's wrench at the "
                                                   "flange).")] = None,
    ft_rate: Annotated[float, typer.Option("--ft-rate", help="--ft-port: the sensor's output rate [Hz], "
                                           "up to 7000.")] = 1000.0,
    ft_cutoff: Annotated[float, typer.Option("--ft-cutoff", help="--ft-port: the sensor's low-pass cut-off "
                                             "[Hz] (0: no filter).")] = 152.0,
    ft_lever: Annotated[Optional[float], typer.Option("--ft-lever", help="--ft-port: the sensor's lever arm "
                                                      "[m] (default: the flange from the description at "
                                                      "--pose).")] = None,
    ft_noise_n: Annotated[float, typer.Option("--ft-noise-n", help="--ft-port: the sensor's own noise per "
                                              "force channel, std [N] (beside the plant's F/T noise).")] = 0.0,
    ft_noise_nm: Annotated[float, typer.Option("--ft-noise-nm", help="--ft-port: the sensor's own noise per "
                                               "torque channel, std [Nm].")] = 0.0,
) -> None:
    """Emulate the robot controller's side of FRI at 1 kHz over UDP, with the simulated joint behind it.

    Sends a monitoring message every millisecond to the client, runs the session states
    (IDLE, MONITORING_WAIT, MONITORING_READY, COMMANDING_WAIT, COMMANDING_ACTIVE), applies the
    client's command to the simulated joint and drops the session after 5 ms without answers or on
    a malformed or inconsistent command, as the robot does. Prints the state transitions and a
    summary; Ctrl-C (SIGINT) or SIGTERM closes the session and still writes --record and --json.
    The run ends after --duration seconds of commanding, or once its client has gone (silent for
    --idle-timeout seconds after its session ended or dropped).
    With --lockstep the robot side waits for each answer before its next cycle (times in the
    output are then virtual): for testing a client, not for measuring it. --stall makes the robot's
    own cycle slip: no message and no answer awaited for that long, the time stamps keep the time.
    While commanding, the simulated joint is held to its data-sheet range, speed and torque: a
    violation is a safety stop (the joint brakes to rest, the session ends, the limit is named).

    Examples:
      iiwa-ident emulate --client 127.0.0.1:30200 --duration 10
      iiwa-ident emulate --duration 5 --loss 0.01 --jitter-ms 0.3 --duplicate 0.01 --reorder 0.01
      iiwa-ident emulate --mode position --agent hand --record robot.h5 --json report.json
      iiwa-ident emulate --plant my_plant.toml --bind 127.0.0.1:30201
      iiwa-ident emulate --lockstep --duration 5 --record robot.h5
      iiwa-ident emulate --duration 10 --stall 2.0:30 --stall 6.5:200
      iiwa-ident emulate --duration 30 --pose 160,30,0,-90,0,60,0
      iiwa-ident emulate --agent hand --ft-port 49152 --ft-rate 1000 --ft-cutoff 152
    """
    from iiwa_ident.emulator import RobotEmulator

    try:
        config = _config(plant, client, bind, duration, mode, loss, jitter_ms, duplicate, reorder, corrupt, seed,
                         agent, record, max_time, hand_speed, lockstep, stall or (), pose, ft_port, ft_rate,
                         ft_cutoff, ft_lever, (ft_noise_n, ft_noise_nm), idle_timeout)
        emulator = RobotEmulator(config, on_event=lambda t, text: typer.echo(f"{t:8.3f} s  {text}"))
    except IiwaIdentError as err:
        raise fail(str(err)) from None
    host, port = emulator.address
    typer.echo(f"robot side on {host}:{port}, sending to {config.client[0]}:{config.client[1]} every "
               f"{config.send_period_ms} ms ({mode} mode); Ctrl-C to stop")
    if emulator.ft_address is not None:
        typer.echo(f"Net F/T (RDT) on {emulator.ft_address[0]}:{emulator.ft_address[1]}, "
                   f"{config.ft.rate_hz:g} Hz, filter "
                   + (f"{config.ft.cutoff_hz:g} Hz" if config.ft.cutoff_hz else "off"))
    with stop_signals(lambda *_: emulator.stop()):
        report = emulator.run()
    typer.echo(format_summary(report))
    if report.dataset is not None:
        typer.echo(f"wrote {report.dataset}")
    try:
        if json_out is not None:
            write_json(json_out, report.as_dict())
    except IiwaIdentError as err:
        raise fail(str(err)) from None
    except OSError as err:
        raise fail(f"{json_out}: {err.strerror}") from None
    if report.dataset_error:
        raise fail(report.dataset_error)
