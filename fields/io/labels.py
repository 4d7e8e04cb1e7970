"""Row labels (image names, point ids) as codes into their distinct values: one object per distinct label.

A measurement file of 5 M rows names a few thousand images and points; its labels are held as int32 codes
(4 bytes a row) into the distinct labels, in order of first appearance, instead of a Python object a row.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Labels:
    """Labels of n rows: `codes` (n,) int32 into `names` (m,) object, the distinct labels in order of first
    appearance (a subset may leave some names unused)."""

    codes: np.ndarray
    names: np.ndarray

    def __len__(self) -> int:
        return len(self.codes)

    @classmethod
    def of(cls, values) -> "Labels":
        """The labels of any array or sequence of hashable values (strings, ints): codes by first appearance."""
        if isinstance(values, Labels):
            return values
        arr = np.asarray(values)
        index: dict = {}
        put = index.setdefault
        codes = np.fromiter((put(v, len(index)) for v in arr.ravel().tolist()), np.int32, arr.size)
        names = np.empty(len(index), dtype=object)
        names[:] = list(index)
        return cls(codes, names)

    def values(self) -> np.ndarray:
        """The label of every row as an object array (the distinct objects shared, not copied)."""
        return self.names[self.codes]

    def subset(self, mask) -> "Labels":
        """The rows where `mask` is true (or the rows of an index array); the names are kept."""
        return Labels(self.codes[mask], self.names)

    def as_str(self) -> "Labels":
        """The labels compared as text (`str` of each distinct value; equal texts merged into one code)."""
        text = [str(v) for v in self.names.tolist()]
        if all(type(v) is str for v in self.names.tolist()) and len(set(text)) == len(text):
            return self
        merged = Labels.of(text)
        return Labels(merged.codes[self.codes], merged.names)

    def present(self) -> np.ndarray:
        """Codes that occur, in order of their first row."""
        if not len(self.codes):
            return np.zeros(0, np.int32)
        first = np.full(len(self.names), len(self.codes), np.int64)
        np.minimum.at(first, self.codes, np.arange(len(self.codes)))
        seen = np.flatnonzero(first < len(self.codes))
        return seen[np.argsort(first[seen], kind="stable")].astype(np.int32)

    def counts(self) -> np.ndarray:
        """(m,) rows of every name."""
        return np.bincount(self.codes, minlength=len(self.names))
