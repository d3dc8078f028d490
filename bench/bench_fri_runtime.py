"""The FRI runtime against the emulator over loopback: per-cycle compute time, missed cycles, logged samples.

Run: ``.venv/bin/python bench/bench_fri_runtime.py [seconds] [task]`` (default 60 s, ``sine``: 15 Nm at 25 Hz
through the additive controller of the default design, a hand holding the link). The emulator runs in its own
process; the runtime
in this one, exactly as ``iiwa-ident run`` does. Target (machine otherwise idle): p99.9 of the compute time
(receive to send) at most 200 us, zero missed cycles, zero lost log samples; the robot, already sending
when the client starts listening, answered within 0.5 s.
"""

from __future__ import annotations

import socket
import sys
import tempfile
import time
from pathlib import Path

from iiwa_ident.datasets import read_dataset
from iiwa_ident.deploy import deploy
from iiwa_ident.design import design_controller, identified_model, make_record, outer_loop_margins
from iiwa_ident.emulator import EmulatorConfig, spawn_emulator
from iiwa_ident.fri import FriRobot
from iiwa_ident.model import JointParameters
from iiwa_ident.runtime import make_task, run_controller


def main(seconds: float = 60.0, task: str = "sine") -> None:
    model = identified_model(seed=1)
    design = design_controller(JointParameters.from_model(model))
    config = deploy(make_record(design, outer_loop_margins(design), model), "iiwa14", 1)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    the_task = make_task(task, 15.0, 25.0) if task == "sine" else make_task(task)
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "run.h5"
        # A hand holds the link (as in a pHRI session): the torque task alone drifts the free joint to the
        # end of its range, where the robot's safety stop would end the run before the timing is measured.
        with spawn_emulator(EmulatorConfig(client=("127.0.0.1", port), duration_s=seconds + 1.0, agent="hand",
                                           spin_s=float(__import__("os").environ.get("EMU_SPIN", "0.0003")))) as emu:
            robot = FriRobot("127.0.0.1", 1, port=port, connect_timeout_s=60.0)
            t0 = time.perf_counter()
            rep = run_controller(config, robot, the_task, seconds, log)
            wall = time.perf_counter() - t0
            emu.stop()
            er = emu.join(60.0)
        rows = len(read_dataset(log)["t"])
    c = rep.compute_us
    print(f"{task} for {seconds:g} s: {rep.cycles} cycles in {wall:.1f} s wall, ended: {rep.stop_reason}")
    print(f"compute (receive to send) us: median {c['median']:.1f}  p99 {c['p99']:.1f}  "
          f"p99.9 {c['p99_9']:.1f}  max {c['max']:.1f}")
    print(f"robot side: {er.missed_commanding} missed cycles while commanding ({er.missed_cycles} in all states; "
          f"missed = no answer before the next send), "
          f"{er.late_answers} late answers, {len(er.session_drops)} session drops, {er.overruns} emulator overruns; "
          f"latency median {1e6 * (er.latency_median_s or 0):.0f} us, max {1e6 * (er.latency_max_s or 0):.0f} us")
    if er.safety_stop:
        print(f"robot side: safety stop after {er.safety_stop_t_s:.1f} s: {er.safety_stop}")
    print(f"client side: {rep.connection}; first answer {rep.first_answer_s * 1e3:.0f} ms after listening "
          "(target <= 500 ms)")
    print(f"log: {rows} rows for {rep.cycles + 1} cycles, {rep.lost_log_rows} lost; "
          f"watchdog events: {len(rep.watchdog_events)}")


if __name__ == "__main__":
    main(float(sys.argv[1]) if len(sys.argv) > 1 else 60.0, sys.argv[2] if len(sys.argv) > 2 else "sine")
