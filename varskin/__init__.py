"""VARSkin: unattended calibration of capacitive tactile robot skins.

The Python API mirrors the CLI: ``read_point_logs`` loads the point-log CSV interchange
format and ``localize`` runs a localization method on it.
"""

from varskin.errors import VarskinError
from varskin.localization import localize
from varskin.patch import Patch, load_patch
from varskin.pointlogs import PointLog, PointLogs
from varskin.predictions import Predictions, SensorEstimate

__all__ = [
    "Patch",
    "PointLog",
    "PointLogs",
    "Predictions",
    "SensorEstimate",
    "VarskinError",
    "load_patch",
    "localize",
    "read_point_logs",
]


def read_point_logs(path) -> PointLogs:
    """Read a point-log CSV (the format is described in ``varskin.pointlog_csv``)."""
    from varskin.pointlog_csv import read_point_logs as _read

    return _read(path)
