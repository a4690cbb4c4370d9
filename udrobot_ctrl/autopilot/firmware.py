"""ArduSub's documented gain ranges and its parameter names and units by firmware version.

The design (:mod:`.design`) works in one set of names and units, the *canonical* ones: ArduSub 4.1-4.6's
``ATC_*`` and ``PSC_POSZ_P``, ``PSC_VELZ_*``, ``PSC_ACCZ_*`` (the names :mod:`.params` reads). This module maps
them to what a given firmware loads, and says what that firmware documents as the range of each gain.

Ranges (``@Range`` of the parameter's ``var_info`` documentation; ArduPilot source):

* ``libraries/AC_AttitudeControl/AC_AttitudeControl_Sub.cpp`` ``AC_AttitudeControl_Sub::var_info`` (master,
  commit 00f02a67266abf4a5ac287a22ea9a98fdb38561f): ``ATC_RAT_RLL_P`` and ``ATC_RAT_PIT_P`` 0.0-0.30, ``_I``
  0.0-0.5, ``_D`` 0.0-0.02, ``_IMAX`` 0-1, ``_FF`` 0-0.5; ``ATC_RAT_YAW_P`` 0.0-0.50, ``_I`` 0.0-0.05, ``_D``
  0.000-0.02, ``_IMAX`` 0-1, ``_FF`` 0-0.5; the same ``@Range`` values in an older stored tree of the file (one
  ``RAT_*_FILT`` per PID, the 3.x-4.0 layout), so they hold for every ArduSub this project reads. (ArduCopter's
  ranges -- rate P 0.01-0.5, I 0.01-2, yaw P 0.1-2.5 --
  are *not* Sub's: a BlueROV2 with ``ATC_RAT_YAW_P`` 2.5 is five times past what ArduSub documents.)
* ``libraries/AC_AttitudeControl/AC_AttitudeControl.cpp`` ``AC_AttitudeControl::var_info`` (same commit):
  ``ATC_ANG_RLL_P`` and ``ATC_ANG_PIT_P`` ``@Range{Sub}`` 0.0-12.0, ``ATC_ANG_YAW_P`` ``@Range{Sub}`` 0.0-6.0.
* ArduSub <= 4.6, ``libraries/AC_AttitudeControl/AC_PosControl.cpp`` ``AC_PosControl::var_info`` (every stored
  tree from the ``AC_P`` era to the last one before the rename, e.g. the tree with ``_p_pos_u_m``; no
  ``@Range{Sub}`` override): ``PSC_POSZ_P`` 1.0-3.0, ``PSC_VELZ_P`` 1.0-8.0, ``PSC_VELZ_I`` 0.02-1.00,
  ``PSC_VELZ_D`` 0.00-1.00, ``PSC_ACCZ_P`` 0.200-1.500, ``PSC_ACCZ_I`` 0.000-3.000, ``PSC_ACCZ_D`` 0.000-0.400,
  ``PSC_ACCZ_IMAX`` 0-1000.
* ArduSub >= 4.7, the same file after the rename (``AP_SUBGROUPINFO(_p_pos_d_m, "_D_POS_", 2, ...)``):
  ``PSC_D_POS_P`` 0.50-4.00, ``PSC_D_VEL_P`` 1.0-10.0, ``PSC_D_VEL_I`` 0.00-10.0, ``PSC_D_VEL_D`` 0.00-2.00,
  ``PSC_D_VEL_IMAX`` 1-10, ``PSC_D_ACC_P`` 0.010-0.250, ``PSC_D_ACC_I`` 0.000-0.500, ``PSC_D_ACC_D``
  0.000-0.100, ``PSC_D_ACC_IMAX`` 0.0-1.0.

Names and units from 4.7 (``AC_PosControl::convert_parameters``, "PARAMETER_CONVERSION - Added: Nov-2024 for
4.7"):

* ``PSC_POSZ_P`` -> ``PSC_D_POS_P`` unscaled: the group keeps index 2 (``"_POSZ_", 2`` became ``"_D_POS_", 2``), so
  the stored value is the same parameter under a new name; no conversion entry is needed or present;
* ``conversion_info`` (moved, unscaled): ``PSC_VELZ_P/I/D/FLTE/FLTD/FF`` -> ``PSC_D_VEL_*``, ``PSC_ACCZ_FF``,
  ``_FLTT``, ``_FLTE``, ``_FLTD``, ``_SMAX``, ``_PDMX``, ``_D_FF``, ``_NEF``, ``_NTF`` -> ``PSC_D_ACC_*``;
* ``conversion_info_01`` (``convert_old_parameters_scaled(..., 0.1, 0)``): ``PSC_ACCZ_P/I/D`` -> ``PSC_D_ACC_P/I/D``
  times 0.1 (the accel controller now takes m/s^2 and gives throttle directly, where 4.6 took cm/s^2 and
  multiplied its output by 0.001);
* ``conversion_info_001`` (x 0.01): ``PSC_VELZ_IMAX`` -> ``PSC_D_VEL_IMAX`` (cm/s^2 -> m/s^2);
* ``psc_d_acc_imax_info`` (x 0.001): ``PSC_ACCZ_IMAX`` -> ``PSC_D_ACC_IMAX``.

``PSC_ACCZ_FF``, ``PSC_ACCZ_PDMX`` and ``PSC_ACCZ_D_FF`` are moved *unscaled* by the code while their new
``@Description`` says "If upgrading from 4.6 this is _ACCZ_FF * 0.1" (resp. ``_ACCZ_P * 0.1``): the source
contradicts itself, so this module refuses to write them for 4.7+ (:class:`UnverifiedConversion`) rather than
guess. The ``ATC_*`` names are unchanged in 4.7 (``AC_AttitudeControl_Sub::var_info`` above).
"""
from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass

