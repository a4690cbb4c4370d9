"""Run logs in the ``udrobot-run/1`` format (docs/formats/runlog.md): read, validate, write, resample.

A run is one logged manoeuvre: a CSV ``NAME.csv`` (one header row, one row per sample, SI units,
radians) and an optional sidecar ``NAME.json`` with the set-up metadata.

Reading is strict. Every rejection raises :class:`RunLogError` naming the file, the row and the
column. Rows are counted two ways and both are given: the *data row* (1-based, the header is not
counted) and the *file line* (1-based physical line of the file, the header is line 1).
A reader never drops a row: the returned run has exactly one sample per data line of the file.

Choices the spec leaves open (stated here so callers can rely on them):

- Header names are stripped of surrounding white space; a UTF-8 byte-order mark is accepted.
- A file must hold at least one data row. Blank lines are accepted only at the end of the file.
- Numeric cells are ASCII decimal numbers (``1``, ``-2.5``, ``3e-4``). Empty cells and ``nan``
  (any case, optional sign) mean "not measured". ``inf``, ``1_000``, hex or non-ASCII digits are rejected.
- ``t`` must be finite in every row (a sample without a time cannot be placed).
- Input cells may be empty/``nan`` (command not logged at that sample); they are never invented here.
- If more than one complete input set is present (e.g. ``thrust_i`` *and* ``pwm_i``), the first in the
  order thrust, pwm, tau is the run's input and the others are kept in :attr:`Run.extra`.
  A partial set (``tau_X`` without ``tau_Y``..., or ``thrust_1, thrust_3`` without ``thrust_2``) is an error.
- Unknown columns are kept in :attr:`Run.extra`: as a float array when every cell is numeric or
  empty (infinities allowed there, since the column is ignored), else as an array of the raw strings.
- The optional ``segment`` column (the stretch of a cut field log a row belongs to) is kept in
  :attr:`Run.extra` like other columns, so every row selection carries it, but it is validated: an integer in every
  row, non-decreasing (:func:`check_segments`). :attr:`Run.segment` and :meth:`Run.segment_bounds` expose it,
  :func:`split_segments` cuts a run into one run per segment (each replayed from its own first row), and the time
  gap check does not judge the interval between two segments (the rows cut there are not in the file).
"""
from __future__ import annotations

import csv
import json
import math
import os
import re
import unicodedata
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from udrobot_ctrl.ardusub.modes import Mode
from udrobot_ctrl.ardusub.params import ESTIMATED_PARAMS, LOGGED_PARAMS, ParameterError, check_log_params
from udrobot_ctrl.constants import STATE_NAMES
from udrobot_files import output as files
from udrobot_files.nesting import NestingError, loads_json, unique_keys

FORMAT = "udrobot-run/1"
STATE_CHANNELS = STATE_NAMES  # the run's state columns are the plant's states, in its order
OTHER_CHANNELS = ("altitude", "voltage", "ax", "ay", "az")
#: ESC pulse widths a ``pwm_i`` cell may hold, us: ArduPilot's servo output range (``SRV_Channel.cpp``,
#: ``SERVOn_MIN`` / ``SERVOn_MAX`` ``@Range: 500 2200``). 0 is MAVLink's "no pulse" on a disabled output, not a command.
PWM_RANGE_US = (500.0, 2200.0)
#: Battery voltages a ``voltage`` cell may hold, V: above 0 and at most 60 V, the DC limit of safety extra-low
#: voltage (IEC 61140), which small-ROV batteries stay under (assumed: a BlueROV2's 4S pack is 12.8-16.8 V).
VOLTAGE_RANGE_V = (0.0, 60.0)
CHANNELS = STATE_CHANNELS + OTHER_CHANNELS
ANGLE_CHANNELS = ("phi", "theta", "psi")
TAU_COLUMNS = ("tau_X", "tau_Y", "tau_Z", "tau_K", "tau_M", "tau_N")
INPUT_KINDS = ("thrust", "pwm", "tau")
METADATA_KEYS = ("format", "vehicle", "water_density", "seabed_depth", "walls", "notes")
#: the optional integer column naming the contiguous stretch (segment) of a log each row belongs to
SEGMENT = "segment"
#: largest segment number accepted: integers of a float64 column are exact up to 2**53
_SEGMENT_MAX = 2.0 ** 53
#: the sidecar's ``channels`` kinds: a sensor; a filter aided by a sensor of that quantity (or of its rate); dead
#: reckoning (no sensor of it fed the estimate: shown, never fitted, scored or counted as observed)
MEASURED, ESTIMATED, UNAIDED = "measured", "estimated", "estimated-unaided"
CHANNEL_KINDS = (MEASURED, ESTIMATED, UNAIDED)

_INDEXED_INPUT = re.compile(r"^(thrust|pwm)_(\d+)$")
_NUMBER = re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?$", re.ASCII)  # ASCII digits only (not '٣', '３')
_NAN = re.compile(r"^[+-]?nan$", re.IGNORECASE)
_INF = re.compile(r"^[+-]?(inf|infinity)$", re.IGNORECASE)


class RunLogError(ValueError):
    """A run log (CSV or sidecar) that does not follow ``udrobot-run/1``; the message names file, row, column."""


@dataclass
class Run:
    """One run: sample times, measured channels, commanded inputs, unknown columns and metadata.

    Attributes
    ----------
    path : str
        File the run was read from ('' if built in memory).
    t : (n,) ndarray
        Sample times, s, strictly increasing.
    channels : dict of str -> (n,) ndarray
        Measured channels present in the file among :data:`CHANNELS` (SI units, rad); nan where not measured.
    input_kind : str
        'thrust' (N), 'pwm' (µs) or 'tau' (N, N m).
    inputs : (n, k) ndarray
        Commanded inputs, columns :attr:`input_names`; held constant on [t_k, t_k+1).
    extra : dict of str -> ndarray
        Unknown columns, kept and ignored; and the optional ``segment`` column (validated, :attr:`segment`).
    metadata : dict
        Validated sidecar content ({} if there is no sidecar).
    """

    path: str
    t: np.ndarray
    channels: dict
    input_kind: str
    inputs: np.ndarray
    extra: dict = field(default_factory=dict)
    metadata: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.t.shape[0])

    @property
    def input_names(self) -> tuple:
        """Column names of :attr:`inputs` (``thrust_1``.. / ``pwm_1``.. / ``tau_X``..)."""
        return input_column_names(self.input_kind, self.inputs.shape[1])

    @property
    def duration(self) -> float:
        """Time span t[-1] - t[0], s (0 for a single sample)."""
        return float(self.t[-1] - self.t[0]) if self.n else 0.0

    @property
    def dt_median(self) -> float:
        """Median sample interval, s (nan with fewer than two samples)."""
        return float(np.median(np.diff(self.t))) if self.n >= 2 else float("nan")

    def channel(self, name: str) -> np.ndarray:
        """Samples of one column by name: a measured channel (all-nan if the file lacks it), an input or an extra.

        Raises
        ------
        KeyError
            If ``name`` is neither a ``udrobot-run/1`` channel nor an input/extra column of this run.
        """
        if name in self.channels:
            return self.channels[name]
        if name in CHANNELS:
            return np.full(self.n, np.nan)
        names = self.input_names
        if name in names:
            return self.inputs[:, names.index(name)]
        if name in self.extra:
            return self.extra[name]
        raise KeyError(f"{self.path or 'run'}: no column '{name}' (known channels: {', '.join(CHANNELS)}; "
                       f"inputs: {', '.join(names)}; extra: {', '.join(self.extra) or 'none'})")

    def battery_voltage(self, default: float) -> np.ndarray:
        """(n,) battery voltage, V: the logged ``voltage`` channel, ``default`` (the model's supply voltage) where a
        sample is not finite or the run has no such column (the T-200 curve's voltage for the run's PWM)."""
        v = self.channels.get("voltage")
        if v is None:
            return np.full(self.n, float(default))
        v = np.asarray(v, float)
        return np.where(np.isfinite(v), v, float(default))

    def state_matrix(self) -> np.ndarray:
        """(n, 12) state [x y z phi theta psi u v w p q r] (m, rad, m/s, rad/s); nan where not measured."""
        return np.column_stack([self.channel(name) for name in STATE_CHANNELS]) if self.n else np.zeros((0, 12))

    @property
    def segment(self) -> np.ndarray | None:
        """(n,) int64 segment number of each row (the ``segment`` column), or None when the run has none (then the
        whole run is one segment)."""
        seg = self.extra.get(SEGMENT)
        return None if seg is None else np.asarray(seg, float).astype(np.int64)

    def segment_bounds(self) -> list:
        """[start, stop) row ranges of the run's segments, in order ([(0, n)] without a ``segment`` column)."""
        return segment_bounds(self.segment, self.n)


