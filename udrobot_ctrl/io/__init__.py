"""Real log formats in and out: ROS bags, MAVLink/dataflash logs, QGC CSV, rostopic CSV, ``udrobot-run/1`` runs.

The package's modules: :mod:`~udrobot_ctrl.io.runlog` (the run format), :mod:`~udrobot_ctrl.io.mapping` (mappings),
the readers (:mod:`~udrobot_ctrl.io.rosbag`, :mod:`~udrobot_ctrl.io.mavlink`, :mod:`~udrobot_ctrl.io.qgc_csv`,
:mod:`~udrobot_ctrl.io.rostopic_csv`) and :mod:`~udrobot_ctrl.io.logs` (which log a file is). This file only
re-exports their most used names. Converting a log to a run (``convert_log``, ``load_any``) uses the ArduSub
emulation too, so it is :mod:`udrobot_ctrl.convert`, a layer above (docs/architecture.md).
"""
from udrobot_ctrl.io.logs import DEFAULT_MAPPINGS, log_input_files, log_kind, motor_evidence, read_streams
from udrobot_ctrl.io.mapping import Mapping, MappingError, load_mapping
from udrobot_ctrl.io.runlog import Run, RunLogError, read_run, resample, write_run
from udrobot_ctrl.io.streams import LogImportError

__all__ = ["DEFAULT_MAPPINGS", "LogImportError", "Mapping", "MappingError", "Run", "RunLogError", "load_mapping",
           "log_input_files", "log_kind", "motor_evidence", "read_run", "read_streams", "resample", "write_run"]