#: the first ArduSub version with the PSC_D_* / PSC_NE_* names
RENAME_VERSION = (4, 7)

_ATC = "AC_AttitudeControl_Sub.cpp var_info (ArduPilot master 00f02a67)"
_ANG = "AC_AttitudeControl.cpp var_info @Range{Sub} (ArduPilot master 00f02a67)"
_PSC46 = "AC_PosControl.cpp var_info (ArduPilot <= 4.6)"
_PSC47 = "AC_PosControl.cpp var_info (ArduPilot >= 4.7, after the PSC_D_* rename)"

#: name -> (low, high, source) in the firmware's own names and units; ATC_* apply to every version
_ATC_RANGES = {
    "ATC_ANG_RLL_P": (0.0, 12.0, _ANG), "ATC_ANG_PIT_P": (0.0, 12.0, _ANG), "ATC_ANG_YAW_P": (0.0, 6.0, _ANG),
    **{f"ATC_RAT_{a}_{k}": (0.0, hi, _ATC) for a in ("RLL", "PIT")
       for k, hi in (("P", 0.30), ("I", 0.5), ("D", 0.02), ("IMAX", 1.0), ("FF", 0.5))},
    **{f"ATC_RAT_YAW_{k}": (0.0, hi, _ATC)
       for k, hi in (("P", 0.50), ("I", 0.05), ("D", 0.02), ("IMAX", 1.0), ("FF", 0.5))},
}
_PSC_RANGES_46 = {
    "PSC_POSZ_P": (1.0, 3.0, _PSC46), "PSC_VELZ_P": (1.0, 8.0, _PSC46), "PSC_VELZ_I": (0.02, 1.0, _PSC46),
    "PSC_VELZ_D": (0.0, 1.0, _PSC46), "PSC_ACCZ_P": (0.2, 1.5, _PSC46), "PSC_ACCZ_I": (0.0, 3.0, _PSC46),
    "PSC_ACCZ_D": (0.0, 0.4, _PSC46), "PSC_ACCZ_IMAX": (0.0, 1000.0, _PSC46),
}
_PSC_RANGES_47 = {
    "PSC_D_POS_P": (0.5, 4.0, _PSC47), "PSC_D_VEL_P": (1.0, 10.0, _PSC47), "PSC_D_VEL_I": (0.0, 10.0, _PSC47),
    "PSC_D_VEL_D": (0.0, 2.0, _PSC47), "PSC_D_VEL_IMAX": (1.0, 10.0, _PSC47), "PSC_D_ACC_P": (0.01, 0.25, _PSC47),
    "PSC_D_ACC_I": (0.0, 0.5, _PSC47), "PSC_D_ACC_D": (0.0, 0.1, _PSC47), "PSC_D_ACC_IMAX": (0.0, 1.0, _PSC47),
}

