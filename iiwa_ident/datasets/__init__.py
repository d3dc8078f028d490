"""Dataset files: the HDF5 format, its background writer for a 1 kHz loop, importers for foreign logs, summaries.

Identification code reads data only through :func:`read_dataset`, which never
exposes ground truth; :func:`read_truth` is reserved for evaluation code.
"""

from iiwa_ident.datasets._format import (
    COLUMN_LOG_MARK,
    EXPERIMENTS,
    FORMAT_NAME,
    FORMAT_VERSION,
    REQUIRED_SIGNALS,
    ROBOT_NAME_ATTR,
    SIGNAL_UNITS,
    SOURCES,
    Dataset,
    dataset_files,
    dataset_pose,
    read_dataset,
    read_truth,
    robot_name,
    set_robot_name,
    sha256_file,
    validate_dataset,
    write_dataset,
)
from iiwa_ident.datasets._import import (
    MAX_RATE_HZ,
    MIN_MESSAGE_RATE_HZ,
    MIN_RATE_HZ,
    import_columns,
    import_csv,
    moving_joint_problem,
)
from iiwa_ident.datasets._info import dataset_info, format_info
from iiwa_ident.datasets._lcmlog import IIWA_STATUS_CHANNEL, decode_iiwa_status, import_lcm, lcm_fingerprint
from iiwa_ident.datasets._logwriter import SHM_PREFIX as LOG_SHM_PREFIX
from iiwa_ident.datasets._logwriter import LogStats, LogWriter
from iiwa_ident.datasets._provenance import (
    IMPORT_WARNINGS_ATTR,
    SIGN_MIN_GRAVITY_NM,
    band_limited_problem,
    dataset_warnings,
    joint_velocity,
    low_rate_problem,
    note_warnings,
    substituted_position_problem,
    time_gaps_problem,
    torque_sign_problem,
)
from iiwa_ident.datasets._rosbag import LBR_STATE_MSG, LBR_STATE_TYPES, import_rosbag, ros_typestore

__all__ = [
    "EXPERIMENTS",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "REQUIRED_SIGNALS",
    "SIGNAL_UNITS",
    "SOURCES",
    "MIN_RATE_HZ",
    "MAX_RATE_HZ",
    "MIN_MESSAGE_RATE_HZ",
    "Dataset",
    "dataset_pose",
    "ROBOT_NAME_ATTR",
    "robot_name",
    "set_robot_name",
    "read_dataset",
    "dataset_files",
    "COLUMN_LOG_MARK",
    "read_truth",
    "sha256_file",
    "validate_dataset",
    "write_dataset",
    "import_columns",
    "import_csv",
    "import_lcm",
    "import_rosbag",
    "ros_typestore",
    "LBR_STATE_MSG",
    "LBR_STATE_TYPES",
    "IIWA_STATUS_CHANNEL",
    "decode_iiwa_status",
    "lcm_fingerprint",
    "moving_joint_problem",
    "LogWriter",
    "LogStats",
    "LOG_SHM_PREFIX",
    "dataset_info",
    "dataset_warnings",
    "joint_velocity",
    "low_rate_problem",
    "note_warnings",
    "IMPORT_WARNINGS_ATTR",
    "time_gaps_problem",
    "band_limited_problem",
    "substituted_position_problem",
    "torque_sign_problem",
    "SIGN_MIN_GRAVITY_NM",
    "format_info",
]
