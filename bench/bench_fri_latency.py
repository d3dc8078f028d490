"""Answer latency of ``iiwa-ident run`` against a robot peer written in C, at 1 kHz, with and without stalls.

Run: ``.venv/bin/python bench/bench_fri_latency.py [seconds]`` (default 60 s per run).

A minimal robot peer (``bench/fri_peer.c``) is compiled at benchmark time with the system's C compiler;
without one the benchmark says so and exits. The peer sends monitoring messages in COMMANDING_ACTIVE every
millisecond (prepared here with the toolkit's encoder, joint 1 moving slowly so the filters work) and
time-stamps every answer on arrival. The client is the ``iiwa-ident run`` command with the default design
(``--task sine``, 3 Nm at 1 Hz), pinned to the highest CPU, under SCHED_FIFO and with locked memory where
permitted; the peer is pinned to CPU 0. Two runs:

1. plain: one message per millisecond;
2. stalls: the same, with a 30 ms robot-side stall every 10 s (no message; the time stamps keep the time,
   the sequence counter does not jump, as when the robot's cycle slips).

For each: the peer's answer latency (message sent to answer received, loopback both ways) over the steady
part of the run (from 0.5 s after the first answer to 0.1 s before the last), as median, p99, p99.9 and
max, the number of answers later than 1 ms and of messages not answered; the client's own receive-to-send
time from its report; how the run ended and its watchdog trips. Goal: p99.9 of the answer latency at most
200 us on an otherwise idle core.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from iiwa_ident import fri as P
from iiwa_ident.deploy import deploy, write_config
from iiwa_ident.design import design_controller, identified_model, make_record, outer_loop_margins
from iiwa_ident.emulator import DEFAULT_JOINT_POSITIONS
from iiwa_ident.model import JointParameters

HERE = Path(__file__).resolve().parent
CLI = str(Path(sys.executable).with_name("iiwa-ident"))
WARMUP_S = 4.0  # the client starts its log writer and waits for COMMANDING_ACTIVE meanwhile
STALL_S, STALL_EVERY_S = 0.030, 10.0


def compile_peer(folder: Path) -> Path | None:
    """The peer built with the first C compiler found; None (and a message) without one."""
    cc = next((c for c in (os.environ.get("CC"), "cc", "gcc", "clang") if c and shutil.which(c)), None)
    if cc is None:
        print("skipped: no C compiler (cc, gcc or clang) on PATH; install one (e.g. 'apt install gcc') "
              "to measure the answer latency")
        return None
    exe = folder / "fri_peer"
    res = subprocess.run([cc, "-O2", "-std=c11", "-o", str(exe), str(HERE / "fri_peer.c")],
                         capture_output=True, text=True)
    if res.returncode != 0:
        print(f"skipped: {cc} could not build bench/fri_peer.c:\n{res.stderr.strip()}")
        return None
    return exe


def write_messages(path: Path, seconds: float, stalls: bool) -> int:
    """The peer's message file; returns the number of messages."""
    n = int(round((WARMUP_S + seconds + 1.0) * 1e3))
    j = 0
    pose = list(DEFAULT_JOINT_POSITIONS)
    info = dict(number_of_joints=7, safety_state=P.SafetyState.NORMAL_OPERATION,
                drive_state=(P.DriveState.ACTIVE,) * 7, operation_mode=P.OperationMode.AUT,
                control_mode=P.ControlMode.JOINT_IMPEDANCE)
    conn = dict(session_state=P.SessionState.COMMANDING_ACTIVE, quality=P.ConnectionQuality.EXCELLENT,
                send_period_ms=1, receive_multiplier=1)
    epoch_ns = time.time_ns()
    chunks = [struct.pack("<I", n)]
    shift_ns = 0
    next_stall = WARMUP_S + 5.0
    for k in range(n):
        t = k * 1e-3
        if stalls and t >= next_stall:
            shift_ns += int(STALL_S * 1e9)
            next_stall += STALL_EVERY_S
        offset = k * 1_000_000 + shift_ns
        pose[j] = DEFAULT_JOINT_POSITIONS[j] + 0.2 * np.sin(0.5 * t)
        positions = tuple(pose)
        tau = [0.0] * 7
        tau[j] = 5.0 + 0.5 * np.sin(3.0 * t)
        sec, nsec = divmod(epoch_ns + offset, 1_000_000_000)
        msg = P.MonitoringMessage(
            header=dict(message_identifier=P.MONITORING_MESSAGE_ID, sequence_counter=k, reflected_sequence_counter=0),
            robot_info=info,
            monitor_data=dict(measured_joint_position=dict(value=positions), measured_torque=dict(value=tau),
                              commanded_joint_position=dict(value=positions), commanded_torque=dict(value=(0.0,) * 7),
                              external_torque=dict(value=(0.0,) * 7), timestamp=dict(sec=sec & 0xFFFFFFFF, nanosec=nsec)),
            connection_info=conn,
            ipo_data=dict(joint_position=dict(value=positions), client_command_mode=P.ClientCommandMode.TORQUE,
                          overlay_type=P.OverlayType.JOINT, tracking_performance=1.0),
        )
        data = P.encode_monitoring(msg)
        chunks.append(struct.pack("<QII", offset, k, len(data)) + data)
    path.write_bytes(b"".join(chunks))
    return n