def input_column_names(input_kind: str, k: int) -> tuple:
    """Column names for ``k`` inputs of kind 'thrust' | 'pwm' | 'tau'."""
    if input_kind == "tau":
        if k != 6:
            raise RunLogError(f"tau inputs need exactly 6 columns ({', '.join(TAU_COLUMNS)}), got {k}")
        return TAU_COLUMNS
    if input_kind not in INPUT_KINDS:
        raise RunLogError(f"input_kind must be one of {INPUT_KINDS}, got {input_kind!r}")
    return tuple(f"{input_kind}_{i}" for i in range(1, k + 1))


def segment_bounds(segment, n: int) -> list:
    """[start, stop) row ranges where ``segment`` (n,) keeps one value, in order; [(0, n)] when it is None.

    Parameters
    ----------
    segment : (n,) array_like of int or None
        Segment number per row (non-decreasing, :func:`check_segments`).
    n : int
        Rows.
    """
    if segment is None or n == 0:
        return [(0, n)] if n else []
    seg = np.asarray(segment)
    cuts = np.flatnonzero(seg[1:] != seg[:-1]) + 1
    edges = [0, *cuts.tolist(), n]
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def segment_breaks(segment, n: int) -> np.ndarray:
    """(n - 1,) bool: True for the interval between rows k and k + 1 when they belong to different segments (the
    rows cut between them are not in the run: no replay, derivative or gap check spans such an interval)."""
    if segment is None or n < 2:
        return np.zeros(max(n - 1, 0), bool)
    seg = np.asarray(segment)
    return seg[1:] != seg[:-1]


def check_segments(values, path="run", lines=None) -> np.ndarray:
    """The ``segment`` column checked: an integer in every row (no empty cell, no fraction), non-decreasing (a
    segment is one contiguous stretch of rows). Returns it as int64.

    Parameters
    ----------
    values : (n,) array_like
        The column as read (float, or text when a cell was not a number).
    path : str
        File named in the error.
    lines : (n,) array_like of int, optional
        File line of each row (named in the error).

    Raises
    ------
    RunLogError
        Naming the file, the data row (and file line) and the column ``segment``.
    """
    arr = np.asarray(values)

    def where(i):
        return _where(path, row=i + 1, line=None if lines is None else int(lines[i]), column=SEGMENT)

    if arr.dtype.kind not in "biuf":
        for i, cell in enumerate(arr):
            value = _parse_cell(str(cell))
            if value is None:
                raise RunLogError(f"{where(i)}: non-numeric cell {str(cell)[:40]!r}; expected an integer segment "
                                  f"number in every row")
        arr = np.array([_parse_cell(str(c)) for c in arr], float)
    arr = arr.astype(float)
    bad = np.flatnonzero(~np.isfinite(arr) | (np.abs(arr) > _SEGMENT_MAX) | (arr != np.round(arr)))
    if bad.size:
        i = int(bad[0])
        what = "empty/nan" if np.isnan(arr[i]) else repr(float(arr[i]))
        raise RunLogError(f"{where(i)}: segment {what}; expected an integer segment number in every row (the "
                          f"stretch of the log the row belongs to)")
    down = np.flatnonzero(np.diff(arr) < 0)
    if down.size:
        i = int(down[0]) + 1
        raise RunLogError(f"{where(i)}: segment {int(arr[i])} follows segment {int(arr[i - 1])}; segment numbers "
                          f"must not decrease (each segment is one contiguous stretch of rows)")
    return arr.astype(np.int64)


def split_segments(run: Run) -> list:
    """One :class:`Run` per segment of ``run`` (the run itself when it has one segment), each replayed from its own
    first row: the single place the replays (``simulate``, ``simulate --windows``, ``diagnose``) get their stretches
    from. A part is labelled ``PATH[segment k]`` (k its segment number) and keeps the sidecar metadata."""
    bounds = run.segment_bounds()
    if len(bounds) <= 1:
        return [run]
    seg = run.segment
    return [replace(run, path=f"{run.path or 'run'}[segment {int(seg[a])}]", t=run.t[a:b],
                    channels={c: v[a:b] for c, v in run.channels.items()}, inputs=run.inputs[a:b],
                    extra={c: v[a:b] for c, v in run.extra.items()}, metadata=run.metadata)
            for a, b in bounds]


# ----------------------------------------------------------------------------------------------- reading


#: the autopilot context columns a closed-loop flight reads (docs/formats/runlog.md): numbers, or empty cells
CONTEXT_NUMERIC = ("mode", "armed", *(f"rcin_{k}" for k in range(1, 9)), "roll_target", "pitch_target", "yaw_target",
                   "z_target")
MODE_NAMES = ", ".join(f"{int(m)} {m.name}" for m in Mode)