#: canonical (<= 4.6) name -> (4.7 name, scale: 4.7 value = scale x 4.6 value), as convert_parameters moves them
_RENAMES_47 = {
    "PSC_POSZ_P": ("PSC_D_POS_P", 1.0),
    **{f"PSC_VELZ_{k}": (f"PSC_D_VEL_{k}", 1.0) for k in ("P", "I", "D", "FLTE", "FLTD", "FF")},
    "PSC_VELZ_IMAX": ("PSC_D_VEL_IMAX", 0.01),
    **{f"PSC_ACCZ_{k}": (f"PSC_D_ACC_{k}", 0.1) for k in ("P", "I", "D")},
    "PSC_ACCZ_IMAX": ("PSC_D_ACC_IMAX", 0.001),
    **{f"PSC_ACCZ_{k}": (f"PSC_D_ACC_{k}", 1.0) for k in ("FLTT", "FLTE", "FLTD", "SMAX", "NEF", "NTF")},
}
#: moved unscaled by convert_parameters but documented as x 0.1: not written for 4.7+ (see the module notes)
UNVERIFIED_47 = {"PSC_ACCZ_FF": "PSC_D_ACC_FF", "PSC_ACCZ_PDMX": "PSC_D_ACC_PDMX", "PSC_ACCZ_D_FF": "PSC_D_ACC_D_FF"}

_VERSION = re.compile(r"(?:ArduSub\s+)?V?(\d+)\.(\d+)(?:\.(\d+))?", re.IGNORECASE)
_VERSION_IN_TEXT = re.compile(r"ArduSub\s+V(\d+)\.(\d+)(?:\.(\d+))?", re.IGNORECASE)


class UnverifiedConversion(ValueError):
    """A parameter whose conversion to the target firmware's units is not established by the source."""


@dataclass(frozen=True)
class Firmware:
    """An ArduSub firmware version and where it was read.

    Attributes
    ----------
    major, minor, patch : int
    source : str
        Where the version came from (``--firmware``, the run's sidecar ``firmware`` field, a log text, or
        ``assumed`` when nothing said it).
    """

    major: int
    minor: int
    patch: int = 0
    source: str = ""

    @property
    def renamed(self) -> bool:
        """True from 4.7: ``PSC_D_POS_P``, ``PSC_D_VEL_*``, ``PSC_D_ACC_*``."""
        return (self.major, self.minor) >= RENAME_VERSION

    @property
    def label(self) -> str:
        return f"ArduSub {self.major}.{self.minor}.{self.patch}"


#: what the design writes for when nothing names the firmware: the <= 4.6 names (every ArduSub release a
#: BlueROV2 ships with before 4.7), said so in the output
ASSUMED_FIRMWARE = Firmware(4, 5, 0, "assumed: no firmware version in the log or on the command line")


def parse_firmware(text: str, source: str = "") -> Firmware:
    """A firmware version from ``4.7``, ``4.5.2``, ``V4.1.0`` or ``ArduSub V4.5.2 (abcd1234)``.

    Raises
    ------
    ValueError
        When ``text`` holds no ``MAJOR.MINOR`` version.
    """
    m = _VERSION.search(str(text))
    if not m:
        raise ValueError(f"firmware {text!r}: expected a version such as 4.5, 4.7.0 or 'ArduSub V4.1.0'")
    return Firmware(int(m.group(1)), int(m.group(2)), int(m.group(3) or 0), source or str(text))


def firmware_of_run(metadata: Mapping) -> Firmware | None:
    """The firmware version a converted run's sidecar names: its ``firmware`` field (the converter writes the
    log's ``ArduSub V...`` text there), else an ``ArduSub V...`` text in its ``notes``; None if neither."""
    value = metadata.get("firmware")
    if value:
        return parse_firmware(str(value), f"the run's sidecar: firmware {value!r}")
    m = _VERSION_IN_TEXT.search(str(metadata.get("notes") or ""))
    if m:
        return Firmware(int(m.group(1)), int(m.group(2)), int(m.group(3) or 0),
                        f"the run's sidecar notes: {m.group(0)!r}")
    return None


