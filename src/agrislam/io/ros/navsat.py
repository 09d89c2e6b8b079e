"""sensor_msgs/NavSatFix as agrislam reads and writes it.

NavSatStatus says no fix (-1), fix (0), SBAS (1) or GBAS (2) augmentation; it has no word
for RTK. Receivers' drivers (ublox, septentrio, novatel) report RTK as a GBAS fix, fixed
and float alike, so a GBAS fix whose horizontal sigma is at most `RTK_FIXED_SIGMA` is RTK
fixed and any other RTK float; a written fix carries its type back the same way.
`position_covariance` is east-north-up in m^2, row-major; type 0 means unknown."""

from __future__ import annotations

from typing import Any

import numpy as np

from agrislam.records import GnssFix

NAVSAT_FIX = "sensor_msgs/msg/NavSatFix"
NO_FIX, FIX, SBAS_FIX, GBAS_FIX = -1, 0, 1, 2  # NavSatStatus.status
SERVICE_GPS = 1
COVARIANCE_UNKNOWN, COVARIANCE_KNOWN = 0, 3  # NavSatFix.position_covariance_type
RTK_FIXED_SIGMA = 0.05  # m: an RTK fix any less sure than this is float
STATUS_OF = {"none": NO_FIX, "single": FIX, "dgps": SBAS_FIX, "rtk_float": GBAS_FIX}
STATUS_OF["rtk_fixed"] = GBAS_FIX


def fix_type(status: int, cov: np.ndarray | None) -> str:
    """The fix type of a NavSatStatus.status and the fix's covariance (None: unknown)."""
    if status < FIX:
        return "none"
    if status == FIX:
        return "single"
    if status == SBAS_FIX:
        return "dgps"
    if cov is not None and max(cov[0, 0], cov[1, 1]) <= RTK_FIXED_SIGMA**2:
        return "rtk_fixed"
    return "rtk_float"


def gnss_record(msg: Any, t: float, robot: str, antenna: np.ndarray | None) -> GnssFix:
    """A NavSatFix as a GnssFix (checked later, as every record, by sources.validate)."""
    cov = None
    if msg.position_covariance_type != COVARIANCE_UNKNOWN:
        cov = np.asarray(msg.position_covariance, dtype=float).reshape(3, 3)
    return GnssFix(
        t=t,
        robot=robot,
        lat=float(msg.latitude),
        lon=float(msg.longitude),
        alt=float(msg.altitude),
        fix=fix_type(int(msg.status.status), cov),
        cov=cov,
        antenna=antenna,
    )


def navsat_message(types: Any, header: Any, fix: GnssFix) -> Any:
    """A GnssFix as a NavSatFix (`types`: the typestore's message classes)."""
    status = types["sensor_msgs/msg/NavSatStatus"](status=STATUS_OF[fix.fix], service=SERVICE_GPS)
    known = fix.cov is not None
    cov = np.asarray(fix.cov, dtype=np.float64).ravel() if known else np.zeros(9)
    return types[NAVSAT_FIX](
        header=header,
        status=status,
        latitude=float(fix.lat),
        longitude=float(fix.lon),
        altitude=float(fix.alt),
        position_covariance=cov,
        position_covariance_type=COVARIANCE_KNOWN if known else COVARIANCE_UNKNOWN,
    )