def check_context_columns(extra: dict, path="run", lines=None) -> None:
    """The autopilot context columns checked where they enter: numbers (or empty cells) in each of
    :data:`CONTEXT_NUMERIC`; every ``mode`` an ArduSub mode number (``ArduSub/mode.h`` ``Mode::Number``, the
    ``control_mode_t`` of ``defines.h`` before 4.1: :class:`~udrobot_ctrl.ardusub.modes.Mode`), never rounded or
    read as another mode; ``armed`` 0 or 1. The RC inputs' "no pulse" (0) and "unused" (65535) sentinels are
    values, read as a centred stick by :func:`~udrobot_ctrl.ardusub.modes.pilot_pulses`.

    Raises
    ------
    RunLogError
        Naming the file, the data row (and file line), the column and what was expected.
    """
    def where(i, column):
        return _where(path, row=i + 1, line=None if lines is None else int(lines[i]), column=column)

    for column in CONTEXT_NUMERIC:
        if column in extra and np.asarray(extra[column]).dtype.kind not in "biuf":
            cells = np.asarray(extra[column])
            i = next(i for i, c in enumerate(cells) if _parse_cell(str(c)) is None)
            raise RunLogError(f"{where(i, column)}: non-numeric cell {str(cells[i])[:40]!r}; expected a number or an "
                              f"empty cell (docs/formats/runlog.md, autopilot context columns)")
    if "mode" in extra:
        mode = np.asarray(extra["mode"], float)
        known = np.array([int(m) for m in Mode], float)
        bad = np.isfinite(mode) & ~np.isin(mode, known) | np.isinf(mode)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise RunLogError(f"{where(i, 'mode')}: {mode[i]:g} is not an ArduSub flight mode; expected one of "
                              f"{MODE_NAMES} (ArduSub/mode.h Mode::Number) or an empty cell")
    if "armed" in extra:
        armed = np.asarray(extra["armed"], float)
        bad = ~np.isnan(armed) & ~np.isin(armed, (0.0, 1.0))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise RunLogError(f"{where(i, 'armed')}: {armed[i]:g}; expected 1 (armed), 0 (disarmed) or an empty cell")


def pulses_outside_range(pwm) -> np.ndarray:
    """Mask of the ESC pulses (us) outside :data:`PWM_RANGE_US`, infinite ones included; nan (not logged) is not."""
    pwm = np.asarray(pwm, float)
    lo, hi = PWM_RANGE_US
    with np.errstate(invalid="ignore"):
        return (pwm < lo) | (pwm > hi)


def voltages_outside_range(volts) -> np.ndarray:
    """Mask of the battery voltages (V) outside :data:`VOLTAGE_RANGE_V` (above 0, at most 60); nan is not."""
    volts = np.asarray(volts, float)
    lo, hi = VOLTAGE_RANGE_V
    with np.errstate(invalid="ignore"):
        return (volts <= lo) | (volts > hi)


def check_measured_values(channels: dict, input_kind: str, inputs: np.ndarray, extra: dict, path="run",
                          lines=None) -> None:
    """The cells whose physical range is known checked where they enter: every ``pwm_i`` (the run's input or
    an extra column) within :data:`PWM_RANGE_US` (:func:`pulses_outside_range`), every ``voltage`` within
    :data:`VOLTAGE_RANGE_V` (:func:`voltages_outside_range`). Empty cells stay "not measured".

    Raises
    ------
    RunLogError
        Naming the file, the data row (and file line), the column, the value and the range expected.
    """
    def where(i, column):
        return _where(path, row=i + 1, line=None if lines is None else int(lines[i]), column=column)

    columns = {}
    if input_kind == "pwm":
        columns.update({f"pwm_{k + 1}": inputs[:, k] for k in range(inputs.shape[1])})
    columns.update({c: np.asarray(v, float) for c, v in extra.items()
                    if _INDEXED_INPUT.match(c) and c.startswith("pwm_") and np.asarray(v).dtype.kind == "f"})
    lo, hi = PWM_RANGE_US
    for column, values in columns.items():
        bad = pulses_outside_range(values)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            zero = " (0 is MAVLink's 'no pulse' of a disabled output, not an ESC command)" if values[i] == 0 else ""
            raise RunLogError(f"{where(i, column)}: {values[i]:g} us{zero}; expected an ESC pulse width in "
                              f"{lo:g}..{hi:g} us (ArduPilot SERVOn_MIN/MAX range) or an empty cell")
    if "voltage" in channels:
        v = np.asarray(channels["voltage"], float)
        bad = voltages_outside_range(v)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            lo, hi = VOLTAGE_RANGE_V
            raise RunLogError(f"{where(i, 'voltage')}: {v[i]:g} V; expected a battery voltage above {lo:g} V and "
                              f"at most {hi:g} V (the safety extra-low voltage limit) or an empty cell")


def _where(path, row=None, line=None, column=None) -> str:
    parts = [str(path)]
    if row is not None:
        parts.append(f"data row {row}" + (f" (file line {line})" if line is not None else ""))
    elif line is not None:
        parts.append(f"file line {line}")
    if column is not None:
        parts.append(f"column '{column}'")
    return ": ".join(parts)


def non_ascii_digits(text: str) -> str:
    """``" (non-ASCII digit U+0663 ARABIC-INDIC DIGIT THREE)"`` for the first digit of ``text`` outside 0-9 (which
    Python's ``float`` would read as a number, but no log writes), else ``""``: for error messages."""
    for ch in text:
        if ch.isdigit() and not ch.isascii():
            return f" (non-ASCII digit U+{ord(ch):04X} {unicodedata.name(ch, '?')}: numbers must use the digits 0-9)"
    return ""


def separator_hint(header: list) -> str:
    """``" (the header is semicolon-separated: the file must be comma-separated)"`` when a one-cell header holds
    another common separator (semicolon, tab, pipe) instead of commas, else ``""``: for error messages.

    Parameters
    ----------
    header : list of str
        The header row as a comma-separated reader split it.

    Returns
    -------
    str
        The hint, with a leading space, or the empty string.
    """
    if len(header) != 1:
        return ""
    for sep, name in ((";", "semicolon"), ("\t", "tab"), ("|", "pipe")):
        if sep in header[0]:
            return f" (the header is {name}-separated: the file must be comma-separated)"
    return ""


def _parse_cell(text: str):
    """Return a float (nan for empty/nan), or None if the cell is not a finite number / empty / nan.

    Infinite values come back as +-inf so the caller can name them.
    """
    s = text.strip()
    if s == "" or _NAN.match(s):
        return math.nan
    if _NUMBER.match(s):
        value = float(s)
        return value  # may overflow to inf (1e999): the caller rejects it as an infinity
    if _INF.match(s):
        return float(s)
    return None


def _bad_utf8(path: Path):
    """(byte offset, file line, reason) of the first byte that is not UTF-8, or None; reads in 1 MiB blocks."""
    carry, base, newlines = b"", 0, 0
    with open(path, "rb") as fh:
        while True:
            block = fh.read(1 << 20)
            data = carry + block
            if not data:
                return None
            try:
                data.decode("utf-8")
            except UnicodeDecodeError as exc:
                if block and exc.reason == "unexpected end of data":
                    carry = data[exc.start:]
                    newlines += data[:exc.start].count(b"\n")
                    base += exc.start
                    continue
                return base + exc.start, newlines + data[:exc.start].count(b"\n") + 1, exc.reason
            carry, base, newlines = b"", base + len(data), newlines + data.count(b"\n")
            if not block:
                return None


def _count_lines(path: Path) -> int:
    """Number of newline characters in the file (an upper bound on the data rows + 1), in 4 MiB blocks."""
    n = 0
    with open(path, "rb") as fh:
        while block := fh.read(1 << 22):
            n += block.count(b"\n")
    return n


