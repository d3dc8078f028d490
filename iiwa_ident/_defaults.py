"""Defaults that the library and its command line share, in a module that imports nothing.

The command line shows them in its help, which must print at once: their home modules (named below)
import them from here, so each value is written once and reading it costs no import of numpy, scipy or
the FRI stack.
"""

from __future__ import annotations

import math

__all__ = ["DESIGN_BETA", "DEFAULT_PREFILTER_HZ", "FEEDFORWARD_MODES", "PERIOD_MIN_RAD", "PERIOD_MAX_RAD",
           "DEFAULT_PORT", "TASKS", "TAU_EXT_SOURCES", "LOOPS"]

#: beta of the filter a design deploys (:mod:`iiwa_ident.design._spatial_filter`; observer, eq (14), and
#: controller feedback, eq (15)) [-]. The paper's 5 stays the default of ``SpatialFilter``; inside the torque
#: loop it costs margin: on the simulated joint the outer-loop kappa_max of the additive controller is 20.9
#: with beta = 5 (2.8x the built-in 7.6) and 26-28 with beta = 2 (3.5-3.7x), and below the notch ``1 - H^2``
#: boosts a 2 Hz torque at 0.3 rad/s by 1.24 dB with beta = 5, 0.17 dB with 2.
DESIGN_BETA = 2.0
#: Reference pre-filter of the feed-forward, natural frequency (:mod:`iiwa_ident.design._additive`) [Hz].
#: 250 Hz keeps eq (22) close to the paper's unfiltered inverse below 50 Hz (0.2 rad of lag at 25 Hz; 50 Hz
#: would lag a 25 Hz reference by 0.93 rad, ~12 Nm of error at 15 Nm). An ideal step through it commands
#: ~7x its height at the peak, which is why the runtime rate-limits the reference
#: (:mod:`iiwa_ident.deploy._checks`, ``reference_range``).
DEFAULT_PREFILTER_HZ = 250.0
#: Ways of combining ``Kr`` and the feed-forward (:mod:`iiwa_ident.design._additive`).
FEEDFORWARD_MODES = ("reference", "paper", "none")
#: Search range of the ripple's period (:mod:`iiwa_ident.ident._ripple`): 2000 down to 50 cycles per motor
#: revolution (the paper's joint has 320; other gear ratios have other counts) [rad].
PERIOD_MIN_RAD = 2.0 * math.pi / 2000.0
PERIOD_MAX_RAD = 2.0 * math.pi / 50.0
#: UDP port the FRI client listens on (:mod:`iiwa_ident.fri._connection`).
DEFAULT_PORT = 30200
#: Task names of the deployed runtime (:mod:`iiwa_ident.runtime._tasks`).
TASKS = ("zero", "constant", "step", "sine", "chirp", "multisine", "kappa")
#: Where the runtime's external torque comes from (:mod:`iiwa_ident.runtime._run`): its own observer of eq (14),
#: KUKA's estimate in the FRI monitoring message, or an F/T sensor over RDT.
TAU_EXT_SOURCES = ("estimate", "fri", "ft")
#: The torque loops the runtime can close: the additive controller, or the reference sent as the command.
LOOPS = ("additive", "builtin")
