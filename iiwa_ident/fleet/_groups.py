"""A fleet's datasets grouped by the robot and joint they were recorded on, and each group's stage, run alone.

A group's work is a plain function of file paths (:func:`run_group`), so that a
Dask worker runs it from the paths it reaches; it returns the stage's own JSON
document, or the one-line error that stopped it.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from iiwa_ident.datasets import read_dataset, robot_name, sha256_file
from iiwa_ident.errors import IiwaIdentError

__all__ = ["STAGES", "UNNAMED", "Group", "group_datasets", "group_key", "run_group"]

#: What a fleet run can do with each group.
STAGES = ("ripple", "diagnose", "fit")
#: The robot of a dataset that does not name one.
UNNAMED = "unnamed"


@dataclass
class Group:
    """The datasets of one robot's joint (``joint`` None: the files that could not be read, one group each)."""

    robot: str
    joint: int | None
    datasets: list[Path] = field(default_factory=list)
    error: str | None = None

    @property
    def label(self) -> str:
        return f"{self.robot} joint {self.joint}" if self.joint is not None else f"{self.robot} (unread)"


def group_datasets(paths: Sequence[str | Path]) -> list[Group]:
    """Group dataset files by (robot name, joint), in the order they are first met.

    A file that cannot be read becomes a group of its own with its one-line error (a fleet run goes on).

    Examples
    --------
    >>> group_datasets([])
    []
    """
    groups: dict[tuple[str, int], Group] = {}
    bad: list[Group] = []
    for p in paths:
        path = Path(p)
        try:
            ds = read_dataset(path)
        except IiwaIdentError as err:
            bad.append(Group(UNNAMED, None, [path], str(err)))
            continue
        key = (robot_name(ds) or UNNAMED, int(ds.joint))
        groups.setdefault(key, Group(key[0], key[1])).datasets.append(path)
    return list(groups.values()) + bad


def group_key(stage: str, group: Group) -> str:
    """The sha256 of the stage and the group's inputs (their contents, in order): a finished group's name."""
    h = hashlib.sha256(f"{stage}\n{group.robot}\n{group.joint}\n".encode())
    for path in group.datasets:
        h.update(sha256_file(path).encode())
    return h.hexdigest()


def _ripple(datasets: list) -> dict[str, Any]:
    from iiwa_ident.ident import dataset_model, ripple_model

    _, result = ripple_model(dataset_model(datasets, borrow=True), datasets)
    return result.to_json()


def _diagnose(datasets: list) -> dict[str, Any]:
    from iiwa_ident.diagnose import diagnose
    from iiwa_ident.ident import dataset_model

    return diagnose(datasets, dataset_model(datasets)).as_json()


def _fit(paths: list[Path]) -> dict[str, Any]:
    from iiwa_ident.ident import fit_model

    _, result = fit_model(paths)
    return result.to_json()


def run_group(stage: str, paths: Sequence[str | Path]) -> dict[str, Any]:
    """Run ``stage`` on one group's datasets: ``{"<stage>": its JSON document}`` or ``{"error": one line}``.

    Never raises for the data: a bad file or a failing analysis is the group's error.
    """
    if stage not in STAGES:
        raise ValueError(f"stage must be one of {', '.join(STAGES)}, got {stage!r}")
    files = [Path(p) for p in paths]
    try:
        if stage == "fit":
            return {stage: _fit(files)}
        datasets = [read_dataset(p) for p in files]
        return {stage: (_ripple if stage == "ripple" else _diagnose)(datasets)}
    except IiwaIdentError as err:
        return {"error": str(err)}
    except Exception as err:  # noqa: BLE001  (an analysis failing on a worker must become a row, not stop the fleet)
        return {"error": f"{type(err).__name__}: {err}".splitlines()[0]}