def _map_header(path, header: list) -> tuple:
    """Validate the header; return (names, input_kind, input_columns, channel_columns, extra_columns)."""
    names = [h.strip() for h in header]
    seen = {}
    for j, name in enumerate(names, start=1):
        if name == "":
            raise RunLogError(f"{_where(path, line=1)}: header column {j} has an empty name")
        if "\x00" in name:
            raise RunLogError(f"{_where(path, line=1)}: header column {j} contains a NUL byte")
        if name in seen:
            raise RunLogError(f"{_where(path, line=1, column=name)}: duplicate column (header columns {seen[name]} "
                              f"and {j})")
        seen[name] = j
    if "t" not in seen:
        raise RunLogError(f"{_where(path, line=1)}: no 't' column in the header {names[:12]!r}"
                          f"{' ...' if len(names) > 12 else ''}; expected 't' (s) plus inputs and channels"
                          f"{separator_hint(names)}")
    sets = {}
    for kind in ("thrust", "pwm"):
        indices = sorted(int(m.group(2)) for m in map(_INDEXED_INPUT.match, names) if m and m.group(1) == kind)
        if not indices:
            continue
        expected = list(range(1, len(indices) + 1))
        if indices != expected:
            missing = sorted(set(range(1, max(indices) + 1)) - set(indices))
            if missing:
                raise RunLogError(f"{_where(path, line=1, column=f'{kind}_{missing[0]}')}: missing input column; "
                                  f"{kind}_1..{kind}_N must be contiguous (found {kind}_{indices})")
            raise RunLogError(f"{_where(path, line=1)}: {kind} columns must be numbered 1..N without leading "
                              f"zeros or gaps (found {kind}_{indices})")
        cols = [f"{kind}_{i}" for i in expected]
        absent = [c for c in cols if c not in seen]  # e.g. 'thrust_01' maps to 1 but is not 'thrust_1'
        if absent:
            raise RunLogError(f"{_where(path, line=1, column=absent[0])}: missing input column (input columns must "
                              f"be named {kind}_1..{kind}_N without leading zeros)")
        sets[kind] = cols
    taus = [c for c in TAU_COLUMNS if c in seen]
    if taus:
        if len(taus) != 6:
            missing = [c for c in TAU_COLUMNS if c not in seen]
            raise RunLogError(f"{_where(path, line=1, column=missing[0])}: missing input column; all six "
                              f"{', '.join(TAU_COLUMNS)} are needed (found {', '.join(taus)})")
        sets["tau"] = list(TAU_COLUMNS)
    if not sets:
        raise RunLogError(f"{_where(path, line=1)}: missing input columns; expected all thrust_1..thrust_N, "
                          f"or all pwm_1..pwm_N, or all six {', '.join(TAU_COLUMNS)}")
    input_kind = next(k for k in INPUT_KINDS if k in sets)
    input_cols = sets[input_kind]
    channel_cols = [c for c in CHANNELS if c in seen]
    used = {"t", *input_cols, *channel_cols}
    extra_cols = [c for c in names if c not in used]
    return names, input_kind, input_cols, channel_cols, extra_cols


_CHUNK_ROWS = 4096  # rows parsed per batch: bounds the memory of the Python strings of one batch
_FAST_BAD = re.compile(r"[^0-9eE+\-.nNaA \t\x1f]")  # a numeric column holding only these parses with float()
MAX_GAP_S = 6 * 3600.0  # s; assumed: one run is one manoeuvre, a 6 h jump is a clock error (e.g. a UNIX-time stamp)
MAX_GAP_RATIO = 1.0e4   # a gap over 1e4 median steps (and over MIN_RATIO_GAP_S) is a clock error, not a pause
MIN_RATIO_GAP_S = 60.0  # s; below this a long pause of a fast log is accepted (work stays bounded)


def _fast_floats(cells: list):
    """Cells -> float64 via numpy when every cell is a plain decimal number, empty or nan; None otherwise.

    The character filter leaves only text that Python's ``float`` parses exactly like :func:`_parse_cell`
    (no ``inf``, hex, ``_`` or non-ASCII digits); anything else goes through the per-cell path.
    """
    if _FAST_BAD.search("\x1f".join(cells)):
        return None
    arr = np.array(cells)
    if arr.dtype.kind != "U":
        return None
    arr[np.char.str_len(arr) == 0] = "nan"
    try:
        return arr.astype(np.float64)
    except ValueError:
        return None


def _column_values(path, rows, j: int, name: str, strict: bool) -> np.ndarray:
    """Per-cell parse of column ``j`` of ``rows`` [(data row, file line, fields)]; names the first bad cell.

    Non-strict (extra columns): an object array of the raw strings if any cell is not numeric.
    """
    out = np.empty(len(rows))
    for i, (row, line, fields) in enumerate(rows):
        value = _parse_cell(fields[j])
        if value is None:
            if not strict:
                return np.array([f[j] for _, _, f in rows], dtype=object)
            raise RunLogError(f"{_where(path, row=row, line=line, column=name)}: non-numeric cell {fields[j][:40]!r}"
                              f"{non_ascii_digits(fields[j])}; expected a decimal number, or empty/nan when not "
                              f"measured")
        if strict and math.isinf(value):
            raise RunLogError(f"{_where(path, row=row, line=line, column=name)}: infinite value {fields[j][:40]!r}; "
                              f"expected a finite number, or empty/nan when not measured")
        out[i] = value
    return out


def _chunk_column(path, fields: list, lines: list, row0: int, j: int, name: str, strict: bool):
    """One column of a batch of rows: float64 (fast path), or the per-cell result (with its error)."""
    values = _fast_floats([f[j] for f in fields])
    if values is not None and not (strict and np.isinf(values).any()):
        return values
    rows = [(row0 + i + 1, lines[i], f) for i, f in enumerate(fields)]
    return _column_values(path, rows, j, name, strict)


def check_time_gaps(t: np.ndarray, path="run", lines=None, segment=None) -> None:
    """Reject a sample interval that no manoeuvre can have (a clock jump), naming the rows and the times.

    A gap is absurd when it exceeds :data:`MAX_GAP_S`, or :data:`MAX_GAP_RATIO` median steps and
    :data:`MIN_RATIO_GAP_S`. Simulating or resampling across such a gap would cost work proportional to it.
    With ``segment`` (the ``segment`` column), the intervals between two segments are not judged (nor counted in
    the median): the rows cut there are not in the run and nothing is replayed across them.

    Raises
    ------
    RunLogError
    """
    t = np.asarray(t, float)
    if t.size < 2:
        return
    dt = np.diff(t)
    within = ~segment_breaks(segment, t.size)
    if not within.any():
        return
    med = float(np.median(dt[within]))
    limit = min(MAX_GAP_S, max(MAX_GAP_RATIO * med, MIN_RATIO_GAP_S))
    bad = np.flatnonzero((dt > limit) & within)
    if bad.size:
        k = int(bad[0])
        line = None if lines is None else int(lines[k + 1])
        raise RunLogError(f"{_where(path, row=k + 2, line=line, column='t')}: t = {float(t[k + 1])!r} s follows "
                          f"{float(t[k])!r} s (data row {k + 1}): a gap of {dt[k]:.6g} s, {dt[k] / med:.3g} times the "
                          f"median step {med:.6g} s (limit {limit:.6g} s); a clock jump (e.g. a UNIX-time stamp) "
                          f"or two runs in one file: fix the time column or split the run")


class _Columns:
    """Preallocated float64 columns of the rows of a run, filled batch by batch."""

    def __init__(self, capacity: int, names: list, input_cols: list, extra_cols: list):
        self.t = np.empty(capacity)
        self.lines = np.empty(capacity, dtype=np.int64)
        self.channels = {c: np.empty(capacity) for c in names}
        self.inputs = np.empty((capacity, len(input_cols)))
        self.extra = {c: np.empty(capacity) for c in extra_cols}
        self.text_extra = set()  # extra columns holding non-numeric cells: re-read as strings at the end
        self.n = 0


