"""``iiwa-ident ripple`` over its valid input space, on runs written apart from the search: every outcome is a
result or a one-line error, never a traceback.

The runs come from a generator of their own (not the simulated joint): the motor at one constant speed per
run (either sign), the deflection ``f`` of eq (5) as one sine in the motor position, the joint torque a
constant load plus ``K f`` scaled down (what a stiff link leaves of it) and white noise, the position
quantised like the iiwa's encoder, at 200 Hz to 1 kHz.
"""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from iiwa_ident.cli import app
from iiwa_ident.datasets import Dataset, write_dataset


def _run(path, speed, duration_s, rate_hz, cycles_per_rev, amplitude_rad, seed, phase=0.7):
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration_s * rate_hz)) / rate_hz
    q = 0.1 + speed * t
    f = amplitude_rad * np.sin(cycles_per_rev * q + phase)  # one transmission: the same phase in every run
    tau = 3.0 + 185.0 * f + 0.02 * rng.standard_normal(len(t))
    tick = 5.989e-8
    write_dataset(path, Dataset(signals={"t": t, "q_m": np.round(q / tick) * tick, "tau_j": tau},
                                experiment="constant_velocity", source="simulation", joint=1,
                                sample_rate_hz=rate_hz))


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cpr=st.floats(100.0, 1000.0), runs=st.integers(1, 6), rate=st.sampled_from([200.0, 500.0, 1000.0]),
       duration=st.floats(0.5, 2.5), amplitude=st.one_of(st.just(0.0), st.floats(1e-6, 1e-4)),
       speeds=st.lists(st.floats(0.05, 1.5), min_size=6, max_size=6), signs=st.lists(st.booleans(), min_size=6,
                                                                                      max_size=6),
       seed=st.integers(0, 2**16))
def test_ripple_never_ends_in_a_traceback(tmp_path_factory, cpr, runs, rate, duration, amplitude, speeds, signs,
                                          seed):
    folder = tmp_path_factory.mktemp("fuzz")
    files = []
    for i in range(runs):
        path = folder / f"run{i}.h5"
        _run(path, speeds[i] * (1 if signs[i] else -1), duration, rate, cpr, amplitude, seed + i)
        files.append(str(path))
    result = CliRunner().invoke(app, ["ripple", *files, "--json", str(folder / "r.json")])
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in result.stdout + result.stderr
    if result.exit_code != 0:
        assert result.exit_code == 2 and len(result.stderr.strip().splitlines()) == 1, result.stderr
