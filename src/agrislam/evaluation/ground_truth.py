"""The true objects of a survey as arrays, so that a whole field's truth is scored without a
Python object per plant."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from agrislam.growing import GrowingRows
from agrislam.records import TruthObject

NO_TEXT = -1  # the code of a row without the attribute's text value


class TruthObjects:
    """A row per truth id, numbered in the order the ids come (`number`); a later record
    of an id replaces its row (a later survey day's truth). A row known only by its id
    (a detection's truth) has no position until its record comes. Attributes by name:
    text values as codes into the name's values, numbers as floats (NaN: none)."""

    def __init__(self) -> None:
        self.numbers: dict[str, int] = {}  # truth id -> its row
        self._xy = GrowingRows((2,))
        self._text: dict[str, tuple[dict[str, int], GrowingRows]] = {}  # values, codes
        self._values: dict[str, GrowingRows] = {}

    @classmethod
    def of(cls, records: Iterable[TruthObject]) -> TruthObjects:
        table = cls()
        for record in records:
            table.add(record)
        return table

    def __len__(self) -> int:
        return len(self._xy)

    def number(self, truth_id: str) -> int:
        """The row of `truth_id`, a new one without a position the first time."""
        row = self.numbers.setdefault(truth_id, len(self.numbers))
        if row == len(self._xy):
            self._xy.append((np.nan, np.nan))
            for _, codes in self._text.values():
                codes.append(NO_TEXT)
            for values in self._values.values():
                values.append(np.nan)
        return row

    def add(self, record: TruthObject) -> None:
        row = self.number(record.id)
        self._xy.array[row] = record.xy
        for name, value in record.attributes.items():
            if isinstance(value, str):
                vocabulary, codes = self._text_column(name)
                codes.array[row] = vocabulary.setdefault(value, len(vocabulary))
            else:
                self._value_column(name).array[row] = float(value)

    def _text_column(self, name: str) -> tuple[dict[str, int], GrowingRows]:
        if name not in self._text:
            self._text[name] = ({}, self._without(np.int32, NO_TEXT))
        return self._text[name]

    def _value_column(self, name: str) -> GrowingRows:
        if name not in self._values:
            self._values[name] = self._without(np.float64, np.nan)
        return self._values[name]

    def _without(self, dtype: type, missing: float) -> GrowingRows:
        """A new attribute column, every row so far without it."""
        column = GrowingRows(dtype=dtype)
        column.extend(np.full(len(self), missing, dtype=dtype))
        return column

    def placed(self) -> np.ndarray:
        """The rows with a position (a record of their own)."""
        return np.flatnonzero(np.isfinite(self._xy.array[:, 0]))

    def xy(self, rows: np.ndarray) -> np.ndarray:
        return self._xy.array[rows]

    def text(self, name: str, rows: np.ndarray) -> np.ndarray:
        """The text value of attribute `name` at `rows` (None where a row has none)."""
        vocabulary, codes = self._text.get(name, ({}, None))
        out = np.full(len(rows), None, dtype=object)
        if codes is not None:
            words = np.array([*vocabulary, None], dtype=object)
            out[:] = words[codes.array[rows]]  # NO_TEXT picks the trailing None
        return out

    def values(self, name: str, rows: np.ndarray) -> np.ndarray:
        """The number of attribute `name` at `rows` (NaN where a row has none)."""
        column = self._values.get(name)
        return np.full(len(rows), np.nan) if column is None else column.array[rows]