def _process_chunk(path, cols: _Columns, fields: list, lines: list, index: dict, input_cols, channel_cols,
                   extra_cols) -> None:
    row0, m = cols.n, len(fields)
    sl = slice(row0, row0 + m)
    t = _chunk_column(path, fields, lines, row0, index["t"], "t", strict=True)
    nan = np.flatnonzero(np.isnan(t))
    if nan.size:
        i = int(nan[0])
        raise RunLogError(f"{_where(path, row=row0 + i + 1, line=lines[i], column='t')}: empty/nan time; every "
                          f"sample needs a finite time in s")
    prev = np.concatenate([cols.t[row0 - 1:row0], t[:-1]]) if row0 else t[:-1]
    later = t if row0 else t[1:]
    bad = np.flatnonzero(~(later > prev))
    if bad.size:
        i = int(bad[0]) + (0 if row0 else 1)
        before = float(cols.t[row0 - 1] if i == 0 else t[i - 1])
        raise RunLogError(f"{_where(path, row=row0 + i + 1, line=lines[i], column='t')}: t = {float(t[i])!r} s is not "
                          f"greater than the previous row's {before!r} s; t must be strictly increasing")
    cols.t[sl] = t
    cols.lines[sl] = lines
    for c in channel_cols:
        cols.channels[c][sl] = _chunk_column(path, fields, lines, row0, index[c], c, strict=True)
    for k, c in enumerate(input_cols):
        cols.inputs[sl, k] = _chunk_column(path, fields, lines, row0, index[c], c, strict=True)
    for c in extra_cols:
        if c in cols.text_extra:
            continue
        values = _chunk_column(path, fields, lines, row0, index[c], c, strict=False)
        if values.dtype == object:
            cols.text_extra.add(c)
        else:
            cols.extra[c][sl] = values
    cols.n += m


#: the longest line read, characters (assumed: a udrobot-run/1 row holds one sample, about 25 characters per
#: column, so the widest the writers produce, ~100 columns, is 2.5 kB; 1 Mi characters is 400 times that and
#: keeps a damaged file's single endless line from being held in memory several times over)
MAX_LINE_CHARS = 1 << 20


def _bounded_lines(fh, path: Path):
    """The lines of ``fh``, refusing one longer than :data:`MAX_LINE_CHARS` before it is read whole (memory stays
    bounded by the limit, not by the line)."""
    number = 0
    while True:
        line = fh.readline(MAX_LINE_CHARS + 1)
        if not line:
            return
        number += 1
        if len(line) > MAX_LINE_CHARS and not line.endswith("\n"):
            raise RunLogError(f"{_where(path, line=number)}: a line longer than {MAX_LINE_CHARS} characters; a "
                              f"udrobot-run/1 row is one sample (a few kB): a damaged file, or not a run log")
        yield line


def _rows(path: Path, fh, on_header):
    """Yield (file line, fields) of the data rows; reject ragged rows, blank lines inside the data and lines
    longer than :data:`MAX_LINE_CHARS`. File lines are 1-based, the header is line 1."""
    reader = csv.reader(_bounded_lines(fh, path), strict=True)
    n_rows = 0
    start = 1  # the file line where the record being parsed starts
    try:
        header = next(reader, None)
        if not header or (len(header) == 1 and header[0].strip() == ""):
            raise RunLogError(f"{path}: file line 1: empty file or empty header; expected a udrobot-run/1 header "
                              f"row starting with 't'")
        on_header(header)
        width = len(header)
        blank_at = None
        while True:
            start = reader.line_num + 1
            fields = next(reader, None)
            if fields is None:
                break
            line = reader.line_num
            if not fields or (width > 1 and len(fields) == 1 and fields[0].strip() == ""):
                blank_at = blank_at or line
                continue
            if blank_at is not None:
                raise RunLogError(f"{_where(path, line=blank_at)}: blank line inside the data (data resumes at file "
                                  f"line {line}); rows are never dropped, remove or fill the blank line")
            n_rows += 1
            if len(fields) != width:
                raise RunLogError(f"{_where(path, row=n_rows, line=line)}: {len(fields)} cells, the header has "
                                  f"{width}")
            yield line, fields
    except csv.Error as exc:  # found at line_num, in the record that starts at ``start``
        found = "" if reader.line_num <= start else f"; found at file line {reader.line_num}"
        raise RunLogError(f"{_where(path, row=n_rows + 1, line=start)}: malformed CSV ({exc}{found})") from exc


def _open_text(path: Path):
    if path.is_dir():
        raise RunLogError(f"{path}: is a directory, expected a udrobot-run/1 CSV file")
    return open(path, encoding="utf-8-sig", newline="")


def _text_columns(path: Path, names: list, index: dict, n: int) -> dict:
    """Second pass: the raw strings of the named (extra) columns."""
    out = {c: np.empty(n, dtype=object) for c in names}
    with _open_text(path) as fh:
        for i, (_line, fields) in enumerate(_rows(path, fh, lambda h: None)):
            for c in names:
                out[c][i] = fields[index[c]]
    return out


def read_run(path, progress: bool | None = None) -> Run:
    """Read and validate a ``udrobot-run/1`` CSV and its optional sidecar ``NAME.json``.

    The file is parsed in batches into preallocated float64 arrays, so memory stays near the size of the
    arrays (8 bytes per numeric cell) plus one batch of text, whatever the file size.

    Parameters
    ----------
    path : str or Path
        The CSV file. The file is only read, never modified.
    progress : bool or None
        Show a progress bar (None: only on a terminal, and only for files over 50 MB).

    Returns
    -------
    Run
        Times (s), channels (SI), inputs, extra columns and the sidecar's metadata.

    Raises
    ------
    RunLogError
        On any violation of the spec (including an absurd time gap, :func:`check_time_gaps`); the message
        names file, data row / file line and column.
    FileNotFoundError
        If the file does not exist.
    """
    path = Path(path)
    with _open_text(path) as fh:
        capacity = _count_lines(path) + 1
        state = {}

        def on_header(header):
            names, input_kind, input_cols, channel_cols, extra_cols = _map_header(path, header)
            state.update(index={name: j for j, name in enumerate(names)}, input_kind=input_kind,
                         input_cols=input_cols, channel_cols=channel_cols, extra_cols=extra_cols,
                         cols=_Columns(capacity, channel_cols, input_cols, extra_cols))

        size = path.stat().st_size
        bar = _progress(size, path, progress)
        fields, lines = [], []
        try:
            for line, row in _rows(path, fh, on_header):
                fields.append(row)
                lines.append(line)
                if len(fields) == _CHUNK_ROWS:
                    _process_chunk(path, state["cols"], fields, lines, state["index"], state["input_cols"],
                                   state["channel_cols"], state["extra_cols"])
                    fields, lines = [], []
                    if bar is not None:
                        bar.update(fh.buffer.tell() - bar.n if hasattr(fh, "buffer") else 0)
            if fields:
                _process_chunk(path, state["cols"], fields, lines, state["index"], state["input_cols"],
                               state["channel_cols"], state["extra_cols"])
        except UnicodeDecodeError as exc:
            where = _bad_utf8(path)
            offset, line, reason = where if where else (exc.start, None, exc.reason)
            raise RunLogError(f"{path}: file line {line} (byte offset {offset}): not UTF-8 text ({reason}); "
                              f"expected a udrobot-run/1 CSV") from exc
        finally:
            if bar is not None:
                bar.close()
    cols = state["cols"]
    n = cols.n
    if not n:
        raise RunLogError(f"{path}: no data rows after the header; a run needs at least one sample")

    def trim(a):
        return a[:n] if n > 0.9 * a.shape[0] else a[:n].copy()

    t = trim(cols.t)
    extra = {c: trim(v) for c, v in cols.extra.items() if c not in cols.text_extra}
    if cols.text_extra:
        extra.update(_text_columns(path, sorted(cols.text_extra), state["index"], n))
    extra = {c: extra[c] for c in state["extra_cols"]}
    segment = None
    if SEGMENT in extra:
        segment = check_segments(extra[SEGMENT], path, cols.lines[:n])
        extra[SEGMENT] = segment.astype(float)
    check_time_gaps(t, path, cols.lines, segment)
    check_context_columns(extra, path, cols.lines)
    channels = {c: trim(v) for c, v in cols.channels.items()}
    inputs = trim(cols.inputs)
    check_measured_values(channels, state["input_kind"], inputs, extra, path, cols.lines)
    metadata = read_metadata(path.with_suffix(".json")) if path.with_suffix(".json").exists() else {}
    return Run(path=str(path), t=t, channels=channels,
               input_kind=state["input_kind"], inputs=inputs, extra=extra, metadata=metadata)


