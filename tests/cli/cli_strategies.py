"""Hypothesis strategies of bad inputs: spoiled text tables, bytes that are not text, bad YAML fields,
bad option values. Every value drawn here is invalid by construction, so a command must reject it."""

from __future__ import annotations

import math
import string
from typing import Any

from hypothesis import strategies as st

Rows = list[list[str]]


def _numeric(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True


words = st.text(alphabet=string.ascii_letters + "_:;!?", min_size=1, max_size=8).filter(
    lambda s: not _numeric(s)
)
nonfinite = st.sampled_from(["nan", "NaN", "inf", "-inf", "1e400", "-1e999"])
absurd = st.sampled_from(["1e308", "-1e300", "3e12", "1e20"])


@st.composite
def spoiled_table(draw: st.DrawFn, rows: Rows, value_cols: tuple[int, ...]) -> bytes:
    """``rows`` (a valid table) spoiled one way: a word, a NaN, an absurd value, a ragged row, time
    going backwards or repeating, a stamp beyond int64, no data, or bytes that are not text."""
    rows = [list(r) for r in rows]
    n = len(rows)
    i = draw(st.integers(1, n - 1))
    kind = draw(
        st.sampled_from(
            [
                "word",
                "nonfinite",
                "absurd",
                "ragged",
                "backwards",
                "repeat",
                "int64",
                "empty",
                "binary",
                "utf16le",
                "nul",
            ]  # fmt: skip
        )
    )
    if kind == "word":
        rows[i][draw(st.integers(0, len(rows[i]) - 1))] = draw(words)
    elif kind == "nonfinite":
        rows[i][draw(st.sampled_from(value_cols))] = draw(nonfinite)
    elif kind == "absurd":
        rows[i][draw(st.sampled_from(value_cols))] = draw(absurd)
    elif kind == "ragged":
        k = len(rows[i])
        if draw(st.booleans()):
            rows[i] = rows[i][: draw(st.integers(1, k - 1))]
        else:
            rows[i] = rows[i] + [draw(st.sampled_from(["0", "1.5", "-2"]))] * draw(
                st.integers(1, 4)
            )
    elif kind == "backwards":
        rows[i][0] = f"{float(rows[i - 1][0]) - draw(st.floats(0.001, 10.0)):.4f}"
    elif (
        kind == "repeat"
    ):  # one stamp again (a regular pattern of repeats is quantisation, repaired)
        rows[i][0] = rows[i - 1][0]
    elif kind == "int64":
        rows[i][0] = draw(st.sampled_from(["99999999999999999999999", "1e20", "9.3e18"]))
    elif kind == "empty":
        return draw(
            st.sampled_from([b"", b"\n\n", b"# only a comment\n", b"t ax ay az gx gy gz\n"])
        )
    text = "".join(" ".join(r) + "\n" for r in rows)
    if kind == "binary":
        return (
            draw(st.binary(min_size=1, max_size=64).filter(lambda b: _not_utf8(b))) + text.encode()
        )
    if kind == "utf16le":
        return text.encode("utf-16-le")  # no BOM: NUL bytes everywhere
    if kind == "nul":
        k = draw(st.integers(0, len(text) - 1))
        return (text[:k] + "\x00" + text[k:]).encode()
    return text.encode()


def _not_utf8(b: bytes) -> bool:
    try:
        b.decode("utf-8")
    except UnicodeDecodeError:
        return True
    return False


def bad_float(lo: float | None = None, hi: float | None = None) -> st.SearchStrategy[str]:
    """A float option value outside ``[lo, hi]``, non-finite or not a number at all."""
    outs: list[st.SearchStrategy[float]] = []
    if lo is not None:
        outs.append(st.floats(max_value=lo, exclude_max=True, allow_nan=False, allow_infinity=False,
                              min_value=-1e12))  # fmt: skip
    if hi is not None:
        outs.append(st.floats(min_value=hi, exclude_min=True, allow_nan=False, allow_infinity=False,
                              max_value=1e12))  # fmt: skip
    nums = st.one_of(*outs).map(repr) if outs else st.nothing()
    return st.one_of(nums, st.sampled_from(["nan", "inf", "-inf"]), words)


def bad_int(lo: int | None = None, hi: int | None = None) -> st.SearchStrategy[str]:
    outs: list[st.SearchStrategy[int]] = []
    if lo is not None:
        outs.append(st.integers(-(10**9), lo - 1))
    if hi is not None:
        outs.append(st.integers(hi + 1, 10**9))
    return st.one_of(st.one_of(*outs).map(str), st.sampled_from(["1.5", "x", "nan"]))


def bad_choice(allowed: tuple[str, ...]) -> st.SearchStrategy[str]:
    return st.one_of(words, st.sampled_from(["", "SE3", "plus ", "m/s2"])).filter(
        lambda s: s not in allowed
    )


#: Wrong values of a calibration.yaml's fields: (field path, value) with every value invalid there.
def bad_calibration_field() -> st.SearchStrategy[tuple[str, Any]]:
    triad_bad = st.one_of(
        st.lists(st.floats(-2, 2), max_size=3), st.just("abc"), st.integers(), st.none()
    )
    matrix_bad = st.one_of(
        st.just([[1, 0], [0, 1]]), st.just("eye"), st.just([[1, 0, 0], [0, 1, 0], [0, 0, "x"]]),
        st.just([[1, 0, 0], [0, 1, 0], [0, 0, math.nan]]),
    )  # fmt: skip
    return st.one_of(
        st.tuples(st.just("units"), st.one_of(st.just("counts"), st.lists(st.integers(), max_size=2))),
        st.tuples(st.just("units.accel_in"), st.one_of(words, st.just("rad/s"), st.integers())),
        st.tuples(st.just("units.gyro_in"), st.one_of(words, st.just("m/s^2"), st.floats(0, 1))),
        st.tuples(st.just("g"), st.one_of(words, st.floats(-100, 9.6), st.floats(10.0, 1e6), st.none())),
        st.tuples(st.sampled_from(["accel", "gyro"]), triad_bad),
        st.tuples(st.sampled_from(["accel.T", "gyro.T"]), matrix_bad),
        st.tuples(st.sampled_from(["accel.K", "gyro.b"]), st.one_of(st.just([1, 2]), words)),
        st.tuples(st.sampled_from(["accel.bias_sign", "gyro.bias_sign"]), words),
        st.tuples(st.sampled_from(["cov_accel", "cov_gyro_bias"]), st.one_of(words, st.just([[1, 2]]))),
        st.tuples(st.just("notes"), st.one_of(words, st.lists(st.integers(), min_size=1))),
    )  # fmt: skip


def set_field(d: dict[str, Any], path: str, value: Any) -> None:
    keys = path.split(".")
    for k in keys[:-1]:
        if not isinstance(d.get(k), dict):
            d[k] = {}
        d = d[k]
    d[keys[-1]] = value