def run_once(peer: Path, config: Path, folder: Path, seconds: float, stalls: bool) -> dict:
    msgs, out = folder / "messages.bin", folder / "peer.bin"
    n = write_messages(msgs, seconds, stalls)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    report = folder / "run.json"
    client = subprocess.Popen(
        [CLI, "run", "--config", str(config), "--robot", "127.0.0.1", "--port", str(port), "--task", "sine",
         "--amplitude", "3", "--frequency", "1", "--duration", str(seconds), "--log", str(folder / "run.h5"),
         "--json", str(report), "--connect-timeout", "30"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    first = client.stdout.readline()  # "listening on UDP port ...": the socket is bound
    peer_proc = subprocess.run([str(peer), str(msgs), str(port), str(out), "0"], capture_output=True, text=True)
    rest = client.communicate(timeout=120)[0]
    if peer_proc.returncode != 0 or client.returncode != 0:
        raise SystemExit(f"peer: {peer_proc.stderr.strip()}\nclient ({client.returncode}):\n{first}{rest}")
    times = np.fromfile(out, dtype="<i8").reshape(n, 2)
    sent, answered = times[:, 0], times[:, 1]
    got = np.flatnonzero(answered > 0)
    window = np.arange(got[0] + 500, got[-1] - 100)
    lat_us = (answered[window] - sent[window]) / 1e3
    ok = answered[window] > 0
    rep = json.loads(report.read_text())
    return {"lat": lat_us[ok], "unanswered": int((~ok).sum()), "n": len(window), "report": rep,
            "realtime": next((line for line in (first + rest).splitlines() if line.startswith("real time")), "")}


def show(name: str, r: dict) -> None:
    lat = r["lat"]
    c = r["report"]["compute_us"]
    trips = [e for _, e in r["report"]["watchdog_events"] if e.startswith("tripped")]
    on_stall = sum(1 for e in trips if int(e.split()[1]) > round(STALL_S * 1e3))
    print(f"{name}: {r['n']} messages, answer latency (peer: sent to answer received) median "
          f"{np.median(lat):.0f} us, p99 {np.percentile(lat, 99):.0f} us, p99.9 {np.percentile(lat, 99.9):.0f} us, "
          f"max {lat.max():.0f} us; later than 1 ms: {int((lat > 1000).sum())}; not answered: {r['unanswered']}")
    print(f"{' ' * len(name)}  client receive to send: median {c['median']:.0f} us, p99 {c['p99']:.0f} us, "
          f"p99.9 {c['p99_9']:.0f} us, max {c['max']:.0f} us; ended: {r['report']['stop_reason']}; "
          f"watchdog trips: {len(trips)} ({on_stall} on a stall)")


def main(seconds: float = 60.0) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        peer = compile_peer(folder)
        if peer is None:
            return
        model = identified_model(seed=1)
        design = design_controller(JointParameters.from_model(model))
        config = write_config(folder / "controller.toml",
                              deploy(make_record(design, outer_loop_margins(design), model), "iiwa14", 1))
        print(f"{os.cpu_count()} CPUs; load average {', '.join(f'{x:.2f}' for x in os.getloadavg())}")
        plain = run_once(peer, config, folder, seconds, stalls=False)
        print(plain["realtime"])
        show("plain", plain)
        stalled = run_once(peer, config, folder, seconds, stalls=True)
        show(f"30 ms stall every {STALL_EVERY_S:g} s", stalled)


if __name__ == "__main__":
    main(float(sys.argv[1]) if len(sys.argv) > 1 else 60.0)