def _progress(total_bytes: int, path, progress):
    """A tqdm bar over bytes, or None (``progress`` None: on a terminal and for files over 50 MB)."""
    if progress is False or (progress is None and total_bytes < 50e6):
        return None
    from tqdm import tqdm

    return tqdm(total=total_bytes, unit="B", unit_scale=True, desc=f"reading {Path(path).name}",
                disable=None if progress is None else False, leave=False)


# ----------------------------------------------------------------------------------------------- metadata


def _finite_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def validate_metadata(meta, source="metadata") -> dict:
    """Check a sidecar dict against ``udrobot-run/1``; return a copy (unknown keys kept).

    Raises
    ------
    RunLogError
        Naming ``source`` and the offending field (e.g. ``walls[1].normal``) and what was expected.
    """
    if not isinstance(meta, dict):
        raise RunLogError(f"{source}: expected a JSON object with keys {', '.join(METADATA_KEYS)}, "
                          f"got {type(meta).__name__}")
    out = dict(meta)
    if "format" in meta and meta["format"] != FORMAT:
        raise RunLogError(f"{source}: field 'format' is {meta['format']!r}; expected {FORMAT!r}")
    for key in ("vehicle", "notes"):
        if key in meta and not isinstance(meta[key], str):
            raise RunLogError(f"{source}: field '{key}' must be a string, got {meta[key]!r}")
    if "water_density" in meta:
        rho = meta["water_density"]
        if not _finite_number(rho) or not 900.0 <= rho <= 1100.0:
            raise RunLogError(f"{source}: field 'water_density' = {rho!r}; expected a number in kg/m^3 "
                              f"between 900 and 1100 (fresh water 1000, sea water 1025)")
    if "seabed_depth" in meta and meta["seabed_depth"] is not None:
        depth = meta["seabed_depth"]
        if not _finite_number(depth) or depth <= 0:
            raise RunLogError(f"{source}: field 'seabed_depth' = {depth!r}; expected a positive number, m "
                              f"(NED z of the floor, positive down)")
    if "walls" in meta:
        walls = meta["walls"]
        if not isinstance(walls, list):
            raise RunLogError(f"{source}: field 'walls' must be a list of {{point, normal}} objects, got {walls!r}")
        for i, wall in enumerate(walls):
            where = f"{source}: field 'walls[{i}]'"
            if not isinstance(wall, dict) or set(wall) - {"point", "normal"} or not {"point", "normal"} <= set(wall):
                raise RunLogError(f"{where}: expected an object with exactly 'point' and 'normal', got {wall!r}")
            for key in ("point", "normal"):
                vec = wall[key]
                if not (isinstance(vec, list) and len(vec) == 3 and all(_finite_number(v) for v in vec)):
                    raise RunLogError(f"{where}.{key}: expected 3 finite numbers [x, y, z] (m, NED), got {vec!r}")
            norm = math.sqrt(sum(v * v for v in wall["normal"]))
            if abs(norm - 1.0) > 1e-3:
                raise RunLogError(f"{where}.normal: must be a unit vector (|n| = {norm:.6g})")
            if abs(wall["normal"][2]) > 1e-3:
                raise RunLogError(f"{where}.normal: walls are vertical planes, the normal's z component must be 0 "
                                  f"(got {wall['normal'][2]!r})")
    if "cut" in meta:
        _check_cut(meta["cut"], f"{source}: field 'cut'")
    if "channels" in meta:
        _check_channels(meta["channels"], f"{source}: field 'channels'")
    for key in (LOGGED_PARAMS, ESTIMATED_PARAMS):  # the autopilot's parameters: checked once, here
        if key in meta:
            try:
                out[key] = check_log_params(meta[key], f"{source}: field '{key}'")
            except ParameterError as exc:
                raise RunLogError(str(exc)) from None
    return out


def _check_channels(channels, where: str) -> None:
    """Check the sidecar's ``channels`` entry: column -> {"source": str, "kind": one of CHANNEL_KINDS, ...}."""
    if not isinstance(channels, dict):
        raise RunLogError(f"{where}: expected an object of column -> {{\"source\", \"kind\"}}, got {channels!r}")
    for column, entry in channels.items():
        if not isinstance(entry, dict) or not isinstance(entry.get("source", ""), str) \
                or entry.get("kind") not in CHANNEL_KINDS:
            raise RunLogError(f"{where}.{column}: expected {{\"source\": text, \"kind\": "
                              f"{' | '.join(CHANNEL_KINDS)}}}, got {entry!r}")


@dataclass(frozen=True)
class ChannelSource:
    """How one column of a run was obtained (the sidecar's ``channels`` entry).

    Attributes
    ----------
    column : str
    source : str
        Sensor / message and field, e.g. ``XKF1.VN/VE/VD (world_to_body)``.
    kind : str
        One of :data:`CHANNEL_KINDS`.
    aiding : str
        For a judged estimate, the evidence (which sources the filter had and what the log shows of them).
    """

    column: str
    source: str
    kind: str
    aiding: str = ""


def channel_sources(metadata) -> dict:
    """column -> :class:`ChannelSource` of a run's sidecar ``channels`` entry; a column without an entry is
    ``measured`` (and absent here)."""
    entries = (metadata or {}).get("channels") or {}
    return {c: ChannelSource(c, str(e.get("source", "")), e["kind"], str(e.get("aiding", "")))
            for c, e in entries.items() if isinstance(e, dict) and e.get("kind") in CHANNEL_KINDS}