def firmware_name(name: str, firmware: Firmware) -> tuple:
    """(name, scale): what ``firmware`` calls the canonical parameter ``name`` and the factor from the canonical
    value to its value.

    Raises
    ------
    UnverifiedConversion
        For a 4.7+ firmware and a parameter whose rescale the source does not establish.
    """
    if not firmware.renamed:
        return name, 1.0
    if name in UNVERIFIED_47:
        raise UnverifiedConversion(
            f"{name}: {firmware.label} renamed it {UNVERIFIED_47[name]}, and ArduPilot's AC_PosControl.cpp moves it "
            f"unscaled (convert_parameters' conversion_info) while its @Description says x 0.1; not written for "
            f"this version rather than guessed")
    return _RENAMES_47.get(name, (name, 1.0))


def to_firmware(values: Mapping, firmware: Firmware) -> dict:
    """Canonical name -> value to the names and units ``firmware`` loads (raises :class:`UnverifiedConversion`)."""
    out = {}
    for name, value in values.items():
        new, scale = firmware_name(name, firmware)
        out[new] = float(value) * scale
    return out


def from_firmware(params: Mapping, firmware: Firmware | None = None) -> dict:
    """A parameter dict in a firmware's names and units -> the canonical ones (what :mod:`.params` reads).

    4.7 names are recognised whatever ``firmware`` says (a log holds the names its firmware uses); when a log
    holds both a 4.7 name and its old one, the 4.7 value is the live one for a 4.7+ ``firmware`` (the old one
    is a leftover of the conversion), the old one otherwise.
    """
    inverse = {new: (old, scale) for old, (new, scale) in _RENAMES_47.items() if new != old}
    inverse.update({new: (old, None) for old, new in UNVERIFIED_47.items()})
    renamed = firmware.renamed if firmware is not None else False
    out = {k: float(v) for k, v in params.items() if k not in inverse}
    for new, (old, scale) in inverse.items():
        if new not in params or scale is None:
            continue
        if old in params and not renamed:
            continue
        out[old] = float(params[new]) / scale
    return out


def gain_range(name: str, firmware: Firmware) -> tuple:
    """(low, high, source) of a canonical parameter in canonical units, as ``firmware`` documents it (None when
    ArduSub documents no range for it)."""
    if name in _ATC_RANGES:
        return _ATC_RANGES[name]
    if not firmware.renamed:
        return _PSC_RANGES_46.get(name)
    new, scale = _RENAMES_47.get(name, (name, 1.0))
    r = _PSC_RANGES_47.get(new)
    return None if r is None else (r[0] / scale, r[1] / scale, r[2])


@dataclass(frozen=True)
class RangeViolation:
    """A gain outside the range its firmware documents (canonical name and units; ``firmware_name`` and the
    firmware's own value and range for the sentence)."""

    name: str
    value: float
    low: float
    high: float
    source: str
    firmware_name: str
    scale: float

    def sentence(self) -> str:
        v, lo, hi = self.value * self.scale, self.low * self.scale, self.high * self.scale
        return (f"{self.firmware_name} = {v:.4g} is outside ArduSub's documented range {lo:g}-{hi:g} "
                f"({self.source})")


def range_violations(values: Mapping, firmware: Firmware, rel_tol: float = 1e-6) -> list:
    """The gains of ``values`` (canonical names and units) outside ``firmware``'s documented ranges."""
    out = []
    for name, value in values.items():
        r = gain_range(name, firmware)
        if r is None or not math.isfinite(float(value)):
            continue
        lo, hi, src = r
        tol = rel_tol * max(abs(lo), abs(hi), 1e-12)
        if float(value) < lo - tol or float(value) > hi + tol:
            try:
                new, scale = firmware_name(name, firmware)
            except UnverifiedConversion:
                new, scale = name, 1.0
            out.append(RangeViolation(name, float(value), lo, hi, src, new, scale))
    return out


__all__ = ["ASSUMED_FIRMWARE", "Firmware", "RENAME_VERSION", "RangeViolation", "UNVERIFIED_47", "UnverifiedConversion",
           "firmware_name", "firmware_of_run", "from_firmware", "gain_range", "parse_firmware", "range_violations",
           "to_firmware"]
