"""A fleet of robots: every joint of many robots identified in parallel on Dask, with a fleet table.

Datasets are grouped by the robot they name (``--robot-name`` of ``import``
and the experiments) and their joint; each group runs one stage (ripple,
diagnose or fit) as a Dask task, on a local cluster or a running scheduler.

Public API
----------
STAGES, UNNAMED, Group, group_datasets, group_key, run_group
    The groups and one group's work (:mod:`iiwa_ident.fleet._groups`).
run_fleet, fleet_table, DEFAULT_WORKERS
    The run on Dask, resumable, and its table (:mod:`iiwa_ident.fleet._engine`).
flag_worn, WEAR_FALSE_ALARM, MIN_GROUPS
    Worn joints: a ripple larger than the fleet's for that joint by more than the uncertainties allow
    (:mod:`iiwa_ident.fleet._wear`).
"""

from iiwa_ident.fleet._engine import DEFAULT_WORKERS, fleet_table, run_fleet
from iiwa_ident.fleet._groups import STAGES, UNNAMED, Group, group_datasets, group_key, run_group
from iiwa_ident.fleet._wear import MIN_GROUPS, WEAR_FALSE_ALARM, flag_worn

__all__ = ["STAGES", "UNNAMED", "Group", "group_datasets", "group_key", "run_group", "run_fleet", "fleet_table",
           "DEFAULT_WORKERS", "flag_worn", "WEAR_FALSE_ALARM", "MIN_GROUPS"]