def unaided_channels(metadata) -> dict:
    """column -> :class:`ChannelSource` of the run's ``estimated-unaided`` columns (dead reckoning): a consumer shows
    them but never fits to them, scores them or counts them as observed."""
    return {c: s for c, s in channel_sources(metadata).items() if s.kind == UNAIDED}


def _check_cut(cut, where: str) -> None:
    """Check the sidecar's ``cut`` record (what a converter's cut kept; docs/formats/runlog.md)."""
    if not isinstance(cut, dict) or not {"invalid_share", "kept"} <= set(cut):
        raise RunLogError(f"{where}: expected an object with 'invalid_share' and 'kept', got {cut!r}")
    share = cut["invalid_share"]
    if not isinstance(share, dict) or not all(isinstance(k, str) and _finite_number(v) and 0 <= v <= 1
                                              for k, v in share.items()):
        raise RunLogError(f"{where}.invalid_share: expected an object of check -> fraction of the rows failing it "
                          f"(0 to 1), got {share!r}")
    kept = cut["kept"]
    if kept is None:
        return
    if not isinstance(kept, dict) or not {"t_start", "t_stop", "rows", "of"} <= set(kept):
        raise RunLogError(f"{where}.kept: expected null (no row kept) or an object with 't_start', 't_stop', 'rows' "
                          f"and 'of', got {kept!r}")
    if not (_finite_number(kept["t_start"]) and _finite_number(kept["t_stop"]) and kept["t_start"] <= kept["t_stop"]):
        raise RunLogError(f"{where}.kept: 't_start' and 't_stop' must be finite times, s, t_start <= t_stop, got "
                          f"{kept['t_start']!r}, {kept['t_stop']!r}")
    rows, n = kept["rows"], kept["of"]
    whole = [isinstance(v, int) and not isinstance(v, bool) for v in (rows if isinstance(rows, list) else [])]
    if not (isinstance(rows, list) and len(rows) == 2 and all(whole) and isinstance(n, int)
            and 0 <= rows[0] <= rows[1] < n):
        raise RunLogError(f"{where}.kept: 'rows' must be [first, last] row indices of the converted log and 'of' its "
                          f"row count (0 <= first <= last < of), got rows {rows!r}, of {n!r}")
    if "segments" in kept:
        _check_cut_segments(kept["segments"], rows, f"{where}.kept.segments")


def _check_cut_segments(segments, span, where: str) -> None:
    """Check ``cut.kept.segments``: per kept segment its number, ``t_start``, ``t_stop`` and ``rows`` [first, last]
    (rows of the converted log), in order, disjoint and inside the kept span ``span`` [first, last]."""
    if not isinstance(segments, list) or not segments:
        raise RunLogError(f"{where}: expected a non-empty list of {{segment, t_start, t_stop, rows}} objects, got "
                          f"{segments!r}")
    last = span[0] - 1
    for i, seg in enumerate(segments):
        at = f"{where}[{i}]"
        if not isinstance(seg, dict) or not {"segment", "t_start", "t_stop", "rows"} <= set(seg):
            raise RunLogError(f"{at}: expected an object with 'segment', 't_start', 't_stop' and 'rows', got {seg!r}")
        rows = seg["rows"]
        whole = isinstance(rows, list) and len(rows) == 2 and all(isinstance(v, int) and not isinstance(v, bool)
                                                                  for v in rows)
        if not (isinstance(seg["segment"], int) and _finite_number(seg["t_start"]) and _finite_number(seg["t_stop"])
                and seg["t_start"] <= seg["t_stop"] and whole and last < rows[0] <= rows[1] <= span[1]):
            raise RunLogError(f"{at}: expected an integer 'segment', times t_start <= t_stop (s) and 'rows' [first, "
                              f"last] after the previous segment's and within the kept rows {span!r}, got {seg!r}")
        last = rows[1]


def read_metadata(path) -> dict:
    """Read and validate a sidecar ``NAME.json``."""
    path = Path(path)
    try:
        meta = loads_json(path.read_text(encoding="utf-8"), path, object_pairs_hook=unique_keys(path))
    except NestingError as exc:
        raise RunLogError(str(exc)) from None
    except UnicodeDecodeError as exc:
        raise RunLogError(f"{path}: byte offset {exc.start}: not UTF-8 text; expected JSON metadata") from exc
    except json.JSONDecodeError as exc:
        raise RunLogError(f"{path}: line {exc.lineno} column {exc.colno}: invalid JSON ({exc.msg})") from exc
    except ValueError as exc:  # a key given twice (unique_keys)
        raise RunLogError(str(exc)) from None
    return validate_metadata(meta, str(path))


# ----------------------------------------------------------------------------------------------- writing


def _format(value: float) -> str:
    return "" if math.isnan(value) else repr(float(value))


_WRITE_CHUNK = 65536  # rows formatted per batch when writing


def write_run(path, t, channels, input_kind, inputs, metadata=None, extra=None, *, overwrite=True,
              protect=()) -> Path:
    """Write a ``udrobot-run/1`` CSV (and the sidecar ``NAME.json`` if ``metadata`` is given), atomically.

    Parameters
    ----------
    path : str or Path
        Output CSV.
    t : (n,) array_like
        Strictly increasing finite sample times, s.
    channels : dict of str -> (n,) array_like
        Measured channels among :data:`CHANNELS` (m, rad, m/s, rad/s, V); nan for not measured.
    input_kind : {'thrust', 'pwm', 'tau'}
        What the inputs are: thrusts, ESC commands or a body wrench.
    inputs : (n, k) array_like
        Commanded inputs (N, µs or N/N m); k = 6 for 'tau'.
    metadata : dict, optional
        Sidecar content; validated; ``format`` is added.
    extra : dict of str -> (n,) array_like, optional
        Additional columns (numeric or strings), written after the standard ones. A ``segment`` column is checked
        (:func:`check_segments`) and written as integers; the intervals between segments are not gap-checked.
    overwrite : bool
        If False, refuse to replace an existing CSV or sidecar. With True, a stale sidecar of the replaced
        run is replaced too (by ``metadata``, or by ``{"format": "udrobot-run/1"}``).
    protect : iterable of paths
        Input files (and their sidecars) the output must not be (:mod:`udrobot_files.output`).

    Returns
    -------
    Path
        The CSV path. The data are validated before anything is written; a failure leaves existing files intact.
    """
    path = Path(path)
    where = str(path)
    t = np.asarray(t, dtype=float).reshape(-1)
    n = t.shape[0]
    if n == 0:
        raise RunLogError(f"{where}: no samples to write")
    if not np.all(np.isfinite(t)):
        raise RunLogError(f"{_where(where, row=int(np.flatnonzero(~np.isfinite(t))[0]) + 1, column='t')}: "
                          f"t must be finite")
    bad = np.flatnonzero(~(np.diff(t) > 0))
    if bad.size:
        raise RunLogError(f"{_where(where, row=int(bad[0]) + 2, column='t')}: t must be strictly increasing")
    segment = None
    if extra and SEGMENT in extra:
        segment = check_segments(extra[SEGMENT], where)
        if segment.shape != (n,):
            raise RunLogError(f"{where}: column '{SEGMENT}' has shape {segment.shape}, expected ({n},)")
        extra = {**extra, SEGMENT: segment.astype(str)}  # written as integers ("2", not "2.0")
    check_time_gaps(t, where, segment=segment)
    inputs = np.asarray(inputs, dtype=float)
    if inputs.ndim == 1:
        inputs = inputs[:, None]
    if inputs.ndim != 2 or inputs.shape[0] != n or inputs.shape[1] == 0:
        raise RunLogError(f"{where}: inputs must be (n, k) with n = {n}, got shape {inputs.shape}")
    cols = {"t": t}
    for c, values in zip(input_column_names(input_kind, inputs.shape[1]), inputs.T):
        cols[c] = values
    for c, values in (channels or {}).items():
        if c not in CHANNELS:
            raise RunLogError(f"{where}: column '{c}': unknown channel; expected one of {', '.join(CHANNELS)} "
                              f"(put other data in extra=)")
        cols[c] = np.asarray(values, dtype=float).reshape(-1)
    for c, values in (extra or {}).items():
        if c in cols or c.strip() != c or not c or any(ch in c for ch in ',"\n\r'):
            raise RunLogError(f"{where}: extra column {c!r} clashes with a standard column or is not a plain name")
        arr = np.asarray(values)
        cols[c] = arr.astype(float) if arr.dtype.kind in "biuf" else arr.astype(str)
    for c, values in cols.items():
        if values.shape != (n,):
            raise RunLogError(f"{where}: column '{c}' has shape {values.shape}, expected ({n},)")
        if values.dtype.kind == "f" and c not in (extra or {}) and np.any(np.isinf(values)):
            row = int(np.flatnonzero(np.isinf(values))[0]) + 1
            raise RunLogError(f"{_where(where, row=row, column=c)}: infinite value; expected finite or nan")
    meta = None
    if metadata is not None:
        meta = validate_metadata({"format": FORMAT, **metadata}, f"{path.with_suffix('.json')} (metadata)")
    side = files.sidecar(path)
    if not overwrite:
        for f in (path, side):
            if f.exists() or f.is_symlink():
                raise RunLogError(f"{f}: exists; refusing to overwrite (pass overwrite=True / --force)")
    if meta is None and (side.exists() or side.is_symlink()):
        meta = {"format": FORMAT}  # replace a stale sidecar: it described the file being replaced

    columns = [(v.dtype.kind == "f", v) for v in cols.values()]
    with files.open_atomic(path, "w", protect=protect) as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(list(cols))
        for start in range(0, n, _WRITE_CHUNK):
            stop = min(n, start + _WRITE_CHUNK)
            writer.writerows([_format(v[i]) if is_float else str(v[i]) for is_float, v in columns]
                             for i in range(start, stop))
        # the CSV on disk (a full disk shows at latest in fsync) before its sidecar, and the sidecar in place
        # before the CSV is renamed: a write that fails leaves neither a run without its sidecar nor a sidecar
        # describing a run that is not there
        fh.flush()
        os.fsync(fh.fileno())
        if meta is not None:
            files.atomic_write(side, json.dumps(meta, indent=2) + "\n", protect=protect)
    return path


def write(run: Run, path, *, overwrite=True, protect=()) -> Path:
    """Write a :class:`Run` (channels, inputs, extra and metadata) to ``path``."""
    return write_run(path, run.t, run.channels, run.input_kind, run.inputs, metadata=run.metadata or None,
                     extra=run.extra, overwrite=overwrite, protect=protect)


# ----------------------------------------------------------------------------------------------- resampling


def _wrap_like(values: np.ndarray, original: np.ndarray) -> np.ndarray:
    finite = original[np.isfinite(original)]
    if finite.size == 0:
        return values
    if finite.min() >= 0.0 and finite.max() < 2 * np.pi:
        return np.mod(values, 2 * np.pi)
    if finite.min() >= -np.pi and finite.max() <= np.pi:
        return (values + np.pi) % (2 * np.pi) - np.pi
    return values  # the log already stores a continuous (unwrapped) angle


def interpolate_linear(t: np.ndarray, y: np.ndarray, t_new: np.ndarray, angle: bool = False) -> np.ndarray:
    """Linear interpolation that never bridges a gap: nan if either neighbouring sample is nan or t_new is outside.

    Angles (rad) are unwrapped over their finite samples first and wrapped back to the log's own range.
    """
    y = np.asarray(y, dtype=float)
    work = y.copy()
    if angle:
        ok = np.isfinite(work)
        if ok.any():
            work[ok] = np.unwrap(work[ok])
    out = np.full(t_new.shape, np.nan)
    inside = (t_new >= t[0]) & (t_new <= t[-1])
    if t.size == 1:
        out[inside] = work[0]
    else:
        i0 = np.clip(np.searchsorted(t, t_new, side="right") - 1, 0, t.size - 2)
        w = (t_new - t[i0]) / (t[i0 + 1] - t[i0])
        a, b = work[i0], work[i0 + 1]
        with np.errstate(invalid="ignore"):
            val = np.where(w == 0.0, a, np.where(w == 1.0, b, a + w * (b - a)))
        valid = ((w == 0.0) & np.isfinite(a)) | ((w == 1.0) & np.isfinite(b)) | (np.isfinite(a) & np.isfinite(b))
        val = np.where(valid, val, np.nan)
        out[inside] = val[inside]
    return _wrap_like(out, y) if angle else out


def hold_previous(t: np.ndarray, y: np.ndarray, t_new: np.ndarray) -> np.ndarray:
    """Zero-order hold: the last sample at or before each t_new (nan before the first sample). Works on (n, ...)."""
    y = np.asarray(y)
    idx = np.searchsorted(t, t_new, side="right") - 1
    out = y[np.clip(idx, 0, None)]
    if out.dtype.kind == "f":
        out = out.copy()
        out[idx < 0] = np.nan
    return out


def resample(run: Run, t_new) -> Run:
    """The run on a new time base: linear for measured channels (angles unwrapped), zero-order hold for inputs.

    Extra columns use zero-order hold (they are of unknown meaning; holding never invents values).
    Samples of t_new outside [t[0], t[-1]] get nan channels; inputs before t[0] are nan. A run of several segments
    is interpolated within each segment: samples of t_new between two segments get nan channels (the rows cut
    there are not bridged), and the ``segment`` column is held like the other extra columns.

    Parameters
    ----------
    run : Run
        The run to resample.
    t_new : (m,) array_like
        Strictly increasing finite times, s.

    Returns
    -------
    Run
        The run on ``t_new``, with the same columns and metadata.
    """
    t_new = np.asarray(t_new, dtype=float).reshape(-1)
    if t_new.size == 0 or not np.all(np.isfinite(t_new)) or np.any(np.diff(t_new) <= 0):
        raise RunLogError(f"{run.path or 'run'}: resample times must be finite and strictly increasing")
    channels = {c: np.full(t_new.shape, np.nan) for c in run.channels}
    for a, b in run.segment_bounds():
        inside = (t_new >= run.t[a]) & (t_new <= run.t[b - 1])
        for c, y in run.channels.items():
            channels[c][inside] = interpolate_linear(run.t[a:b], y[a:b], t_new[inside], angle=c in ANGLE_CHANNELS)
    inputs = hold_previous(run.t, run.inputs, t_new)
    extra = {c: hold_previous(run.t, y, t_new) for c, y in run.extra.items()}
    return replace(run, t=t_new, channels=channels, inputs=inputs, extra=extra)
